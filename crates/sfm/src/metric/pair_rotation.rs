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
