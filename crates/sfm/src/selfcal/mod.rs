//! Linear self-calibration with the dual absolute quadric (§3.4 "Upgrading to Metric", eqs. 22–27).
//!
//! A projective reconstruction `{Pᵢ, Mⱼ}` is only defined up to a 4×4 homography. In a metric frame
//! the dual absolute quadric is `Ω* = diag(1, 1, 1, 0)` and it projects to the dual image of the
//! absolute conic (eqs. 22–23):
//!
//! ```text
//! ω*ᵢ ∼ Pᵢ Ω* Pᵢᵀ ∼ Kᵢ Kᵢᵀ
//! ```
//!
//! Since the images do not depend on the projective basis, prior knowledge about the intrinsics
//! (`f ≈ 1 ± 3`, `u ≈ v ≈ 0 ± 0.1`, `r ≈ 1 ± 0.1`, `s = 0` after the normalization `K_N` of eq. 24)
//! turns into linear equations on the 10 coefficients of the symmetric `Ω*` (eqs. 25–26). They are
//! solved by weighted linear least squares (smallest right singular vector of the stacked system),
//! re-weighted with `ν = P₃ Ω* P₃ᵀ` of the previous estimate, the rank-3 constraint is enforced and
//! the upgrade `T` with `diag(1, 1, 1, 0) = T Ω* Tᵀ` gives the metric cameras and points
//! `P_M = P T⁻¹`, `M_M = T M` (eq. 27).
//!
//! Two additions to the paper, both documented on [`SelfCalibrationOptions`]:
//! - the means of the priors can be estimated jointly (still one linear system), which removes the
//!   bias of eq. 26 when the intrinsics are far from the prior means (on by default; the verbatim
//!   scheme is `estimate_prior_means: false`);
//! - critical motions are detected from the singular values of the equations that do not involve
//!   the focal prior, and reported in [`SelfCalibration::degenerate`] rather than as an error.

use nalgebra::{DMatrix, Matrix3, Matrix3x4, Matrix4, RowVector4, SymmetricEigen, SVD};
use tracing::debug;

mod known;
mod types;
mod upgrade;

pub use known::*;
pub use types::*;
pub use upgrade::decompose_camera;
pub(crate) use upgrade::{rank3_upgrade, sign_of_quadric, Rank3};

/// Index pairs `(i, j)`, `i ≤ j`, of the 10 unknowns of the symmetric `Ω*`.
const SYM_INDEX: [(usize, usize); 10] = [
    (0, 0),
    (0, 1),
    (0, 2),
    (0, 3),
    (1, 1),
    (1, 2),
    (1, 3),
    (2, 2),
    (2, 3),
    (3, 3),
];

/// Coefficients `c` with `a Ω* bᵀ = c · q` where `q` holds the 10 unknowns in [`SYM_INDEX`] order.
fn bilinear_coefficients(a: &RowVector4<f64>, b: &RowVector4<f64>) -> [f64; 10] {
    std::array::from_fn(|k| {
        let (i, j) = SYM_INDEX[k];
        if i == j {
            a[i] * b[i]
        } else {
            a[i] * b[j] + a[j] * b[i]
        }
    })
}

fn symmetric_from_vector(q: &[f64]) -> Matrix4<f64> {
    let mut m = Matrix4::zeros();
    for (k, &(i, j)) in SYM_INDEX.iter().enumerate() {
        m[(i, j)] = q[k];
        m[(j, i)] = q[k];
    }
    m
}

/// The 6 unweighted linear forms of eq. 26 for one camera, as rows over the 10 unknowns:
/// `ω*₁₁ − ω*₃₃`, `ω*₂₂ − ω*₃₃`, `ω*₁₁ − ω*₂₂`, `ω*₁₂`, `ω*₁₃`, `ω*₂₃` (with `ω*ᵢⱼ = Pᵢ Ω* Pⱼᵀ`), and
/// the row of `ω*₃₃ = P₃ Ω* P₃ᵀ` used to shift the prior means.
struct CameraRows {
    forms: [[f64; 10]; 6],
    w33: [f64; 10],
}

