//! The linear self-calibration itself (§3.4, eqs. 22–27): [`self_calibrate`] in named steps, the
//! ν re-weighted solves of eq. 26, the degeneracy tests on the solution and the rank-3 upgrade.

use nalgebra::{Matrix3, Matrix3x4, Matrix4};
use tracing::debug;

use super::equations::{
    build_joint_system, build_system, camera_equations, median, median_forms, svd_of,
    symmetric_from_vector, unit_frobenius, CameraRows,
};
use super::rank3::{decompose_camera, rank3_upgrade, sign_of_quadric, Rank3};
use super::types::{
    NormalizedIntrinsics, SelfCalibration, SelfCalibrationError, SelfCalibrationOptions,
};

/// Linear self-calibration with the dual absolute quadric (§3.4, eqs. 22–27).
///
/// `normalized_cameras` are projective cameras already multiplied by `K_N⁻¹` (eq. 24, see
/// [`super::normalization_matrix`]), so that the focal length is of the order of one and the principal
/// point near zero. Steps:
///
/// 1. every camera is scaled to unit Frobenius norm;
/// 2. for each camera the 6 equations of eq. 26 in the 10 coefficients of `Ω*` are stacked with
///    weights `1 / (σ ν)` (see [`SelfCalibrationOptions`]), `ν = 1` at first;
/// 3. `Ω*` is the right singular vector of the smallest singular value; its sign is fixed so that
///    it is positive semi-definite (the majority of its three largest-magnitude eigenvalues are
///    positive — the inertia is invariant under the projective ambiguity);
/// 4. `ν = |P₃ Ω* P₃ᵀ|` is recomputed and steps 2–3 repeated until the `ν` converge or
///    `options.iterations` solves were made; with
///    [`SelfCalibrationOptions::estimate_prior_means`] (default) these later solves also estimate
///    the common means of the six prior equations, which removes the bias of eq. 26 for
///    intrinsics away from the prior means;
/// 5. critical motion is judged from the equations without the focal prior (see
///    [`SelfCalibration::critical_ratio`]), and from the signs of the eigenvalues of `Ω*` and of
///    `ω* = P Ω* Pᵀ`;
/// 6. the rank 3 is enforced by zeroing the smallest-magnitude eigenvalue of
///    `Ω* = V diag(λ₁, λ₂, λ₃, λ₄) Vᵀ`, and `T⁻¹ = V diag(√λ₁, √λ₂, √λ₃, 1)`, so that
///    `Ω* = T⁻¹ diag(1, 1, 1, 0) T⁻ᵀ`, i.e. `diag(1, 1, 1, 0) = T Ω* Tᵀ`, and the upgraded cameras
///    `P_M = P T⁻¹` satisfy `P_M diag(1, 1, 1, 0) P_Mᵀ = P Ω* Pᵀ ∼ K Kᵀ` (eqs. 22, 23, 27).
///
/// The metric frame is defined up to a similarity, including a reflection: whether the scene lies
/// in front of the cameras has to be checked with the points (flip the sign of one axis of `T`).
///
/// Degenerate (critical) motions do not make this fail: they give `Ok` with
/// [`SelfCalibration::degenerate`] set and finite numbers (negative eigenvalues are clamped).
pub fn self_calibrate(
    normalized_cameras: &[Matrix3x4<f64>],
    options: &SelfCalibrationOptions,
) -> Result<SelfCalibration, SelfCalibrationError> {
    options.validate()?;
    let cams = unit_cameras(normalized_cameras)?;
    let base_weights = prior_weights(options);
    let rows: Vec<CameraRows> = cams.iter().map(camera_equations).collect();
    let all = [true; 6];
    let Solved {
        omega_raw,
        nu,
        centers,
        iterations,
    } = solve_reweighted(&cams, &rows, &base_weights, options)?;

    // The final system over the 10 unknowns of Ω*: eq. 26 with the last ν (and, when the means
    // are estimated, with the forms taken relative to their estimated common means).
    let final_svd = svd_of(
        build_system(&rows, &base_weights, &centers, &nu, &all),
        false,
    )?;
    let mut singular_values: Vec<f64> = final_svd.singular_values.iter().copied().collect();
    singular_values.resize(10, 0.0);

    let mut reasons: Vec<String> = Vec::new();
    let critical_ratio =
        critical_motion(&rows, &base_weights, &centers, &nu, options, &mut reasons)?;
    not_positive_definite(&cams, &omega_raw, &mut reasons);

    let Rank3 {
        t,
        t_inv,
        omega,
        eigenvalues: omega_eigenvalues,
        clamped,
    } = rank3_upgrade(&omega_raw)?;
    if clamped {
        reasons.push(format!(
            "Ω* is not positive semi-definite of rank 3 (eigenvalues {:.3e}, {:.3e}, {:.3e}, {:.3e}); clamped",
            omega_eigenvalues[0], omega_eigenvalues[1], omega_eigenvalues[2], omega_eigenvalues[3]
        ));
    }
    let per_camera = upgraded_intrinsics(&cams, &t_inv, &mut reasons);

    let degenerate = if reasons.is_empty() {
        None
    } else {
        Some(reasons.join("; "))
    };
    debug!(
        iterations,
        ?singular_values,
        ?omega_eigenvalues,
        ?degenerate,
        "linear self-calibration (eqs. 24-27)"
    );
    Ok(SelfCalibration {
        t,
        t_inv,
        omega,
        iterations,
        singular_values,
        critical_ratio,
        omega_eigenvalues,
        per_camera,
        degenerate,
    })
}

