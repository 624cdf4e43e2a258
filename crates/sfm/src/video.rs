//! Video mode, after the key-frames are reconstructed (Table 2's "for every frame", §3.1 footnote 1):
//! every in-between frame gets its pose by calibrated resection from the KLT tracks it shares with
//! the key-frames, then one metric bundle adjustment refines all frames together. Augmented video and
//! image-based rendering need these per-frame cameras.
//!
//! A frame whose tracks reach too few of the key-frames' 3D points (the frames after the last
//! key-frame, whose tracks were born after it; a key-frame pair with little structure between
//! them) is not given up: the tracks seen by two or more registered frames and not yet a point are
//! triangulated (the registered in-between frames widen their baselines), as incremental
//! reconstruction triangulates after each registration, and the frames left are tried again,
//! until a round registers nothing. This runs only when a frame was left out, so a video whose
//! frames all register from the key-frames' points keeps the same model.

use std::collections::{BTreeMap, HashMap};

use handheld_core::{MetricReconstruction, Point3D, PointId, Track, TrackElement};
use nalgebra::Point3;
use rayon::prelude::*;

use crate::context::Context;
use crate::metric::register::{normalized_camera, MIN_ANGLE_DEG};
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
/// least `min_resection_inliers` 3D points, in frame order; while some are left out, the tracks
/// the registered frames share are triangulated and those frames tried again (module notes).
/// Returns the registered image indices; `failures` gets the reason for every frame that could not
/// be registered.
pub(crate) fn register_frames(
    ctx: &Context,
    rec: &mut MetricReconstruction,
    failures: &mut BTreeMap<usize, String>,
) -> Vec<usize> {
    let mut added = register_pass(ctx, rec, failures);
    while left_out(ctx, rec) && triangulate_tracks(ctx, rec) > 0 {
        let more = register_pass(ctx, rec, failures);
        if more.is_empty() {
            break;
        }
        added.extend(more);
    }
    added.sort_unstable();
    added
}

/// Whether a video frame is not in `rec`.
fn left_out(ctx: &Context, rec: &MetricReconstruction) -> bool {
    ctx.input
        .images
        .iter()
        .any(|im| !im.track_ids.is_empty() && !rec.views.contains_key(&im.id))
}

/// One pass of [`register_frames`] over the frames not yet in `rec`, in frame order.
fn register_pass(
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

/// A triangulated track: its point and its registered observations `(image, keypoint)`.
type TrackPoint = (Point3<f64>, Vec<(usize, usize)>);

/// Triangulates every track that two or more registered frames see and that is not yet a point:
/// from all its registered observations (the iterated linear method, eqs. 19–20), kept where every
/// one of them reprojects within `metric_max_error_px` in front of its camera and its outermost
/// rays meet at [`MIN_ANGLE_DEG`] or more (the checks of `metric::register::triangulate_new`).
/// Returns how many points were added, numbered in track order.
pub(crate) fn triangulate_tracks(ctx: &Context, rec: &mut MetricReconstruction) -> usize {
    let by_track = points_by_track(ctx, rec);
    // track → its registered observations without a point, (image, keypoint), in frame order.
    let mut open: BTreeMap<u64, Vec<(usize, usize)>> = BTreeMap::new();
    for (i, im) in ctx.input.images.iter().enumerate() {
        let Some(v) = rec.views.get(&im.id) else {
            continue;
        };
        for (k, &t) in im.track_ids.iter().enumerate() {
            let free = v.observations.get(k).is_some_and(|o| o.point_id.is_none());
            if free && !by_track.contains_key(&t) {
                open.entry(t).or_default().push((i, k));
            }
        }
    }
    let thr = ctx.opts.metric_max_error_px;
    let min_cos = MIN_ANGLE_DEG.to_radians().cos();
    let found: Vec<TrackPoint> = open
        .into_par_iter()
        .filter(|(_, obs)| obs.len() >= 2)
        .filter_map(|(_, obs)| {
            let mut cams = Vec::with_capacity(obs.len());
            let mut xs = Vec::with_capacity(obs.len());
            for &(i, k) in &obs {
                let im = &ctx.input.images[i];
                let v = rec.views.get(&im.id)?;
                let cam = rec.cameras.get(&v.camera_id)?;
                cams.push(normalized_camera(v));
                xs.push(cam.intrinsics.pixel_to_normalized(*im.keypoints.get(k)?));
            }
            let m = handheld_geometry::triangulate_iterative(&cams, &xs, 2).ok()?;
            if m.w.abs() < 1e-12 {
                return None;
            }
            let x = Point3::from(m.xyz() / m.w);
            let centre = |i: usize| {
                rec.views
                    .get(&ctx.input.images[i].id)
                    .map(|v| v.cam_from_world.inverse().translation.vector)
            };
            let (first, last) = (centre(obs[0].0)?, centre(obs[obs.len() - 1].0)?);
            let (ra, rb) = (
                (x.coords - first).normalize(),
                (x.coords - last).normalize(),
            );
            if ra.dot(&rb).is_nan() || ra.dot(&rb) > min_cos {
                return None;
            }
            let fits = obs.iter().all(|&(i, k)| {
                let im = &ctx.input.images[i];
                let Some(v) = rec.views.get(&im.id) else {
                    return false;
                };
                let (Some(cam), Some(xy)) = (rec.cameras.get(&v.camera_id), im.keypoints.get(k))
                else {
                    return false;
                };
                cam.project(&v.cam_from_world, &x)
                    .is_some_and(|p| (p - xy).norm() <= thr)
            });
            fits.then_some((x, obs))
        })
        .collect();
    let base = rec.points.keys().next_back().map_or(0, |p| p.0 + 1);
    for (next, (x, obs)) in (base..).zip(&found) {
        let id = PointId(next);
        let mut track = Track::default();
        for &(i, k) in obs {
            let im = &ctx.input.images[i];
            track.elements.push(TrackElement {
                image_id: im.id,
                point2d_idx: k as u32,
            });
            if let Some(o) = rec
                .views
                .get_mut(&im.id)
                .and_then(|v| v.observations.get_mut(k))
            {
                o.point_id = Some(id);
            }
        }
        rec.points.insert(
            id,
            Point3D {
                xyz: *x,
                color: [128, 128, 128],
                error: 0.0,
                track,
            },
        );
    }
    if !found.is_empty() {
        tracing::debug!(
            points = found.len(),
            "video tracks triangulated between registered frames"
        );
    }
    found.len()
}
