//! The linear system of eq. 26 and the small linear algebra that the self-calibration
//! ([`super::linear`]), the upgrade for a given focal length ([`super::known`]) and the rank-3
//! enforcement ([`super::rank3`]) share: the 10 unknowns of the symmetric `Ω*`, the six forms of
//! eq. 26 per camera, their weighted stacking (with or without the prior means as unknowns), and
//! guarded SVD and eigen-decompositions.

use nalgebra::{DMatrix, Matrix3, Matrix3x4, Matrix4, RowVector4, SymmetricEigen, SVD};

use super::types::SelfCalibrationError;

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
pub(super) fn bilinear_coefficients(a: &RowVector4<f64>, b: &RowVector4<f64>) -> [f64; 10] {
    std::array::from_fn(|k| {
        let (i, j) = SYM_INDEX[k];
        if i == j {
            a[i] * b[i]
        } else {
            a[i] * b[j] + a[j] * b[i]
        }
    })
}

pub(super) fn symmetric_from_vector(q: &[f64]) -> Matrix4<f64> {
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
pub(super) struct CameraRows {
    pub forms: [[f64; 10]; 6],
    pub w33: [f64; 10],
}

pub(super) fn camera_equations(p: &Matrix3x4<f64>) -> CameraRows {
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
pub(super) fn forms_of(w: &Matrix3<f64>) -> [f64; 6] {
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
pub(super) fn build_system(
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

pub(super) fn svd_of(
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
pub(super) fn build_joint_system(
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
pub(super) fn median_forms(omegas: &[Matrix3<f64>]) -> Option<[f64; 6]> {
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
pub(super) fn median(values: &mut [f64]) -> Option<f64> {
    values.sort_by(f64::total_cmp);
    values.get(values.len() / 2).copied()
}

/// Scales a camera to unit Frobenius norm without overflow (divides by the largest entry first).
pub(super) fn unit_frobenius(p: &Matrix3x4<f64>) -> Option<Matrix3x4<f64>> {
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

pub(super) fn symmetric_eigen(
    m: Matrix4<f64>,
) -> Result<SymmetricEigen<f64, nalgebra::U4>, SelfCalibrationError> {
    SymmetricEigen::try_new(m, f64::EPSILON, 10_000).ok_or_else(|| {
        SelfCalibrationError::Numerical("eigen-decomposition of Ω* did not converge".into())
    })
}
