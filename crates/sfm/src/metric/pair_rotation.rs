//! A verified pair's relative rotation under the model's calibration, and how well the pair fixes
//! it: the rotation of `E = K_bᵀ F K_a` (H&Z §9.6.2) refined by Gauss–Newton on the inliers'
//! Sampson errors (and, from a second start, the model's own relative pose: [`best_pose`]), and
//! its first-order covariance (H&Z §5.2). Used by the view-consistency check
//! (`consistency.rs`) to widen what a pair allows: a long lens or a short baseline fixes a pair's
//! rotation only to degrees, a wide pair to a fraction of one.

use nalgebra::Vector2;

/// The standard deviation (radians, the largest axis) of the relative rotation that the matches
/// `xa ↔ xb` (normalised coordinates) give with `x_b ~ R x_a + t`: the first-order covariance
/// σ̂² (JᵀJ)⁻¹ of the five-parameter pose (a rotation increment, two angles of the unit
/// translation) that minimises their Sampson errors (H&Z §5.2, §11.4.3), with σ̂ from the residuals
/// themselves. `scale` is the number of inliers per sample (JᵀJ grows with them). A long lens, a
/// short baseline or few inliers give a wide covariance: rotation then trades against translation
/// (a narrow field of view cannot tell a turn from a sideways step). `None` when the matches do
/// not fix the pose (JᵀJ singular).
pub(crate) fn rotation_sigma(
    r: &nalgebra::Matrix3<f64>,
    t: &nalgebra::Vector3<f64>,
    xa: &[Vector2<f64>],
    xb: &[Vector2<f64>],
    scale: f64,
) -> Option<f64> {
    pose_step(r, t, xa, xb, scale).and_then(|s| s.sigma)
}

/// The relative pose `(R, t)` refined by Gauss–Newton on the Sampson errors of `xa ↔ xb` (a few
/// damped steps, each kept only when it lowers their sum of squares), with the rotation's standard
/// deviation there ([`rotation_sigma`]). A step, and the deviation, use the matches within
/// [`reach`] of their epipolar lines under the current pose: `cap` (normalised units) once the pose
/// fits, wider while it does not yet (a start projected from `E` can put every match beyond `cap`).
pub(crate) fn refine_pose(
    r: &nalgebra::Matrix3<f64>,
    t: &nalgebra::Vector3<f64>,
    xa: &[Vector2<f64>],
    xb: &[Vector2<f64>],
    scale: f64,
    cap: f64,
) -> (nalgebra::Matrix3<f64>, nalgebra::Vector3<f64>, Option<f64>) {
    let (mut r, mut t) = (*r, *t);
    for _ in 0..8 {
        let (ia, ib) = within(&r, &t, xa, xb, cap);
        let Some(s) = pose_step(&r, &t, &ia, &ib, scale) else {
            break;
        };
        match s.next {
            Some((r2, t2)) => (r, t) = (r2, t2),
            None => return (r, t, s.sigma),
        }
    }
    let (ia, ib) = within(&r, &t, xa, xb, cap);
    let sigma = rotation_sigma(&r, &t, &ia, &ib, scale);
    (r, t, sigma)
}

/// How far from its epipolar line (normalised units) a match may lie to take part in a step of
/// [`refine_pose`]: `cap`, or three times the matches' median distance when that is wider (a
/// graduated threshold: the better half always takes part).
fn reach(e: &nalgebra::Matrix3<f64>, xa: &[Vector2<f64>], xb: &[Vector2<f64>], cap: f64) -> f64 {
    let mut d: Vec<f64> = xa
        .iter()
        .zip(xb)
        .map(|(a, b)| sampson_sq(e, a, b))
        .collect();
    if d.is_empty() {
        return cap;
    }
    let mid = d.len() / 2;
    let (_, median, _) = d.select_nth_unstable_by(mid, f64::total_cmp);
    cap.max(3.0 * median.sqrt())
}

/// The matches of `xa ↔ xb` within [`reach`] of their epipolar lines under `(r, t)`.
fn within(
    r: &nalgebra::Matrix3<f64>,
    t: &nalgebra::Vector3<f64>,
    xa: &[Vector2<f64>],
    xb: &[Vector2<f64>],
    cap: f64,
) -> (Vec<Vector2<f64>>, Vec<Vector2<f64>>) {
    let e = handheld_geometry::skew(t) * r;
    let bound = reach(&e, xa, xb, cap);
    xa.iter()
        .zip(xb)
        .filter(|(a, b)| sampson_sq(&e, a, b) <= bound * bound)
        .map(|(a, b)| (*a, *b))
        .unzip()
}

