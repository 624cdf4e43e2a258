//! Focal-length hypotheses for the metric upgrade under critical motion (§3.4, "critical motion
//! sequences").
//!
//! When the linear self-calibration of eq. 26 is flagged degenerate, the focal length is the
//! direction the equations leave (nearly) free. With the other priors made exact (square pixels,
//! zero skew, centred principal point) a *given* focal determines `Ω*` for any general motion
//! ([`crate::upgrade::selfcal::upgrade_for_focal`]), and how well the cameras fit that hypothesis is a 1-D
//! function of the focal. Its local minima over a wide range (0.2–5 × (w + h), wide-angle to
//! telephoto) are the hypotheses; the metric bundle adjustment decides between them.
//!
//! An independent source that does not depend on the projective frame: the median of the two-view
//! focal lengths of the verified pairs with the most inliers ([`two_view_focal`], Bougnoux 1998's
//! formula from `F` alone). And with a known calibration, eq. 26 with `K` given
//! ([`known_focal_upgrade`]) is the upgrade itself, whatever the motion.

use nalgebra::{Matrix3, Matrix3x4, Vector3};

use crate::context::Context;
use handheld_robust::TwoViewConfiguration;

use crate::projective::model::{cameras_in_order, ProjectiveModel};
use crate::upgrade::selfcal::{upgrade_for_focal, FocalUpgrade};

/// Focal range searched, in `K_N` units (eq. 24: `f / (w + h)`).
pub(crate) const RANGE: (f64, f64) = (0.2, 5.0);
/// Grid samples over [`RANGE`] (log-spaced).
const SAMPLES: usize = 33;
/// ν re-weighting solves per evaluation.
const SOLVES: usize = 3;

fn evaluate(cams: &[Matrix3x4<f64>], log_f: f64) -> Option<FocalUpgrade> {
    let u = upgrade_for_focal(cams, log_f.exp(), SOLVES).ok()?;
    u.residual.is_finite().then_some(u)
}

/// Golden-section refinement of a bracketed minimum of the residual over `log f ∈ [a, b]`.
fn refine(cams: &[Matrix3x4<f64>], mut a: f64, mut b: f64) -> Option<FocalUpgrade> {
    let g = (5f64.sqrt() - 1.0) / 2.0;
    let cost = |x: f64| evaluate(cams, x).map_or(f64::INFINITY, |u| u.residual);
    let mut c = b - g * (b - a);
    let mut d = a + g * (b - a);
    let (mut fc, mut fd) = (cost(c), cost(d));
    for _ in 0..24 {
        if fc < fd {
            b = d;
            d = c;
            fd = fc;
            c = b - g * (b - a);
            fc = cost(c);
        } else {
            a = c;
            c = d;
            fc = fd;
            d = a + g * (b - a);
            fd = cost(d);
        }
    }
    evaluate(cams, 0.5 * (a + b))
}

/// Up to `max` focal hypotheses (best residual first), each with its upgrade `T`.
pub(crate) fn focal_hypotheses(model: &ProjectiveModel, max: usize) -> Vec<FocalUpgrade> {
    let cams: Vec<Matrix3x4<f64>> = cameras_in_order(model).into_iter().map(|c| c.1).collect();
    if cams.len() < 2 {
        return Vec::new();
    }
    let (lo, hi) = (RANGE.0.ln(), RANGE.1.ln());
    let step = (hi - lo) / (SAMPLES - 1) as f64;
    let grid: Vec<f64> = (0..SAMPLES).map(|i| lo + step * i as f64).collect();
    let res: Vec<f64> = grid
        .iter()
        .map(|&x| evaluate(&cams, x).map_or(f64::INFINITY, |u| u.residual))
        .collect();
    let mut out: Vec<FocalUpgrade> = Vec::new();
    for i in 0..SAMPLES {
        let left = if i == 0 { f64::INFINITY } else { res[i - 1] };
        let right = if i + 1 == SAMPLES {
            f64::INFINITY
        } else {
            res[i + 1]
        };
        if !(res[i].is_finite() && res[i] <= left && res[i] <= right) {
            continue;
        }
        let a = grid[i.saturating_sub(1)];
        let b = grid[(i + 1).min(SAMPLES - 1)];
        if let Some(u) = refine(&cams, a, b) {
            out.push(u);
        }
    }
    // Consistent hypotheses (semi-definite Ω*) first, then by residual.
    out.sort_by(|a, b| {
        a.clamped
            .cmp(&b.clamped)
            .then(a.residual.total_cmp(&b.residual))
    });
    out.truncate(max);
    out
}

