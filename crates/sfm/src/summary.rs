//! What [`crate::reconstruct`] returns: one [`SfmModel`] per piece of the sequence, each with the
//! [`ModelSummary`] of everything measured about it (the self-calibration's report, every projective
//! and metric adjustment, the view-consistency check, the merges, the uncertainty, the timings).
//! Only the summary's types are imported here; the phases never import this module, only the
//! pipeline and the merge, which fill it in.

use std::collections::BTreeMap;

use handheld_core::MetricReconstruction;
use serde::Serialize;

use crate::context::Context;
use crate::merge::MergeRecord;
use crate::metric::ba::MetricBaRecord;
use crate::metric::consistency::ConsistencyReport;
use crate::metric::rolling::RollingShutterReport;
use crate::metric::uncertainty::UncertaintyReport;
use crate::projective::model::{ProjectiveBaRecord, ProjectiveModel};
use crate::upgrade::transform::SelfCalibrationReport;

/// Per-group intrinsics of a model, in pixels.
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
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

impl GroupSummary {
    /// Whether the principal point lies outside the image. No camera's does, unless its photos were
    /// cropped off-centre: where the model puts it there, the calibration it was adjusted with
    /// does not describe a camera, and the poses adjusted with it are not to be trusted either
    /// (a long lens on a synthetic hemisphere: principal point 256 px above a 480 px image, k1
    /// 0.80, every view 100° off, at 0.56 px RMS).
    pub fn principal_point_outside(&self) -> bool {
        let [x, y] = self.pp;
        let inside = |v: f64, size: u32| (0.0..=f64::from(size)).contains(&v);
        !(inside(x, self.width) && inside(y, self.height))
    }
}

/// Everything measured about one model.
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
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
    /// Views whose projective resection inliers lay on one plane, completed by the matches off it
    /// (`projective/planar.rs`).
    #[serde(default)]
    pub planar_resections: Vec<String>,
    pub metric_ba: Vec<MetricBaRecord>,
    /// Points taken out of the finished model because their rays were parallel within their noise
    /// (`metric/depthless.rs`).
    #[serde(default)]
    pub points_without_depth: usize,
    pub uncertainty: Option<UncertaintyReport>,
    /// Why uncertainty statistics are missing, when they are.
    pub uncertainty_note: Option<String>,
    /// Whether the views agree with their verified pairs, and those taken out (`metric/consistency.rs`).
    pub view_consistency: ConsistencyReport,
    /// Video: the rolling shutter's read-out adjusted with the model (`metric/rolling.rs`).
    #[serde(default)]
    pub rolling_shutter: Option<RollingShutterReport>,
    /// Models merged into this one (`merge/`), in order.
    pub merged: Vec<MergeRecord>,
    pub timings_s: BTreeMap<String, f64>,
}

/// One metric model and its summary.
#[derive(Clone, Debug)]
pub struct SfmModel {
    pub reconstruction: MetricReconstruction,
    pub summary: ModelSummary,
}

/// The result of [`crate::reconstruct`]: models, largest first, and the images left out with the reason.
#[derive(Clone, Debug)]
pub struct SfmResult {
    pub models: Vec<SfmModel>,
    pub unregistered: Vec<(String, String)>,
    /// Duplicate shots (`duplicates.rs`): no point is made from an identical copy and its original
    /// alone.
    pub duplicates: Vec<DuplicateShot>,
    /// What split-and-merge did, when the input was split (`split/`).
    pub split: Option<crate::split::SplitReport>,
}

/// A photo that repeats another one (the same shot twice, a burst).
#[derive(Clone, Debug, Serialize, serde::Deserialize, PartialEq)]
pub struct DuplicateShot {
    pub image: String,
    /// The photo it repeats.
    pub of: String,
    /// Median displacement of their matched keypoints, pixels.
    pub shift_px: f64,
    /// The same keypoints (a copy of the file): no point is made from the two alone.
    pub identical: bool,
}

#[allow(clippy::too_many_arguments)]
pub(crate) fn summarize(
    ctx: &Context,
    model: &ProjectiveModel,
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
        planar_resections: model
            .planar_completed
            .iter()
            .map(|&i| names[i].name.clone())
            .collect(),
        metric_ba,
        points_without_depth: 0,
        uncertainty,
        uncertainty_note,
        view_consistency: Default::default(),
        rolling_shutter: None,
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_principal_point_off_the_image_is_named() {
        let g = |pp: [f64; 2]| GroupSummary {
            camera_id: 1,
            views: 2,
            width: 640,
            height: 480,
            f: 3300.0,
            aspect: 1.0,
            skew: 0.0,
            pp,
            k1: 0.0,
            k2: 0.0,
        };
        assert!(!g([320.0, 240.0]).principal_point_outside());
        assert!(!g([0.0, 480.0]).principal_point_outside());
        assert!(g([315.6, -16.1]).principal_point_outside());
        assert!(g([700.0, 240.0]).principal_point_outside());
        assert!(g([f64::NAN, 240.0]).principal_point_outside());
    }
}
