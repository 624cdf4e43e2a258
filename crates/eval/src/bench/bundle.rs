//! Bundle adjustment on a BAL problem (compare with Ceres' `bundle_adjuster`: cost `½Σ‖r‖²`, no
//! gauge fixing, every camera refining its own `f, k1, k2`) or on a large synthetic problem
//! (testkit's ring scene, e.g. 1000 cameras × 200 000 points) that exercises the sparse Schur solver.

use std::path::PathBuf;
use std::str::FromStr;
use std::time::Instant;

use handheld_bundle::{
    bundle_adjust_metric, BundleOptions, IntrinsicsMask, LinearSolverKind, MetricBundleConfig,
    RobustLoss,
};
use handheld_core::Progress;
use serde::{Deserialize, Serialize};

use crate::error::{EvalError, Result};
use handheld_pipeline::Context;

/// The problem a bundle benchmark solves.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BundleProblem {
    /// A BAL problem file (`problem-49-7776-pre.txt`).
    Bal(PathBuf),
    /// Testkit's ring scene with this many cameras and points.
    Synthetic { cameras: usize, points: usize },
}

impl FromStr for BundleProblem {
    type Err = EvalError;

    /// `CAMERASxPOINTS`, e.g. `1000x200000`, as a synthetic problem.
    fn from_str(spec: &str) -> Result<Self> {
        let bad = || {
            EvalError::option(
                "--synthetic",
                format!("expects CAMERASxPOINTS (e.g. 1000x200000), got `{spec}`"),
            )
        };
        let (c, p) = spec.split_once(['x', 'X']).ok_or_else(bad)?;
        let cameras = c.trim().parse().map_err(|_| bad())?;
        let points = p.trim().parse().map_err(|_| bad())?;
        let problem = BundleProblem::Synthetic { cameras, points };
        problem.validate().map_err(|_| bad())?;
        Ok(problem)
    }
}

impl BundleProblem {
    fn validate(&self) -> Result<()> {
        match self {
            BundleProblem::Synthetic { cameras, points } if *cameras < 2 || *points < 1 => Err(
                EvalError::option("--synthetic", "needs at least 2 cameras and 1 point"),
            ),
            _ => Ok(()),
        }
    }
}

/// The robust loss of the benchmark.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BenchLoss {
    /// Plain least squares.
    #[default]
    None,
    /// Huber's loss with the robust scale.
    Huber,
    /// Cauchy's loss with the robust scale.
    Cauchy,
}

/// The linear solver of the reduced camera system.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BenchSolver {
    /// Dense up to the library's size limit, else sparse.
    #[default]
    Auto,
    /// Dense Schur complement.
    Dense,
    /// Sparse Schur complement.
    Sparse,
}

/// Options of the bundle benchmark.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct BundleBenchOptions {
    /// The problem. Default: synthetic 1000 × 200 000.
    pub problem: BundleProblem,
    /// Maximum Levenberg–Marquardt iterations. Default 50.
    pub iterations: usize,
    /// Robust loss. Default none.
    pub robust: BenchLoss,
    /// Scale of the robust loss in pixels. Default 1.
    pub robust_scale: f64,
    /// Worker threads (0: all cores). Default 0.
    pub threads: usize,
    /// Linear solver of the reduced camera system. Default auto.
    pub linear_solver: BenchSolver,
    /// Seed of the synthetic problem. Default 1.
    pub seed: u64,
}

impl Default for BundleBenchOptions {
    fn default() -> Self {
        Self {
            problem: BundleProblem::Synthetic {
                cameras: 1000,
                points: 200_000,
            },
            iterations: 50,
            robust: BenchLoss::None,
            robust_scale: 1.0,
            threads: 0,
            linear_solver: BenchSolver::Auto,
            seed: 1,
        }
    }
}

impl BundleBenchOptions {
    /// Checks the options (the bundle library checks its own again).
    pub fn validate(&self) -> Result<()> {
        self.problem.validate()?;
        if self.robust != BenchLoss::None
            && !(self.robust_scale.is_finite() && self.robust_scale > 0.0)
        {
            return Err(EvalError::option("--robust-scale", "must be positive"));
        }
        Ok(())
    }

