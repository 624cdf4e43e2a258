//! The Levenberg–Marquardt trust-region loop, as in Ceres Solver (`TrustRegionMinimizer` with the
//! `LevenbergMarquardtStrategy`): the damped system is `(JᵀJ + D/radius) δ = −Jᵀr` with `D` the diagonal
//! of `JᵀJ` after Jacobi scaling, clamped to `[1e-6, 1e32]`; the step is accepted when the gain ratio
//! (actual over model decrease) exceeds `min_relative_decrease`, then
//! `radius ← radius / max(1/3, 1 − (2ρ − 1)³)`; a rejected step divides the radius by a factor that
//! doubles at each consecutive failure. Stops on the gradient, step and relative-cost tolerances.
//! Optionally, every point is re-solved with the cameras held before a step's gain is measured
//! (embedded point iterations, `embedded.rs`).

use std::time::Instant;

use handheld_core::Progress;
use rayon::prelude::*;

use crate::assembly::assemble;
use crate::linear::{analyse, flop_ratio, Factorizer};
use crate::loss::RobustLoss;
use crate::options::{BundleError, BundleOptions, BundleSummary, LinearSolverKind, Termination};
use crate::problem::{CameraModel, Problem};
use crate::residual::{pose_plus, sphere_plus, NUM_INTRINSICS};
use crate::schur::{
    back_substitute, invert_points, jacobian_step_norm2, linearize, linearize_into, ReducedMatrix,
};
use crate::structure::Structure;

const MIN_DIAGONAL: f64 = 1e-6;
const MAX_DIAGONAL: f64 = 1e32;

/// Ceres' Jacobi scaling `s = 1/(1 + ‖column‖)`, computed once from the initial Jacobian.
#[inline]
fn jacobi_scale(h: f64) -> f64 {
    1.0 / (1.0 + h.sqrt())
}

/// Ceres' damping for one parameter with Jacobian column norm² `h` and scale `s`: `clamp(h s²)/radius`
/// in the scaled coordinates, returned in the original ones.
#[inline]
fn damping(h: f64, s: f64, radius: f64) -> f64 {
    (h * s * s).clamp(MIN_DIAGONAL, MAX_DIAGONAL) / radius / (s * s)
}

/// The parameter vectors that a step changes.
struct Params {
    cameras: Vec<[f64; 12]>,
    groups: Vec<[f64; NUM_INTRINSICS]>,
    points: Vec<[f64; 4]>,
}

fn swap_params(p: &mut Problem, x: &mut Params) {
    std::mem::swap(&mut p.cameras, &mut x.cameras);
    std::mem::swap(&mut p.groups, &mut x.groups);
    std::mem::swap(&mut p.points, &mut x.points);
}

/// A step that gained more than this multiple of the decrease its Gauss–Newton model promised is
/// tried again longer ([`extrapolate`]).
const EXTRAPOLATION_RATIO: f64 = 1.5;

/// Doublings of a step [`extrapolate`] tries at most.
const MAX_EXTRAPOLATIONS: usize = 3;

/// The accepted step `δ` (`p` holds `x ⊕ δ`, `old` holds `x`) tried again as `x ⊕ 2δ`, `x ⊕ 4δ`, …
/// while the cost keeps falling; `p` ends on the best of them. Returns its cost.
///
/// A robust loss in its linear part (Huber beyond its scale) has `ρ'' < 0`, which the
/// Gauss–Newton model drops (Triggs et al. 2000 §4.3): the model then overstates the curvature
/// and its step falls short. In a long, flat valley (the principal point against the rotations,
/// under a Huber scale of a few tenths of a pixel) every step gained twice what the model
/// promised, and the adjustment crawled for 100 iterations (fountain-P11: 3·10⁻⁶ of the cost per
/// step). A longer step is kept only where the cost says it is better.
fn extrapolate(
    p: &mut Problem,
    st: &Structure,
    old: &mut Params,
    dc: &[f64],
    dp: &[f64],
    cost: f64,
    loss: &RobustLoss,
) -> f64 {
    let mut best = cost;
    let mut factor = 1.0;
    for _ in 0..MAX_EXTRAPOLATIONS {
        factor *= 2.0;
        swap_params(p, old); // p: x, old: the best so far
        let dc2: Vec<f64> = dc.iter().map(|v| factor * v).collect();
        let dp2: Vec<f64> = dp.iter().map(|v| factor * v).collect();
        let mut longer = plus(p, st, &dc2, &dp2);
        swap_params(p, old); // p: the best so far, old: x
        swap_params(p, &mut longer); // p: the longer step, longer: the best so far
        let c = p.cost(loss);
        if c.is_finite() && c < best {
            best = c;
        } else {
            swap_params(p, &mut longer);
            break;
        }
    }
    best
}

