//! Rotation-only pairs as witnesses of the model's relative pose.
//!
//! A pair that a homography explains better than a fundamental matrix (`RotationOnly` in the
//! matcher's GRIC, Torr 1998) has no usable `F`, so the check of its two-view rotation skips it.
//! It still carries the relative rotation: with no baseline the images are related by the
//! infinite homography `K_b R K_a⁻¹` (H&Z §8.4.2), and with a small one by the homography of
//! the plane the matches lie on, `K_b (R + t mᵀ) K_a⁻¹` with `m = n / d` (H&Z eq. 13.2), whose two
//! decompositions come together as `|t| / d` goes to zero. So the model's relative pose `(R, t)`
//! agrees with such a pair when some plane `m` carries most of its matches under it, and the
//! fit of `m` given `(R, t)` is linear. A wrong rotation of a few degrees moves every match by
//! tens of pixels, which no choice of `m` takes back. These pairs are the neighbours of a video
//! frame, matched over a short baseline where a repeated texture's copies lie far apart; the
//! general pairs of the same frames can be wrong (module notes of `consistency.rs`).

use nalgebra::{Matrix3, Vector2, Vector3};

/// Share of a rotation-only pair's matches the model's relative pose must carry through one plane
/// for the pair to confirm it.
pub(super) const CONFIRMING_SUPPORT: f64 = 0.8;

/// The share of the matches `xa ↔ xb` (normalised coordinates) within `cap` of where the model's
/// relative pose `(r, t)` (`x_b ~ R x_a + t`) puts them through the plane `m` that fits them best
/// (least squares on the linear transfer equations, refitted twice on the matches within 16 and 4
/// times `cap`). `None` for fewer than 8 matches.
pub(super) fn plane_support(
    r: &Matrix3<f64>,
    t: &Vector3<f64>,
    xa: &[Vector2<f64>],
    xb: &[Vector2<f64>],
    cap: f64,
) -> Option<f64> {
    if xa.len() < 8 || xa.len() != xb.len() {
        return None;
    }
    let transfer = |m: &Vector3<f64>, a: &Vector2<f64>, b: &Vector2<f64>| {
        let x = a.push(1.0);
        let v = r * x + t * m.dot(&x);
        if v.z > 0.0 {
            (Vector2::new(v.x / v.z, v.y / v.z) - b).norm()
        } else {
            f64::INFINITY
        }
    };
    let mut m = Vector3::zeros();
    for reach in [f64::INFINITY, 16.0 * cap, 4.0 * cap] {
        // Each match: (x_b,i t_z − t_i) (x_aᵀ m) = y_i − x_b,i y_z, with y = R x_a, i = x, y.
        let (mut n, mut rhs) = (Matrix3::zeros(), Vector3::zeros());
        for (a, b) in xa.iter().zip(xb) {
            if transfer(&m, a, b) > reach {
                continue;
            }
            let x = a.push(1.0);
            let y = r * x;
            for (bi, ti, yi) in [(b.x, t.x, y.x), (b.y, t.y, y.y)] {
                let row = x * (bi * t.z - ti);
                n += row * row.transpose();
                rhs += row * (yi - bi * y.z);
            }
        }
        // With no baseline every row vanishes and the plane does not matter: m stays.
        let ridge = 1e-12 * (1.0 + n.trace());
        if let Some(next) = (n + Matrix3::identity() * ridge)
            .cholesky()
            .map(|c| c.solve(&rhs))
        {
            if next.iter().all(|v| v.is_finite()) {
                m = next;
            }
        }
    }
    let held = xa
        .iter()
        .zip(xb)
        .filter(|(a, b)| transfer(&m, a, b) < cap)
        .count();
    Some(held as f64 / xa.len() as f64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Rotation3;

    /// Matches of a wall 3 m in front of camera a (normal tilted 20°), seen from a camera moved
    /// `baseline` m sideways and turned 3°.
    #[allow(clippy::type_complexity)]
    fn wall(
        baseline: f64,
    ) -> (
        Matrix3<f64>,
        Vector3<f64>,
        Vec<Vector2<f64>>,
        Vec<Vector2<f64>>,
    ) {
        let r = *Rotation3::from_axis_angle(&Vector3::y_axis(), 3f64.to_radians()).matrix();
        let t = Vector3::new(-baseline, 0.01 * baseline, 0.0);
        let normal = Rotation3::from_axis_angle(&Vector3::x_axis(), 20f64.to_radians())
            * Vector3::new(0.0, 0.0, 1.0);
        let (mut xa, mut xb) = (Vec::new(), Vec::new());
        for i in 0..200 {
            let (u, v) = ((i % 20) as f64 / 20.0 - 0.5, (i / 20) as f64 / 10.0 - 0.5);
            let ray = Vector3::new(u, v, 1.0);
            // The ray meets the plane n·X = 3.
            let p = ray * (3.0 / normal.dot(&ray));
            let q = r * p + t;
            xa.push(Vector2::new(u, v));
            xb.push(Vector2::new(q.x / q.z, q.y / q.z));
        }
        (r, t, xa, xb)
    }

    #[test]
    fn the_right_pose_explains_a_plane_and_a_turned_one_does_not() {
        let cap = 4.0 / 1000.0;
        for baseline in [0.0, 0.05, 0.3] {
            let (r, t, xa, xb) = wall(baseline);
            let right = plane_support(&r, &t, &xa, &xb, cap).expect("enough");
            assert!(right > 0.99, "baseline {baseline}: {right}");
            for axis in [Vector3::x_axis(), Vector3::y_axis(), Vector3::z_axis()] {
                let turned = Rotation3::from_axis_angle(&axis, 3f64.to_radians()).matrix() * r;
                let wrong = plane_support(&turned, &t, &xa, &xb, cap).expect("enough");
                // The plane takes up part of a turn about an axis across the baseline (0.33 of
                // the matches at 3°), all of it only with no baseline.
                let bound = if baseline == 0.0 {
                    0.1
                } else {
                    0.5 * CONFIRMING_SUPPORT
                };
                assert!(wrong < bound, "baseline {baseline}, axis {axis:?}: {wrong}");
            }
        }
    }
}
