//! Options, the summary report and the error type of bundle adjustment. Options are plain data with
//! documented defaults (those of Ceres Solver's `Solver::Options` where a counterpart exists) and a
//! `validate()`.

use serde::{Deserialize, Serialize};

use crate::loss::RobustLoss;

/// How the reduced camera system `S δc = b` (Triggs et al. 2000, eq. 6.2) is solved.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LinearSolverKind {
    /// Sparse Cholesky beyond [`BundleOptions::dense_max_dimension`] reduced parameters, dense for
    /// small systems, and in between whichever the pattern favours: sparse when its factor (AMD
    /// ordering) costs at most a quarter of the dense one's flops, as a walk's banded system does.
    Auto,
    /// Dense Cholesky (faer, blocked) of the full reduced matrix.
    DenseSchur,
    /// Sparse supernodal Cholesky (faer) with an AMD ordering; the symbolic factorisation is computed
    /// once and reused at every iteration.
    SparseSchur,
}

impl LinearSolverKind {
    pub fn name(&self) -> &'static str {
        match self {
            LinearSolverKind::Auto => "auto",
            LinearSolverKind::DenseSchur => "dense_schur",
            LinearSolverKind::SparseSchur => "sparse_schur",
        }
    }
}

/// Levenberg–Marquardt options.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BundleOptions {
    /// Maximum number of iterations (linear solves, successful or not). Default 100.
    pub max_iterations: usize,
    /// Stop when `|Δcost| ≤ function_tolerance · cost`. Default 1e-6 (Ceres).
    pub function_tolerance: f64,
    /// Stop when the max-norm of the gradient is below this. Default 1e-10 (Ceres).
    pub gradient_tolerance: f64,
    /// Stop when `‖δ‖ ≤ parameter_tolerance · (‖x‖ + parameter_tolerance)`. Default 1e-8 (Ceres).
    pub parameter_tolerance: f64,
    /// Initial trust-region radius. Default 1e4 (Ceres).
    pub initial_trust_region_radius: f64,
    /// Maximum trust-region radius. Default 1e16 (Ceres).
    pub max_trust_region_radius: f64,
    /// The solve fails (termination [`Termination::NoConvergence`]) below this radius. Default 1e-32.
    pub min_trust_region_radius: f64,
    /// A step is accepted when the gain ratio exceeds this. Default 1e-3 (Ceres).
    pub min_relative_decrease: f64,
    /// Robust loss applied to each observation's squared reprojection error. Default none.
    pub loss: RobustLoss,
    /// Linear solver for the reduced camera system. Default [`LinearSolverKind::Auto`].
    pub linear_solver: LinearSolverKind,
    /// `Auto` never uses dense Cholesky beyond this many reduced (camera-side) parameters (below
    /// it, the pattern decides). Default 1500.
    pub dense_max_dimension: usize,
    /// Worker threads; 0 uses rayon's global pool. Default 0.
    pub num_threads: usize,
    /// Try an accepted step again longer when it gained more than its model promised (a robust
    /// loss in its linear part, see `lm::extrapolate`). Default true.
    pub extrapolate: bool,
    /// Gauss–Newton steps on each point alone, the cameras held, after every joint step and before
    /// its gain is measured (embedded point iterations, Jeong et al. 2012 §4.2; `embedded.rs`).
    /// They shorten the crawl of long chains of views near a minimum; from a rough start they can
    /// change which minimum is reached. Metric problems only. Default 0 (off).
    #[serde(default)]
    pub embedded_point_iterations: usize,
}

impl Default for BundleOptions {
    fn default() -> Self {
        Self {
            max_iterations: 100,
            function_tolerance: 1e-6,
            gradient_tolerance: 1e-10,
            parameter_tolerance: 1e-8,
            initial_trust_region_radius: 1e4,
            max_trust_region_radius: 1e16,
            min_trust_region_radius: 1e-32,
            min_relative_decrease: 1e-3,
            loss: RobustLoss::None,
            linear_solver: LinearSolverKind::Auto,
            dense_max_dimension: 1500,
            num_threads: 0,
            extrapolate: true,
            embedded_point_iterations: 0,
        }
    }
}

