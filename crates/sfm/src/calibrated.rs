//! The calibrated incremental candidate: the safety net under the stratified upgrade.
//!
//! The stratified route (projective model, then the dual absolute quadric, then the metric frame,
//! §3.1–3.4) builds its projective model from the raw keypoints. A phone's lens bends them (k1 ≈
//! 0.06 is 40 px at the corners of a 1080×1920 frame) and a wall fills most of the frame: the
//! projective model then absorbs the distortion into a frame that no metric camera explains, and
//! every candidate's metric adjustment throws out most of its observations (the 12-frame portrait
//! wall of `handheld demo --scene wall --k1 0.06`: 52–100 % removed, no model, even with the exact
//! calibration given). Radial distortion is only modelled once a metric frame exists (eq. 3).
//!
//! So, when no stratified start gives a sound metric frame, the model is also built the way
//! COLMAP's incremental mapper builds it (Schönberger & Frahm, *Structure-from-Motion Revisited*,
//! CVPR 2016): a focal length assumed from the start (EXIF where present, the two-view Bougnoux
//! estimate, and values across the plausible range), the initial pair's pose from its essential
//! matrix `E = K_bᵀ F K_a` (H&Z §9.6), calibrated resection (P3P) for every further view,
//! triangulation with an angle test, and a bundle adjustment that refines the focal length and k1
//! whenever the model has grown by a fifth, each followed by the outlier filter once it has
//! converged. Each start is scored as the stratified candidates are (`upgrade/guard`): the
//! observations kept, discounted by the reprojection error; when starts that explain the images
//! about equally well disagree on the focal length, the run says the focal length is undetermined.
//! The sound models are ranked by their registered views that agree with their own verified image
//! pairs (`metric/consistency.rs`), then by score: a model grown under a wrong focal length can
//! register more views than the right one by misplacing them.
//! When the best model's focal length ended far from every start, the model is built again from
//! that focal length ([`build_all`]): a model grown under a focal length several times too short
//! can be adjusted to nearly the right one and still be the wrong model. Two starts that agree do
//! not settle it when both ended far from where they began: they can share the same error.

use std::collections::{BTreeMap, BTreeSet};

use handheld_bundle::{bundle_adjust_metric, BundleOptions, IntrinsicsMask, MetricBundleConfig};
use handheld_core::{Camera, CameraId, Intrinsics, MetricReconstruction, Observation};
use nalgebra::{Rotation3, UnitQuaternion, Vector2};

use crate::common::image_centre;
use crate::context::Context;
use crate::metric::ba::MetricBaRecord;
use crate::metric::ba::{filter_metric, first_step_loss, keep_scale, refine_metric, setup};
use crate::metric::register::{matches_2d3d, register_calibrated, triangulate_new};
use crate::metric::resect::{insert_view, register_one};
use crate::projective::init::{can_start, essential_pose, initial_pair_candidates};
use crate::upgrade::guard::{self, CandidateRecord};
use crate::upgrade::hypotheses::two_view_focal_among;

mod ranking;
use ranking::{agree, sort_best_first};

/// The model grows by this factor between bundle adjustments (COLMAP: 1.1–1.2).
const GROWTH: f64 = 1.2;
/// Fewest views of a calibrated model.
const MIN_VIEWS: usize = 3;
/// Initial pairs grown per focal length.
const MAX_PAIRS: usize = 3;
/// Initial pairs whose two-view model is set up per focal length, at most: a pair that gives too
/// few points under the start's focal length costs one triangulation and is passed over.
const MAX_TWO_VIEW: usize = 60;
/// Focal lengths of the starts without other information, as multiples of the longer image side:
/// 0.8 (a 64° field of view across it, a phone's main camera), 1.2 (COLMAP's default prior) and 2.
pub const SPREAD: [f64; 3] = [0.8, 1.2, 2.0];
/// Two starts whose focal lengths are within this ratio are the same start.
const SAME_FOCAL: f64 = 0.1;

