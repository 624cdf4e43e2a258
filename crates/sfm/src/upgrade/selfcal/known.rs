//! The metric upgrade for a hypothesised focal length: eq. 26 with every prior made exact.
//!
//! Under critical or near-critical motion (a turntable ring, forward motion along a road) the
//! linear system of eq. 26 leaves `Ω*` undetermined along the focal direction: only the weak
//! `f ≈ 1 ± 3` prior fixes it, and the estimate can even come out indefinite. Once the focal
//! length is *given*, `K = diag(f, f, 1)` in `K_N` units (square pixels, zero skew, centred
//! principal point, eq. 25's means) and `ω*ᵢ = Pᵢ Ω* Pᵢᵀ ∼ K Kᵀ` holds for every camera: after
//! `P̃ᵢ = K⁻¹ Pᵢ` all six forms of eq. 26 (`ω̃*₁₁ − ω̃*₃₃`, `ω̃*₂₂ − ω̃*₃₃`, `ω̃*₁₁ − ω̃*₂₂`, `ω̃*₁₂`,
//! `ω̃*₁₃`, `ω̃*₂₃`) vanish, which is the calibrated (essential-matrix) case, determined for any
//! general motion, critical ones included. The caller tries a few focal lengths and lets the
//! metric bundle adjustment judge (see `upgrade/hypotheses.rs`).

use nalgebra::{Matrix3, Matrix3x4, Matrix4};

use super::equations::{
    build_system, camera_equations, svd_of, symmetric_from_vector, unit_frobenius,
};
use super::rank3::{rank3_upgrade, sign_of_quadric};
use super::types::SelfCalibrationError;

/// Result of [`upgrade_for_focal`].
#[derive(Clone, Debug, PartialEq)]
pub struct FocalUpgrade {
    /// The hypothesised focal length in `K_N` units.
    pub focal: f64,
    /// `T` with `P_M = P T⁻¹`, `M_M = T M` (eq. 27), for the input (normalized) cameras.
    pub t: Matrix4<f64>,
    /// `T⁻¹`.
    pub t_inv: Matrix4<f64>,
    /// RMS over the cameras of the six forms of `ω̃* / ω̃*₃₃ − I` for the rank-3 `Ω*`: zero when the
    /// hypothesis explains every camera exactly.
    pub residual: f64,
    /// True when `Ω*` was not semi-definite (the hypothesis is inconsistent with the cameras).
    pub clamped: bool,
}

