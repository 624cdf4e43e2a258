//! Registering further views into a *metric* model (§3.2's "adding views", calibrated).
//!
//! Projective resection (the 6-point DLT) is degenerate when the 3D points a view sees lie on one
//! plane — a wall, a façade, a table top — and a view whose matches only reach such points cannot
//! join the projective model. Once the upgrade (§3.4) and the metric bundle adjustment have fixed
//! the intrinsics, calibrated resection has no such degeneracy: P3P inside the shared RANSAC
//! (T(1,1), MSAC) gives the pose from 2D–3D matches read from the correspondence graph, as in the
//! projective stage. New points are then triangulated with every registered partner (linear
//! two-view triangulation in normalized coordinates, kept when they reproject within the threshold
//! in front of both cameras with a triangulation angle of at least [`MIN_ANGLE_DEG`]).
//!
//! The same routine gives every frame of a video its pose once the key-frames are reconstructed.

use std::collections::BTreeMap;

use handheld_core::{MetricReconstruction, Point3D, PointId, Track, TrackElement, View};
use nalgebra::{Matrix3x4, Point3};

use crate::context::Context;
use crate::metric::register_pair::register_from_partner;
use crate::metric::resect::register_one;

/// Smallest triangulation angle of a new two-view point.
pub(crate) const MIN_ANGLE_DEG: f64 = 1.5;

/// Registers the `allowed` images that have enough 2D–3D matches into `rec`, most-matched first,
/// until none is left that succeeds. Returns the newly registered image indices; `failures` gets a
/// reason for every image that was tried and failed.
pub(crate) fn register_calibrated(
    ctx: &Context,
    rec: &mut MetricReconstruction,
    allowed: &[bool],
    failures: &mut BTreeMap<usize, String>,
) -> Vec<usize> {
    let n = ctx.input.images.len();
    let mut tried = vec![false; n];
    let mut added = Vec::new();
    loop {
        // The untried candidate with the most 2D–3D matches.
        let mut best: Option<(usize, Vec<(usize, PointId)>)> = None;
        for i in 0..n {
            if !allowed[i] || tried[i] || rec.views.contains_key(&ctx.input.images[i].id) {
                continue;
            }
            let m = matches_2d3d(ctx, rec, i);
            if best.as_ref().is_none_or(|b| m.len() > b.1.len()) {
                best = Some((i, m));
            }
        }
        let Some((image, matches)) = best else { break };
        tried[image] = true;
        let result = if matches.len() < ctx.opts.min_resection_inliers {
            // No (or too few) shared points: place the view from a registered partner's depths.
            register_from_partner(ctx, rec, image).map_err(|e| {
                format!(
                    "{} 2D–3D correspondences with the metric model, need {}; {e}",
                    matches.len(),
                    ctx.opts.min_resection_inliers
                )
            })
        } else {
            register_one(ctx, rec, image, &matches)
        };
        match result {
            Ok(()) => {
                triangulate_new(ctx, rec, image);
                added.push(image);
                // A newly registered view may bring the earlier failures within reach.
                tried.iter_mut().for_each(|t| *t = false);
                for i in &added {
                    tried[*i] = true;
                }
            }
            Err(e) => {
                failures.insert(image, e);
            }
        }
    }
    added
}

/// `(keypoint, point)` pairs of `image`: keypoints matched to an observation of a metric point,
/// each to the point most of its matches observe (among equals the largest id). Called for every
/// unregistered view after each registration, so the registered views are looked up once per call
/// (by image index, not per correspondence) and the votes counted on a reused sorted list: the
/// 189-frame corridor's calibrated growth spent a tenth of its time here.
pub(crate) fn matches_2d3d(
    ctx: &Context,
    rec: &MetricReconstruction,
    image: usize,
) -> Vec<(usize, PointId)> {
    let views: Vec<Option<&View>> = ctx
        .input
        .images
        .iter()
        .map(|im| rec.views.get(&im.id))
        .collect();
    let mut out = Vec::new();
    let mut votes: Vec<PointId> = Vec::new();
    for k in 0..ctx.graph.num_keypoints(image) {
        votes.clear();
        for &(j, kj) in ctx.graph.correspondences(image, k) {
            let Some(v) = views.get(j as usize).copied().flatten() else {
                continue;
            };
            if let Some(pid) = v.observations.get(kj as usize).and_then(|o| o.point_id) {
                votes.push(pid);
            }
        }
        if let Some(pid) = most_voted(&mut votes) {
            out.push((k, pid));
        }
    }
    out
}