/// One start of the calibrated candidate: a focal length and where it came from.
#[derive(Clone, Debug)]
pub(crate) struct Start {
    pub focal_px: f64,
    pub source: &'static str,
}

/// The focal lengths to start from, for the images marked in `allowed`: a known calibration's
/// alone when one is given; else the EXIF focal length
/// (median over the images that have one), the two-view estimate, then [`SPREAD`]; duplicates
/// (within 10 %) dropped.
pub(crate) fn starts(ctx: &Context, allowed: &[bool]) -> Vec<Start> {
    let imgs: Vec<usize> = (0..allowed.len()).filter(|&i| allowed[i]).collect();
    let Some(&first) = imgs.first() else {
        return Vec::new();
    };
    // A calibration given is the only start: the model is built under it (the adjustments pin it).
    if let Some(k) = ctx.opts.known_intrinsics {
        return vec![Start {
            focal_px: k.fx,
            source: "calibrated incremental (known calibration)",
        }];
    }
    let mut out: Vec<Start> = Vec::new();
    let mut exif: Vec<f64> = imgs
        .iter()
        .filter_map(|&i| ctx.input.images[i].focal_prior_px)
        .collect();
    if !exif.is_empty() {
        exif.sort_by(f64::total_cmp);
        out.push(Start {
            focal_px: exif[exif.len() / 2],
            source: "calibrated incremental (EXIF focal length)",
        });
    }
    if let Some(f) = two_view_focal_among(ctx, allowed) {
        out.push(Start {
            focal_px: f * ctx.kn[first][(0, 0)],
            source: "calibrated incremental (two-view focal length)",
        });
    }
    let im = &ctx.input.images[first];
    let side = f64::from(im.width.max(im.height));
    for m in SPREAD {
        out.push(Start {
            focal_px: m * side,
            source: "calibrated incremental (assumed focal length)",
        });
    }
    let mut kept: Vec<Start> = Vec::new();
    for s in out {
        if kept
            .iter()
            .all(|k| (s.focal_px / k.focal_px - 1.0).abs() > SAME_FOCAL)
        {
            kept.push(s);
        }
    }
    kept
}

/// A built calibrated model: the adjusted reconstruction, its adjustments and its initial pair.
pub(crate) struct Built {
    pub rec: MetricReconstruction,
    pub adjustments: Vec<MetricBaRecord>,
    pub init_pair: (usize, usize),
    pub record: CandidateRecord,
    /// Registered views whose pose disagrees with their verified image pairs
    /// (`metric::consistency::inconsistent_views`), judged where it decides the rank
    /// ([`sort_best_first`]).
    pub disagreeing: Option<usize>,
}

