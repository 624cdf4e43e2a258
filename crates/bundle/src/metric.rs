//! Metric bundle adjustment (§3.4): poses, points and intrinsics groups of a [`MetricReconstruction`],
//! with any subset of the intrinsics held constant per group and soft Gaussian priors on the others
//! (the paper's soft constraints, e.g. aspect ≈ 1, skew ≈ 0, principal point ≈ image centre).

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;

use handheld_core::{CameraId, ImageId, MetricReconstruction, PointId};
use nalgebra::{Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};

use crate::options::{BundleError, BundleOptions, BundleSummary};
pub use crate::problem::GaussianPrior;
use crate::problem::{CameraModel, Problem};
use crate::residual::NUM_INTRINSICS;

/// One intrinsic parameter, in the order of the metric residual (`[f, aspect, skew, u₀, v₀, k1, k2,
/// ρx, ρy]`; the last two: the rolling shutter's read-out, [`RollingShutter`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum IntrinsicParam {
    F,
    Aspect,
    Skew,
    Ppx,
    Ppy,
    K1,
    K2,
    ReadoutX,
    ReadoutY,
}

impl IntrinsicParam {
    pub fn index(self) -> usize {
        self as usize
    }
}

/// Which intrinsics of a group are refined (`true`) or held constant.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct IntrinsicsMask {
    pub f: bool,
    pub aspect: bool,
    pub skew: bool,
    pub principal_point: bool,
    pub k1: bool,
    pub k2: bool,
}

impl IntrinsicsMask {
    pub fn none() -> Self {
        Self {
            f: false,
            aspect: false,
            skew: false,
            principal_point: false,
            k1: false,
            k2: false,
        }
    }

    pub fn all() -> Self {
        Self {
            f: true,
            aspect: true,
            skew: true,
            principal_point: true,
            k1: true,
            k2: true,
        }
    }

    /// Focal length and both radial coefficients (BAL's camera).
    pub fn focal_and_radial() -> Self {
        Self {
            f: true,
            k1: true,
            k2: true,
            ..Self::none()
        }
    }

    pub fn to_array(self) -> [bool; NUM_INTRINSICS] {
        [
            self.f,
            self.aspect,
            self.skew,
            self.principal_point,
            self.principal_point,
            self.k1,
            self.k2,
            false,
            false,
        ]
    }
}

impl Default for IntrinsicsMask {
    /// Focal length and `k1` (eq. 3).
    fn default() -> Self {
        Self {
            f: true,
            k1: true,
            ..Self::none()
        }
    }
}

/// What metric bundle adjustment may change.
#[derive(Clone, Debug, PartialEq)]
pub struct MetricBundleConfig {
    /// Intrinsics refined for every group without an entry in `intrinsics`. Default: `f` and `k1`.
    pub refine: IntrinsicsMask,
    /// Per-group overrides of `refine`.
    pub intrinsics: BTreeMap<CameraId, IntrinsicsMask>,
    /// Soft priors per group (used only for refined parameters). Default none.
    pub priors: BTreeMap<CameraId, Vec<(IntrinsicParam, GaussianPrior)>>,
    /// Views whose pose is held constant. Default none.
    pub constant_views: BTreeSet<ImageId>,
    /// Also hold the first view (smallest id) constant, fixing 6 of the 7 gauge freedoms. Default true.
    pub fix_first_view: bool,
    /// Standard deviation (pixels) of each keypoint of a view, indexed like `View::observations`.
    /// Views without an entry, and keypoints past its end, have σ = 1. Default none.
    pub keypoint_sigma: BTreeMap<ImageId, Arc<[f64]>>,
    /// A rolling-shutter camera ([`crate::residual`]'s notes) for the views with a velocity. Default
    /// none: a global shutter.
    pub rolling_shutter: Option<RollingShutter>,
}

/// The rolling shutter of a video's frames: each frame's velocity, held, and each group's read-out
/// `[ρx, ρy]` (frame intervals across the image along x and y), refined under a prior.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RollingShutter {
    /// `[ω, ν]` per frame interval in the camera frame: the pose at time `τ` is
    /// `(exp([τω]×) R, t + τ ν)`. Views without one are taken as still.
    pub velocity: BTreeMap<ImageId, [f64; 6]>,
    /// The start (and, after [`bundle_adjust_metric`], the adjusted) read-out of each group;
    /// groups without one start at 0.
    pub readout: BTreeMap<CameraId, [f64; 2]>,
    /// Refine the read-out (else hold it), under a zero-mean prior of this σ (frame intervals).
    pub refine_sigma: Option<f64>,
}