    /// The bundle library's options.
    pub fn bundle_options(&self) -> BundleOptions {
        BundleOptions {
            max_iterations: self.iterations,
            loss: match self.robust {
                BenchLoss::None => RobustLoss::None,
                BenchLoss::Huber => RobustLoss::Huber(self.robust_scale),
                BenchLoss::Cauchy => RobustLoss::Cauchy(self.robust_scale),
            },
            linear_solver: match self.linear_solver {
                BenchSolver::Auto => LinearSolverKind::Auto,
                BenchSolver::Dense => LinearSolverKind::DenseSchur,
                BenchSolver::Sparse => LinearSolverKind::SparseSchur,
            },
            num_threads: self.threads,
            ..Default::default()
        }
    }
}

/// What the bundle benchmark measured (the fields of Ceres' summary that compare).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct BundleBenchReport {
    /// The BAL file, or `synthetic CxP`.
    pub problem: String,
    pub cameras: usize,
    pub points: usize,
    pub observations: usize,
    pub initial_cost: f64,
    pub final_cost: f64,
    pub initial_rms_px: f64,
    pub final_rms_px: f64,
    pub iterations: usize,
    pub successful_steps: usize,
    pub termination: String,
    pub total_seconds: f64,
    pub seconds_per_iteration: f64,
    pub linear_solver_seconds: f64,
    /// The solver actually used.
    pub linear_solver: String,
    /// Size of the reduced camera system.
    pub reduced_parameters: usize,
    pub threads: usize,
}

/// Loads or generates the problem and bundle-adjusts it.
pub fn bench_bundle(o: &BundleBenchOptions, progress: &dyn Progress) -> Result<BundleBenchReport> {
    o.validate()?;
    let options = o.bundle_options();
    let config = MetricBundleConfig {
        refine: IntrinsicsMask::focal_and_radial(),
        fix_first_view: false,
        ..Default::default()
    };
    let t_load = Instant::now();
    let (name, summary, (nc, np, no)) = match &o.problem {
        BundleProblem::Bal(path) => {
            let bal = handheld_io::bal::read_bal(path)?;
            let mut rec = bal.to_metric_reconstruction();
            let counts = (bal.cameras.len(), bal.points.len(), bal.observations.len());
            let load = t_load.elapsed().as_secs_f64();
            tracing::info!(load_seconds = load, "loaded {}", path.display());
            let s = bundle_adjust_metric(&mut rec, &config, &options)
                .with_context(|| format!("bundle adjustment of {}", path.display()))?;
            (path.display().to_string(), s, counts)
        }
        BundleProblem::Synthetic { cameras, points } => {
            let set = handheld_testkit::ring_set(&handheld_testkit::RingOptions {
                num_views: *cameras,
                num_points: *points,
                seed: o.seed,
                ..Default::default()
            })
            .context("generating the synthetic ring")?;
            let mut rec = set.initial;
            let counts = (
                *cameras,
                rec.points.len(),
                rec.views.values().map(|v| v.observations.len()).sum(),
            );
            tracing::info!(
                load_seconds = t_load.elapsed().as_secs_f64(),
                "generated the testkit ring scene"
            );
            progress.start("bundle adjustment", 0);
            let s = bundle_adjust_metric(&mut rec, &config, &options);
            progress.finish();
            let s = s.context("bundle adjustment of the synthetic ring")?;
            (format!("synthetic {cameras}x{points}"), s, counts)
        }
    };
    let s = summary;
    Ok(BundleBenchReport {
        problem: name,
        cameras: nc,
        points: np,
        observations: no,
        initial_cost: s.initial_cost,
        final_cost: s.final_cost,
        initial_rms_px: s.initial_rms_px,
        final_rms_px: s.final_rms_px,
        iterations: s.iterations,
        successful_steps: s.successful_steps,
        termination: s.termination.name().to_string(),
        total_seconds: s.total_seconds,
        seconds_per_iteration: s.total_seconds / s.iterations.max(1) as f64,
        linear_solver_seconds: s.linear_solver_seconds,
        linear_solver: s.linear_solver.name().to_string(),
        reduced_parameters: s.num_camera_parameters,
        threads: if options.num_threads == 0 {
            rayon::current_num_threads()
        } else {
            options.num_threads
        },
    })
}
