//! The last steps of §3.4: rank-3 enforcement of `Ω*` and the upgrade `T` of eq. 27, the sign of a
//! quadric, and the decomposition of an upgraded camera into `K [R | t]`.

use nalgebra::{Matrix3, Matrix3x4, Matrix4, Vector3};

use super::equations::symmetric_eigen;
use super::types::SelfCalibrationError;

/// The rank-3 upgrade of a sign-fixed `Ω*` (step 6 of [`super::self_calibrate`]).
pub(crate) struct Rank3 {
    pub t: Matrix4<f64>,
    pub t_inv: Matrix4<f64>,
    pub omega: Matrix4<f64>,
    /// Eigenvalues before the enforcement, descending.
    pub eigenvalues: [f64; 4],
    /// True when one of the three largest-magnitude eigenvalues was not positive.
    pub clamped: bool,
}

/// Enforces rank 3 by zeroing the smallest-magnitude eigenvalue of `Ω* = V diag(λ) Vᵀ` and returns
/// `T⁻¹ = V diag(√λ₁, √λ₂, √λ₃, 1)` with `diag(1, 1, 1, 0) = T Ω* Tᵀ` (eq. 27); non-positive
/// eigenvalues among the three largest are clamped to a small positive floor.
pub(crate) fn rank3_upgrade(omega_raw: &Matrix4<f64>) -> Result<Rank3, SelfCalibrationError> {
    // Eigen-decomposition: order the three largest-magnitude eigenpairs first (descending), the
    // smallest-magnitude one (the plane at infinity) last.
    let eig = symmetric_eigen(*omega_raw)?;
    let mut by_value: Vec<f64> = eig.eigenvalues.iter().copied().collect();
    by_value.sort_by(|a, b| b.total_cmp(a));
    let omega_eigenvalues = [by_value[0], by_value[1], by_value[2], by_value[3]];
    let mut order = [0usize, 1, 2, 3];
    order.sort_by(|&a, &b| {
        eig.eigenvalues[b]
            .abs()
            .total_cmp(&eig.eigenvalues[a].abs())
    });
    let mut top = [order[0], order[1], order[2]];
    top.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    let null = order[3];

    let lambda_max = eig.eigenvalues[top[0]].abs().max(f64::MIN_POSITIVE);
    let floor = 1e-6 * lambda_max;
    let mut lambdas = [0.0; 3];
    let mut clamped = false;
    for (slot, &idx) in top.iter().enumerate() {
        let l = eig.eigenvalues[idx];
        if l.is_finite() && l > floor {
            lambdas[slot] = l;
        } else {
            lambdas[slot] = floor;
            clamped = true;
        }
    }
    // Unit Frobenius norm of the rank-3 Ω*.
    let norm = (lambdas.iter().map(|l| l * l).sum::<f64>()).sqrt();
    for l in &mut lambdas {
        *l /= norm;
    }

    let mut v = Matrix4::zeros();
    for (col, &idx) in top.iter().chain(std::iter::once(&null)).enumerate() {
        v.set_column(col, &eig.eigenvectors.column(idx));
    }
    let s = Matrix4::from_diagonal(&nalgebra::Vector4::new(
        lambdas[0].sqrt(),
        lambdas[1].sqrt(),
        lambdas[2].sqrt(),
        1.0,
    ));
    let s_inv = Matrix4::from_diagonal(&nalgebra::Vector4::new(
        1.0 / lambdas[0].sqrt(),
        1.0 / lambdas[1].sqrt(),
        1.0 / lambdas[2].sqrt(),
        1.0,
    ));
    let t_inv = v * s;
    let t = s_inv * v.transpose();
    let omega =
        v * Matrix4::from_diagonal(&nalgebra::Vector4::new(
            lambdas[0], lambdas[1], lambdas[2], 0.0,
        )) * v.transpose();

    Ok(Rank3 {
        t,
        t_inv,
        omega,
        eigenvalues: omega_eigenvalues,
        clamped,
    })
}

/// `+1` when the majority of the three largest-magnitude eigenvalues of `omega` are positive,
/// `-1` otherwise. Sylvester's law of inertia makes this independent of the projective frame.
pub(crate) fn sign_of_quadric(omega: &Matrix4<f64>) -> Result<f64, SelfCalibrationError> {
    let eig = symmetric_eigen(*omega)?;
    let mut vals: Vec<f64> = eig.eigenvalues.iter().copied().collect();
    vals.sort_by(|a, b| b.abs().total_cmp(&a.abs()));
    let positive = vals[..3].iter().filter(|v| **v > 0.0).count();
    Ok(if positive >= 2 { 1.0 } else { -1.0 })
}

/// RQ decomposition of the left 3×3 block of a (metric) camera: `P ∼ K [R | t]` with `K` upper
/// triangular with a positive diagonal and `K₃₃ = 1`, `R` a rotation (`det R = +1`; the sign of
/// `P` is flipped when needed, which does not change the projective camera). `t` is such that
/// `P ∼ K [R | t]` holds for `P` of any scale (the centre is `C = −Rᵀ t`).
///
/// Returns `None` for a non-finite camera or a (numerically) singular left block.
pub fn decompose_camera(p: &Matrix3x4<f64>) -> Option<(Matrix3<f64>, Matrix3<f64>, Vector3<f64>)> {
    if p.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let max = p.amax();
    if max == 0.0 {
        return None;
    }
    let p = p / max;
    let m: Matrix3<f64> = p.fixed_view::<3, 3>(0, 0).into_owned();
    let scale = m.norm();
    if scale.is_nan() || scale <= 0.0 || m.determinant().abs() <= 1e-12 * scale.powi(3) {
        return None;
    }
    // RQ through QR: with J the anti-identity, (J M)ᵀ = Q U  ⇒  M = (J Uᵀ J)(J Qᵀ),
    // J Uᵀ J upper triangular and J Qᵀ orthogonal.
    let j = Matrix3::new(0.0, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 0.0);
    let qr = (j * m).transpose().qr();
    let q = qr.q();
    let u = qr.r();
    let mut k = j * u.transpose() * j;
    let mut r = j * q.transpose();
    for i in 0..3 {
        if k[(i, i)] < 0.0 {
            for row in 0..3 {
                k[(row, i)] = -k[(row, i)];
            }
            for col in 0..3 {
                r[(i, col)] = -r[(i, col)];
            }
        }
    }
    let mut p4: Vector3<f64> = p.column(3).into_owned();
    if r.determinant() < 0.0 {
        // −P = [K(−R) | −p₄]
        r = -r;
        p4 = -p4;
    }
    let t = k.solve_upper_triangular(&p4)?;
    let k33 = k[(2, 2)];
    if k33.is_nan() || k33 <= 0.0 {
        return None;
    }
    let k = k / k33;
    if k.iter()
        .chain(r.iter())
        .chain(t.iter())
        .any(|v| !v.is_finite())
    {
        return None;
    }
    Some((k, r, t))
}
