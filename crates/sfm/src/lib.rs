//! Uncalibrated structure and motion (§3, Table 2): correspondence graph and tracks, initial pair
//! (§3.1), projective resection and structure extension (§3.2), projective bundle adjustment (§3.3),
//! linear self-calibration with the dual absolute quadric (§3.4, eqs. 24–27), metric bundle
//! adjustment with radial distortion, and the video mode (KLT tracks, GRIC key-frames, per-frame poses).
//!
//! One call, [`reconstruct`], takes an [`SfmInput`] (images with keypoints, verified pairs) and
//! returns one or more metric models: a broken sequence gives several models with the reason, never
//! a silent partial result.

mod context;
pub mod graph;
mod hypotheses;
mod init;
pub mod input;
pub mod metric;
pub mod metric_ba;
mod model;
pub mod options;
mod predict;
pub mod projective;
mod projective_ba;
mod register;
mod register_pair;
pub mod selfcal;
mod tracks;
mod uncertainty;
mod video;

use std::collections::BTreeMap;
use std::time::Instant;

use handheld_core::{MetricReconstruction, Progress};
use serde::Serialize;

pub use input::{SfmImage, SfmInput, SfmPair};
pub use metric::SelfCalibrationReport;
pub use metric_ba::MetricBaRecord;
pub use options::{Distortion, KnownIntrinsics, SfmOptions};
pub use model::ProjectiveBaRecord;
pub use uncertainty::UncertaintyReport;

/// Why the SfM stage could not produce any model.
#[derive(Debug, thiserror::Error)]
pub enum SfmError {
    /// A [`SfmOptions`] field is out of its valid range; `option` is the field's name
    /// (`self_calibration.<field>` for the nested self-calibration options).
    #[error("invalid SfM option `{option}`: {reason}")]
    InvalidOption {
        option: &'static str,
        reason: String,
    },
    #[error("invalid SfM input: {0}")]
    InvalidInput(String),
    #[error("need at least 2 images with features, got {0}; add more overlapping photos")]
    TooFewImages(usize),
    #[error("no model could be built: {0}")]
    NoModel(String),
}

/// Per-group intrinsics of a model, in pixels.
#[derive(Clone, Debug, Serialize)]
pub struct GroupSummary {
    pub camera_id: u32,
    pub views: usize,
    pub width: u32,
    pub height: u32,
    pub f: f64,
    pub aspect: f64,
    pub skew: f64,
    pub pp: [f64; 2],
    pub k1: f64,
    pub k2: f64,
}

/// Everything measured about one model.
#[derive(Clone, Debug, Serialize)]
pub struct ModelSummary {
    pub registered: usize,
    pub total_images: usize,
    pub points: usize,
    pub observations: usize,
    pub mean_track_length: f64,
    pub mean_reprojection_error_px: f64,
    pub initial_pair: [String; 2],
    pub groups: Vec<GroupSummary>,
    pub self_calibration: SelfCalibrationReport,
    pub projective_ba: Vec<ProjectiveBaRecord>,
    pub metric_ba: Vec<MetricBaRecord>,
    pub uncertainty: Option<UncertaintyReport>,
    /// Why uncertainty statistics are missing, when they are.
    pub uncertainty_note: Option<String>,
    pub timings_s: BTreeMap<String, f64>,
}

/// One metric model and its summary.
#[derive(Clone, Debug)]
pub struct SfmModel {
    pub reconstruction: MetricReconstruction,
    pub summary: ModelSummary,
}

/// The result of [`reconstruct`]: models, largest first, and the images left out with the reason.
#[derive(Clone, Debug)]
pub struct SfmResult {
    pub models: Vec<SfmModel>,
    pub unregistered: Vec<(String, String)>,
}