/// Step 1: every camera checked (finite, at least 2 of them) and scaled to unit Frobenius norm.
fn unit_cameras(
    normalized_cameras: &[Matrix3x4<f64>],
) -> Result<Vec<Matrix3x4<f64>>, SelfCalibrationError> {
    let n = normalized_cameras.len();
    if n < 2 {
        return Err(SelfCalibrationError::TooFewCameras(n));
    }
    let mut cams = Vec::with_capacity(n);
    for (index, p) in normalized_cameras.iter().enumerate() {
        if p.iter().any(|v| !v.is_finite()) {
            return Err(SelfCalibrationError::NonFiniteCamera { index });
        }
        cams.push(unit_frobenius(p).ok_or(SelfCalibrationError::ZeroCamera { index })?);
    }
    Ok(cams)
}

/// The weights `1 / σ` of the six forms of eq. 26 (eq. 25's priors).
fn prior_weights(options: &SelfCalibrationOptions) -> [f64; 6] {
    let aspect_factor = if options.estimate_aspect {
        options.estimated_aspect_weight
    } else {
        1.0
    };
    [
        1.0 / options.sigma_focal_sq,
        1.0 / options.sigma_focal_sq,
        aspect_factor / options.sigma_aspect,
        1.0 / options.sigma_skew,
        1.0 / options.sigma_principal_point,
        1.0 / options.sigma_principal_point,
    ]
}

/// What the re-weighted solves leave: the sign-fixed `Ω*` of the last solve, the last `ν`, the
/// estimated common means of the six forms (zero unless estimated) and the solves made.
struct Solved {
    omega_raw: Matrix4<f64>,
    nu: Vec<f64>,
    centers: [f64; 6],
    iterations: usize,
}

/// Steps 2–4: the weighted solves of eq. 26, re-weighted by `ν = |P₃ Ω* P₃ᵀ|` of the previous
/// estimate until the `ν` converge or `options.iterations` solves were made (with
/// `estimate_prior_means`, the later solves also estimate the common means of the six forms).
fn solve_reweighted(
    cams: &[Matrix3x4<f64>],
    rows: &[CameraRows],
    base_weights: &[f64; 6],
    options: &SelfCalibrationOptions,
) -> Result<Solved, SelfCalibrationError> {
    let n = cams.len();
    let all = [true; 6];
    let mut nu = vec![1.0_f64; n];
    let mut centers = [0.0_f64; 6];
    let mut omega_raw = Matrix4::zeros();
    let mut iterations = 0;
    for it in 0..options.iterations {
        iterations = it + 1;
        // First solve: eq. 26 verbatim (ν = 1). Later ones: with ν of the previous estimate, and
        // optionally with the common means of the six forms as extra unknowns.
        let joint = options.estimate_prior_means && it > 0;
        let a = if joint {
            build_joint_system(rows, base_weights, &nu, options.prior_mean_weight)
        } else {
            build_system(rows, base_weights, &[0.0; 6], &nu, &all)
        };
        let svd = svd_of(a, true)?;
        let v_t = svd.v_t.ok_or_else(|| {
            SelfCalibrationError::Numerical("SVD returned no right singular vectors".into())
        })?;
        let q: Vec<f64> = v_t.row(v_t.nrows() - 1).iter().take(10).copied().collect();
        let mut omega = symmetric_from_vector(&q);
        let norm = omega.norm();
        if !(norm > 0.0 && norm.is_finite()) {
            return Err(SelfCalibrationError::Numerical(
                "the eq. 26 solution has no Ω* part".into(),
            ));
        }
        omega /= norm;
        if sign_of_quadric(&omega)? < 0.0 {
            omega = -omega;
        }
        omega_raw = omega;

        let omegas: Vec<Matrix3<f64>> = cams.iter().map(|p| p * omega * p.transpose()).collect();
        if joint {
            centers = median_forms(&omegas).unwrap_or(centers);
        }
        if it + 1 == options.iterations {
            break;
        }

        // ν = P₃ Ω* P₃ᵀ of this estimate, guarded against ~0 by a fraction of the median.
        let mut new_nu: Vec<f64> = omegas.iter().map(|w| w[(2, 2)].abs()).collect();
        let mut finite: Vec<f64> = new_nu.iter().copied().filter(|v| v.is_finite()).collect();
        match median(&mut finite) {
            // Cameras and Ω* have unit norm, so ν ≤ 1; a median below 1e-12 means Ω* is useless.
            Some(m) if m > 1e-12 && m.is_finite() && finite.len() == n => {
                for v in &mut new_nu {
                    *v = v.max(1e-3 * m);
                }
            }
            _ => new_nu = vec![1.0; n],
        }
        // ν only matters up to a common scale: compare the normalized factors.
        let scale_old = nu.iter().sum::<f64>() / n as f64;
        let scale_new = new_nu.iter().sum::<f64>() / n as f64;
        let nu_change = nu
            .iter()
            .zip(&new_nu)
            .map(|(o, m)| ((o / scale_old) - (m / scale_new)).abs() / (m / scale_new))
            .fold(0.0, f64::max);
        debug!(
            iteration = iterations,
            nu_change, "self-calibration ν re-weighting"
        );
        let converged = nu_change < 1e-12 && (joint || !options.estimate_prior_means);
        nu = new_nu;
        if converged {
            break;
        }
    }
    Ok(Solved {
        omega_raw,
        nu,
        centers,
        iterations,
    })
}

