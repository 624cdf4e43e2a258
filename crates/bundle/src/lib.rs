//! Sparse Levenberg–Marquardt bundle adjustment with Schur complement, projective and metric (§3.3, §3.4).
//!
//! Bundle adjustment is the maximum-likelihood refinement of Pollefeys et al. (IJCV 2004) §3.3 (eq. 19,
//! projective cameras and homogeneous points) and §3.4 (metric cameras with intrinsics shared by groups of
//! views, radial distortion, and soft priors on the intrinsics). The engine follows Triggs et al.,
//! *Bundle Adjustment — A Modern Synthesis* (2000): the points are eliminated by the Schur complement
//! (§6.1 there) and the reduced camera system is solved by dense or sparse supernodal Cholesky (faer).
//! The damping is Ceres' Levenberg–Marquardt trust region (Ceres Solver docs, *Solving Non-linear Least
//! Squares*, §LevenbergMarquardt): `λ = 1/radius` scaled by the Jacobian diagonal, radius updated by the
//! gain ratio. The cost is `½ Σ ρ(‖r‖²)` as in Ceres.
//!
//! Split by concept:
//! - [`options`]: [`BundleOptions`], the [`BundleSummary`] report and the error type;
//! - [`loss`]: robust losses and Triggs' correction;
//! - [`problem`]: the flat [`Problem`] (parameter blocks and index arrays) and its cost;
//! - [`residual`]: one small residual function per camera model, with analytic Jacobians and the
//!   manifold updates (rotation, unit sphere);
//! - `structure` (private): the block layout of the reduced camera system;
//! - `schur`, `linear`, `lm` (private): linearisation, Schur complement, Cholesky, trust-region loop;
//! - [`metric`] and [`projective`]: the public entry points on the core reconstructions;
//! - [`covariance`]: marginal covariances of points and camera centres from the Schur system.
//!
//! Where the rest lives: shared intrinsics, masks (parameters held fixed), priors on the intrinsics and per-observation
//! σ are part of [`Problem`]; a step that gains more than its model promised is tried again longer
//! (`lm.rs`, [`BundleOptions::extrapolate`]); every point can be re-solved alone after each joint
//! step (`embedded.rs`, [`BundleOptions::embedded_point_iterations`]).

mod assembly;
pub mod covariance;
mod embedded;
mod linear;
mod lm;
pub mod loss;
pub mod metric;
pub mod options;
pub mod problem;
pub mod projective;
pub mod residual;
mod schur;
mod structure;

pub use covariance::{metric_uncertainty, MetricUncertainty, PointUncertainty};
pub use loss::RobustLoss;
pub use metric::{
    bundle_adjust_metric, bundle_adjust_metric_rolling, observation_sigma, GaussianPrior,
    IntrinsicParam, IntrinsicsMask, MetricBundleConfig, RollingShutter,
};
pub use options::{BundleError, BundleOptions, BundleSummary, LinearSolverKind, Termination};
pub use problem::{CameraModel, Problem};
pub use projective::{bundle_adjust_projective, ProjectiveBundleConfig};

/// Solves a [`Problem`] in place with Levenberg–Marquardt (see the crate documentation).
pub fn solve(problem: &mut Problem, options: &BundleOptions) -> Result<BundleSummary, BundleError> {
    lm::solve(problem, options, &handheld_core::NoProgress)
}

/// Like [`solve`], reporting one unit of progress per iteration.
pub fn solve_with_progress(
    problem: &mut Problem,
    options: &BundleOptions,
    progress: &dyn handheld_core::Progress,
) -> Result<BundleSummary, BundleError> {
    lm::solve(problem, options, progress)
}