impl Default for MetricBundleConfig {
    fn default() -> Self {
        Self {
            refine: IntrinsicsMask::default(),
            intrinsics: BTreeMap::new(),
            priors: BTreeMap::new(),
            constant_views: BTreeSet::new(),
            fix_first_view: true,
            keypoint_sigma: BTreeMap::new(),
            rolling_shutter: None,
        }
    }
}

/// The ids behind a metric [`Problem`]'s indices.
pub(crate) struct MetricIndex {
    pub views: Vec<ImageId>,
    pub cameras: Vec<CameraId>,
    pub points: Vec<PointId>,
}

/// Builds the flat problem of a reconstruction. Points without observations are left out.
pub(crate) fn metric_problem(
    rec: &MetricReconstruction,
    config: &MetricBundleConfig,
) -> Result<(Problem, MetricIndex), BundleError> {
    let mut p = Problem::new(CameraModel::Metric);
    let cameras: Vec<CameraId> = rec.cameras.keys().copied().collect();
    let group_of: BTreeMap<CameraId, usize> =
        cameras.iter().enumerate().map(|(i, c)| (*c, i)).collect();
    let rs = config.rolling_shutter.as_ref();
    for (id, cam) in &rec.cameras {
        let k = &cam.intrinsics;
        let [rx, ry] = rs
            .and_then(|r| r.readout.get(id))
            .copied()
            .unwrap_or([0.0; 2]);
        p.groups
            .push([k.f, k.aspect, k.skew, k.pp.x, k.pp.y, k.k1, k.k2, rx, ry]);
        let mut free = config
            .intrinsics
            .get(id)
            .copied()
            .unwrap_or(config.refine)
            .to_array();
        let mut pri = [None; NUM_INTRINSICS];
        for (param, prior) in config.priors.get(id).map(|v| v.as_slice()).unwrap_or(&[]) {
            pri[param.index()] = Some(*prior);
        }
        if let Some(sigma) = rs.and_then(|r| r.refine_sigma) {
            for param in [IntrinsicParam::ReadoutX, IntrinsicParam::ReadoutY] {
                free[param.index()] = true;
                pri[param.index()] = Some(GaussianPrior { mean: 0.0, sigma });
            }
        }
        p.group_free.push(free);
        p.group_priors.push(pri);
    }
    let views: Vec<ImageId> = rec.views.keys().copied().collect();
    let view_of: BTreeMap<ImageId, usize> =
        views.iter().enumerate().map(|(i, v)| (*v, i)).collect();
    for (i, v) in rec.views.values().enumerate() {
        let g = *group_of.get(&v.camera_id).ok_or_else(|| {
            BundleError::InvalidInput(format!("view {} uses unknown camera {}", v.id, v.camera_id))
        })?;
        p.cameras.push(pose_to_block(&v.cam_from_world));
        p.camera_group.push(g);
        if let Some(r) = rs {
            p.camera_velocity
                .push(r.velocity.get(&v.id).copied().unwrap_or([0.0; 6]));
        }
        p.camera_constant
            .push(config.constant_views.contains(&v.id) || (config.fix_first_view && i == 0));
    }
    let mut points = Vec::new();
    for (pid, pt) in &rec.points {
        if pt.track.is_empty() {
            continue;
        }
        let idx = points.len() as u32;
        for el in &pt.track.elements {
            let vi = *view_of.get(&el.image_id).ok_or_else(|| {
                BundleError::InvalidInput(format!(
                    "point {pid} is seen by unknown view {}",
                    el.image_id
                ))
            })?;
            let obs = rec.views[&el.image_id]
                .observations
                .get(el.point2d_idx as usize)
                .ok_or_else(|| {
                    BundleError::InvalidInput(format!(
                        "point {pid}: view {} has no keypoint {}",
                        el.image_id, el.point2d_idx
                    ))
                })?;
            p.obs_camera.push(vi as u32);
            p.obs_point.push(idx);
            p.obs_xy.push([obs.xy.x, obs.xy.y]);
            if rs.is_some() {
                let cam = &rec.cameras[&rec.views[&el.image_id].camera_id];
                p.obs_basis.push([
                    obs.xy.x / f64::from(cam.width.max(1)) - 0.5,
                    obs.xy.y / f64::from(cam.height.max(1)) - 0.5,
                ]);
            }
            if !config.keypoint_sigma.is_empty() {
                p.obs_sigma.push(observation_sigma(
                    &config.keypoint_sigma,
                    el.image_id,
                    el.point2d_idx,
                ));
            }
        }
        p.points.push([pt.xyz.x, pt.xyz.y, pt.xyz.z, 1.0]);
        points.push(*pid);
    }
    Ok((
        p,
        MetricIndex {
            views,
            cameras,
            points,
        },
    ))
}