/// The id that occurs most often in `votes` (sorted here); among equals the largest.
fn most_voted(votes: &mut [PointId]) -> Option<PointId> {
    votes.sort_unstable();
    let mut best: Option<(PointId, usize)> = None;
    for run in votes.chunk_by(|a, b| a == b) {
        if best.is_none_or(|(_, c)| run.len() >= c) {
            best = Some((run[0], run.len()));
        }
    }
    best.map(|(pid, _)| pid)
}

/// `[R | t]` of a view as a 3×4 matrix (normalized camera).
pub(crate) fn normalized_camera(v: &View) -> Matrix3x4<f64> {
    v.cam_from_world
        .to_homogeneous()
        .fixed_view::<3, 4>(0, 0)
        .into_owned()
}

/// New points between `image` and every registered partner, for keypoints matched to observations
/// that have no point yet.
pub(crate) fn triangulate_new(ctx: &Context, rec: &mut MetricReconstruction, image: usize) {
    let im = &ctx.input.images[image];
    let Some(v) = rec.views.get(&im.id) else {
        return;
    };
    let cam_a = rec.cameras[&v.camera_id].clone();
    let pa = normalized_camera(v);
    let ca = v.cam_from_world.inverse().translation.vector;
    let thr = ctx.opts.metric_max_error_px;
    let min_cos = MIN_ANGLE_DEG.to_radians().cos();
    let mut next = rec.points.keys().next_back().map_or(0, |p| p.0 + 1);
    for k in 0..im.keypoints.len() {
        if rec.views[&im.id].observations[k].point_id.is_some() {
            continue;
        }
        for &(j, kj) in ctx.graph.correspondences(image, k) {
            let jm = &ctx.input.images[j as usize];
            let Some(vb) = rec.views.get(&jm.id) else {
                continue;
            };
            if vb.observations[kj as usize].point_id.is_some() {
                continue;
            }
            let cam_b = &rec.cameras[&vb.camera_id];
            let xa = cam_a.intrinsics.pixel_to_normalized(im.keypoints[k]);
            let xb = cam_b
                .intrinsics
                .pixel_to_normalized(jm.keypoints[kj as usize]);
            let pb = normalized_camera(vb);
            let Ok(m) = handheld_geometry::triangulate_iterative(&[pa, pb], &[xa, xb], 2) else {
                continue;
            };
            if m.w.abs() < 1e-12 {
                continue;
            }
            let x = Point3::from(m.xyz() / m.w);
            let cb = vb.cam_from_world.inverse().translation.vector;
            let (ra, rb) = ((x.coords - ca).normalize(), (x.coords - cb).normalize());
            if ra.dot(&rb) > min_cos {
                continue;
            }
            let ok_a = cam_a
                .project(&rec.views[&im.id].cam_from_world, &x)
                .is_some_and(|p| (p - im.keypoints[k]).norm() <= thr);
            let ok_b = cam_b
                .project(&vb.cam_from_world, &x)
                .is_some_and(|p| (p - jm.keypoints[kj as usize]).norm() <= thr);
            if !(ok_a && ok_b) {
                continue;
            }
            let id = PointId(next);
            next += 1;
            let track = Track {
                elements: vec![
                    TrackElement {
                        image_id: im.id,
                        point2d_idx: k as u32,
                    },
                    TrackElement {
                        image_id: jm.id,
                        point2d_idx: kj,
                    },
                ],
            };
            rec.points.insert(
                id,
                Point3D {
                    xyz: x,
                    color: [128, 128, 128],
                    error: 0.0,
                    track,
                },
            );
            if let Some(v) = rec.views.get_mut(&im.id) {
                v.observations[k].point_id = Some(id);
            }
            if let Some(v) = rec.views.get_mut(&jm.id) {
                v.observations[kj as usize].point_id = Some(id);
            }
            break;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The count by map and the last maximum in id order: what `most_voted` must agree with.
    fn by_map(votes: &[PointId]) -> Option<PointId> {
        let mut m: BTreeMap<PointId, usize> = BTreeMap::new();
        for &p in votes {
            *m.entry(p).or_default() += 1;
        }
        m.into_iter().max_by_key(|(_, c)| *c).map(|(p, _)| p)
    }

    #[test]
    fn the_most_voted_point_is_the_maps_with_ties_to_the_largest_id() {
        let mut state = 12345u64;
        let mut next = |m: u64| {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 33) % m
        };
        assert_eq!(most_voted(&mut []), None);
        for _ in 0..2000 {
            let len = next(9) as usize;
            let votes: Vec<PointId> = (0..len).map(|_| PointId(next(4))).collect();
            let mut v = votes.clone();
            assert_eq!(most_voted(&mut v), by_map(&votes), "{votes:?}");
        }
        let mut tie = vec![PointId(7), PointId(3), PointId(3), PointId(7), PointId(5)];
        assert_eq!(most_voted(&mut tie), Some(PointId(7)));
    }
}
