//! The demo's accuracy of matching and of the sparse model against the exact ground truth.

use std::collections::HashMap;
use std::path::Path;

use handheld_core::{MetricReconstruction, Sim3, View};
use handheld_io::database::{Database, TwoViewConfig};
use handheld_pipeline::files;
use nalgebra::{Vector2, Vector3};
use serde::{Deserialize, Serialize};

use super::sequence::GROUND_TRUTH_DIR;
use crate::error::{EvalError, Result};

/// Ground-truth views keyed by the name the workspace gives them: the rendered file name for the
/// photo folder, `frame_<index>.png` (the ingest stage's name for decoded frames) for the video.
pub fn gt_by_name(gt: &MetricReconstruction, video: bool) -> HashMap<String, &View> {
    let mut views: Vec<&View> = gt.views.values().collect();
    views.sort_by(|a, b| a.name.cmp(&b.name));
    views
        .into_iter()
        .enumerate()
        .map(|(k, v)| {
            let name = if video {
                format!("frame_{k:06}.png")
            } else {
                v.name.clone()
            };
            (name, v)
        })
        .collect()
}

/// A demo's ground truth and estimated model, with the similarity (model → ground truth) that
/// aligns the registered camera centres.
pub struct Aligned {
    pub gt: MetricReconstruction,
    pub est: MetricReconstruction,
    pub sim: Sim3,
    video: bool,
}

impl Aligned {
    /// Reads both models and aligns them; fails with fewer than 3 registered views.
    pub fn load(out: &Path, workspace: &Path, video: bool) -> Result<Self> {
        let gt =
            handheld_io::colmap::read_reconstruction(&out.join(GROUND_TRUTH_DIR).join("sparse"))?;
        let est = handheld_io::colmap::read_reconstruction(&workspace.join(files::stage::SPARSE))?;
        let mut a = Self {
            gt,
            est,
            sim: Sim3::identity(),
            video,
        };
        let pairs = a.pairs();
        if pairs.len() < 3 {
            return Err(EvalError::Data(format!(
                "only {} views registered",
                pairs.len()
            )));
        }
        let src: Vec<_> = pairs.iter().map(|p| p.0.center()).collect();
        let dst: Vec<_> = pairs.iter().map(|p| p.1.center()).collect();
        a.sim = Sim3::align(&src, &dst)
            .ok_or_else(|| EvalError::Data("aligning the camera centres failed".into()))?;
        Ok(a)
    }

    /// (estimated view, ground-truth view) for every registered view.
    pub fn pairs(&self) -> Vec<(&View, &View)> {
        let by_name = gt_by_name(&self.gt, self.video);
        self.est
            .views
            .values()
            .filter_map(|v| by_name.get(v.name.as_str()).map(|g| (v, *g)))
            .collect()
    }
}

/// The median of `v` (NaN when empty), sorting it.
pub(crate) fn median_nan(v: &mut [f64]) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

/// Matching scored against the exact relative poses.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct MatchingAccuracy {
    /// Pairs verified as general (fundamental matrix).
    pub verified_pairs: usize,
    /// Their inliers.
    pub inliers: usize,
    /// Median distance of an inlier to its true epipolar line (pixels).
    pub inlier_epipolar_error_median_px: Option<f64>,
    /// Fraction of the inliers within 1 px of their true epipolar line.
    pub inliers_within_1px_of_true_epipolar_line: f64,
}

/// For every pair verified as general, the epipolar distance of its inliers under the exact
/// relative pose (keypoints undistorted with the GT intrinsics, distance scaled back to pixels).
pub fn matching_accuracy(out: &Path, workspace: &Path, video: bool) -> Result<MatchingAccuracy> {
    let gt = handheld_io::colmap::read_reconstruction(&out.join(GROUND_TRUTH_DIR).join("sparse"))?;
    let db = Database::open(&workspace.join(files::stage::MATCHES).join(files::DATABASE))?;
    let images = db.images()?;
    let views = gt_by_name(&gt, video);
    let mut errors = Vec::new();
    let mut verified = 0;
    let mut keypoints = HashMap::new();
    for (ia, (a, name_a, _)) in images.iter().enumerate() {
        for (b, name_b, _) in &images[ia + 1..] {
            let Some(g) = db.read_two_view_geometry(*a, *b)? else {
                continue;
            };
            if g.config != TwoViewConfig::Uncalibrated as i64 {
                continue;
            }
            let (Some(va), Some(vb)) = (views.get(name_a.as_str()), views.get(name_b.as_str()))
            else {
                continue;
            };
            let (Some(ca), Some(cb)) =
                (gt.cameras.get(&va.camera_id), gt.cameras.get(&vb.camera_id))
            else {
                continue;
            };
            verified += 1;
            let rel = vb.cam_from_world * va.cam_from_world.inverse();
            let e = handheld_geometry::skew(&rel.translation.vector)
                * rel.rotation.to_rotation_matrix().matrix();
            for id in [*a, *b] {
                if let std::collections::hash_map::Entry::Vacant(slot) = keypoints.entry(id) {
                    slot.insert(db.read_keypoints(id)?);
                }
            }
            let (Some(ka), Some(kb)) = (keypoints.get(a), keypoints.get(b)) else {
                continue;
            };
            for &(i, j) in &g.inliers {
                let (Some(pa), Some(pb)) = (ka.get(i as usize), kb.get(j as usize)) else {
                    continue;
                };
                let na = ca
                    .intrinsics
                    .pixel_to_normalized(Vector2::new(pa[0] as f64, pa[1] as f64));
                let nb = cb
                    .intrinsics
                    .pixel_to_normalized(Vector2::new(pb[0] as f64, pb[1] as f64));
                let l = e * Vector3::new(na.x, na.y, 1.0);
                let d = (l.x * nb.x + l.y * nb.y + l.z).abs() / (l.x * l.x + l.y * l.y).sqrt();
                errors.push(d * cb.intrinsics.f);
            }
        }
    }
    errors.sort_by(|x, y| x.total_cmp(y));
    let within = errors.iter().filter(|&&d| d <= 1.0).count();
    Ok(MatchingAccuracy {
        verified_pairs: verified,
        inliers: errors.len(),
        inlier_epipolar_error_median_px: errors.get(errors.len() / 2).copied(),
        inliers_within_1px_of_true_epipolar_line: within as f64 / errors.len().max(1) as f64,
    })
}