/// Builds the calibrated incremental model of the `allowed` images from every start, and returns
/// the sound ones (judged by [`guard::judge`]) best first, with the records of all.
pub(crate) fn build_all(
    ctx: &Context,
    allowed: &[bool],
    estimate_aspect: bool,
    tried: &mut Vec<CandidateRecord>,
    progress: &dyn handheld_core::Progress,
) -> Vec<Built> {
    let mut sound: Vec<Built> = Vec::new();
    let mut starts = starts(ctx, allowed);
    let mut started: Vec<f64> = starts.iter().map(|s| s.focal_px).collect();
    let mut agreed = false;
    let mut refined = 0;
    progress.start("calibrated incremental candidate", starts.len() as u64);
    let mut next = 0;
    loop {
        if next == starts.len() {
            // The starts are done (or two agreed). When the best model ended far from every
            // start, it was grown under a focal length that its own adjustment then moved by more
            // than the starts are apart (a long lens, 5.2 times the image side, from starts of
            // 0.8–2 times it: every model came out depth-reversed, at 3.6–4.6 times). It is built
            // again from the focal length it found, as a start of its own ([`refined_start`]).
            sort_best_first(ctx, &mut sound, tried);
            let best = sound
                .first()
                .and_then(|b| guard::focal_lengths(&b.rec).first().copied());
            match refined_start(best, &started, agreed, refined) {
                Some(f) => {
                    refined += 1;
                    started.push(f);
                    starts.push(Start {
                        focal_px: f,
                        source: "calibrated incremental (refined focal length)",
                    });
                }
                _ => break,
            }
        }
        let s = starts[next].clone();
        next += 1;
        progress.inc(1);
        let clock = std::time::Instant::now();
        match build(ctx, allowed, &s, estimate_aspect) {
            Ok(mut b) => {
                b.record.seconds = Some(clock.elapsed().as_secs_f64());
                tracing::info!(
                    "{} from f = {:.0} px: {} views, f = {:.0} px, {} rejected",
                    s.source,
                    s.focal_px,
                    b.rec.views.len(),
                    guard::focal_lengths(&b.rec).first().copied().unwrap_or(0.0),
                    b.record.rejected.as_deref().unwrap_or("not")
                );
                tried.push(b.record.clone());
                if b.record.sound {
                    agreed = sound.iter().any(|o: &Built| agree(o, &b));
                    sound.push(b);
                    // Two starts from different focal lengths that end at the same one, with the
                    // same views: the other starts would end there too. Whether the images
                    // determine it is another matter when both moved far from where they began
                    // ([`refined_start`]).
                    if agreed {
                        next = starts.len();
                    }
                }
            }
            Err(e) => {
                tracing::info!("{} from f = {:.0} px failed: {e}", s.source, s.focal_px);
                tried.push(CandidateRecord {
                    source: s.source.to_string(),
                    focal_before_px: vec![s.focal_px],
                    tried: true,
                    rejected: Some(e),
                    seconds: Some(clock.elapsed().as_secs_f64()),
                    ..Default::default()
                });
            }
        }
    }
    progress.finish();
    sort_best_first(ctx, &mut sound, tried);
    sound
}

/// Starts built again from the focal length the best model found ([`build_all`]), at most.
const MAX_REFINED: usize = 2;

/// The focal length to build the calibrated model again from ([`build_all`]): the best sound
/// model's (`best`), when fewer than [`MAX_REFINED`] were built this way and it is more than
/// [`SAME_FOCAL`] from every start so far (`started`). When the last model built `agreed` with
/// another, only if every start lies on one side of it: two starts from below can end at the same
/// wrong focal length (the hemisphere of [`build_all`], seed 0, with every pair matched: 639 and
/// 512 px both ended at 4 590 px with 40 views, 38 % long; built again from there, 3 340 px,
/// 0.5 %, and all 48 views within 1° of the truth), while starts on both sides that meet between
/// them bracket it (the 189-frame corridor: 650 and 512 px both at 577 px, the truth 576 px).
fn refined_start(best: Option<f64>, started: &[f64], agreed: bool, refined: usize) -> Option<f64> {
    let one_side = |f: f64| {
        started.iter().all(|&s| f > s * (1.0 + SAME_FOCAL))
            || started.iter().all(|&s| f < s / (1.0 + SAME_FOCAL))
    };
    best.filter(|&f| {
        refined < MAX_REFINED
            && f.is_finite()
            && f > 0.0
            && started.iter().all(|&s| (f / s - 1.0).abs() > SAME_FOCAL)
            && (!agreed || one_side(f))
    })
}

