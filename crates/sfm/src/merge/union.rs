//! The union of two models once a similarity maps one into the other's frame, and its
//! adjustment and checks (see the parent module).

use std::collections::{BTreeMap, BTreeSet};

use handheld_core::{CameraId, ImageId, MetricReconstruction, PointId, Sim3, TrackElement};

use super::correspondences::Correspondence;
use crate::context::Context;
use crate::metric::ba::{self as metric_ba, MetricBaRecord};
use crate::metric::consistency;
use crate::upgrade::guard;

/// Free keypoints that join a point of the other model in the union: `(view, keypoint, point)`,
/// with B's views' keypoints joining A's points (`to_a`) and A's views' keypoints joining B's
/// points (`to_b`, B's ids).
#[derive(Default)]
pub(crate) struct Attachments {
    pub to_a: Vec<(ImageId, u32, PointId)>,
    pub to_b: Vec<(ImageId, u32, PointId)>,
}

/// `b` mapped by `a_from_b` into `a`'s frame and added to it: `b`'s intrinsics groups become
/// `a`'s groups of the same camera key (new groups otherwise), its points get fresh ids, and the
/// corresponding points are fused (the B point's observations join the A point's track, unless
/// the A point already has an observation in that view).
pub(crate) fn union(
    ctx: &Context,
    a: &MetricReconstruction,
    b: &MetricReconstruction,
    a_from_b: &Sim3,
    fused: &[(PointId, PointId)],
    attach: &Attachments,
) -> MetricReconstruction {
    let mut out = a.clone();
    let mut b = b.clone();
    b.transform(a_from_b);
    let key = |id: ImageId| {
        ctx.input
            .images
            .iter()
            .find(|im| im.id == id)
            .map(|im| im.camera_key.clone())
    };
    let mut camera_map: BTreeMap<CameraId, CameraId> = BTreeMap::new();
    let mut next_camera = out.cameras.keys().map(|c| c.0).max().unwrap_or(0) + 1;
    for (cid, cam) in &b.cameras {
        let k = b
            .views
            .values()
            .find(|v| v.camera_id == *cid)
            .and_then(|v| key(v.id));
        let target = out
            .views
            .values()
            .find(|v| k.is_some() && key(v.id) == k)
            .map(|v| v.camera_id);
        let id = target.unwrap_or_else(|| {
            let id = CameraId(next_camera);
            next_camera += 1;
            let mut c = cam.clone();
            c.id = id;
            out.cameras.insert(id, c);
            id
        });
        camera_map.insert(*cid, id);
    }
    let mut next_point = out.points.keys().map(|p| p.0).max().unwrap_or(0) + 1;
    let mut point_map: BTreeMap<PointId, PointId> = BTreeMap::new();
    let into: BTreeMap<PointId, PointId> = fused.iter().map(|&(pa, pb)| (pb, pa)).collect();
    for (pid, p) in &b.points {
        match into.get(pid) {
            Some(&pa) => {
                let Some(target) = out.points.get_mut(&pa) else {
                    continue;
                };
                let have: BTreeSet<ImageId> =
                    target.track.elements.iter().map(|e| e.image_id).collect();
                let mut kept = false;
                for e in &p.track.elements {
                    if !have.contains(&e.image_id) {
                        target.track.elements.push(*e);
                        kept = true;
                    }
                }
                if kept {
                    point_map.insert(*pid, pa);
                }
            }
            None => {
                let id = PointId(next_point);
                next_point += 1;
                out.points.insert(id, p.clone());
                point_map.insert(*pid, id);
            }
        }
    }
    // Views registered in both models (the overlap of split-and-merge, `split/`) keep A's pose;
    // B's points claim their keypoints there below.
    let shared: BTreeSet<ImageId> = b
        .views
        .keys()
        .filter(|v| a.views.contains_key(v))
        .copied()
        .collect();
    for (vid, v) in &b.views {
        if shared.contains(vid) {
            continue;
        }
        let mut v = v.clone();
        v.camera_id = camera_map.get(&v.camera_id).copied().unwrap_or(v.camera_id);
        for o in v.observations.iter_mut() {
            o.point_id = o.point_id.and_then(|p| point_map.get(&p).copied());
        }
        out.views.insert(*vid, v);
    }
    let MetricReconstruction { views, points, .. } = &mut out;
    let targets = attach.to_a.iter().copied().chain(
        attach
            .to_b
            .iter()
            .filter_map(|&(view, key, pb)| point_map.get(&pb).map(|&p| (view, key, p))),
    );
    for (view, key, p) in targets {
        let (Some(o), Some(pt)) = (
            views
                .get_mut(&view)
                .and_then(|v| v.observations.get_mut(key as usize)),
            points.get_mut(&p),
        ) else {
            continue;
        };
        if o.point_id.is_none() && pt.track.elements.iter().all(|e| e.image_id != view) {
            pt.track.elements.push(TrackElement {
                image_id: view,
                point2d_idx: key,
            });
            o.point_id = Some(p);
        }
    }
    if !shared.is_empty() {
        claim_shared(&mut out, &shared);
    }
    // A fused B point whose observation in some view duplicated the A point's was left out of
    // the track: its observation there is detached.
    for v in out.views.values_mut() {
        for (k, o) in v.observations.iter_mut().enumerate() {
            if let Some(p) = o.point_id {
                let listed = out.points.get(&p).is_some_and(|q| {
                    q.track
                        .elements
                        .iter()
                        .any(|e| e.image_id == v.id && e.point2d_idx as usize == k)
                });
                if !listed {
                    o.point_id = None;
                }
            }
        }
    }
    out
}