/// The sparse model's cameras against the exact cameras.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SparseAccuracy {
    /// Registered views, of `total`.
    pub registered: usize,
    pub total: usize,
    /// Absolute rotation error after the similarity fit (degrees).
    pub rotation_error_deg_median: f64,
    pub rotation_error_deg_max: f64,
    /// Relative rotation error over all pairs of registered views (gauge-free; degrees).
    pub relative_rotation_error_deg_median: f64,
    pub relative_rotation_error_deg_max: f64,
    /// Camera centre error after the similarity fit (metres, and relative to the path's extent).
    pub center_error_median_m: f64,
    pub center_error_rel_extent_median: f64,
    /// Focal error after metric BA, and of self-calibration before it (%).
    pub focal_error_pct: f64,
    pub self_calibration_focal_error_pct: f64,
    /// Estimated and true pixel aspect ratio and first radial coefficient.
    pub aspect: Option<f64>,
    pub aspect_true: Option<f64>,
    pub k1: Option<f64>,
    pub k1_true: Option<f64>,
    /// As the sparse stage's summary reports it.
    pub mean_reprojection_error_px: Option<f64>,
}

/// Camera accuracy of the sparse model against the exact cameras: registered views, rotation and
/// centre error after a similarity fit of the centres (as `eval_sfm.py`), focal error, and the focal
/// error of self-calibration before metric BA.
pub fn sparse_accuracy(out: &Path, workspace: &Path, video: bool) -> Result<SparseAccuracy> {
    let summary_path = workspace
        .join(files::stage::SPARSE)
        .join(files::SUMMARY_JSON);
    let bytes =
        std::fs::read(&summary_path).map_err(|e| handheld_io::IoError::io(&summary_path, e))?;
    let summary: serde_json::Value = serde_json::from_slice(&bytes)
        .map_err(|e| handheld_io::IoError::format(&summary_path, e.to_string()))?;
    let aligned = Aligned::load(out, workspace, video)?;
    let (gt, est, sim) = (&aligned.gt, &aligned.est, aligned.sim);
    let pairs = aligned.pairs();
    let dst: Vec<_> = pairs.iter().map(|p| p.1.center()).collect();
    let mut rot: Vec<f64> = Vec::new();
    let mut cen: Vec<f64> = Vec::new();
    for (e, g) in &pairs {
        let pose = sim.transform_pose(&e.cam_from_world);
        rot.push(
            (pose.rotation * g.cam_from_world.rotation.inverse())
                .angle()
                .to_degrees(),
        );
        cen.push((handheld_core::pose::center_of(&pose) - g.center()).norm());
    }
    let rot_max = rot.iter().fold(0.0f64, |a, b| a.max(*b));
    // Relative rotations between all pairs (gauge-free, the basis of the pose AUC).
    let mut rel: Vec<f64> = Vec::new();
    for (k, (ea, ga)) in pairs.iter().enumerate() {
        for (eb, gb) in &pairs[k + 1..] {
            let re = ea.cam_from_world.rotation * eb.cam_from_world.rotation.inverse();
            let rg = ga.cam_from_world.rotation * gb.cam_from_world.rotation.inverse();
            rel.push((re * rg.inverse()).angle().to_degrees());
        }
    }
    let rel_max = rel.iter().fold(0.0f64, |a, b| a.max(*b));
    let gt_cam = gt.cameras.values().next().map(|c| &c.intrinsics);
    let est_cam = est.cameras.values().next().map(|c| &c.intrinsics);
    let f_true = gt_cam.map(|c| c.f).unwrap_or(f64::NAN);
    let f_est = est_cam.map(|c| c.f).unwrap_or(f64::NAN);
    let f_selfcal = summary["self_calibration"]["focal_before_ba_px"]
        .as_object()
        .and_then(|m| m.values().next())
        .and_then(|v| v.as_f64())
        .unwrap_or(f64::NAN);
    let extent = dst
        .iter()
        .map(|c| dst.first().map_or(0.0, |d0| (c - d0).norm()))
        .fold(0.0f64, f64::max);
    let center_median = median_nan(&mut cen);
    Ok(SparseAccuracy {
        registered: pairs.len(),
        total: gt.views.len(),
        rotation_error_deg_median: median_nan(&mut rot),
        rotation_error_deg_max: rot_max,
        relative_rotation_error_deg_median: median_nan(&mut rel),
        relative_rotation_error_deg_max: rel_max,
        center_error_median_m: center_median,
        center_error_rel_extent_median: center_median / extent.max(1e-12),
        focal_error_pct: 100.0 * (f_est / f_true - 1.0).abs(),
        self_calibration_focal_error_pct: 100.0 * (f_selfcal / f_true - 1.0).abs(),
        aspect: est_cam.map(|c| c.aspect),
        aspect_true: gt_cam.map(|c| c.aspect),
        k1: est_cam.map(|c| c.k1),
        k1_true: gt_cam.map(|c| c.k1),
        mean_reprojection_error_px: summary["mean_reprojection_error_px"].as_f64(),
    })
}
