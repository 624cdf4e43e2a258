//! Focal-length hypotheses for the metric upgrade under critical motion (§3.4, "critical motion
//! sequences").
//!
//! When the linear self-calibration of eq. 26 is flagged degenerate, the focal length is the
//! direction the equations leave (nearly) free. With the other priors made exact (square pixels,
//! zero skew, centred principal point) a *given* focal determines `Ω*` for any general motion
//! ([`crate::selfcal::upgrade_for_focal`]), and how well the cameras fit that hypothesis is a 1-D
//! function of the focal. Its local minima over a wide range (0.2–5 × (w + h), wide-angle to
//! telephoto) are the hypotheses; the metric bundle adjustment decides between them.

use nalgebra::Matrix3x4;

use crate::model::{cameras_in_order, ProjectiveModel};
use crate::selfcal::{upgrade_for_focal, FocalUpgrade};

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