/// The flat camera block of a pose (`residual::PoseBlock`: `R` row-major, then `t`).
pub fn pose_to_block(pose: &handheld_core::Rigid3) -> [f64; 12] {
    let r = pose.rotation.to_rotation_matrix();
    let t = pose.translation.vector;
    let mut b = [0.0; 12];
    for i in 0..3 {
        for j in 0..3 {
            b[3 * i + j] = r[(i, j)];
        }
        b[9 + i] = t[i];
    }
    b
}

pub(crate) fn block_to_pose(b: &[f64; 12]) -> handheld_core::Rigid3 {
    let m = Matrix3::new(b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7], b[8]);
    let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(m));
    handheld_core::Rigid3::from_parts(Translation3::from(Vector3::new(b[9], b[10], b[11])), q)
}

/// The localisation σ of keypoint `idx` of view `image` in `sigmas` (as in
/// [`MetricBundleConfig::keypoint_sigma`]); 1 px where none is given.
pub fn observation_sigma(sigmas: &BTreeMap<ImageId, Arc<[f64]>>, image: ImageId, idx: u32) -> f64 {
    sigmas
        .get(&image)
        .and_then(|s| s.get(idx as usize))
        .copied()
        .unwrap_or(1.0)
}

/// Metric bundle adjustment (§3.4) of poses, points and the refined intrinsics, in place. Each point's
/// `error` is set to its mean reprojection error after adjustment.
pub fn bundle_adjust_metric(
    rec: &mut MetricReconstruction,
    config: &MetricBundleConfig,
    options: &BundleOptions,
) -> Result<BundleSummary, BundleError> {
    Ok(bundle_adjust_metric_rolling(rec, config, options)?.0)
}

/// [`bundle_adjust_metric`], also returning each group's adjusted rolling-shutter read-out
/// `[ρx, ρy]` (zero without [`MetricBundleConfig::rolling_shutter`]).
pub fn bundle_adjust_metric_rolling(
    rec: &mut MetricReconstruction,
    config: &MetricBundleConfig,
    options: &BundleOptions,
) -> Result<(BundleSummary, BTreeMap<CameraId, [f64; 2]>), BundleError> {
    let (mut p, index) = metric_problem(rec, config)?;
    let summary = crate::solve(&mut p, options)?;
    for (i, id) in index.views.iter().enumerate() {
        if let Some(v) = rec.views.get_mut(id) {
            v.cam_from_world = block_to_pose(&p.cameras[i]);
        }
    }
    for (g, id) in index.cameras.iter().enumerate() {
        if let Some(c) = rec.cameras.get_mut(id) {
            let v = &p.groups[g];
            let k = &mut c.intrinsics;
            (k.f, k.aspect, k.skew, k.pp.x, k.pp.y, k.k1, k.k2) =
                (v[0], v[1], v[2], v[3], v[4], v[5], v[6]);
        }
    }
    let mut err = vec![(0.0, 0usize); p.points.len()];
    for o in 0..p.num_observations() {
        let r = p.residual(o);
        let e = &mut err[p.obs_point[o] as usize];
        e.0 += (r[0] * r[0] + r[1] * r[1]).sqrt();
        e.1 += 1;
    }
    for (i, id) in index.points.iter().enumerate() {
        if let Some(pt) = rec.points.get_mut(id) {
            let x = &p.points[i];
            pt.xyz = nalgebra::Point3::new(x[0], x[1], x[2]);
            pt.error = err[i].0 / err[i].1.max(1) as f64;
        }
    }
    let readout = index
        .cameras
        .iter()
        .zip(&p.groups)
        .map(|(id, g)| (*id, [g[7], g[8]]))
        .collect();
    Ok((summary, readout))
}
