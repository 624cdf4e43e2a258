//! Whether every registered view agrees with its own verified image pairs.
//!
//! A view can be registered to the wrong place and still fit: resection against a repeated
//! structure, or a partner's points seen from the far side of an object, gives a pose whose few
//! observations reproject well, and every check on the adjustment (removed observations,
//! reprojection error, focal length) passes. The view's verified pairs still carry the truth: the
//! fundamental matrix of each pair, with the model's calibration, is an essential matrix
//! `E = K_bᵀ F K_a` (H&Z eq. 9.12), whose rotation (H&Z §9.6.2, the one of four that puts the
//! inliers in front of both cameras) is the pair's relative rotation, found without the model.
//! A sound view agrees with its partners to a degree or two (the model's calibration is not exact
//! and a two-view rotation is noisy); a misplaced view disagrees with nearly all of them by much
//! more.
//!
//! A view is flagged when the median of its disagreements over its partners, weighted by their
//! inlier counts, exceeds [`MAX_DISAGREEMENT_DEG`]. A misplaced view also raises its partners'
//! medians, so views are judged one at a time: the one with the largest share of disagreeing
//! inliers first (a misplaced view has all of its pairs against it, a partner only the one pair
//! with it); its pairs are then set aside and the others judged again.

use std::collections::BTreeMap;

use handheld_core::MetricReconstruction;
use handheld_robust::TwoViewConfiguration;
use nalgebra::{Rotation3, Vector2};
use serde::Serialize;

use crate::context::Context;

/// Largest weighted-median disagreement (degrees) between a view's relative rotations in the model
/// and those of its verified pairs. Sound views on the project's data sets stay within 1.8°
/// (templeSparseRing, whose ring turns 23° between neighbours) and within 0.3° on the Strecha and
/// KITTI sets; a view registered to the wrong side of templeSparseRing disagreed by 13–24° with
/// every partner.
pub const MAX_DISAGREEMENT_DEG: f64 = 5.0;
/// Fewest inlier matches of a pair whose rotation is trusted.
pub const MIN_PAIR_INLIERS: usize = 30;

/// One view's agreement with its verified pairs.
#[derive(Clone, Debug, Serialize)]
pub struct ViewDisagreement {
    pub image: String,
    /// Weighted median over its partners, degrees.
    pub median_deg: f64,
    /// Partners compared (registered, general configuration, enough inliers).
    pub partners: usize,
}

/// The check's result for the summary.
#[derive(Clone, Debug, Default, Serialize)]
pub struct ConsistencyReport {
    /// The largest weighted-median disagreement among the views kept, degrees.
    pub max_kept_deg: Option<f64>,
    /// Views taken out of the model because their pose disagreed with their pairs.
    pub removed: Vec<ViewDisagreement>,
    /// Views whose first registration disagreed with their pairs: the model was built again
    /// without them, then they were registered into it by calibrated resection where possible
    /// (and judged again).
    pub rebuilt_without: Vec<ViewDisagreement>,
}

/// The angle (degrees) between the relative rotation of views `a` → `b` in `rec` and the one of
/// their verified pair; `None` when the pair is not usable.
fn pair_disagreement(
    ctx: &Context,
    rec: &MetricReconstruction,
    pair: &crate::input::SfmPair,
) -> Option<f64> {
    if pair.configuration != TwoViewConfiguration::General || pair.matches.len() < MIN_PAIR_INLIERS
    {
        return None;
    }
    let f = pair.f?;
    let (ia, ib) = (&ctx.input.images[pair.a], &ctx.input.images[pair.b]);
    let (va, vb) = (rec.views.get(&ia.id)?, rec.views.get(&ib.id)?);
    let ka = &rec.cameras.get(&va.camera_id)?.intrinsics;
    let kb = &rec.cameras.get(&vb.camera_id)?.intrinsics;
    // x_bᵀ F x_a = 0 in pixels; in normalised coordinates x_bᵀ (K_bᵀ F K_a) x_a = 0.
    let e = kb.k_matrix().transpose() * f * ka.k_matrix();
    let (xa, xb): (Vec<Vector2<f64>>, Vec<Vector2<f64>>) = pair
        .matches
        .iter()
        .map(|&(i, j)| {
            (
                ka.pixel_to_normalized(ctx.kps[pair.a][i as usize]),
                kb.pixel_to_normalized(ctx.kps[pair.b][j as usize]),
            )
        })
        .unzip();
    let (_, r, _) = crate::init::essential_pose(&e, &xa, &xb)?;
    let model = (vb.cam_from_world.rotation * va.cam_from_world.rotation.inverse())
        .to_rotation_matrix();
    let two_view = Rotation3::from_matrix_unchecked(r);
    Some((two_view * model.inverse()).angle().to_degrees())
}