/// Runs Table 2 and §3.4 end to end. Deterministic for a given input and seed.
pub fn reconstruct(
    input: &SfmInput,
    options: &SfmOptions,
    progress: &dyn Progress,
) -> Result<SfmResult, SfmError> {
    options.validate()?;
    input.validate().map_err(SfmError::InvalidInput)?;
    let usable = input
        .images
        .iter()
        .filter(|im| !im.keypoints.is_empty())
        .count();
    if usable < 2 {
        return Err(SfmError::TooFewImages(usable));
    }
    let graph = graph::CorrespondenceGraph::build(input, 8);
    let ctx = context::Context::new(input, &graph, options);
    let estimate_aspect = options.estimate_aspect.unwrap_or(input.video);
    let n = input.images.len();
    // Images without any verified pair (a video's in-between frames) cannot start or join the
    // projective model; video frames are registered from their tracks afterwards.
    let mut allowed: Vec<bool> = input
        .images
        .iter()
        .enumerate()
        .map(|(i, im)| !im.keypoints.is_empty() && !graph.neighbours(i).is_empty())
        .collect();
    let mut models = Vec::new();
    let mut failures: BTreeMap<usize, String> = BTreeMap::new();
    let mut last_err = String::new();
    for _ in 0..options.max_models {
        if allowed.iter().filter(|a| **a).count() < 2 {
            break;
        }
        let mut timings = BTreeMap::new();
        let t0 = Instant::now();
        let model = match projective::reconstruct_projective(&ctx, &allowed, progress) {
            Ok(m) => m,
            Err(e) => {
                last_err = e;
                break;
            }
        };
        timings.insert("projective".to_string(), t0.elapsed().as_secs_f64());
        for &i in &model.order {
            allowed[i] = false;
        }
        for (i, e) in &model.failures {
            failures.insert(*i, e.clone());
        }
        if model.order.len() < 2 {
            break;
        }
        let t1 = Instant::now();
        let up = match metric::upgrade(&ctx, &model, estimate_aspect) {
            Ok(u) => u,
            Err(e) => {
                last_err = e;
                continue;
            }
        };
        timings.insert("self_calibration".to_string(), t1.elapsed().as_secs_f64());
        let t2 = Instant::now();
        let mut report = up.report;
        // A known calibration gives the upgrade itself (eq. 26 with K given), whatever the motion;
        // the self-calibrated candidates are built only without one, or if it is inconsistent with
        // the cameras.
        let known = ctx.opts.known_intrinsics.and_then(|k| {
            let focal = 0.5 * (k.fx + k.fy) * ctx.scale.first().copied().unwrap_or(f64::NAN);
            let h = hypotheses::known_focal_upgrade(&model, focal).filter(|h| !h.clamped)?;
            metric::from_transform(&ctx, &model, &h.t, estimate_aspect).ok()
        });
        // When the linear self-calibration is doubtful (critical motion, or an Ω* that is not
        // semi-definite), the frame from the priors alone is adjusted too and the better-explaining
        // model kept: the paper's "fall back on the priors" without trusting either blindly.
        let from_known = known.is_some();
        let mut candidates = vec![(known.unwrap_or(up.rec), false)];
        if report.degenerate.is_some() && !from_known {
            if !report.used_prior_fallback {
                if let Ok(r) = metric::prior_frame(&ctx, &model, estimate_aspect) {
                    candidates.push((r, true));
                }
            }
            // Critical motion leaves the focal free in eq. 26: try the focal lengths that the
            // cameras fit best with the other priors exact (see `hypotheses`).
            for h in hypotheses::focal_hypotheses(&model, 3) {
                tracing::debug!(focal = h.focal, residual = h.residual, "focal hypothesis");
                if let Ok(r) = metric::from_transform(&ctx, &model, &h.t, estimate_aspect) {
                    candidates.push((r, true));
                }
            }
        }
        // One candidate: adjust it. Several: keep the one a short adjustment explains best.
        let (mut rec, is_prior) = if candidates.len() == 1 {
            candidates.pop().expect("one candidate")
        } else {
            let scores: Vec<f64> = candidates
                .iter()
                .map(|(r, _)| metric_ba::quick_score(&ctx, r, estimate_aspect))
                .collect();
            tracing::debug!(?scores, "metric frame candidates");
            let best = (0..candidates.len())
                .max_by(|&a, &b| scores[a].total_cmp(&scores[b]))
                .unwrap_or(0);
            candidates.swap_remove(best)
        };
        let mut metric_ba = match metric_ba::refine_metric(&ctx, &mut rec, estimate_aspect) {
            Ok(r) => r,
            Err(e) => {
                last_err = e;
                continue;
            }
        };
        // Views the projective stage could not add (planar 2D–3D matches, late links) are tried
        // again with calibrated resection, then everything is adjusted once more.
        let t_reg = Instant::now();
        let added = register::register_calibrated(&ctx, &mut rec, &allowed, &mut failures);
        if !added.is_empty() {
            for &i in &added {
                allowed[i] = false;
                failures.remove(&i);
            }
            match metric_ba::refine_metric(&ctx, &mut rec, estimate_aspect) {
                Ok(r) => metric_ba.extend(r),
                Err(e) => {
                    last_err = e;
                    continue;
                }
            }
        }
        timings.insert(
            "calibrated_registration".to_string(),
            t_reg.elapsed().as_secs_f64(),
        );
        // §3.2: more observations of the existing points, found at their predicted projections.
        let t_pred = Instant::now();
        let extended = predict::extend_tracks(&ctx, &mut rec);
        if extended > 0 {
            tracing::debug!(extended, "observations added by predicted projection");
            match metric_ba::final_adjustment(&ctx, &mut rec, estimate_aspect) {
                Ok(r) => metric_ba.extend(r),
                Err(e) => {
                    last_err = e;
                    continue;
                }
            }
        }
        timings.insert(
            "predicted_matches".to_string(),
            t_pred.elapsed().as_secs_f64(),
        );
        // Video: every in-between frame from its tracks, then all frames adjusted together.
        let t_frames = Instant::now();
        let frames = video::register_frames(&ctx, &mut rec, &mut failures);
        if !frames.is_empty() {
            tracing::info!("registered {} in-between video frames", frames.len());
            match metric_ba::refine_metric(&ctx, &mut rec, estimate_aspect) {
                Ok(r) => metric_ba.extend(r),
                Err(e) => {
                    last_err = e;
                    continue;
                }
            }
            timings.insert("video_frames".to_string(), t_frames.elapsed().as_secs_f64());
        }
        if is_prior {
            report.used_prior_fallback = true;
        }
        timings.insert("metric_ba".to_string(), t2.elapsed().as_secs_f64());
        let t3 = Instant::now();
        let (uncertainty, uncertainty_note) = if options.uncertainty {
            match uncertainty::uncertainty(&ctx, &rec) {
                Ok(u) => (Some(u), None),
                Err(e) => (None, Some(e)),
            }
        } else {
            (None, Some("disabled".into()))
        };
        timings.insert("uncertainty".to_string(), t3.elapsed().as_secs_f64());
        let summary = summarize(
            &ctx,
            &model,
            &rec,
            report,
            metric_ba,
            uncertainty,
            uncertainty_note,
            timings,
        );
        models.push(SfmModel {
            reconstruction: rec,
            summary,
        });
    }
    if models.is_empty() {
        if last_err.is_empty() {
            let linked = (0..n).filter(|&i| !graph.neighbours(i).is_empty()).count();
            last_err = format!(
                "only {linked} of {n} images have verified matches with another image (need 2): \
                 the images do not overlap, or the camera hardly moves (video: too few key-frames)"
            );
        }
        return Err(SfmError::NoModel(last_err));
    }
    models.sort_by_key(|m| std::cmp::Reverse(m.summary.registered));
    let registered: std::collections::BTreeSet<_> = models
        .iter()
        .flat_map(|m| m.reconstruction.views.keys().copied())
        .collect();
    let unregistered = (0..n)
        .filter(|&i| !registered.contains(&input.images[i].id))
        .map(|i| {
            let im = &input.images[i];
            let why = if im.keypoints.is_empty() {
                "no features".to_string()
            } else if let Some(f) = failures.get(&i) {
                f.clone()
            } else if graph.neighbours(i).is_empty() {
                "no verified matches with any other image".to_string()
            } else {
                "not connected to a model".to_string()
            };
            (im.name.clone(), why)
        })
        .collect();
    Ok(SfmResult {
        models,
        unregistered,
    })
}