/// One start: the initial pair (up to [`MAX_PAIRS`] grown), growth by calibrated resection with
/// adjustments as the model grows, the views still missing by calibrated registration, and the
/// full metric adjustment; judged like every metric candidate.
///
/// A pair whose two-view model gives too few points under the start's focal length is passed
/// over without counting against [`MAX_PAIRS`]. The wide-baseline pairs that rank first by eq. 14
/// are the ones a focal length a few per cent off cannot triangulate (their reprojection errors
/// grow with the baseline): along a corridor, the three best pairs all shared one view 4–5 m up
/// the corridor from the other, gave 0–12 points each, and no start was ever grown.
fn build(
    ctx: &Context,
    allowed: &[bool],
    start: &Start,
    estimate_aspect: bool,
) -> Result<Built, String> {
    let mut last = String::from("no initial pair");
    let mut grown = 0;
    for (a, b) in initial_pairs(ctx, allowed).into_iter().take(MAX_TWO_VIEW) {
        if grown == MAX_PAIRS {
            break;
        }
        let mut rec = match two_view(ctx, allowed, a, b, start.focal_px) {
            Ok(r) => r,
            Err(e) => {
                last = e;
                continue;
            }
        };
        grown += 1;
        adjust(ctx, &mut rec, estimate_aspect, false)?;
        grow(ctx, &mut rec, allowed, estimate_aspect)?;
        // Two views do not determine the calibration: a model of two would report the focal
        // length it started from (the 2-frame demo: 27 % off, and nothing said so).
        if rec.views.len() < MIN_VIEWS {
            last = format!(
                "the initial pair ({}, {}) could not be extended to {MIN_VIEWS} views (two views do not determine the calibration)",
                ctx.input.images[a].name, ctx.input.images[b].name
            );
            continue;
        }
        let mut record = guard::record_before(start.source, &rec);
        record.focal_before_px = vec![start.focal_px];
        record.tried = true;
        let adjustments = refine_metric(ctx, &mut rec, estimate_aspect)?;
        let why = guard::judge(&mut record, &rec, &adjustments, None);
        record.sound = why.is_none();
        return Ok(Built {
            rec,
            adjustments,
            init_pair: (a, b),
            record,
            disagreeing: None,
        });
    }
    Err(last)
}

/// The initial pairs of the calibrated model, best first: the stratified route's (general pairs,
/// by inliers × the eq. 14 distance), then the pairs a homography explains that still have a
/// fundamental matrix, by inliers. Where a wall fills every frame, no pair is general (GRIC
/// prefers H while the points off the plane are a minority; the paper defers this case to
/// Pollefeys et al. 2002), yet the F that RANSAC found on all the matches, the off-plane ones
/// included, gives the essential matrix once a calibration is assumed: the calibrated relative
/// pose has no planar degeneracy.
fn initial_pairs(ctx: &Context, allowed: &[bool]) -> Vec<(usize, usize)> {
    use handheld_robust::TwoViewConfiguration as C;
    let mut out: Vec<(usize, usize)> = initial_pair_candidates(ctx, allowed)
        .into_iter()
        .map(|(a, b, _)| (a, b))
        .collect();
    let mut planar: Vec<(usize, usize, usize)> = ctx
        .input
        .pairs
        .iter()
        .filter(|p| {
            matches!(p.configuration, C::Planar | C::PureRotation)
                && p.f.is_some()
                && can_start(ctx, allowed, p)
        })
        .map(|p| (p.a.min(p.b), p.a.max(p.b), p.matches.len()))
        .collect();
    planar.sort_by(|x, y| y.2.cmp(&x.2).then((x.0, x.1).cmp(&(y.0, y.1))));
    out.extend(planar.into_iter().map(|(a, b, _)| (a, b)));
    out
}

