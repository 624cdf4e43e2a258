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
//! (`guard::collapsed`) and every view still agrees with its verified pairs (`consistency.rs`);
//! otherwise the models stay apart, as before.
//!
//! Pieces that share too few triangulated points for that are merged through their 2D–3D links
//! instead ([`sightings`]): the keypoints of one piece's views matched to the other piece's points.

use std::collections::{BTreeMap, BTreeSet};

use handheld_core::{CameraId, ImageId, MetricReconstruction, PointId, Sim3, TrackElement};
use nalgebra::{Point3, Vector2};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use crate::context::Context;
use crate::metric_ba::{self, MetricBaRecord};
use crate::{consistency, guard, SfmModel};

mod sightings;

/// Fewest RANSAC inliers a merge needs (a similarity has 7 degrees of freedom; 3
/// correspondences fix it). templeSparseRing without view 8 splits into 11 + 4 views that share
/// 13 correspondences, 8 of them explained by one similarity.
pub const MIN_MERGE_INLIERS: usize = 8;
/// Smallest fraction of the correspondences the similarity must explain: a chance similarity
/// explains few of them.
pub const MIN_MERGE_INLIER_FRACTION: f64 = 0.5;
/// RANSAC samples of three correspondences.
const MERGE_SAMPLES: usize = 400;

/// One merge, for the summary.
#[derive(Clone, Debug, Default, Serialize)]
pub struct MergeRecord {
    /// Views of the model merged into this one.
    pub views_added: usize,
    /// 3D–3D correspondences found through the verified pairs, and those the similarity explains.
    pub correspondences: usize,
    pub inliers: usize,
    /// 2D–3D links (keypoints of one model's views matched to the other model's points) and those
    /// the similarity explains; zero when the 3D–3D correspondences sufficed.
    pub sightings: usize,
    pub sighting_inliers: usize,
    /// Verified pairs between the two pieces strong enough to fix a relative rotation, and the
    /// merged model's weighted-median disagreement with them (degrees); none usable means the
    /// merge rests on the correspondences alone.
    pub cross_pairs: usize,
    pub cross_disagreement_deg: Option<f64>,
    /// Scale of the similarity that maps the merged model into this one's frame.
    pub scale: f64,
}

impl MergeRecord {
    /// The record with the check across the pieces (`consistency::across`) filled in.
    fn across(mut self, across: Option<(f64, usize)>) -> Self {
        self.cross_disagreement_deg = across.map(|x| x.0);
        self.cross_pairs = across.map_or(0, |x| x.1);
        self
    }
}

/// A correspondence: a point of A, a point of B, and one observation of it in A (the view and
/// its keypoint position) where the mapped B point is checked.
struct Correspondence {
    a: PointId,
    b: PointId,
    view: ImageId,
    xy: Vector2<f64>,
}

/// The keypoint → point map of a model: `(input image index, keypoint) → point`.
fn point_of(ctx: &Context, rec: &MetricReconstruction) -> BTreeMap<(usize, u32), PointId> {
    let mut out = BTreeMap::new();
    for (i, im) in ctx.input.images.iter().enumerate() {
        if let Some(v) = rec.views.get(&im.id) {
            for (k, o) in v.observations.iter().enumerate() {
                if let Some(p) = o.point_id {
                    out.insert((i, k as u32), p);
                }
            }
        }
    }
    out
}

/// 3D–3D correspondences between the points of `a` and `b` through the verified pairs.
fn correspondences(
    ctx: &Context,
    a: &MetricReconstruction,
    b: &MetricReconstruction,
) -> Vec<Correspondence> {
    let (pa, pb) = (point_of(ctx, a), point_of(ctx, b));
    let mut seen = BTreeSet::new();
    let mut out = Vec::new();
    for pair in &ctx.input.pairs {
        for (ia, ib, swap) in [(pair.a, pair.b, false), (pair.b, pair.a, true)] {
            let (ida, idb) = (ctx.input.images[ia].id, ctx.input.images[ib].id);
            if !a.views.contains_key(&ida) || !b.views.contains_key(&idb) {
                continue;
            }
            for &(m0, m1) in &pair.matches {
                let (ka, kb) = if swap { (m1, m0) } else { (m0, m1) };
                let (Some(&x), Some(&y)) = (pa.get(&(ia, ka)), pb.get(&(ib, kb))) else {
                    continue;
                };
                if seen.insert((x, y)) {
                    out.push(Correspondence {
                        a: x,
                        b: y,
                        view: ida,
                        xy: ctx.input.images[ia].keypoints[ka as usize],
                    });
                }
            }
        }
    }
    out
}