/// The upgrade for a known focal length (`focal` in `K_N` units), the principal point taken at the
/// image centre and the pixels square: eq. 26 with `K` given, so it does not depend on the motion
/// being general (§3.4's known-calibration case).
pub(crate) fn known_focal_upgrade(model: &ProjectiveModel, focal: f64) -> Option<FocalUpgrade> {
    let cams: Vec<Matrix3x4<f64>> = cameras_in_order(model).into_iter().map(|c| c.1).collect();
    if cams.len() < 2 || !(focal.is_finite() && focal > 0.0) {
        return None;
    }
    evaluate(&cams, focal.ln())
}

/// Verified pairs whose two-view focal lengths are pooled (most inliers first).
const TWO_VIEW_PAIRS: usize = 12;
/// Two-view estimates needed before their median is a hypothesis.
const MIN_TWO_VIEW_ESTIMATES: usize = 3;

/// The focal length of the first camera of a pair from its fundamental matrix alone (Bougnoux,
/// "From projective to Euclidean space under any practical situation, a criticism of
/// self-calibration", ICCV 1998, eq. 6), with both principal points known, square pixels and zero
/// skew: with `x₂ᵀ F x₁ = 0`, `F e₁ = 0`, `Fᵀ e₂ = 0` and `Ĩ = diag(1, 1, 0)`,
///
/// `f₁² = − (p₂ᵀ [e₂]ₓ Ĩ F p₁ · p₁ᵀ Fᵀ p₂) / (p₂ᵀ [e₂]ₓ Ĩ F Ĩ Fᵀ p₂)`.
///
/// `f` maps normalised coordinates (principal point at the origin) of image 1 to those of image 2.
/// `None` when the estimate is not a positive square: the formula is singular when the optical
/// axes are coplanar (a turntable, pure forward motion), exactly the critical motions for which
/// the other sources of hypotheses are needed, so its failures are expected and skipped.
pub(crate) fn bougnoux_focal(f: &Matrix3<f64>) -> Option<f64> {
    let p = Vector3::new(0.0, 0.0, 1.0);
    let it = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, 0.0));
    let svd = f.transpose().svd(false, true);
    let v_t = svd.v_t?;
    let (k, _) = svd
        .singular_values
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))?;
    let e2: Vector3<f64> = v_t.row(k).transpose();
    let e2x = e2.cross_matrix();
    let num = (p.transpose() * e2x * it * f * p)[0] * (p.transpose() * f.transpose() * p)[0];
    let den = (p.transpose() * e2x * it * f * it * f.transpose() * p)[0];
    let f2 = -num / den;
    (f2.is_finite() && f2 > 0.0).then(|| f2.sqrt())
}

/// A focal hypothesis from the verified pairs between the model's views: the median of the
/// two-view (Bougnoux) estimates of both cameras of the pairs with the most inliers, in `K_N` units
/// (principal points at the image centres). It does not depend on the projective frame, so it is
/// an independent source beside the absolute quadric's hypotheses; `None` when fewer than
/// [`MIN_TWO_VIEW_ESTIMATES`] pairs give one in [`RANGE`].
pub(crate) fn two_view_focal(ctx: &Context, model: &ProjectiveModel) -> Option<f64> {
    let mut members = vec![false; ctx.input.images.len()];
    for &i in &model.order {
        members[i] = true;
    }
    two_view_focal_among(ctx, &members)
}