/// The two-view model of the pair `(a, b)` under focal length `f`: one camera per camera key of
/// the `allowed` images (principal point at the centre, no distortion), `a` at the origin, `b`
/// from the essential matrix of the pair's `F`, the points triangulated between them.
fn two_view(
    ctx: &Context,
    allowed: &[bool],
    a: usize,
    b: usize,
    f: f64,
) -> Result<MetricReconstruction, String> {
    let pair = ctx
        .input
        .pairs
        .iter()
        .find(|p| (p.a, p.b) == (a, b) || (p.a, p.b) == (b, a))
        .ok_or("no verified pair")?;
    let fm = pair.f.ok_or("the pair has no fundamental matrix")?;
    let (ia, ib) = (pair.a, pair.b);
    let mut rec = MetricReconstruction::default();
    let mut group: BTreeMap<&str, CameraId> = BTreeMap::new();
    for i in (0..allowed.len()).filter(|&i| allowed[i]) {
        let im = &ctx.input.images[i];
        let n = group.len() as u32;
        let id = *group
            .entry(im.camera_key.as_str())
            .or_insert(CameraId(n + 1));
        rec.cameras.entry(id).or_insert_with(|| Camera {
            id,
            width: im.width,
            height: im.height,
            intrinsics: Intrinsics {
                f,
                aspect: 1.0,
                skew: 0.0,
                pp: image_centre(im.width, im.height),
                k1: 0.0,
                k2: 0.0,
            },
        });
    }
    let cam = |i: usize| group[ctx.input.images[i].camera_key.as_str()];
    let k = |i: usize| rec.cameras[&cam(i)].intrinsics.k_matrix();
    let e = k(ib).transpose() * fm * k(ia);
    let norm = |i: usize, kp: u32| {
        rec.cameras[&cam(i)]
            .intrinsics
            .pixel_to_normalized(ctx.input.images[i].keypoints[kp as usize])
    };
    let (xa, xb): (Vec<Vector2<f64>>, Vec<Vector2<f64>>) = pair
        .matches
        .iter()
        .map(|&(p, q)| (norm(ia, p), norm(ib, q)))
        .unzip();
    let (_, r, t) = essential_pose(&e, &xa, &xb).ok_or("the essential matrix has no pose")?;
    let rot = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
    let observations = |i: usize| -> Vec<Observation> {
        ctx.input.images[i]
            .keypoints
            .iter()
            .map(|&xy| Observation { xy, point_id: None })
            .collect()
    };
    let origin = handheld_geometry::Pose {
        rotation: UnitQuaternion::identity(),
        translation: nalgebra::Vector3::zeros(),
    };
    let posed = handheld_geometry::Pose {
        rotation: rot,
        translation: t.normalize(),
    };
    let (ca, cb) = (cam(ia), cam(ib));
    insert_view(ctx, &mut rec, ia, ca, &origin, observations(ia));
    insert_view(ctx, &mut rec, ib, cb, &posed, observations(ib));
    triangulate_new(ctx, &mut rec, ib);
    if rec.points.len() < ctx.opts.init_min_points {
        return Err(format!(
            "the initial pair ({}, {}) gave {} points, need {}",
            ctx.input.images[ia].name,
            ctx.input.images[ib].name,
            rec.points.len(),
            ctx.opts.init_min_points
        ));
    }
    Ok(rec)
}

/// One adjustment of the growing model, then the outlier filter (after convergence, as COLMAP
/// filters). The intrinsics (f and k1, the aspect ratio for video) are refined once the model has
/// three views: two views do not determine them.
fn adjust(
    ctx: &Context,
    rec: &mut MetricReconstruction,
    estimate_aspect: bool,
    intrinsics: bool,
) -> Result<(), String> {
    implausible_focal(rec)?;
    let s = setup(ctx, rec, estimate_aspect);
    let config = MetricBundleConfig {
        refine: if intrinsics {
            s.base
        } else {
            IntrinsicsMask::none()
        },
        priors: s.priors,
        keypoint_sigma: ctx.keypoint_sigma.clone(),
        ..Default::default()
    };
    let bopts = BundleOptions {
        max_iterations: 50,
        loss: first_step_loss(rec, ctx.opts.loss_scale_px),
        ..Default::default()
    };
    bundle_adjust_metric(rec, &config, &bopts)
        .map_err(|e| format!("calibrated incremental adjustment: {e}"))?;
    keep_scale(rec);
    filter_metric(rec, ctx.opts.metric_max_error_px, ctx.opts.min_track_length);
    implausible_focal(rec)
}