/// The pair's relative pose from several starts, each refined by [`refine_pose`]: the one with
/// the smallest sum of squared Sampson errors, each capped at `cap` (normalised units; MSAC's
/// cost, Torr & Zisserman 2000), with its rotation's standard deviation; `None` when no start is
/// usable.
///
/// The pose is calibrated (five parameters under the model's `K`), which a plane does not make
/// degenerate; the fundamental matrix it starts from is not: where most inliers lie on one plane
/// (a ground seen from across an object, a façade) or the field of view is narrow, `F` is poorly
/// determined and the pose projected from `E = K_bᵀ F K_a` can lie tens of degrees away, in another
/// basin of the pose's cost that a few Gauss–Newton steps do not leave. The model's own relative
/// pose is then the second start: where the model is right it reaches the deeper minimum, where a
/// view is misplaced its start descends to a shallower one and the pair's own pose wins.
///
/// Why capped: a poorly determined `F` also admits wrong matches (repeated texture) that the true
/// geometry puts tens of pixels off their lines. On a synthetic hemisphere at an 11° field of view,
/// the true pose put 89 % of a pair's 285 inliers within 0.3 px and the other 11 % some 90 px
/// off; the pose from `E` fitted all of them at 5.6 px RMS. The plain sum of squares chose the
/// latter, 73° from the truth, and six correctly placed views were taken out as misplaced.
pub(crate) fn best_pose(
    starts: &[(nalgebra::Matrix3<f64>, nalgebra::Vector3<f64>)],
    xa: &[Vector2<f64>],
    xb: &[Vector2<f64>],
    scale: f64,
    cap: f64,
) -> Option<(nalgebra::Matrix3<f64>, Option<f64>)> {
    starts
        .iter()
        .filter(|(_, t)| t.norm() > 1e-12)
        .map(|(r, t)| {
            let (r, t, sigma) = refine_pose(r, t, xa, xb, scale, cap);
            let e = handheld_geometry::skew(&t) * r;
            let cost: f64 = xa
                .iter()
                .zip(xb)
                .map(|(a, b)| sampson_sq(&e, a, b).min(cap * cap))
                .sum();
            (r, sigma, cost)
        })
        .filter(|x| x.2.is_finite())
        .min_by(|a, b| a.2.total_cmp(&b.2))
        .map(|(r, sigma, _)| (r, sigma))
}

/// One Gauss–Newton step of [`refine_pose`] and the covariance at its start.
struct PoseStep {
    /// The pose after the step, when it lowered the cost.
    next: Option<(nalgebra::Matrix3<f64>, nalgebra::Vector3<f64>)>,
    sigma: Option<f64>,
}

fn pose_step(
    r: &nalgebra::Matrix3<f64>,
    t: &nalgebra::Vector3<f64>,
    xa: &[Vector2<f64>],
    xb: &[Vector2<f64>],
    scale: f64,
) -> Option<PoseStep> {
    use nalgebra::{Matrix5, Rotation3, Vector3, Vector5};
    let n = xa.len();
    if n < 8 {
        return None;
    }
    let t0 = t.try_normalize(1e-12)?;
    // Two unit vectors orthogonal to t0.
    let helper = if t0.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let b1 = t0.cross(&helper).normalize();
    let b2 = t0.cross(&b1);
    let residuals = |p: &Vector5<f64>| -> Vec<f64> {
        let rot = Rotation3::new(Vector3::new(p[0], p[1], p[2])).matrix() * r;
        let tt = (t0 + p[3] * b1 + p[4] * b2).normalize();
        let e = handheld_geometry::skew(&tt) * rot;
        xa.iter()
            .zip(xb)
            .map(|(a, b)| {
                let (ha, hb) = (a.push(1.0), b.push(1.0));
                let (ea, etb) = (e * ha, e.transpose() * hb);
                let den = (ea.x * ea.x + ea.y * ea.y + etb.x * etb.x + etb.y * etb.y).sqrt();
                if den > 0.0 {
                    hb.dot(&ea) / den
                } else {
                    0.0
                }
            })
            .collect()
    };
    let r0 = residuals(&Vector5::zeros());
    let h = 1e-7;
    let cols: Vec<Vec<f64>> = (0..5)
        .map(|k| {
            let mut p = Vector5::zeros();
            p[k] = h;
            residuals(&p)
                .iter()
                .zip(&r0)
                .map(|(a, b)| (a - b) / h)
                .collect()
        })
        .collect();
    let mut jtj = Matrix5::zeros();
    for i in 0..5 {
        for j in 0..5 {
            jtj[(i, j)] = (0..n).map(|k| cols[i][k] * cols[j][k]).sum::<f64>() * scale;
        }
    }
    let cost0 = r0.iter().map(|v| v * v).sum::<f64>();
    let sigma2 = cost0 / (n as f64 - 5.0).max(1.0);
    let inv = jtj.try_inverse()?;
    let rot = (inv * sigma2).fixed_view::<3, 3>(0, 0).into_owned();
    let largest = rot.symmetric_eigenvalues().max();
    let sigma = (largest.is_finite() && largest >= 0.0).then(|| largest.sqrt());
    // The Gauss–Newton step (JᵀJ was scaled by `scale`; so is Jᵀr).
    let mut jtr = Vector5::zeros();
    for i in 0..5 {
        jtr[i] = (0..n).map(|k| cols[i][k] * r0[k]).sum::<f64>() * scale;
    }
    let delta = -(inv * jtr);
    let next = delta.iter().all(|d| d.is_finite()).then(|| {
        let rot = Rotation3::new(Vector3::new(delta[0], delta[1], delta[2])).matrix() * r;
        let tt = (t0 + delta[3] * b1 + delta[4] * b2).normalize();
        (rot, tt)
    });
    let next = next.filter(|(r2, t2)| {
        let e = handheld_geometry::skew(t2) * r2;
        sampson_cost(&e, xa, xb) < cost0 * (1.0 - 1e-9)
    });
    Some(PoseStep { next, sigma })
}