/// [`two_view_focal`] over the verified pairs between the images marked in `members`.
pub(crate) fn two_view_focal_among(ctx: &Context, members: &[bool]) -> Option<f64> {
    let mut pairs: Vec<_> = ctx
        .input
        .pairs
        .iter()
        .filter(|p| p.configuration == TwoViewConfiguration::General)
        .filter(|p| members[p.a] && members[p.b])
        .filter_map(|p| Some((p, p.f?)))
        .collect();
    pairs.sort_by_key(|p| std::cmp::Reverse(p.0.matches.len()));
    let mut estimates: Vec<f64> = Vec::new();
    for (p, f) in pairs.into_iter().take(TWO_VIEW_PAIRS) {
        // In normalised coordinates x = K_N⁻¹ x_px: F_n = K_N,bᵀ F K_N,a.
        let fnorm = ctx.kn[p.b].transpose() * f * ctx.kn[p.a];
        let fnorm = fnorm / fnorm.norm();
        for g in [fnorm, fnorm.transpose()] {
            if let Some(x) = bougnoux_focal(&g).filter(|x| *x > RANGE.0 && *x < RANGE.1) {
                estimates.push(x);
            }
        }
    }
    if estimates.len() < MIN_TWO_VIEW_ESTIMATES {
        return None;
    }
    estimates.sort_by(f64::total_cmp);
    Some(estimates[estimates.len() / 2])
}

#[cfg(test)]
mod tests {
    use nalgebra::{Rotation3, Vector3};

    use super::*;

    /// `F` of two cameras `K[I | 0]` and `K[R | t]` with a centred principal point.
    fn fundamental(f: f64, r: Rotation3<f64>, t: Vector3<f64>) -> Matrix3<f64> {
        let k = Matrix3::new(f, 0.0, 0.0, 0.0, f, 0.0, 0.0, 0.0, 1.0);
        let ki = k.try_inverse().unwrap_or_else(Matrix3::identity);
        ki.transpose() * t.cross_matrix() * r.matrix() * ki
    }

    #[test]
    fn bougnoux_recovers_the_focal_length_of_a_general_pair() {
        for (f, axis, angle, t) in [
            (
                0.8,
                Vector3::new(0.1, 1.0, 0.2),
                0.3,
                Vector3::new(-1.0, 0.1, 0.2),
            ),
            (
                2.4,
                Vector3::new(0.3, 1.0, -0.1),
                0.15,
                Vector3::new(-0.5, 0.2, 0.1),
            ),
            (
                0.45,
                Vector3::new(1.0, 0.2, 0.4),
                -0.4,
                Vector3::new(0.2, -1.0, 0.3),
            ),
        ] {
            let r = Rotation3::from_axis_angle(&nalgebra::Unit::new_normalize(axis), angle);
            let fm = fundamental(f, r, t);
            for g in [fm, fm.transpose()] {
                let est = bougnoux_focal(&(g * 7.0)).expect("a general pair");
                assert!((est / f - 1.0).abs() < 1e-6, "{est} against {f}");
            }
        }
    }

    #[test]
    fn coplanar_optical_axes_give_no_estimate() {
        // A turntable: rotation about the image's y axis, translation in the x–z plane. The
        // optical axes are coplanar and the formula is singular (0 / 0 up to round-off).
        let r = Rotation3::from_axis_angle(&Vector3::y_axis(), 0.3);
        let fm = fundamental(1.0, r, Vector3::new(-1.0, 0.0, 0.3));
        // The turntable's focal length (1.0) must not come out: the estimate is refused, not a
        // number near the truth by chance (nor any other one, which the hypotheses would trust).
        let est = bougnoux_focal(&fm);
        assert_eq!(est, None, "a turntable pair gave the focal length {est:?}");
        // The same pair with the optical axes out of the plane (a tilted axis) is general again.
        let tilted = Rotation3::from_axis_angle(
            &nalgebra::Unit::new_normalize(Vector3::new(0.3, 1.0, 0.0)),
            0.3,
        );
        let est = bougnoux_focal(&fundamental(1.0, tilted, Vector3::new(-1.0, 0.2, 0.3)))
            .expect("a general pair gives an estimate");
        assert!((est - 1.0).abs() < 1e-6, "{est}");
    }
}