/// The weighted median of `(value, weight)`.
fn weighted_median(mut v: Vec<(f64, f64)>) -> f64 {
    v.sort_by(|a, b| a.0.total_cmp(&b.0));
    let half = v.iter().map(|x| x.1).sum::<f64>() / 2.0;
    let mut acc = 0.0;
    for (x, w) in &v {
        acc += w;
        if acc >= half {
            return *x;
        }
    }
    v.last().map_or(0.0, |x| x.0)
}

/// The registered views (input indices) whose pose disagrees with their verified pairs, worst
/// first, and the largest disagreement among the others.
pub(crate) fn inconsistent_views(
    ctx: &Context,
    rec: &MetricReconstruction,
) -> (Vec<(usize, ViewDisagreement)>, Option<f64>) {
    // (a, b, disagreement, inliers) of every usable pair.
    let pairs: Vec<(usize, usize, f64, f64)> = ctx
        .input
        .pairs
        .iter()
        .filter_map(|p| {
            pair_disagreement(ctx, rec, p).map(|d| (p.a, p.b, d, p.matches.len() as f64))
        })
        .collect();
    let mut flagged: Vec<(usize, ViewDisagreement)> = Vec::new();
    loop {
        let out = |i: usize| flagged.iter().any(|(j, _)| *j == i);
        let mut per_view: BTreeMap<usize, Vec<(f64, f64)>> = BTreeMap::new();
        for &(a, b, d, w) in &pairs {
            if out(a) || out(b) {
                continue;
            }
            per_view.entry(a).or_default().push((d, w));
            per_view.entry(b).or_default().push((d, w));
        }
        // The view with the largest share of its inliers in pairs that disagree goes first (a
        // misplaced view disagrees with all its partners, each of them only with it), then the
        // one with the larger median.
        let worst = per_view
            .into_iter()
            .map(|(i, v)| {
                let total: f64 = v.iter().map(|x| x.1).sum();
                let bad: f64 = v
                    .iter()
                    .filter(|x| x.0 > MAX_DISAGREEMENT_DEG)
                    .map(|x| x.1)
                    .sum();
                (i, v.len(), bad / total.max(1.0), weighted_median(v))
            })
            .max_by(|x, y| x.2.total_cmp(&y.2).then(x.3.total_cmp(&y.3)))
            .map(|(i, n, _, m)| (i, n, m));
        let Some((i, partners, median_deg)) = worst else {
            return (flagged, None);
        };
        if median_deg <= MAX_DISAGREEMENT_DEG || rec.views.len() - flagged.len() <= 2 {
            return (flagged, Some(median_deg));
        }
        flagged.push((
            i,
            ViewDisagreement {
                image: ctx.input.images[i].name.clone(),
                median_deg,
                partners,
            },
        ));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weighted_median_follows_the_weights() {
        assert_eq!(weighted_median(vec![(1.0, 1.0), (2.0, 1.0), (30.0, 1.0)]), 2.0);
        assert_eq!(weighted_median(vec![(1.0, 10.0), (20.0, 1.0), (30.0, 1.0)]), 1.0);
        assert_eq!(weighted_median(vec![(1.0, 1.0), (20.0, 5.0), (30.0, 5.0)]), 20.0);
    }
}
