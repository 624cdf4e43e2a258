//! Video mode, after the key-frames are reconstructed (Table 2's "for every frame", §3.1 footnote 1):
//! every in-between frame gets its pose by calibrated resection from the KLT tracks it shares with
//! the key-frames, then one metric bundle adjustment refines all frames together. Augmented video and
//! image-based rendering need these per-frame cameras.

use std::collections::{BTreeMap, HashMap};

use handheld_core::{MetricReconstruction, PointId};

use crate::context::Context;
use crate::metric::resect::register_one;

/// `track id → 3D point` over every registered view.
fn points_by_track(ctx: &Context, rec: &MetricReconstruction) -> HashMap<u64, PointId> {
    let mut map = HashMap::new();
    for im in &ctx.input.images {
        let Some(v) = rec.views.get(&im.id) else {
            continue;
        };
        for (k, o) in v.observations.iter().enumerate() {
            if let (Some(pid), Some(&t)) = (o.point_id, im.track_ids.get(k)) {
                map.entry(t).or_insert(pid);
            }
        }
    }
    map
}

/// Registers every video frame of `ctx.input` that is not yet in `rec` and whose tracks reach at
/// least `min_resection_inliers` 3D points, in frame order. Returns the registered image indices;
/// `failures` gets the reason for every frame that could not be registered.
pub(crate) fn register_frames(
    ctx: &Context,
    rec: &mut MetricReconstruction,
    failures: &mut BTreeMap<usize, String>,
) -> Vec<usize> {
    let by_track = points_by_track(ctx, rec);
    let mut added = Vec::new();
    for (i, im) in ctx.input.images.iter().enumerate() {
        if im.track_ids.is_empty() || rec.views.contains_key(&im.id) {
            continue;
        }
        let matches: Vec<(usize, PointId)> = im
            .track_ids
            .iter()
            .enumerate()
            .filter_map(|(k, t)| by_track.get(t).map(|&p| (k, p)))
            .filter(|(_, p)| rec.points.contains_key(p))
            .collect();
        if matches.len() < ctx.opts.min_resection_inliers {
            failures.insert(
                i,
                format!(
                    "its tracks reach {} 3D points, need {}",
                    matches.len(),
                    ctx.opts.min_resection_inliers
                ),
            );
            continue;
        }
        match register_one(ctx, rec, i, &matches) {
            Ok(()) => {
                failures.remove(&i);
                added.push(i);
            }
            Err(e) => {
                failures.insert(i, e);
            }
        }
    }
    added
}
