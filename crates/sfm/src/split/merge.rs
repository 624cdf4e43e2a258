//! The clusters' models merged into one, then adjusted as a whole.
//!
//! Two neighbouring clusters share the views of their overlap. A keypoint of such a view that is
//! a point in both models gives a 3D–3D correspondence without any matching; the similarity
//! between the two frames is estimated from them by the seeded RANSAC of `merge/` (Umeyama fits
//! of three, inliers judged by reprojection in the first model's view), and from the
//! correspondences through the verified pairs when the overlap registered too few. The union
//! keeps the first model's pose of a shared view, fuses the corresponding points, and gives the
//! other model's points the keypoints that are still free there (`merge/union.rs`).
//!
//! Each merge is checked before it is kept: the verified pairs between the merged model's views
//! and the newcomer's must agree with the poses they are given (`consistency::across`, the test a
//! merge of two pieces of one reconstruction passes). A model that fails stays apart and is
//! tried again once the merged model has grown.
//!
//! Models are merged in the order of their shared views with the merged model (the most first),
//! so each merge rests on the largest overlap available; no adjustment runs in between. One
//! global bundle adjustment (the full metric schedule of `metric/ba.rs`, one intrinsics group per
//! camera key) then pulls the whole together, and the views are judged against their pairs.

use std::collections::{BTreeMap, BTreeSet};
use std::time::Instant;

use handheld_core::{ImageId, MetricReconstruction, Progress};
use serde::{Deserialize, Serialize};

use super::Cluster;
use crate::context::Context;
use crate::error::SfmError;
use crate::graph::CorrespondenceGraph;
use crate::input::SfmInput;
use crate::merge::correspondences::{correspondences, similarity, Correspondence};
use crate::merge::union::{union, Attachments};
use crate::merge::{MergeRecord, MIN_MERGE_INLIERS};
use crate::metric::ba as metric_ba;
use crate::metric::consistency;
use crate::metric::principal_point::principal_point_test;
use crate::metric::uncertainty::uncertainty_step;
use crate::options::SfmOptions;
use crate::summary::{DuplicateShot, ModelSummary, SfmModel, SfmResult};

/// What one cluster's reconstruction gave: serialisable, so that a cluster can run as a task on
/// another machine.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ClusterOutcome {
    pub models: Vec<(MetricReconstruction, ModelSummary)>,
    pub unregistered: Vec<(String, String)>,
    pub duplicates: Vec<DuplicateShot>,
    /// Why no model could be built.
    pub error: Option<String>,
    pub seconds: f64,
}

impl ClusterOutcome {
    pub fn new(result: Result<SfmResult, String>, seconds: f64) -> Self {
        match result {
            Ok(r) => Self {
                models: r
                    .models
                    .into_iter()
                    .map(|m| (m.reconstruction, m.summary))
                    .collect(),
                unregistered: r.unregistered,
                duplicates: r.duplicates,
                error: None,
                seconds,
            },
            Err(e) => Self {
                models: Vec::new(),
                unregistered: Vec::new(),
                duplicates: Vec::new(),
                error: Some(e),
                seconds,
            },
        }
    }
}

/// One cluster in the report.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct ClusterReport {
    /// Its views, overlap included, and its own.
    pub views: usize,
    pub core: usize,
    /// Views in its largest model, and its models.
    pub registered: usize,
    pub models: usize,
    /// Focal length of its largest model's first camera group, pixels.
    pub focal_px: Option<f64>,
    pub error: Option<String>,
    pub seconds: f64,
}

/// What split-and-merge did (`sparse/summary.json`, `split`).
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
pub struct SplitReport {
    pub clusters: Vec<ClusterReport>,
    /// Models merged into the others, and the models of clusters left out of the first (largest)
    /// model with the reason.
    pub merged: usize,
    pub apart: Vec<String>,
    /// Views the global adjustment found disagreeing with their verified pairs.
    pub inconsistent_views: Vec<String>,
    /// The focal length the clusters' models were brought to before the merge, when they
    /// disagreed (`consensus`).
    pub consensus_focal_px: Option<f64>,
    pub merge_seconds: f64,
    pub global_adjustment_seconds: f64,
}

/// One model waiting to be merged: the cluster it came from and its reconstruction.
struct Piece {
    cluster: usize,
    rec: MetricReconstruction,
    summary: ModelSummary,
    /// Why its last merge failed.
    why: Option<String>,
}

