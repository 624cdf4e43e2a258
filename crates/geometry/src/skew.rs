//! The cross-product matrix and the canonical projective camera pair of eq. 16, which turns a
//! fundamental matrix into the initial projective frame of §3.1 ("Initial Frame").

use handheld_core::ProjectiveCamera;
use nalgebra::{Matrix3, Matrix3x4, Vector3};

use crate::error::{GeometryError, Result};
use crate::fundamental::epipoles;

/// `[v]×`, the matrix with `[v]× w = v × w` (H&Z §A4.5).
pub fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// The camera pair of eq. 16 (H&Z result 9.15): `P1 = [I | 0]`,
/// `P2 = [[e12]× F12 + e12 aᵀ | σ e12]`, with `e12` the epipole in the second image (`Fᵀ e12 = 0`,
/// unit norm). `a` fixes the reference plane and `σ ≠ 0` the global scale; the paper uses
/// `a = 0`, `σ = 1`. The pair reproduces `F` up to scale (see [`crate::fundamental_from_cameras`]).
///
/// Errors: `F` of rank below 2, `σ = 0`, or a non-finite input.
pub fn canonical_cameras(
    f: &Matrix3<f64>,
    a: &Vector3<f64>,
    sigma: f64,
) -> Result<(ProjectiveCamera, ProjectiveCamera)> {
    if !sigma.is_finite() || a.iter().any(|v| !v.is_finite()) {
        return Err(GeometryError::NonFinite);
    }
    if sigma == 0.0 {
        return Err(GeometryError::Degenerate {
            reason: "σ = 0 gives a singular second camera",
        });
    }
    let (_, e2) = epipoles(f)?;
    let m = skew(&e2) * f + e2 * a.transpose();
    let mut p2 = Matrix3x4::zeros();
    p2.fixed_view_mut::<3, 3>(0, 0).copy_from(&m);
    p2.fixed_view_mut::<3, 1>(0, 3).copy_from(&(e2 * sigma));
    Ok((ProjectiveCamera::canonical(), ProjectiveCamera { P: p2 }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fundamental::fundamental_from_cameras;
    use crate::test_util::*;

    #[test]
    fn skew_is_cross_product() {
        let v = Vector3::new(0.3, -2.0, 1.5);
        let w = Vector3::new(4.0, 0.1, -0.7);
        assert!((skew(&v) * w - v.cross(&w)).norm() < 1e-15);
    }

    #[test]
    fn canonical_pair_reproduces_f() {
        let tv = two_view(11, 10);
        let f = fundamental_from_cameras(
            &ProjectiveCamera { P: tv.p1 },
            &ProjectiveCamera { P: tv.p2 },
        )
        .expect("distinct");
        for (a, sigma) in [(Vector3::zeros(), 1.0), (Vector3::new(0.2, -0.1, 0.4), 2.5)] {
            let (c1, c2) = canonical_cameras(&f, &a, sigma).expect("rank 2");
            assert_eq!(c1.P, Matrix3x4::identity());
            let back = fundamental_from_cameras(&c1, &c2).expect("distinct");
            assert!(equal_up_to_scale(&back, &f) < 1e-10);
        }
        assert!(canonical_cameras(&f, &Vector3::zeros(), 0.0).is_err());
        assert!(canonical_cameras(&Matrix3::repeat(1.0), &Vector3::zeros(), 1.0).is_err());
    }
}