/// `x ⊕ δ` on every block's manifold.
fn plus(p: &Problem, st: &Structure, dc: &[f64], dp: &[f64]) -> Params {
    let cameras = p
        .cameras
        .par_iter()
        .enumerate()
        .map(|(c, cam)| match st.cam_pose_at[c] {
            None => *cam,
            Some(i) => match p.model {
                CameraModel::Metric => pose_plus(cam, &dc[i..i + 6]),
                CameraModel::Projective => sphere_plus(cam, &dc[i..i + 11]),
            },
        })
        .collect();
    let mut groups = p.groups.clone();
    for (g, vals) in groups.iter_mut().enumerate() {
        for (k, v) in vals.iter_mut().enumerate() {
            if let Some(i) = st.group_param_at[g][k] {
                *v += dc[i];
            }
        }
    }
    let points = p
        .points
        .par_iter()
        .enumerate()
        .with_min_len(1024)
        .map(|(pt, x)| {
            let d = &dp[3 * pt..3 * pt + 3];
            match p.model {
                CameraModel::Metric => [x[0] + d[0], x[1] + d[1], x[2] + d[2], x[3]],
                CameraModel::Projective => sphere_plus(x, d),
            }
        })
        .collect();
    Params {
        cameras,
        groups,
        points,
    }
}

/// Norm of the ambient parameter vector (for the step tolerance).
fn param_norm(p: &Problem) -> f64 {
    let c: f64 = p.cameras.iter().flatten().map(|v| v * v).sum();
    let g: f64 = p.groups.iter().flatten().map(|v| v * v).sum();
    let x: f64 = p
        .points
        .par_iter()
        .map(|x| x.iter().map(|v| v * v).sum::<f64>())
        .collect::<Vec<f64>>()
        .iter()
        .sum();
    (c + g + x).sqrt()
}