/// Whether the B point mapped by `sim` reprojects within `thr` pixels in A's view.
fn explains(
    a: &MetricReconstruction,
    b: &MetricReconstruction,
    sim: &Sim3,
    c: &Correspondence,
    thr: f64,
) -> bool {
    let Some(p) = b.points.get(&c.b) else {
        return false;
    };
    a.project(c.view, &sim.transform_point(&p.xyz))
        .is_some_and(|x| (x - c.xy).norm() <= thr)
}

/// The similarity `a_from_b` by RANSAC over the correspondences, refined on its inliers; `None`
/// with fewer than [`MIN_MERGE_INLIERS`] inliers or under [`MIN_MERGE_INLIER_FRACTION`] of them.
fn similarity(
    ctx: &Context,
    a: &MetricReconstruction,
    b: &MetricReconstruction,
    corr: &[Correspondence],
) -> Option<(Sim3, Vec<usize>)> {
    if corr.len() < MIN_MERGE_INLIERS {
        return None;
    }
    let thr = ctx.opts.metric_max_error_px;
    let xyz = |r: &MetricReconstruction, p: PointId| r.points.get(&p).map(|q| q.xyz);
    let inliers_of = |sim: &Sim3| -> Vec<usize> {
        (0..corr.len())
            .filter(|&k| explains(a, b, sim, &corr[k], thr))
            .collect()
    };
    let mut rng = ChaCha8Rng::seed_from_u64(ctx.opts.seed ^ 0x4D45_5247);
    let mut best: Vec<usize> = Vec::new();
    let mut best_sim = Sim3::identity();
    for _ in 0..MERGE_SAMPLES {
        let s: Vec<usize> = (0..3).map(|_| rng.random_range(0..corr.len())).collect();
        if s[0] == s[1] || s[1] == s[2] || s[0] == s[2] {
            continue;
        }
        let (Some(src), Some(dst)) = (
            s.iter()
                .map(|&k| xyz(b, corr[k].b))
                .collect::<Option<Vec<Point3<f64>>>>(),
            s.iter()
                .map(|&k| xyz(a, corr[k].a))
                .collect::<Option<Vec<Point3<f64>>>>(),
        ) else {
            continue;
        };
        let Some(sim) = Sim3::align(&src, &dst) else {
            continue;
        };
        if !(sim.scale.is_finite() && sim.scale > 0.0) {
            continue;
        }
        let inl = inliers_of(&sim);
        if inl.len() > best.len() {
            best = inl;
            best_sim = sim;
        }
    }
    let enough = |n: usize| {
        n >= MIN_MERGE_INLIERS && n as f64 >= MIN_MERGE_INLIER_FRACTION * corr.len() as f64
    };
    if !enough(best.len()) {
        return None;
    }
    // Refined on every inlier, kept when it explains at least as many (a least-squares fit in 3D
    // weighs the far, poorly triangulated points most, and can explain fewer in the images).
    let src: Vec<Point3<f64>> = best.iter().filter_map(|&k| xyz(b, corr[k].b)).collect();
    let dst: Vec<Point3<f64>> = best.iter().filter_map(|&k| xyz(a, corr[k].a)).collect();
    if let Some(refined) = Sim3::align(&src, &dst) {
        let inl = inliers_of(&refined);
        if inl.len() >= best.len() {
            return Some((refined, inl));
        }
    }
    Some((best_sim, best))
}