#[allow(clippy::too_many_arguments)]
fn summarize(
    ctx: &context::Context,
    model: &model::ProjectiveModel,
    rec: &MetricReconstruction,
    self_calibration: SelfCalibrationReport,
    metric_ba: Vec<MetricBaRecord>,
    uncertainty: Option<UncertaintyReport>,
    uncertainty_note: Option<String>,
    timings_s: BTreeMap<String, f64>,
) -> ModelSummary {
    let observations: usize = rec.points.values().map(|p| p.track.len()).sum();
    let groups = rec
        .cameras
        .values()
        .map(|c| {
            let k = &c.intrinsics;
            GroupSummary {
                camera_id: c.id.0,
                views: rec.views.values().filter(|v| v.camera_id == c.id).count(),
                width: c.width,
                height: c.height,
                f: k.f,
                aspect: k.aspect,
                skew: k.skew,
                pp: [k.pp.x, k.pp.y],
                k1: k.k1,
                k2: k.k2,
            }
        })
        .collect();
    let names = &ctx.input.images;
    ModelSummary {
        registered: rec.views.len(),
        total_images: names.len(),
        points: rec.points.len(),
        observations,
        mean_track_length: observations as f64 / rec.points.len().max(1) as f64,
        mean_reprojection_error_px: rec.mean_reprojection_error(),
        initial_pair: [
            names[model.init_pair.0].name.clone(),
            names[model.init_pair.1].name.clone(),
        ],
        groups,
        self_calibration,
        projective_ba: model.ba.clone(),
        metric_ba,
        uncertainty,
        uncertainty_note,
        timings_s,
    }
}