/// Merges the clusters' models (see the module's text) into an [`SfmResult`] over the whole input.
pub fn merge_clusters(
    input: &SfmInput,
    options: &SfmOptions,
    clusters: &[Cluster],
    outcomes: Vec<ClusterOutcome>,
    progress: &dyn Progress,
) -> Result<SfmResult, SfmError> {
    let t = Instant::now();
    let mut report = SplitReport {
        clusters: clusters
            .iter()
            .zip(&outcomes)
            .map(|(c, o)| ClusterReport {
                views: c.views.len(),
                core: c.core.len(),
                registered: o.models.first().map_or(0, |m| m.0.views.len()),
                models: o.models.len(),
                focal_px: o
                    .models
                    .first()
                    .and_then(|m| m.0.cameras.values().next().map(|c| c.intrinsics.f)),
                error: o.error.clone(),
                seconds: o.seconds,
            })
            .collect(),
        ..Default::default()
    };
    let mut unregistered_why: BTreeMap<String, String> = BTreeMap::new();
    let mut duplicates: BTreeMap<String, DuplicateShot> = BTreeMap::new();
    let mut pieces = Vec::new();
    for (k, o) in outcomes.into_iter().enumerate() {
        for (name, why) in o.unregistered {
            unregistered_why.entry(name).or_insert(why);
        }
        for d in o.duplicates {
            duplicates.entry(d.image.clone()).or_insert(d);
        }
        if let Some(e) = o.error {
            tracing::warn!("cluster {k} gave no model: {e}");
        }
        for (rec, summary) in o.models {
            if rec.views.len() >= 2 {
                pieces.push(Piece {
                    cluster: k,
                    rec,
                    summary,
                    why: None,
                });
            }
        }
    }
    if pieces.is_empty() {
        return Err(SfmError::NoModel(crate::error::StepError::Projective(
            "split-and-merge: no cluster gave a model".into(),
        )));
    }
    let graph = CorrespondenceGraph::build(input, 8);
    let ctx = Context::new(input, &graph, options);
    let estimate_aspect = options.estimate_aspect.unwrap_or(input.video);
    report.consensus_focal_px = consensus(input, &graph, options, estimate_aspect, &mut pieces);
    pieces.sort_by_key(|p| std::cmp::Reverse(p.rec.views.len()));
    let mut models: Vec<SfmModel> = Vec::new();
    progress.start("merging clusters", pieces.len() as u64);
    while !pieces.is_empty() {
        let seed = pieces.remove(0);
        progress.inc(1);
        let mut rec = seed.rec;
        let mut summary = seed.summary;
        let mut members = vec![seed.cluster];
        // Pieces refused since the merged model last grew.
        let mut refused: BTreeSet<usize> = BTreeSet::new();
        loop {
            // The piece with the most views in common, then the most verified pairs across
            // (a piece whose overlap was not registered still merges through its pairs).
            let views: BTreeSet<ImageId> = rec.views.keys().copied().collect();
            let mut order: Vec<(usize, (usize, usize))> = pieces
                .iter()
                .enumerate()
                .filter(|(k, _)| !refused.contains(k))
                .map(|(k, p)| (k, links(input, &views, &p.rec)))
                .filter(|&(_, (shared, pairs))| shared + pairs > 0)
                .collect();
            order.sort_by_key(|&(k, l)| (std::cmp::Reverse(l), k));
            let Some(&(k, _)) = order.first() else {
                break;
            };
            match merge_one(&ctx, &rec, &pieces[k].rec) {
                Ok((merged, record)) => {
                    let p = pieces.remove(k);
                    tracing::debug!(
                        "cluster {} merged: {} views added, {} of {} correspondences",
                        p.cluster,
                        record.views_added,
                        record.inliers,
                        record.correspondences
                    );
                    members.push(p.cluster);
                    rec = merged;
                    summary.merged.push(record);
                    refused.clear();
                    progress.inc(1);
                }
                Err(why) => {
                    pieces[k].why = Some(why);
                    refused.insert(k);
                }
            }
        }
        if models.is_empty() {
            // What stays out of the first (largest) model, and why.
            report.apart = pieces
                .iter()
                .map(|p| {
                    format!(
                        "a model of {} views of cluster {}: {}",
                        p.rec.views.len(),
                        p.cluster,
                        p.why
                            .as_deref()
                            .unwrap_or("no view or verified pair in common with the merged model")
                    )
                })
                .collect();
        }
        report.merged += members.len() - 1;
        models.push(finish(&ctx, rec, summary, estimate_aspect, &mut report)?);
        if models.len() >= options.max_models {
            break;
        }
    }
    progress.finish();
    report.merge_seconds = t.elapsed().as_secs_f64() - report.global_adjustment_seconds;
    models.sort_by_key(|m| std::cmp::Reverse(m.summary.registered));
    let registered: BTreeSet<ImageId> = models
        .iter()
        .flat_map(|m| m.reconstruction.views.keys().copied())
        .collect();
    let unregistered = input
        .images
        .iter()
        .filter(|im| !registered.contains(&im.id))
        .map(|im| {
            let why = unregistered_why
                .get(&im.name)
                .cloned()
                .unwrap_or_else(|| "not registered in a cluster that was merged".into());
            (im.name.clone(), why)
        })
        .collect();
    Ok(SfmResult {
        models,
        unregistered,
        duplicates: duplicates.into_values().collect(),
        split: Some(report),
    })
}