/// Σ of the squared Sampson errors of `xa ↔ xb` under `e`.
fn sampson_cost(e: &nalgebra::Matrix3<f64>, xa: &[Vector2<f64>], xb: &[Vector2<f64>]) -> f64 {
    xa.iter().zip(xb).map(|(a, b)| sampson_sq(e, a, b)).sum()
}

/// The squared Sampson error of `a ↔ b` under `e`.
fn sampson_sq(e: &nalgebra::Matrix3<f64>, a: &Vector2<f64>, b: &Vector2<f64>) -> f64 {
    let (ha, hb) = (a.push(1.0), b.push(1.0));
    let (ea, etb) = (e * ha, e.transpose() * hb);
    let den = ea.x * ea.x + ea.y * ea.y + etb.x * etb.x + etb.y * etb.y;
    if den > 0.0 {
        hb.dot(&ea).powi(2) / den
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    /// Matches of points 9.6–10.4 m away (an object 0.8 m deep) filling a `w`×480 image of focal length `f`, seen from a
    /// camera 0.5 m to the side turned by 2°, with `noise_px` of uniform noise (deterministic).
    #[allow(clippy::type_complexity)]
    fn pair(
        f: f64,
        noise_px: f64,
    ) -> (
        Vec<Vector2<f64>>,
        Vec<Vector2<f64>>,
        nalgebra::Matrix3<f64>,
        Vector3<f64>,
    ) {
        let r =
            *nalgebra::Rotation3::from_axis_angle(&Vector3::y_axis(), 2f64.to_radians()).matrix();
        let t = Vector3::new(-0.5, 0.0, 0.0);
        let mut state = 12345u64;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let (mut xa, mut xb) = (Vec::new(), Vec::new());
        for _ in 0..300 {
            let z = 9.6 + 0.8 * next();
            let (u, v) = ((next() - 0.5) * 640.0 / f, (next() - 0.5) * 480.0 / f);
            let p = Vector3::new(u * z, v * z, z);
            let q = r * p + t;
            let mut noisy = |x: Vector2<f64>| {
                x + Vector2::new(next() - 0.5, next() - 0.5) * (2.0 * noise_px / f)
            };
            xa.push(noisy(Vector2::new(p.x / p.z, p.y / p.z)));
            xb.push(noisy(Vector2::new(q.x / q.z, q.y / q.z)));
        }
        (xa, xb, r, t)
    }

    #[test]
    fn a_long_lens_leaves_a_pair_rotation_uncertain_and_a_wide_one_does_not() {
        let (xa, xb, r, t) = pair(500.0, 0.5);
        let wide = rotation_sigma(&r, &t, &xa, &xb, 1.0)
            .expect("fixed")
            .to_degrees();
        let (xa, xb, r, t) = pair(3300.0, 0.5);
        let long = rotation_sigma(&r, &t, &xa, &xb, 1.0)
            .expect("fixed")
            .to_degrees();
        assert!(wide < 0.1, "wide lens: σ = {wide}°");
        assert!(long > 3.0 * wide, "long lens: σ = {long}°, wide {wide}°");
        // More inliers of the same spread fix it better (σ ∝ 1/√n).
        let (xa, xb, r, t) = pair(3300.0, 0.5);
        let more = rotation_sigma(&r, &t, &xa, &xb, 4.0)
            .expect("fixed")
            .to_degrees();
        assert!((more / long - 0.5).abs() < 0.01, "{more} vs {long}");
    }

    #[test]
    fn a_pose_off_by_a_degree_is_refined_back_onto_its_matches() {
        let (xa, xb, r, t) = pair(500.0, 0.0);
        let off = *nalgebra::Rotation3::from_axis_angle(&Vector3::x_axis(), 1f64.to_radians())
            .matrix()
            * r;
        let (r1, _, sigma) = refine_pose(&off, &t.normalize(), &xa, &xb, 1.0, f64::INFINITY);
        let angle = |a: &nalgebra::Matrix3<f64>| {
            (((a * r.transpose()).trace() - 1.0) / 2.0)
                .clamp(-1.0, 1.0)
                .acos()
                .to_degrees()
        };
        assert!(angle(&r1) < 1e-3, "{}° after refinement", angle(&r1));
        assert!(sigma.is_some_and(|s| s < 1e-6), "{sigma:?} without noise");
        // Capped at 0.1 px, which the start puts nearly every match beyond: the graduated reach
        // still brings it back.
        let e = handheld_geometry::skew(&t.normalize()) * off;
        let beyond = xa
            .iter()
            .zip(&xb)
            .filter(|(a, b)| {
                let (ha, hb) = (a.push(1.0), b.push(1.0));
                let (ea, etb) = (e * ha, e.transpose() * hb);
                hb.dot(&ea).abs() / (ea.xy().norm_squared() + etb.xy().norm_squared()).sqrt()
                    > 0.1 / 500.0
            })
            .count();
        assert!(
            beyond > xa.len() * 9 / 10,
            "{beyond} of {} beyond",
            xa.len()
        );
        let (r2, _, _) = refine_pose(&off, &t.normalize(), &xa, &xb, 1.0, 0.1 / 500.0);
        assert!(angle(&r2) < 1e-3, "{}° after capped refinement", angle(&r2));
    }

    #[test]
    fn the_better_of_two_starts_gives_the_pairs_rotation() {
        let (xa, xb, r, t) = pair(500.0, 0.5);
        // A start in another basin (as a poorly determined F gives) and the true one, either way
        // round: the true basin's fit wins.
        let far = *nalgebra::Rotation3::from_axis_angle(&Vector3::x_axis(), 40f64.to_radians())
            .matrix()
            * r;
        for starts in [
            [(far, -t), (r, t.normalize())],
            [(r, t.normalize()), (far, -t)],
        ] {
            let (got, sigma) = best_pose(&starts, &xa, &xb, 1.0, f64::INFINITY).expect("a pose");
            let deg = (((got * r.transpose()).trace() - 1.0) / 2.0)
                .clamp(-1.0, 1.0)
                .acos()
                .to_degrees();
            assert!(deg < 0.2, "{deg}° from the truth");
            assert!(sigma.is_some());
        }
    }

    #[test]
    fn wrong_matches_far_off_their_lines_do_not_choose_the_pairs_rotation() {
        // A long lens (f = 3300 px) and one match in ten wrong (a repeated pattern: 30–150 px
        // off its true line). Their squares outweigh everything else: the plain sum of squares
        // prefers the basin another start descends to, 3° off; capped at 4 px, the truth's.
        let f = 3300.0;
        let (mut xa, xb, r, t) = pair(f, 0.5);
        for (k, x) in xa.iter_mut().enumerate().filter(|(k, _)| k % 10 == 0) {
            let off = 30.0 + (k % 7) as f64 * 20.0;
            *x += Vector2::new(0.3, 1.0).normalize() * (off / f);
        }
        let deg = |got: &nalgebra::Matrix3<f64>| {
            (((got * r.transpose()).trace() - 1.0) / 2.0)
                .clamp(-1.0, 1.0)
                .acos()
                .to_degrees()
        };
        // A start 40° off about x with the translation reversed (as a poorly determined F gives)
        // and the true one.
        let far = *nalgebra::Rotation3::from_axis_angle(&Vector3::x_axis(), 40f64.to_radians())
            .matrix()
            * r;
        let starts = [(far, -t.normalize()), (r, t.normalize())];
        let (plain, _) = best_pose(&starts, &xa, &xb, 1.0, f64::INFINITY).expect("a pose");
        let (capped, sigma) = best_pose(&starts, &xa, &xb, 1.0, 4.0 / f).expect("a pose");
        assert!(deg(&plain) > 2.0, "the plain fit is {}° off", deg(&plain));
        assert!(
            deg(&capped) < 0.3,
            "the capped fit is {}° off",
            deg(&capped)
        );
        assert!(sigma.is_some());
    }
}
