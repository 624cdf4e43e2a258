//! Merging models that the incremental reconstruction left apart (issue #18: "when pieces remain,
//! merge them").
//!
//! A sequence breaks into several models where its views are only weakly linked: no view of the
//! second piece had enough 2D–3D matches with the first one when it was built. The two pieces
//! still observe common scene points, found through the verified pairs between their views: a
//! keypoint of a view of model A that is a point of A, matched to a keypoint of a view of model B
//! that is a point of B, gives the 3D–3D correspondence `X_A ↔ X_B`. The two frames differ by a
//! similarity (a metric reconstruction is defined up to one, §3.4), estimated from 3
//! correspondences (Umeyama 1991) inside a seeded RANSAC whose inliers are the correspondences
//! that reproject, once B's point is mapped into A, within the metric threshold in A's view.
//! B is then mapped into A's frame, the inlier points are fused, and the union is adjusted (the
//! full metric schedule). The merge is kept only when that adjustment does not collapse
//! (`guard::collapsed`) and every view still agrees with its verified pairs (`metric/consistency.rs`);
//! otherwise the models stay apart, as before.
//!
//! Pieces that share too few triangulated points for that are merged through their 2D–3D links
//! instead ([`sightings`]): the keypoints of one piece's views matched to the other piece's points.
//!
//! Layout: `correspondences.rs` (the 3D–3D correspondences and their similarity), `sightings.rs`
//! (the 2D–3D links and theirs), `union.rs` (the union of two pieces and its checked adjustment),
//! `pair.rs` (one merge, trying both), `record.rs` (what a merge records); this module merges the
//! models of one reconstruction pairwise, largest first.

use std::collections::BTreeSet;

use crate::context::Context;
use crate::metric::principal_point::principal_point_test;
use crate::metric::uncertainty::uncertainty_step;
use crate::summary::SfmModel;

pub(crate) mod correspondences;
mod pair;
mod record;
mod sightings;
pub(crate) mod union;

pub use correspondences::{MIN_MERGE_INLIERS, MIN_MERGE_INLIER_FRACTION};
pub(crate) use pair::merge;
pub use record::MergeRecord;

/// Merges models pairwise while a merge succeeds: the largest model with each smaller one
/// (largest partner first), then the second largest with the ones after it, and so on, so that
/// two pieces that share points merge even when neither shares any with the largest. Each merge is
/// recorded in the kept model's summary, whose counts and uncertainty are those of the merged model.
pub(crate) fn merge_models(ctx: &Context, models: &mut Vec<SfmModel>) {
    let estimate_aspect = ctx.opts.estimate_aspect.unwrap_or(ctx.input.video);
    // Pairs found not to merge stay apart until one of them changes.
    let mut refused: BTreeSet<(usize, usize)> = BTreeSet::new();
    // A stable identity per model across the merges: its first view.
    let key = |m: &SfmModel| {
        m.reconstruction
            .views
            .keys()
            .next()
            .map_or(0, |v| v.0 as usize)
    };
    loop {
        if models.len() < 2 {
            return;
        }
        models.sort_by_key(|m| std::cmp::Reverse(m.summary.registered));
        let mut merged = None;
        'search: for i in 0..models.len() {
            for k in i + 1..models.len() {
                let pair = (key(&models[i]), key(&models[k]));
                if refused.contains(&pair) {
                    continue;
                }
                // The merged model is adjusted with the principal point free, and then asked again
                // whether its views determine it (more views, and a wider turn, than either piece).
                ctx.hold_principal_point(false);
                match merge(
                    ctx,
                    &models[i].reconstruction,
                    &models[k].reconstruction,
                    estimate_aspect,
                ) {
                    Ok(m) => {
                        merged = Some((i, k, m));
                        break 'search;
                    }
                    Err(why) => {
                        tracing::debug!(
                            "the model of {} views is not merged into the model of {}: {why}",
                            models[k].summary.registered,
                            models[i].summary.registered
                        );
                        refused.insert(pair);
                    }
                }
            }
        }
        let Some((i, k, (mut rec, mut records, record))) = merged else {
            return;
        };
        let held_before = models[i].summary.self_calibration.principal_point_held;
        if ctx.opts.known_intrinsics.is_none() && ctx.refines_principal_point() {
            let report = &mut models[i].summary.self_calibration;
            report.principal_point_held = false;
            principal_point_test(ctx, &mut rec, &mut records, estimate_aspect, report);
            if held_before != report.principal_point_held {
                tracing::info!(
                    "the merged model's principal point is {}",
                    if report.principal_point_held {
                        "held at the image centre"
                    } else {
                        "estimated"
                    }
                );
            }
        }
        tracing::info!(
            "merged a model of {} views into the model of {} views ({} of {} 3D–3D correspondences, {} of {} 2D–3D links)",
            record.views_added,
            models[i].summary.registered,
            record.inliers,
            record.correspondences,
            record.sighting_inliers,
            record.sightings
        );
        models.remove(k);
        let m = &mut models[i];
        let old_key = key(m);
        m.reconstruction = rec;
        // The grown model may now share points with a piece that was refused before.
        let new_key = key(m);
        refused.retain(|&(a, b)| ![a, b].iter().any(|&x| x == old_key || x == new_key));
        m.summary.metric_ba.extend(records);
        m.summary.merged.push(record);
        m.summary.recount(&m.reconstruction);
        let (uncertainty, note) = uncertainty_step(ctx, &m.reconstruction);
        m.summary.uncertainty = uncertainty;
        m.summary.uncertainty_note = note;
    }
}

#[cfg(test)]
mod tests;
