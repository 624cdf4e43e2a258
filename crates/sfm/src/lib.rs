//! Uncalibrated structure and motion (§3, Table 2): correspondence graph and tracks, initial pair
//! (§3.1), projective resection and structure extension (§3.2), projective bundle adjustment (§3.3),
//! linear self-calibration with the dual absolute quadric (§3.4, eqs. 24–27), metric bundle
//! adjustment with radial distortion, and the video mode (KLT tracks, GRIC key-frames, per-frame poses).
//!
//! One call, [`reconstruct`], takes an [`SfmInput`] (images with keypoints, verified pairs) and
//! returns one or more metric models: a broken sequence gives several models with the reason, never
//! a silent partial result.

mod canonical;
pub mod consistency;
mod context;
mod frame;
pub mod graph;
pub mod guard;
mod hypotheses;
mod init;
pub mod input;
pub mod merge;
pub mod metric;
pub mod metric_ba;
mod model;
mod noise;
pub mod options;
mod pipeline;
mod planes;
mod predict;
mod profile;
pub mod projective;
mod projective_ba;
mod register;
mod register_pair;
pub mod selfcal;
#[cfg(test)]
mod test_scene;
mod tracks;
mod uncertainty;
mod video;

use std::collections::BTreeMap;

use handheld_core::{MetricReconstruction, Progress};
use serde::Serialize;

pub use guard::CandidateRecord;
pub use input::{SfmImage, SfmInput, SfmPair};
pub use metric::SelfCalibrationReport;
pub use metric_ba::MetricBaRecord;
pub use model::ProjectiveBaRecord;
pub use options::{Distortion, KnownIntrinsics, SfmOptions};
pub use pipeline::StepError;
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
    /// Model building stopped at a step, for every model attempted (the last failure).
    #[error("no model could be built: {0}")]
    NoModel(StepError),
    /// Fewer than 2 images are matched to another one, so no model can start.
    #[error(
        "no model could be built: only {linked} of {total} images have verified matches with \
         another image (need 2): the images do not overlap, or the camera hardly moves (video: too \
         few key-frames)"
    )]
    NoOverlap { linked: usize, total: usize },
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
    /// Whether the views agree with their verified pairs, and those taken out (`consistency.rs`).
    pub view_consistency: consistency::ConsistencyReport,
    /// Models merged into this one (`merge.rs`), in order.
    pub merged: Vec<merge::MergeRecord>,
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

/// Runs Table 2 and §3.4 end to end: models are built one after the other from the views still
/// free (the steps of `pipeline.rs`) until `max_models`, or until no view is left to start one.
/// Deterministic for a given input and seed, and for photos independent of their order (see
/// `canonical.rs`).
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
    let canonical = canonical::Canonical::new(input);
    let input = canonical.as_ref().map_or(input, |c| &c.input);
    let graph = graph::CorrespondenceGraph::build(input, 8);
    let ctx = context::Context::new(input, &graph, options);
    let mut search = pipeline::Search::new(&ctx);
    let mut models = Vec::new();
    // The last failure, reported when no model could be built.
    let mut last_err: Option<StepError> = None;
    for _ in 0..options.max_models {
        if search.free() < 2 {
            break;
        }
        match pipeline::build_model(&ctx, &mut search, progress) {
            Ok(Some(model)) => models.push(model),
            Ok(None) => break,
            Err(e) => {
                let ends = e.ends_search();
                last_err = Some(e);
                if ends {
                    break;
                }
            }
        }
    }
    if models.is_empty() {
        let n = input.images.len();
        return Err(match last_err {
            Some(e) => SfmError::NoModel(e),
            None => SfmError::NoOverlap {
                linked: (0..n).filter(|&i| !graph.neighbours(i).is_empty()).count(),
                total: n,
            },
        });
    }
    merge::merge_models(&ctx, &mut models);
    models.sort_by_key(|m| std::cmp::Reverse(m.summary.registered));
    let unregistered = unregistered(input, &graph, &models, &search.failures);
    if let Some(c) = &canonical {
        for m in &mut models {
            c.restore(&mut m.reconstruction);
        }
    }
    Ok(SfmResult {
        models,
        unregistered,
    })
}

/// The images in no model, each with the reason.
fn unregistered(
    input: &SfmInput,
    graph: &graph::CorrespondenceGraph,
    models: &[SfmModel],
    failures: &BTreeMap<usize, String>,
) -> Vec<(String, String)> {
    let registered: std::collections::BTreeSet<_> = models
        .iter()
        .flat_map(|m| m.reconstruction.views.keys().copied())
        .collect();
    input
        .images
        .iter()
        .enumerate()
        .filter(|(_, im)| !registered.contains(&im.id))
        .map(|(i, im)| {
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
        .collect()
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
    let groups = group_summaries(rec);
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
        view_consistency: Default::default(),
        merged: Vec::new(),
        timings_s,
    }
}

impl ModelSummary {
    /// Recounts what depends on the model's contents (after a merge).
    pub(crate) fn recount(&mut self, rec: &MetricReconstruction) {
        let observations: usize = rec.points.values().map(|p| p.track.len()).sum();
        self.registered = rec.views.len();
        self.points = rec.points.len();
        self.observations = observations;
        self.mean_track_length = observations as f64 / rec.points.len().max(1) as f64;
        self.mean_reprojection_error_px = rec.mean_reprojection_error();
        self.groups = group_summaries(rec);
    }
}

/// Per-group intrinsics of `rec`.
fn group_summaries(rec: &MetricReconstruction) -> Vec<GroupSummary> {
    rec.cameras
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
        .collect()
}
