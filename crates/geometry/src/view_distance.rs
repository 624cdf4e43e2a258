//! The image-based view distance of §3.1, eqs. 14–15: the median transfer error through the
//! "average" plane homography `H = [e]× F + e a_minᵀ`, with `a_min` chosen by linear least squares.
//! It is large for views far apart (large parallax) and small for close or purely rotated views, and
//! needs no projective frame. The SfM stage uses it to pick the initial pair and the close views.

use nalgebra::{Matrix3, Vector2, Vector3};

use crate::error::{check_pair_lengths, GeometryError, Result};
use crate::fundamental::epipoles;
use crate::homography::transfer_error_sq;
use crate::skew::skew;

/// The homography of eq. 15 for matches `x1 ↔ x2` under `x2ᵀ F x1 = 0`, and the view distance of
/// eq. 14 (the median of `d(H x1, x2)` in pixels).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ViewDistance {
    pub h: Matrix3<f64>,
    pub a_min: Vector3<f64>,
    pub median_transfer_px: f64,
}

/// Eq. 15: `a_min = argmin_a Σ d(([e]× F + e aᵀ) m, m′)²`, linearised through the cross product
/// `m′ × ([e]× F m + e (aᵀ m)) = 0` (two independent rows per match, linear in `a`), solved in
/// least squares; then eq. 14, the median transfer distance. `e` is the epipole in image 2.
pub fn view_distance(
    f: &Matrix3<f64>,
    x1: &[Vector2<f64>],
    x2: &[Vector2<f64>],
) -> Result<ViewDistance> {
    check_pair_lengths(x1, x2, 3)?;
    let (_, e) = epipoles(f)?;
    let m0 = skew(&e) * f;
    // Normal equations of the stacked rows A a = b (3 unknowns).
    let mut ata = Matrix3::zeros();
    let mut atb = Vector3::zeros();
    for (p, q) in x1.iter().zip(x2) {
        let m = Vector3::new(p.x, p.y, 1.0);
        let mp = Vector3::new(q.x, q.y, 1.0);
        // m′ × (M0 m) + (m′ × e) (mᵀ a) = 0  →  rows: (m′ × e)_k mᵀ a = −(m′ × M0 m)_k
        let c = mp.cross(&e);
        let r = mp.cross(&(m0 * m));
        for k in 0..2 {
            let row = m * c[k];
            ata += row * row.transpose();
            atb -= row * r[k];
        }
    }
    let a_min = ata
        .try_inverse()
        .map(|inv| inv * atb)
        .ok_or(GeometryError::Degenerate {
            reason: "a_min is not determined",
        })?;
    let h = m0 + e * a_min.transpose();
    let mut d: Vec<f64> = x1
        .iter()
        .zip(x2)
        .map(|(p, q)| transfer_error_sq(&h, p, q).sqrt())
        .collect();
    d.sort_by(|a, b| a.total_cmp(b));
    let median_transfer_px = d[d.len() / 2];
    if !median_transfer_px.is_finite() {
        return Err(GeometryError::Degenerate {
            reason: "transfer through H is undefined",
        });
    }
    Ok(ViewDistance {
        h,
        a_min,
        median_transfer_px,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fundamental::fundamental_from_cameras;
    use crate::test_util::*;
    use handheld_core::ProjectiveCamera;
    use nalgebra::{Point3, Rotation3};

    fn setup(baseline: f64) -> (Matrix3<f64>, Vec<Vector2<f64>>, Vec<Vector2<f64>>) {
        let k = Matrix3::new(800.0, 0.0, 320.0, 0.0, 800.0, 240.0, 0.0, 0.0, 1.0);
        let p1 = camera_matrix(&k, Rotation3::identity(), Point3::origin());
        let p2 = camera_matrix(
            &k,
            Rotation3::from_euler_angles(0.0, 0.05, 0.0),
            Point3::new(baseline, 0.0, 0.0),
        );
        let mut r = rng(3);
        let pts: Vec<Point3<f64>> = (0..200)
            .map(|_| {
                Point3::new(
                    gauss(&mut r),
                    gauss(&mut r),
                    6.0 + 2.0 * gauss(&mut r).abs(),
                )
            })
            .collect();
        let x1: Vec<_> = pts.iter().map(|p| project(&p1, p)).collect();
        let x2: Vec<_> = pts.iter().map(|p| project(&p2, p)).collect();
        let f = fundamental_from_cameras(&ProjectiveCamera { P: p1 }, &ProjectiveCamera { P: p2 })
            .unwrap();
        (f, x1, x2)
    }

    #[test]
    fn distance_grows_with_baseline() {
        let (f, x1, x2) = setup(0.1);
        let near = view_distance(&f, &x1, &x2).unwrap().median_transfer_px;
        let (f, x1, x2) = setup(1.0);
        let far = view_distance(&f, &x1, &x2).unwrap().median_transfer_px;
        assert!(near > 0.0 && far > 5.0 * near, "near {near} far {far}");
    }

    #[test]
    fn h_is_compatible_with_f() {
        // Any H = [e]×F + e aᵀ satisfies Hᵀ F + Fᵀ H = 0 (H&Z result 13.3): F ~ [e]× H.
        let (f, x1, x2) = setup(0.5);
        let vd = view_distance(&f, &x1, &x2).unwrap();
        let (_, e) = epipoles(&f).unwrap();
        let f2 = skew(&e) * vd.h;
        assert!(equal_up_to_scale(&f, &f2) < 1e-8);
    }
}