/// `b` mapped by `a_from_b` into `a`'s frame and added to it: `b`'s intrinsics groups become
/// `a`'s groups of the same camera key (new groups otherwise), its points get fresh ids, and the
/// corresponding points are fused (the B point's observations join the A point's track, unless
/// the A point already has an observation in that view).
fn union(
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
    for (vid, v) in &b.views {
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

/// Free keypoints that join a point of the other model in the union: `(view, keypoint, point)`,
/// with B's views' keypoints joining A's points (`to_a`) and A's views' keypoints joining B's
/// points (`to_b`, B's ids).
#[derive(Default)]
struct Attachments {
    to_a: Vec<(ImageId, u32, PointId)>,
    to_b: Vec<(ImageId, u32, PointId)>,
}

/// Tries to merge `b` into `a`: the merged, adjusted model with its adjustment records and the
/// merge record, or why not. The similarity from the 3D–3D correspondences is tried first; when
/// there is none, or its merged model fails a check, the one from the 2D–3D links.
pub(crate) fn merge(
    ctx: &Context,
    a: &MetricReconstruction,
    b: &MetricReconstruction,
    estimate_aspect: bool,
) -> Result<(MetricReconstruction, Vec<MetricBaRecord>, MergeRecord), String> {
    let corr = correspondences(ctx, a, b);
    let mut why = Vec::new();
    match similarity(ctx, a, b, &corr) {
        Some((sim, inliers)) => {
            let record = MergeRecord {
                views_added: b.views.len(),
                correspondences: corr.len(),
                inliers: inliers.len(),
                sightings: 0,
                sighting_inliers: 0,
                cross_pairs: 0,
                cross_disagreement_deg: None,
                scale: sim.scale,
            };
            match adjusted_union(ctx, a, b, &corr, &sim, &inliers, &Attachments::default(), estimate_aspect) {
                Ok((merged, records, across)) => return Ok((merged, records, record.across(across))),
                Err(e) => why.push(format!(
                    "through {} of {} 3D–3D correspondences, {e}",
                    inliers.len(),
                    corr.len()
                )),
            }
        }
        None => why.push(format!(
            "{} 3D–3D correspondences through the verified pairs, fewer than {MIN_MERGE_INLIERS} (or under half) explained by one similarity",
            corr.len()
        )),
    }
    let links = sightings::Links::new(ctx, a, b);
    let mut rng = ChaCha8Rng::seed_from_u64(ctx.opts.seed ^ 0x5349_4748);
    let Some((sim, (ib, ia))) =
        sightings::similarity(ctx, a, b, &links, MIN_MERGE_INLIER_FRACTION, &mut rng)
    else {
        why.push(format!(
            "{} 2D–3D links, too few (or under half) explained by one similarity",
            links.len()
        ));
        return Err(why.join("; "));
    };
    let key = |s: &sightings::Sighting| (s.view, s.key, s.point);
    let attach = Attachments {
        to_a: ib.iter().map(|&k| key(&links.b_sees_a[k])).collect(),
        to_b: ia.iter().map(|&k| key(&links.a_sees_b[k])).collect(),
    };
    let thr = ctx.opts.metric_max_error_px;
    let explained: Vec<usize> = (0..corr.len())
        .filter(|&k| explains(a, b, &sim, &corr[k], thr))
        .collect();
    let record = MergeRecord {
        views_added: b.views.len(),
        correspondences: corr.len(),
        inliers: explained.len(),
        sightings: links.len(),
        sighting_inliers: ib.len() + ia.len(),
        cross_pairs: 0,
        cross_disagreement_deg: None,
        scale: sim.scale,
    };
    match adjusted_union(ctx, a, b, &corr, &sim, &explained, &attach, estimate_aspect) {
        Ok((merged, records, across)) => Ok((merged, records, record.across(across))),
        Err(e) => {
            why.push(format!(
                "through {} of {} 2D–3D links, {e}",
                record.sighting_inliers,
                links.len()
            ));
            Err(why.join("; "))
        }
    }
}

/// `b` mapped by `a_from_b` into `a` (the corresponding points fused, the attached keypoints
/// joined), adjusted by the full metric schedule, and checked: nothing collapsed, every view agrees
/// with its verified pairs, and the pairs between the two pieces agree with how they were put
/// together.
#[allow(clippy::too_many_arguments)]
fn adjusted_union(
    ctx: &Context,
    a: &MetricReconstruction,
    b: &MetricReconstruction,
    corr: &[Correspondence],
    a_from_b: &Sim3,
    inliers: &[usize],
    attach: &Attachments,
    estimate_aspect: bool,
) -> Result<
    (
        MetricReconstruction,
        Vec<MetricBaRecord>,
        Option<(f64, usize)>,
    ),
    String,
> {
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
            crate::frame::principal_point_test(
                ctx,
                &mut rec,
                &mut records,
                estimate_aspect,
                report,
            );
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
        let (uncertainty, note) = crate::pipeline::uncertainty_step(ctx, &m.reconstruction);
        m.summary.uncertainty = uncertainty;
        m.summary.uncertainty_note = note;
    }
}

#[cfg(test)]
mod tests;
