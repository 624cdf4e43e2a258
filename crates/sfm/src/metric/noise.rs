//! The noise of a metric model's observations, measured on its residuals, and what the later
//! adjustments of the metric schedule take from it: their Huber scale and the weight of their
//! priors ([`noise_scaled_loss`]).

use std::collections::BTreeMap;

use handheld_bundle::{
    observation_sigma, GaussianPrior, IntrinsicParam, RobustLoss, RollingShutter,
};
use handheld_core::{CameraId, MetricReconstruction};

use crate::context::Context;

/// Huber's tuning constant for 95 % efficiency under Gaussian noise (Holland & Welsch 1977).
pub(crate) const HUBER_95: f64 = 1.345;

/// The spread of a model's residuals and the noise of its observations, in pixels of a median-σ
/// keypoint (σᵢ: the keypoint's localisation σ, [`Context::keypoint_sigma`]).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Noise {
    /// σ_r = median(‖rᵢ‖ / σᵢ) / 1.1774 (the median of a 2D Gaussian error's norm is 1.1774 σ).
    pub residual: f64,
    /// σ̂ = σ_r √(n / (n − p)): the `p` parameters the adjustment fitted to the `n` residuals (the
    /// points' 3 and the views' 6) took part of the noise out of them; a 2-view point keeps only
    /// a quarter of it.
    pub observation: f64,
}

/// The [`Noise`] of the adjusted model `rec`; `None` without redundant observations.
pub(crate) fn noise_sigma(ctx: &Context, rec: &MetricReconstruction) -> Option<Noise> {
    noise_sigma_rolling(ctx, rec, None)
}

/// [`noise_sigma`], the observations projected from their rows' poses under `rolling`.
pub(crate) fn noise_sigma_rolling(
    ctx: &Context,
    rec: &MetricReconstruction,
    rolling: Option<&RollingShutter>,
) -> Option<Noise> {
    let mut e: Vec<f64> = crate::metric::rolling::residuals(rec, rolling)
        .filter_map(|(_, el, r)| {
            Some(r? / observation_sigma(&ctx.keypoint_sigma, el.image_id, el.point2d_idx))
        })
        .collect();
    let n = 2.0 * e.len() as f64;
    let p = 3.0 * rec.points.len() as f64 + 6.0 * rec.views.len() as f64;
    if e.is_empty() || n <= p {
        return None;
    }
    let mid = e.len() / 2;
    let residual = *e.select_nth_unstable_by(mid, f64::total_cmp).1 / 1.1774;
    Some(Noise {
        residual,
        observation: residual * (n / (n - p)).sqrt(),
    })
}

/// Smallest σ_r and σ̂ [`noise_scaled_loss`] uses: exact synthetic data would otherwise make the Huber scale
/// vanish and every residual an L1 term.
const MIN_NOISE_SIGMA_PX: f64 = 0.01;

/// The loss of the adjustments after the first, and the factor on the priors' σ, from the
/// observations' measured noise ([`noise_sigma`]), as in Huber's proposal 2 (Huber 1981 §7.8):
/// the scale is Huber's 95 %-efficiency constant times the residuals' spread σ_r (never above
/// `SfmOptions::loss_scale_px`), and the priors are weighed against data of noise σ̂.
///
/// The adjustment's cost counts a residual of 1 px (of a median-σ keypoint) as one unit of χ², so a
/// prior with σ in pixels is a statement against data of σ = 1 px. Real keypoints are better than
/// that (herzjesu-P8: σ̂ = 0.24 px), so the data's cost must be divided by σ̂², or equivalently
/// each prior's σ multiplied by 1/σ̂: otherwise the principal point's prior at the image centre
/// outweighs the data 17-fold (templeSparseRing: 17 px from the centre in truth, held at 3 px from
/// it by the prior under a tight loss). And a fixed 1.5 px Huber scale is 6 σ̂ there: the
/// mismatches along the epipolar lines, 1–2 px off, counted as inliers and pulled the principal
/// point (herzjesu-P8: 616 observations, 1.8 %, more than 1.5 px from the ground-truth cameras'
/// reprojection moved it by 2.5 px).
pub(crate) fn noise_scaled_loss(
    ctx: &Context,
    rec: &MetricReconstruction,
    rolling: Option<&RollingShutter>,
) -> (RobustLoss, f64, Option<Noise>) {
    let fixed = ctx.opts.loss_scale_px;
    if !ctx.opts.noise_scaled_loss {
        return (RobustLoss::Huber(fixed), 1.0, None);
    }
    match noise_sigma_rolling(ctx, rec, rolling) {
        Some(n) if n.residual.is_finite() && n.observation.is_finite() => {
            // The loss acts on the residuals: its scale is theirs. The priors compete with the
            // observations' information, whose noise is σ̂.
            let r = n.residual.max(MIN_NOISE_SIGMA_PX);
            let s = n.observation.max(MIN_NOISE_SIGMA_PX);
            (
                RobustLoss::Huber((HUBER_95 * r).min(fixed)),
                1.0 / s,
                Some(n),
            )
        }
        _ => (RobustLoss::Huber(fixed), 1.0, None),
    }
}

/// `priors` with every σ multiplied by `factor`.
pub(crate) fn scaled_priors(
    priors: &BTreeMap<CameraId, Vec<(IntrinsicParam, GaussianPrior)>>,
    factor: f64,
) -> BTreeMap<CameraId, Vec<(IntrinsicParam, GaussianPrior)>> {
    let mut out = priors.clone();
    for v in out.values_mut() {
        for (_, g) in v.iter_mut() {
            g.sigma *= factor;
        }
    }
    out
}