/// Pieces whose focal length differs from the others' by more than this are adjusted again at the
/// consensus before they are merged.
const CONSENSUS_TOLERANCE: f64 = 0.005;

/// Brings the pieces to one focal length before they are merged: the median over the pieces,
/// weighted by their views, of their own self-calibrated focal lengths (one camera group each).
///
/// A cluster's self-calibration rests on its own views only, and a short stretch of a street
/// filmed forwards determines the focal length to a few percent (kitti-seq1 in clusters of 20:
/// 659–705 px). Two models built under focal lengths 7 % apart differ by more than a similarity:
/// a point at the edge of the image lies on rays 40 px apart, so no similarity explains half of
/// their correspondences, and the merge fails. Each such piece is therefore adjusted again with
/// its focal length held at the consensus (its structure follows), and the global adjustment
/// then frees the focal length over all the views together. Returns the consensus, when one was
/// applied.
fn consensus(
    input: &SfmInput,
    graph: &CorrespondenceGraph,
    options: &SfmOptions,
    estimate_aspect: bool,
    pieces: &mut [Piece],
) -> Option<f64> {
    use rayon::prelude::*;
    if options.known_intrinsics.is_some() || pieces.len() < 2 {
        return None;
    }
    let single = |p: &Piece| {
        (p.rec.cameras.len() == 1)
            .then(|| p.rec.cameras.values().next())
            .flatten()
            .cloned()
    };
    let mut fs: Vec<(f64, usize)> = Vec::new();
    for p in pieces.iter() {
        let c = single(p)?;
        fs.push((c.intrinsics.f, p.rec.views.len()));
    }
    fs.sort_by(|a, b| a.0.total_cmp(&b.0));
    let half = fs.iter().map(|x| x.1).sum::<usize>() as f64 / 2.0;
    let mut acc = 0.0;
    let fc = fs
        .iter()
        .find(|x| {
            acc += x.1 as f64;
            acc >= half
        })?
        .0;
    if fs
        .iter()
        .all(|x| (x.0 / fc - 1.0).abs() < CONSENSUS_TOLERANCE)
    {
        return None;
    }
    tracing::info!(
        "split-and-merge: the clusters' focal lengths span {:.0}–{:.0} px; each is adjusted again at {fc:.0} px before the merge",
        fs[0].0,
        fs[fs.len() - 1].0
    );
    pieces.par_iter_mut().for_each(|p| {
        let Some(cam) = single(p) else {
            return;
        };
        if (cam.intrinsics.f / fc - 1.0).abs() < CONSENSUS_TOLERANCE {
            return;
        }
        let mut o = options.clone();
        o.known_intrinsics = Some(crate::options::KnownIntrinsics {
            fx: fc,
            fy: fc * cam.intrinsics.aspect,
            cx: cam.intrinsics.pp.x,
            cy: cam.intrinsics.pp.y,
        });
        let ctx = Context::new(input, graph, &o);
        let mut rec = p.rec.clone();
        // Kept only when the held focal length explains the piece's images about as well: an
        // adjustment that had to remove many observations says the piece cannot take it.
        match metric_ba::refine_metric(&ctx, &mut rec, estimate_aspect) {
            Ok(records) => match crate::upgrade::guard::collapsed(&rec, &records) {
                None => {
                    p.rec = rec;
                    p.summary.metric_ba.extend(records);
                }
                Some(why) => tracing::debug!(
                    "a model of cluster {} kept its focal length: at {fc:.0} px its adjustment {why}",
                    p.cluster
                ),
            },
            Err(e) => tracing::debug!(
                "a model of cluster {} kept its focal length: {e}",
                p.cluster
            ),
        }
    });
    Some(fc)
}

/// Views of `b` that `views` holds too, and verified pairs between a view of `views` and one of
/// `b` alone.
fn links(input: &SfmInput, views: &BTreeSet<ImageId>, b: &MetricReconstruction) -> (usize, usize) {
    let shared = b.views.keys().filter(|v| views.contains(v)).count();
    let id = |i: usize| input.images.get(i).map(|im| im.id);
    let pairs = input
        .pairs
        .iter()
        .filter(|p| {
            let (Some(x), Some(y)) = (id(p.a), id(p.b)) else {
                return false;
            };
            let only_b = |v: &ImageId| b.views.contains_key(v) && !views.contains(v);
            (views.contains(&x) && only_b(&y)) || (views.contains(&y) && only_b(&x))
        })
        .count();
    (shared, pairs)
}

