//! Options, the summary report and the error type of bundle adjustment. Options are plain data with
//! documented defaults (those of Ceres Solver's `Solver::Options` where a counterpart exists) and a
//! `validate()`.

use crate::loss::RobustLoss;

/// How the reduced camera system `S δc = b` (Triggs et al. 2000, eq. 6.2) is solved.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LinearSolverKind {
    /// Dense Cholesky for up to [`BundleOptions::dense_max_dimension`] reduced parameters, else sparse.
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
#[derive(Clone, Debug, PartialEq)]
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
    /// `Auto` uses dense Cholesky up to this many reduced (camera-side) parameters. Default 1500.
    pub dense_max_dimension: usize,
    /// Worker threads; 0 uses rayon's global pool. Default 0.
    pub num_threads: usize,
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
        }
    }
}

impl BundleOptions {
    pub fn validate(&self) -> Result<(), BundleError> {
        let bad = |what: &str| Err(BundleError::InvalidOptions(what.to_string()));
        let nonneg = [
            self.function_tolerance,
            self.gradient_tolerance,
            self.parameter_tolerance,
        ];
        if nonneg.iter().any(|v| !(v.is_finite() && *v >= 0.0)) {
            return bad("tolerances must be finite and non-negative");
        }
        if !(self.initial_trust_region_radius > 0.0
            && self.max_trust_region_radius >= self.initial_trust_region_radius
            && self.min_trust_region_radius >= 0.0
            && self.min_trust_region_radius < self.initial_trust_region_radius)
        {
            return bad("trust-region radii must satisfy 0 ≤ min < initial ≤ max");
        }
        if !(self.min_relative_decrease > 0.0 && self.min_relative_decrease < 1.0) {
            return bad("min_relative_decrease must lie in (0, 1)");
        }
        self.loss.validate().map_err(BundleError::InvalidOptions)
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
    #[error("invalid bundle adjustment options: {0}")]
    InvalidOptions(String),
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