fn camera_equations(p: &Matrix3x4<f64>) -> CameraRows {
    let r1 = p.row(0).into_owned();
    let r2 = p.row(1).into_owned();
    let r3 = p.row(2).into_owned();
    let c11 = bilinear_coefficients(&r1, &r1);
    let c22 = bilinear_coefficients(&r2, &r2);
    let c33 = bilinear_coefficients(&r3, &r3);
    let diff = |a: &[f64; 10], b: &[f64; 10]| -> [f64; 10] { std::array::from_fn(|k| a[k] - b[k]) };
    CameraRows {
        forms: [
            diff(&c11, &c33),
            diff(&c22, &c33),
            diff(&c11, &c22),
            bilinear_coefficients(&r1, &r2),
            bilinear_coefficients(&r1, &r3),
            bilinear_coefficients(&r2, &r3),
        ],
        w33: c33,
    }
}

/// The six linear forms of [`camera_equations`] evaluated on a 3×3 `ω*`.
fn forms_of(w: &Matrix3<f64>) -> [f64; 6] {
    [
        w[(0, 0)] - w[(2, 2)],
        w[(1, 1)] - w[(2, 2)],
        w[(0, 0)] - w[(1, 1)],
        w[(0, 1)],
        w[(0, 2)],
        w[(1, 2)],
    ]
}

/// Stacks the weighted equations `(formₑ − mₑ ω*₃₃) · wₑ / ν` of the selected kinds `e`.
fn build_system(
    rows: &[CameraRows],
    weights: &[f64; 6],
    centers: &[f64; 6],
    nu: &[f64],
    select: &[bool; 6],
) -> DMatrix<f64> {
    let kinds: Vec<usize> = (0..6).filter(|&e| select[e]).collect();
    let mut a = DMatrix::<f64>::zeros(kinds.len() * rows.len(), 10);
    for (c, cam) in rows.iter().enumerate() {
        for (slot, &e) in kinds.iter().enumerate() {
            let w = weights[e] / nu[c];
            for k in 0..10 {
                a[(kinds.len() * c + slot, k)] = w * (cam.forms[e][k] - centers[e] * cam.w33[k]);
            }
        }
    }
    a
}

fn svd_of(
    a: DMatrix<f64>,
    compute_v: bool,
) -> Result<SVD<f64, nalgebra::Dyn, nalgebra::Dyn>, SelfCalibrationError> {
    // nalgebra's sorted SVD panics on NaN singular values: refuse non-finite systems first.
    if a.iter().any(|v| !v.is_finite()) {
        return Err(SelfCalibrationError::Numerical(
            "the eq. 26 system has non-finite entries".into(),
        ));
    }
    SVD::try_new(a, false, compute_v, f64::EPSILON, 10_000).ok_or_else(|| {
        SelfCalibrationError::Numerical("SVD of the eq. 26 system did not converge".into())
    })
}

/// Stacks eq. 26 with the common means `μₑ` of the six normalized forms as six extra unknowns
/// (columns 10–15): `wₑ (formₑ(Ω*)/ν − μₑ) = 0` for every camera, plus `√λ wₑ μₑ = 0`, the
/// priors of eq. 25 acting as `λ` virtual cameras at the prior means.
fn build_joint_system(
    rows: &[CameraRows],
    weights: &[f64; 6],
    nu: &[f64],
    lambda: f64,
) -> DMatrix<f64> {
    let n = rows.len();
    let mut a = DMatrix::<f64>::zeros(6 * n + 6, 16);
    for (c, cam) in rows.iter().enumerate() {
        for e in 0..6 {
            let w = weights[e] / nu[c];
            for k in 0..10 {
                a[(6 * c + e, k)] = w * cam.forms[e][k];
            }
            a[(6 * c + e, 10 + e)] = -weights[e];
        }
    }
    for e in 0..6 {
        a[(6 * n + e, 10 + e)] = lambda.sqrt() * weights[e];
    }
    a
}