pub(crate) fn solve(
    p: &mut Problem,
    opts: &BundleOptions,
    progress: &dyn Progress,
) -> Result<BundleSummary, BundleError> {
    opts.validate()?;
    p.validate()?;
    if opts.num_threads == 0 {
        return run(p, opts, progress);
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(opts.num_threads)
        .build()
        .map_err(|e| BundleError::InvalidOption {
            option: "num_threads",
            reason: format!("cannot start {} threads: {e}", opts.num_threads),
        })?;
    pool.install(|| run(p, opts, progress))
}

/// Reduced systems of at most this many parameters are solved dense without a look at their
/// pattern: the dense factor costs under 6 MFLOP there (about a millisecond), less than the
/// sparse analysis would save.
const DENSE_ALWAYS_MAX: usize = 256;

/// With [`LinearSolverKind::Auto`], the sparse factor is kept when its work is at most this share
/// of the dense factor's ([`flop_ratio`]): supernodal kernels on narrow supernodes do less per
/// flop than the dense blocked one, and the dense assembly also writes all `n²` entries at every
/// iteration, so the margin is wide. A walk's reduced matrix is banded (`bench bundle --synthetic
/// 150x20000`, 1 350 parameters: a flop ratio of 0.03, 44 ms an iteration against 80 ms dense), an
/// orbit's where every view sees the object is full (BAL problem-49: 1.0, and the dense solve
/// 10 % faster).
const SPARSE_MAX_FLOP_RATIO: f64 = 0.25;

/// The reduced camera system's storage and solver. [`LinearSolverKind::Auto`] takes the dense
/// Cholesky for small systems, the sparse one beyond `dense_max_dimension`, and in between
/// whichever the pattern favours: the sparse factor when its work, from the symbolic analysis with
/// the AMD ordering (made once per adjustment), is at most [`SPARSE_MAX_FLOP_RATIO`] of the dense
/// one's. A pattern the analysis cannot handle is solved dense.
fn reduced_system(
    st: &Structure,
    opts: &BundleOptions,
) -> Result<(ReducedMatrix, Factorizer), BundleError> {
    let n = st.num_reduced;
    let dense = match opts.linear_solver {
        LinearSolverKind::DenseSchur => true,
        LinearSolverKind::SparseSchur => false,
        LinearSolverKind::Auto if n > opts.dense_max_dimension => false,
        LinearSolverKind::Auto if n <= DENSE_ALWAYS_MAX => true,
        LinearSolverKind::Auto => {
            let m = ReducedMatrix::new(st, false);
            match analyse(&m) {
                Ok(symbolic) => {
                    let ratio = flop_ratio(&symbolic, n);
                    tracing::trace!(n, ratio, "reduced camera system: sparse over dense flops");
                    if ratio <= SPARSE_MAX_FLOP_RATIO {
                        let factor = Factorizer::sparse(symbolic)?;
                        return Ok((m, factor));
                    }
                }
                Err(e) => tracing::debug!("sparse analysis failed ({e}): solved dense"),
            }
            true
        }
    };
    let m = ReducedMatrix::new(st, dense);
    let factor = Factorizer::new(&m)?;
    Ok((m, factor))
}

fn run(
    p: &mut Problem,
    opts: &BundleOptions,
    progress: &dyn Progress,
) -> Result<BundleSummary, BundleError> {
    let t0 = Instant::now();
    let st = Structure::new(p);
    let n = st.num_reduced;
    let (mut m, mut factor) = reduced_system(&st, opts)?;
    let dense = m.dense;
    let loss = opts.loss;
    let initial_rms_px = p.rms_px();
    let mut lin = linearize(p, &st, &loss);
    if !lin.cost.is_finite() {
        return Err(BundleError::NonFiniteCost);
    }
    let initial_cost = lin.cost;
    let scale_c: Vec<f64> = lin.dc.iter().map(|h| jacobi_scale(*h)).collect();
    let scale_p: Vec<f64> = lin
        .v
        .iter()
        .flat_map(|v| [v[(0, 0)], v[(1, 1)], v[(2, 2)]])
        .map(jacobi_scale)
        .collect();
    let mut x_norm = param_norm(p);
    let mut radius = opts.initial_trust_region_radius;
    let mut decrease_factor = 2.0;
    let (mut iterations, mut successful) = (0, 0);
    let mut linear_seconds = 0.0;
    let mut rhs = vec![0.0; n];
    progress.start("bundle adjustment", opts.max_iterations as u64);
    let termination = loop {
        let grad_max = lin
            .bc
            .iter()
            .chain(lin.bp.iter().flat_map(|b| b.iter()))
            .fold(0.0f64, |a, v| a.max(v.abs()));
        if grad_max <= opts.gradient_tolerance {
            break Termination::GradientTolerance;
        }
        if iterations >= opts.max_iterations {
            break Termination::MaxIterations;
        }
        if radius < opts.min_trust_region_radius {
            break Termination::NoConvergence;
        }
        iterations += 1;
        progress.inc(1);
        let mu_c: Vec<f64> = lin
            .dc
            .iter()
            .zip(&scale_c)
            .zip(&lin.prior_h)
            .map(|((h, s), ph)| damping(*h, *s, radius) + ph)
            .collect();
        let mu_p: Vec<f64> = lin
            .v
            .iter()
            .flat_map(|v| [v[(0, 0)], v[(1, 1)], v[(2, 2)]])
            .zip(&scale_p)
            .map(|(h, s)| damping(h, *s, radius))
            .collect();
        let vinv = invert_points(&lin, &mu_p);
        assemble(p, &st, &lin, &vinv, &mu_c, &mut m, &mut rhs);
        let tl = Instant::now();
        let ok = factor.solve(&mut m, &mut rhs);
        linear_seconds += tl.elapsed().as_secs_f64();
        let rejected = |radius: &mut f64, decrease_factor: &mut f64| {
            *radius /= *decrease_factor;
            *decrease_factor *= 2.0;
        };
        if !ok {
            rejected(&mut radius, &mut decrease_factor);
            continue;
        }
        let dc = &rhs;
        let dp = back_substitute(&st, &lin, &vinv, dc);
        let b_dot: f64 = lin
            .bc
            .iter()
            .zip(dc.iter())
            .map(|(a, b)| a * b)
            .sum::<f64>()
            + lin
                .bp
                .iter()
                .flat_map(|b| b.iter())
                .zip(&dp)
                .map(|(a, b)| a * b)
                .sum::<f64>();
        let model_decrease = b_dot - 0.5 * jacobian_step_norm2(p, &st, &lin, dc, &dp);
        let step_norm = (dc.iter().chain(&dp).map(|v| v * v).sum::<f64>()).sqrt();
        if step_norm <= opts.parameter_tolerance * (x_norm + opts.parameter_tolerance) {
            break Termination::ParameterTolerance;
        }
        let mut cand = plus(p, &st, dc, &dp);
        swap_params(p, &mut cand);
        let cand_cost =
            match crate::embedded::refine_points(p, &st, &loss, opts.embedded_point_iterations) {
                Some(data) => data + p.prior_cost(),
                None => p.cost(&loss),
            };
        let mut change = lin.cost - cand_cost;
        let ratio = change / model_decrease;
        let success =
            cand_cost.is_finite() && model_decrease > 0.0 && ratio > opts.min_relative_decrease;
        if opts.extrapolate && success && ratio > EXTRAPOLATION_RATIO {
            change = lin.cost - extrapolate(p, &st, &mut cand, dc, &dp, cand_cost, &loss);
        }
        // Converged when an accepted step gains almost nothing, or when even the linear model
        // promises almost nothing. A rejected step whose cost barely moved is not convergence:
        // it overshot along a long, flat valley (a weakly determined parameter such as the
        // principal point against the rotations), and a smaller step still descends.
        let negligible = |v: f64| v.abs() <= opts.function_tolerance * lin.cost;
        if (success && negligible(change)) || (!success && negligible(model_decrease)) {
            if success {
                successful += 1;
            } else {
                swap_params(p, &mut cand);
            }
            break Termination::FunctionTolerance;
        }
        if success {
            successful += 1;
            radius = (radius / (1.0f64 / 3.0).max(1.0 - (2.0 * ratio - 1.0).powi(3)))
                .min(opts.max_trust_region_radius);
            decrease_factor = 2.0;
            linearize_into(p, &st, &loss, &mut lin);
            x_norm = param_norm(p);
        } else {
            swap_params(p, &mut cand);
            rejected(&mut radius, &mut decrease_factor);
        }
        tracing::debug!(
            iterations,
            cost = lin.cost,
            ratio,
            radius,
            "bundle adjustment iteration"
        );
    };
    progress.finish();
    let final_cost = p.cost(&loss);
    Ok(BundleSummary {
        initial_cost,
        final_cost,
        iterations,
        successful_steps: successful,
        termination,
        linear_solver: if dense {
            LinearSolverKind::DenseSchur
        } else {
            LinearSolverKind::SparseSchur
        },
        num_observations: p.num_observations(),
        num_camera_parameters: n,
        num_point_parameters: 3 * p.points.len(),
        initial_rms_px,
        final_rms_px: p.rms_px(),
        total_seconds: t0.elapsed().as_secs_f64(),
        linear_solver_seconds: linear_seconds,
    })
}