/// The 3D–3D correspondences through the keypoints both models made points of, in the views both
/// registered.
fn shared_keypoints(a: &MetricReconstruction, b: &MetricReconstruction) -> Vec<Correspondence> {
    let mut out = Vec::new();
    for (id, va) in &a.views {
        let Some(vb) = b.views.get(id) else {
            continue;
        };
        for (oa, ob) in va.observations.iter().zip(&vb.observations) {
            if let (Some(pa), Some(pb)) = (oa.point_id, ob.point_id) {
                out.push(Correspondence {
                    a: pa,
                    b: pb,
                    view: *id,
                    xy: oa.xy,
                });
            }
        }
    }
    out
}

/// `b` merged into `a` without adjustment, or why not.
fn merge_one(
    ctx: &Context,
    a: &MetricReconstruction,
    b: &MetricReconstruction,
) -> Result<(MetricReconstruction, MergeRecord), String> {
    let mut corr = shared_keypoints(a, b);
    if corr.len() < MIN_MERGE_INLIERS {
        corr = correspondences(ctx, a, b);
    }
    let (sim, inliers) = similarity(ctx, a, b, &corr).ok_or_else(|| {
        format!(
            "{} 3D–3D correspondences, too few (or under half) explained by one similarity",
            corr.len()
        )
    })?;
    let (mut used_a, mut used_b) = (BTreeSet::new(), BTreeSet::new());
    let fused: Vec<_> = inliers
        .iter()
        .map(|&k| (corr[k].a, corr[k].b))
        .filter(|(x, y)| used_a.insert(*x) && used_b.insert(*y))
        .collect();
    let merged = union(ctx, a, b, &sim, &fused, &Attachments::default());
    let va: BTreeSet<ImageId> = a.views.keys().copied().collect();
    let vb: BTreeSet<ImageId> = b
        .views
        .keys()
        .filter(|v| !va.contains(v))
        .copied()
        .collect();
    let across = consistency::across(ctx, &merged, &va, &vb);
    if let Some((d, n)) = across {
        if d > consistency::MAX_DISAGREEMENT_DEG {
            return Err(format!(
                "the merged model disagrees with the {n} verified pairs across the cut by {d:.1}°"
            ));
        }
    }
    let record = MergeRecord {
        views_added: vb.len(),
        correspondences: corr.len(),
        inliers: inliers.len(),
        sightings: 0,
        sighting_inliers: 0,
        cross_pairs: across.map_or(0, |x| x.1),
        cross_disagreement_deg: across.map(|x| x.0),
        scale: sim.scale,
    };
    Ok((merged, record))
}

/// The global adjustment of a merged model, its views judged against their pairs, and its
/// summary brought up to date.
fn finish(
    ctx: &Context,
    mut rec: MetricReconstruction,
    mut summary: ModelSummary,
    estimate_aspect: bool,
    report: &mut SplitReport,
) -> Result<SfmModel, SfmError> {
    let t = Instant::now();
    if !summary.merged.is_empty() {
        // A far point of one piece can fall behind a view of another once mapped (kitti-seq1 in
        // clusters of 20: a handful of 155 460 observations); the robust schedule takes care of
        // the large but finite residuals.
        let (gone, _) = metric_ba::filter_metric(&mut rec, f64::MAX, ctx.opts.min_track_length);
        tracing::debug!("{gone} observations of the merged model do not project");
        // As for the pieces of one reconstruction (`merge_models`): adjusted with the principal
        // point free, then asked whether the merged views determine it.
        ctx.hold_principal_point(false);
        let records = metric_ba::refine_metric(ctx, &mut rec, estimate_aspect).map_err(|e| {
            SfmError::NoModel(crate::error::StepError::MetricAdjustment(format!(
                "global adjustment of the merged clusters: {e}"
            )))
        })?;
        summary.metric_ba.extend(records);
        if ctx.opts.known_intrinsics.is_none() && ctx.refines_principal_point() {
            let sc = &mut summary.self_calibration;
            sc.principal_point_held = false;
            principal_point_test(ctx, &mut rec, &mut summary.metric_ba, estimate_aspect, sc);
        }
        let (flagged, _) = consistency::inconsistent_views(ctx, &rec);
        report
            .inconsistent_views
            .extend(flagged.into_iter().map(|(_, d)| d.image));
        summary.recount(&rec);
        let (u, note) = uncertainty_step(ctx, &rec);
        summary.uncertainty = u;
        summary.uncertainty_note = note;
    }
    summary.total_images = ctx.input.images.len();
    report.global_adjustment_seconds += t.elapsed().as_secs_f64();
    Ok(SfmModel {
        reconstruction: rec,
        summary,
    })
}