impl BundleOptions {
    /// Checks every option; the error names the first offending one.
    pub fn validate(&self) -> Result<(), BundleError> {
        let check = |ok: bool, option: &'static str, reason: &str| {
            if ok {
                Ok(())
            } else {
                Err(BundleError::InvalidOption {
                    option,
                    reason: reason.to_string(),
                })
            }
        };
        for (option, v) in [
            ("function_tolerance", self.function_tolerance),
            ("gradient_tolerance", self.gradient_tolerance),
            ("parameter_tolerance", self.parameter_tolerance),
        ] {
            check(
                v.is_finite() && v >= 0.0,
                option,
                "tolerances must be finite and non-negative",
            )?;
        }
        let radii = "trust-region radii must satisfy 0 ≤ min < initial ≤ max";
        let (initial, max, min) = (
            self.initial_trust_region_radius,
            self.max_trust_region_radius,
            self.min_trust_region_radius,
        );
        check(initial > 0.0, "initial_trust_region_radius", radii)?;
        check(max >= initial, "max_trust_region_radius", radii)?;
        check(
            min >= 0.0 && min < initial,
            "min_trust_region_radius",
            radii,
        )?;
        check(
            self.min_relative_decrease > 0.0 && self.min_relative_decrease < 1.0,
            "min_relative_decrease",
            "must lie in (0, 1)",
        )?;
        self.loss.validate()
    }
}

/// Why the solver stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Termination {
    FunctionTolerance,
    GradientTolerance,
    ParameterTolerance,
    MaxIterations,
    /// The trust region shrank below its minimum without an acceptable step.
    NoConvergence,
}

impl Termination {
    pub fn name(&self) -> &'static str {
        match self {
            Termination::FunctionTolerance => "function_tolerance",
            Termination::GradientTolerance => "gradient_tolerance",
            Termination::ParameterTolerance => "parameter_tolerance",
            Termination::MaxIterations => "max_iterations",
            Termination::NoConvergence => "no_convergence",
        }
    }

    /// True for the three tolerance criteria.
    pub fn converged(&self) -> bool {
        matches!(
            self,
            Termination::FunctionTolerance
                | Termination::GradientTolerance
                | Termination::ParameterTolerance
        )
    }
}

/// What a bundle adjustment did.
#[derive(Clone, Debug, PartialEq)]
pub struct BundleSummary {
    /// `½ Σ ρ(‖r‖²)` (plus prior terms) before and after.
    pub initial_cost: f64,
    pub final_cost: f64,
    /// Iterations (linear solves) and how many of them were accepted.
    pub iterations: usize,
    pub successful_steps: usize,
    pub termination: Termination,
    /// The linear solver actually used (`DenseSchur` or `SparseSchur`).
    pub linear_solver: LinearSolverKind,
    pub num_observations: usize,
    /// Free camera-side parameters (the size of the reduced system) and free point parameters.
    pub num_camera_parameters: usize,
    pub num_point_parameters: usize,
    /// Root mean square reprojection error (pixels, no loss) before and after.
    pub initial_rms_px: f64,
    pub final_rms_px: f64,
    /// Wall-clock seconds: everything, and the part spent in Cholesky factorisations and solves.
    pub total_seconds: f64,
    pub linear_solver_seconds: f64,
}

/// Errors of bundle adjustment. Finding no better solution is not an error (see [`Termination`]).
#[derive(Debug, thiserror::Error)]
pub enum BundleError {
    /// An option is out of its valid range; `option` is the field's name.
    #[error("invalid bundle adjustment option `{option}`: {reason}")]
    InvalidOption {
        option: &'static str,
        reason: String,
    },
    #[error("invalid bundle adjustment input: {0}")]
    InvalidInput(String),
    #[error("the initial cost is not finite (a point lies in a camera's focal plane, or a parameter is NaN)")]
    NonFiniteCost,
    #[error(
        "the reduced camera system is too large for {what}: {dimension} parameters (limit {limit})"
    )]
    TooLarge {
        what: &'static str,
        dimension: usize,
        limit: usize,
    },
    #[error("sparse Cholesky failed: {0}")]
    Linear(String),
}

#[cfg(test)]
mod tests {
    use super::*;

    fn option_of(o: BundleOptions) -> &'static str {
        match o.validate() {
            Err(BundleError::InvalidOption { option, .. }) => option,
            other => panic!("expected an option error, got {other:?}"),
        }
    }

    #[test]
    fn validate_names_the_option() {
        assert!(BundleOptions::default().validate().is_ok());
        let d = BundleOptions::default;
        let o = |f: fn(&mut BundleOptions)| {
            let mut o = d();
            f(&mut o);
            option_of(o)
        };
        assert_eq!(o(|o| o.gradient_tolerance = -1.0), "gradient_tolerance");
        assert_eq!(
            o(|o| o.initial_trust_region_radius = 0.0),
            "initial_trust_region_radius"
        );
        assert_eq!(
            o(|o| o.max_trust_region_radius = 1.0),
            "max_trust_region_radius"
        );
        assert_eq!(
            o(|o| o.min_trust_region_radius = 1e5),
            "min_trust_region_radius"
        );
        assert_eq!(
            o(|o| o.min_relative_decrease = 1.0),
            "min_relative_decrease"
        );
        assert_eq!(o(|o| o.loss = RobustLoss::Cauchy(f64::NAN)), "loss");
    }
}
