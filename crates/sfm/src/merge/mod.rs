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

use handheld_core::{ImageId, MetricReconstruction, PointId, Sim3};
use nalgebra::{Point3, Vector2};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use crate::context::Context;
use crate::metric_ba::MetricBaRecord;
use crate::SfmModel;

mod sightings;
mod union;

use union::{adjusted_union, Attachments};

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

/// Every verified match between a view of `x` and a view of `y`, oriented as
/// `(x's input image, its keypoint, y's input image, its keypoint)`, in the pairs' order.
fn matches_between<'a>(
    ctx: &'a Context,
    x: &'a MetricReconstruction,
    y: &'a MetricReconstruction,
) -> impl Iterator<Item = (usize, u32, usize, u32)> + 'a {
    ctx.input.pairs.iter().flat_map(move |pair| {
        [(pair.a, pair.b, false), (pair.b, pair.a, true)]
            .into_iter()
            .filter(move |&(ix, iy, _)| {
                x.views.contains_key(&ctx.input.images[ix].id)
                    && y.views.contains_key(&ctx.input.images[iy].id)
            })
            .flat_map(move |(ix, iy, swap)| {
                pair.matches.iter().map(move |&(m0, m1)| {
                    let (kx, ky) = if swap { (m1, m0) } else { (m0, m1) };
                    (ix, kx, iy, ky)
                })
            })
    })
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
    for (ia, ka, ib, kb) in matches_between(ctx, a, b) {
        let (Some(&x), Some(&y)) = (pa.get(&(ia, ka)), pb.get(&(ib, kb))) else {
            continue;
        };
        if seen.insert((x, y)) {
            out.push(Correspondence {
                a: x,
                b: y,
                view: ctx.input.images[ia].id,
                xy: ctx.input.images[ia].keypoints[ka as usize],
            });
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