/// The track elements of B's points in the views both models registered: each keypoint there
/// belongs to the point that first claims it (A's points own theirs already); an element whose
/// keypoint another point owns is dropped, and a point left with fewer than two views is removed.
fn claim_shared(out: &mut MetricReconstruction, shared: &BTreeSet<ImageId>) {
    let MetricReconstruction { views, points, .. } = out;
    let mut orphans = Vec::new();
    for (pid, p) in points.iter_mut() {
        p.track.elements.retain(|e| {
            if !shared.contains(&e.image_id) {
                return true;
            }
            let Some(o) = views
                .get_mut(&e.image_id)
                .and_then(|v| v.observations.get_mut(e.point2d_idx as usize))
            else {
                return false;
            };
            match o.point_id {
                None => {
                    o.point_id = Some(*pid);
                    true
                }
                Some(q) => q == *pid,
            }
        });
        if p.track.elements.len() < 2 {
            orphans.push(*pid);
        }
    }
    for pid in orphans {
        if let Some(p) = points.remove(&pid) {
            for e in p.track.elements {
                if let Some(o) = views
                    .get_mut(&e.image_id)
                    .and_then(|v| v.observations.get_mut(e.point2d_idx as usize))
                {
                    if o.point_id == Some(pid) {
                        o.point_id = None;
                    }
                }
            }
        }
    }
}

/// The merged, adjusted model, its adjustment records and the check across the pieces
/// (`consistency::across`: weighted-median disagreement, pairs).
pub(super) type Adjusted = (
    MetricReconstruction,
    Vec<MetricBaRecord>,
    Option<(f64, usize)>,
);

/// `b` mapped by `a_from_b` into `a` (the corresponding points fused, the attached keypoints
/// joined), adjusted by the full metric schedule, and checked: nothing collapsed, every view agrees
/// with its verified pairs, and the pairs between the two pieces agree with how they were put
/// together.
#[allow(clippy::too_many_arguments)]
pub(super) fn adjusted_union(
    ctx: &Context,
    a: &MetricReconstruction,
    b: &MetricReconstruction,
    corr: &[Correspondence],
    a_from_b: &Sim3,
    inliers: &[usize],
    attach: &Attachments,
    estimate_aspect: bool,
) -> Result<Adjusted, String> {
    // One fusion per point on each side (the correspondence seen first).
    let (mut used_a, mut used_b) = (BTreeSet::new(), BTreeSet::new());
    let fused: Vec<(PointId, PointId)> = inliers
        .iter()
        .map(|&k| (corr[k].a, corr[k].b))
        .filter(|(x, y)| {
            let fresh = !used_a.contains(x) && !used_b.contains(y);
            if fresh {
                used_a.insert(*x);
                used_b.insert(*y);
            }
            fresh
        })
        .collect();
    let mut merged = union(ctx, a, b, a_from_b, &fused, attach);
    let records = metric_ba::refine_metric(ctx, &mut merged, estimate_aspect)?;
    if let Some(why) = guard::collapsed(&merged, &records) {
        return Err(format!("the adjustment of the merged model {why}"));
    }
    let (flagged, _) = consistency::inconsistent_views(ctx, &merged);
    if let Some((_, d)) = flagged.first() {
        return Err(format!(
            "in the merged model {} disagrees with its verified pairs by {:.1}°",
            d.image, d.median_deg
        ));
    }
    let (va, vb): (BTreeSet<ImageId>, BTreeSet<ImageId>) = (
        a.views.keys().copied().collect(),
        b.views.keys().copied().collect(),
    );
    let across = consistency::across(ctx, &merged, &va, &vb);
    if let Some((d, n)) = across {
        tracing::debug!(
            "the merged pieces agree with the {n} verified pairs between them to {d:.2}°"
        );
        if d > consistency::MAX_DISAGREEMENT_DEG {
            return Err(format!(
                "the merged pieces disagree with the {n} verified pairs between them by {d:.1}°"
            ));
        }
    } else {
        tracing::debug!("no verified pair between the merged pieces fixes a relative rotation");
    }
    Ok((merged, records, across))
}