/// Step 5, critical motion: the equations that do not involve the focal prior must determine
/// `Ω*` on their own. Returns [`SelfCalibration::critical_ratio`], with the reason in `reasons`
/// when it is below `options.degenerate_singular_ratio`.
fn critical_motion(
    rows: &[CameraRows],
    base_weights: &[f64; 6],
    centers: &[f64; 6],
    nu: &[f64],
    options: &SelfCalibrationOptions,
    reasons: &mut Vec<String>,
) -> Result<f64, SelfCalibrationError> {
    // Critical motion: the equations that do not depend on the focal prior (aspect, skew,
    // principal point) must determine Ω* up to scale, i.e. have a null space of dimension one.
    let data_only = [false, false, true, true, true, true];
    let reduced = svd_of(
        build_system(rows, base_weights, centers, nu, &data_only),
        false,
    )?;
    let mut reduced_sv: Vec<f64> = reduced.singular_values.iter().copied().collect();
    reduced_sv.resize(10, 0.0);
    let critical_ratio = if reduced_sv[0] > 0.0 {
        reduced_sv[8] / reduced_sv[0]
    } else {
        0.0
    };
    if critical_ratio.is_nan() || critical_ratio < options.degenerate_singular_ratio {
        reasons.push(format!(
            "Ω* is not determined without the focal prior (critical motion): second-smallest / largest \
             singular value = {critical_ratio:.3e} < {:.1e}",
            options.degenerate_singular_ratio
        ));
    }
    Ok(critical_ratio)
}

/// Step 5, the signs: `ω* = P Ω* Pᵀ` must be positive definite (eq. 23) for most cameras.
fn not_positive_definite(
    cams: &[Matrix3x4<f64>],
    omega_raw: &Matrix4<f64>,
    reasons: &mut Vec<String>,
) {
    let n = cams.len();
    // ω* = P Ω* Pᵀ must be positive definite (eq. 23).
    let pd_count = cams
        .iter()
        .filter(|p| {
            let w = *p * omega_raw * p.transpose();
            let w = (w + w.transpose()) * 0.5;
            w.cholesky().is_some()
        })
        .count();
    if 2 * pd_count <= n {
        reasons.push(format!(
            "ω* = P Ω* Pᵀ is positive definite for only {pd_count} of {n} cameras"
        ));
    }
}

/// The normalised intrinsics of every upgraded camera `P T⁻¹` (zeros, and a reason, for one
/// whose left 3×3 block is singular).
fn upgraded_intrinsics(
    cams: &[Matrix3x4<f64>],
    t_inv: &Matrix4<f64>,
    reasons: &mut Vec<String>,
) -> Vec<NormalizedIntrinsics> {
    let n = cams.len();
    let mut failed = 0;
    let per_camera: Vec<NormalizedIntrinsics> = cams
        .iter()
        .map(|p| match decompose_camera(&(p * t_inv)) {
            Some((k, _, _)) => NormalizedIntrinsics::from_k(&k),
            None => {
                failed += 1;
                NormalizedIntrinsics {
                    f: 0.0,
                    aspect: 0.0,
                    skew: 0.0,
                    u: 0.0,
                    v: 0.0,
                }
            }
        })
        .collect();
    if failed > 0 {
        reasons.push(format!(
            "{failed} of {n} upgraded cameras have a singular left 3×3 block"
        ));
    }
    per_camera
}