/// Stops a start whose focal length has left the range the focal hypotheses search (0.2–5 ×
/// (w + h), `upgrade::hypotheses::RANGE`): the judge would reject it at the end, after the whole
/// growth (a calibration 100× too short grew every view into a model that the judge then threw
/// away).
fn implausible_focal(rec: &MetricReconstruction) -> Result<(), String> {
    let (lo, hi) = crate::upgrade::hypotheses::RANGE;
    match rec.cameras.values().find(|c| {
        let s = f64::from(c.width + c.height);
        let f = c.intrinsics.f;
        !(f.is_finite() && f > lo * s && f < hi * s)
    }) {
        Some(c) => Err(format!(
            "implausible focal length {:.1} px for a {}×{} image (outside {lo}–{hi} × (w + h))",
            c.intrinsics.f, c.width, c.height
        )),
        None => Ok(()),
    }
}

/// Adds the `allowed` views by calibrated resection, most 2D–3D matches first, triangulating the
/// new points of each, with an adjustment whenever the model has grown by [`GROWTH`]; then the
/// views still missing by calibrated registration (which also places a view from a partner's
/// depths), and one more adjustment.
fn grow(
    ctx: &Context,
    rec: &mut MetricReconstruction,
    allowed: &[bool],
    estimate_aspect: bool,
) -> Result<(), String> {
    let n = ctx.input.images.len();
    let mut failed: BTreeSet<usize> = BTreeSet::new();
    let mut last_ba = rec.views.len();
    loop {
        let best = (0..n)
            .filter(|&i| {
                allowed[i]
                    && !failed.contains(&i)
                    && !rec.views.contains_key(&ctx.input.images[i].id)
            })
            .map(|i| (i, matches_2d3d(ctx, rec, i)))
            .filter(|(_, m)| m.len() >= ctx.opts.min_resection_inliers)
            .max_by(|x, y| x.1.len().cmp(&y.1.len()).then(y.0.cmp(&x.0)));
        let Some((image, matches)) = best else { break };
        match register_one(ctx, rec, image, &matches) {
            Ok(()) => {
                triangulate_new(ctx, rec, image);
                failed.clear();
                let r = rec.views.len();
                if r as f64 >= last_ba as f64 * GROWTH || r <= 5 {
                    adjust(ctx, rec, estimate_aspect, r >= 3)?;
                    last_ba = r;
                }
            }
            Err(_) => {
                failed.insert(image);
            }
        }
    }
    let mut failures = BTreeMap::new();
    let added = register_calibrated(ctx, rec, allowed, &mut failures);
    if last_ba != rec.views.len() || !added.is_empty() {
        adjust(ctx, rec, estimate_aspect, rec.views.len() >= 3)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_model_that_ended_far_from_every_start_is_built_again_from_where_it_ended() {
        // The narrow-lens hemisphere: starts 915, 512, 768, 1280 px, the best model at 3 627 px.
        let started = [915.0, 512.0, 768.0, 1280.0];
        assert_eq!(
            refined_start(Some(3627.0), &started, false, 0),
            Some(3627.0)
        );
        // Two starts that agreed far above every start: built again all the same.
        assert_eq!(refined_start(Some(3627.0), &started, true, 0), Some(3627.0));
        // Near a start already built, or twice already: no more.
        assert_eq!(refined_start(Some(1350.0), &started, false, 0), None);
        assert_eq!(
            refined_start(Some(3627.0), &started, false, MAX_REFINED),
            None
        );
        assert_eq!(refined_start(None, &started, false, 0), None);
        assert_eq!(refined_start(Some(f64::NAN), &started, false, 0), None);
        // The corridor: starts 650, 512, 768, 1 280 px, two agreed at 577 px, between them.
        let corridor = [650.0, 512.0, 768.0, 1280.0];
        assert_eq!(refined_start(Some(577.0), &corridor, true, 0), None);
        assert_eq!(refined_start(Some(577.0), &corridor, false, 0), Some(577.0));
    }
}