/// Solves eq. 26 for `Ω*` with `K = diag(focal, focal, 1)` known (all six equations with unit
/// weight, re-weighted by `ν = P̃₃ Ω* P̃₃ᵀ` for `iterations` solves), enforces rank 3 and returns the
/// upgrade. `normalized_cameras` are multiplied by `K_N⁻¹` already (eq. 24).
pub fn upgrade_for_focal(
    normalized_cameras: &[Matrix3x4<f64>],
    focal: f64,
    iterations: usize,
) -> Result<FocalUpgrade, SelfCalibrationError> {
    let n = normalized_cameras.len();
    if n < 2 {
        return Err(SelfCalibrationError::TooFewCameras(n));
    }
    if !(focal.is_finite() && focal > 0.0) {
        return Err(SelfCalibrationError::InvalidOption {
            option: "focal",
            reason: format!("the focal hypothesis must be positive and finite, got {focal}"),
        });
    }
    let k_inv = Matrix3::new(1.0 / focal, 0.0, 0.0, 0.0, 1.0 / focal, 0.0, 0.0, 0.0, 1.0);
    let mut cams = Vec::with_capacity(n);
    for (index, p) in normalized_cameras.iter().enumerate() {
        if p.iter().any(|v| !v.is_finite()) {
            return Err(SelfCalibrationError::NonFiniteCamera { index });
        }
        cams.push(unit_frobenius(&(k_inv * p)).ok_or(SelfCalibrationError::ZeroCamera { index })?);
    }
    let rows: Vec<_> = cams.iter().map(camera_equations).collect();
    let mut nu = vec![1.0; n];
    let mut omega = Matrix4::zeros();
    for _ in 0..iterations.max(1) {
        let a = build_system(&rows, &[1.0; 6], &[0.0; 6], &nu, &[true; 6]);
        let svd = svd_of(a, true)?;
        let v_t = svd.v_t.ok_or_else(|| {
            SelfCalibrationError::Numerical("SVD returned no right singular vectors".into())
        })?;
        let q: Vec<f64> = v_t.row(v_t.nrows() - 1).iter().copied().collect();
        omega = symmetric_from_vector(&q);
        if sign_of_quadric(&omega)? < 0.0 {
            omega = -omega;
        }
        let w33: Vec<f64> = cams
            .iter()
            .map(|p| (p * omega * p.transpose())[(2, 2)].abs())
            .collect();
        let mut sorted = w33.clone();
        sorted.sort_by(f64::total_cmp);
        let med = sorted[n / 2];
        if !(med > 1e-12 && med.is_finite()) {
            break;
        }
        nu = w33.iter().map(|v| v.max(1e-3 * med) / med).collect();
    }
    let r3 = rank3_upgrade(&omega)?;
    let mut sq = 0.0;
    for p in &cams {
        let w = p * r3.omega * p.transpose();
        let w = w / w[(2, 2)];
        sq += (w[(0, 0)] - 1.0).powi(2)
            + (w[(1, 1)] - 1.0).powi(2)
            + (w[(0, 0)] - w[(1, 1)]).powi(2)
            + w[(0, 1)].powi(2)
            + w[(0, 2)].powi(2)
            + w[(1, 2)].powi(2);
    }
    // The cameras were divided by K: the upgrade of the K_N-normalized cameras is the same T
    // (K⁻¹ P T⁻¹ = K⁻¹ (P T⁻¹)), so T applies to the input cameras unchanged.
    Ok(FocalUpgrade {
        focal,
        t: r3.t,
        t_inv: r3.t_inv,
        residual: (sq / (6 * n) as f64).sqrt(),
        clamped: r3.clamped,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Rotation3, Vector3};

    /// Cameras `K [R | t] H` on a turntable ring (rotation about one axis: critical for eq. 26
    /// with a free focal), with a random projective `H`; the true focal length must give a zero
    /// residual and an upgrade whose cameras decompose to that focal, a wrong one a larger residual.
    #[test]
    fn turntable_ring_is_upgraded_for_the_true_focal() {
        let f_true = 1.3;
        let k = Matrix3::new(f_true, 0.0, 0.0, 0.0, f_true, 0.0, 0.0, 0.0, 1.0);
        let h = Matrix4::new(
            1.0, 0.2, -0.1, 0.3, 0.1, 0.9, 0.2, -0.2, -0.3, 0.1, 1.1, 0.4, 0.05, -0.02, 0.03, 1.0,
        );
        let cams: Vec<Matrix3x4<f64>> = (0..12)
            .map(|i| {
                let a = i as f64 * 0.4;
                // Camera on a circle of radius 3 around the y axis, tilted down by 20°, looking at
                // the origin.
                let r = Rotation3::from_axis_angle(&Vector3::x_axis(), 0.35)
                    * Rotation3::from_axis_angle(&Vector3::y_axis(), a);
                let c = r.inverse() * Vector3::new(0.0, 0.0, -3.0);
                let t = -(r * c);
                let mut rt = Matrix3x4::zeros();
                rt.fixed_view_mut::<3, 3>(0, 0).copy_from(r.matrix());
                rt.set_column(3, &t);
                k * rt * h
            })
            .collect();
        let good = upgrade_for_focal(&cams, f_true, 3).expect("upgrade");
        let bad = upgrade_for_focal(&cams, 0.7 * f_true, 3).expect("upgrade");
        assert!(good.residual < 1e-8, "residual {}", good.residual);
        assert!(bad.residual > 1e-3, "wrong focal residual {}", bad.residual);
        for p in &cams {
            let (kk, _, _) =
                super::super::rank3::decompose_camera(&(p * good.t_inv)).expect("camera");
            assert!(
                (kk[(0, 0)] - f_true).abs() < 1e-6 * f_true,
                "focal {}",
                kk[(0, 0)]
            );
            assert!((kk[(1, 1)] - f_true).abs() < 1e-6 * f_true);
            assert!(kk[(0, 2)].abs() < 1e-6 && kk[(1, 2)].abs() < 1e-6);
        }
    }
}