/// Medians over the cameras whose `ω*` is positive definite of the six forms normalized by
/// `ω*₃₃`; `None` unless most cameras qualify.
fn median_forms(omegas: &[Matrix3<f64>]) -> Option<[f64; 6]> {
    let valid: Vec<[f64; 6]> = omegas
        .iter()
        .filter(|w| w.cholesky().is_some())
        .map(|w| forms_of(&(w / w[(2, 2)])))
        .filter(|f| f.iter().all(|v| v.is_finite()))
        .collect();
    if 2 * valid.len() <= omegas.len() {
        return None;
    }
    let mut out = [0.0; 6];
    for (e, c) in out.iter_mut().enumerate() {
        let mut vals: Vec<f64> = valid.iter().map(|f| f[e]).collect();
        *c = median(&mut vals)?;
    }
    Some(out)
}

/// Median of the finite values, `None` when there are none.
fn median(values: &mut [f64]) -> Option<f64> {
    values.sort_by(f64::total_cmp);
    values.get(values.len() / 2).copied()
}

/// Scales a camera to unit Frobenius norm without overflow (divides by the largest entry first).
fn unit_frobenius(p: &Matrix3x4<f64>) -> Option<Matrix3x4<f64>> {
    let max = p.amax();
    if max == 0.0 || !max.is_finite() {
        return None;
    }
    let q = p / max;
    let n = q.norm();
    if n == 0.0 || !n.is_finite() {
        return None;
    }
    Some(q / n)
}

pub(crate) fn symmetric_eigen(
    m: Matrix4<f64>,
) -> Result<SymmetricEigen<f64, nalgebra::U4>, SelfCalibrationError> {
    SymmetricEigen::try_new(m, f64::EPSILON, 10_000).ok_or_else(|| {
        SelfCalibrationError::Numerical("eigen-decomposition of Ω* did not converge".into())
    })
}

/// Linear self-calibration with the dual absolute quadric (§3.4, eqs. 22–27).
///
/// `normalized_cameras` are projective cameras already multiplied by `K_N⁻¹` (eq. 24, see
/// [`normalization_matrix`]), so that the focal length is of the order of one and the principal
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

    let aspect_factor = if options.estimate_aspect {
        options.estimated_aspect_weight
    } else {
        1.0
    };
    let base_weights = [
        1.0 / options.sigma_focal_sq,
        1.0 / options.sigma_focal_sq,
        aspect_factor / options.sigma_aspect,
        1.0 / options.sigma_skew,
        1.0 / options.sigma_principal_point,
        1.0 / options.sigma_principal_point,
    ];
    let rows: Vec<CameraRows> = cams.iter().map(camera_equations).collect();
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
            build_joint_system(&rows, &base_weights, &nu, options.prior_mean_weight)
        } else {
            build_system(&rows, &base_weights, &[0.0; 6], &nu, &all)
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

    // The final system over the 10 unknowns of Ω*: eq. 26 with the last ν (and, when the means
    // are estimated, with the forms taken relative to their estimated common means).
    let final_svd = svd_of(
        build_system(&rows, &base_weights, &centers, &nu, &all),
        false,
    )?;
    let mut singular_values: Vec<f64> = final_svd.singular_values.iter().copied().collect();
    singular_values.resize(10, 0.0);

    let mut reasons: Vec<String> = Vec::new();

    // Critical motion: the equations that do not depend on the focal prior (aspect, skew,
    // principal point) must determine Ω* up to scale, i.e. have a null space of dimension one.
    let data_only = [false, false, true, true, true, true];
    let reduced = svd_of(
        build_system(&rows, &base_weights, &centers, &nu, &data_only),
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

#[cfg(test)]
mod test_scenes;
#[cfg(test)]
mod tests;
#[cfg(test)]
mod tests_degenerate;
