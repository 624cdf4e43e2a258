//! The flat bundle-adjustment problem: parameter blocks in plain vectors and index arrays saying which
//! camera and point each observation uses (the layout of Ceres' BAL example). Cameras belong to
//! intrinsics groups (metric model only) whose parameters may be shared by many cameras, held constant
//! by a mask, and softly tied to a Gaussian prior (§3.4's soft constraints).

use rayon::prelude::*;

use crate::loss::RobustLoss;
use crate::options::BundleError;
use crate::residual::{metric_residual, projective_residual, Motion, NUM_INTRINSICS};

/// Which residual function the cameras use.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CameraModel {
    /// `cameras[c]` is `R` row-major then `t` (`cam_from_world`), with intrinsics from `groups`.
    Metric,
    /// `cameras[c]` is the 3×4 matrix `P` row-major (unit Frobenius norm); `groups` is unused.
    Projective,
}

/// A Gaussian prior `x ~ N(mean, sigma²)` on one parameter: adds `½((x − mean)/sigma)²` to the cost.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GaussianPrior {
    pub mean: f64,
    pub sigma: f64,
}

/// A bundle-adjustment problem with flat parameter blocks.
#[derive(Clone, Debug, PartialEq)]
pub struct Problem {
    pub model: CameraModel,
    /// One 12-vector per camera (see [`CameraModel`]).
    pub cameras: Vec<[f64; 12]>,
    /// Cameras whose block is held constant (gauge fixing, known poses).
    pub camera_constant: Vec<bool>,
    /// Metric: intrinsics group of each camera (index into `groups`).
    pub camera_group: Vec<usize>,
    /// Metric: intrinsics `[f, aspect, skew, u₀, v₀, k1, k2]` per group.
    pub groups: Vec<[f64; NUM_INTRINSICS]>,
    /// Which intrinsics of each group are refined.
    pub group_free: Vec<[bool; NUM_INTRINSICS]>,
    /// Soft priors on intrinsics (only used for free parameters).
    pub group_priors: Vec<[Option<GaussianPrior>; NUM_INTRINSICS]>,
    /// Metric: `(X, Y, Z, 1)`; projective: homogeneous, unit norm.
    pub points: Vec<[f64; 4]>,
    /// Camera, point and pixel of each observation.
    pub obs_camera: Vec<u32>,
    pub obs_point: Vec<u32>,
    pub obs_xy: Vec<[f64; 2]>,
    /// Standard deviation (pixels) of each observation's position; empty means 1 for all. Residuals
    /// are divided by it before the robust loss, so the cost is the Mahalanobis distance of an
    /// isotropic measurement model (eq. 21 with per-observation weights).
    pub obs_sigma: Vec<f64>,
    /// Metric, rolling shutter: each camera's velocity `[ω, ν]` per frame interval (camera frame;
    /// [`crate::residual`]); empty means a global shutter, and then `obs_basis` is unused.
    pub camera_velocity: Vec<[f64; 6]>,
    /// Metric, rolling shutter: each observation's read-out basis `[u/w − ½, v/h − ½]`.
    pub obs_basis: Vec<[f64; 2]>,
}

impl Problem {
    /// An empty problem of the given model.
    pub fn new(model: CameraModel) -> Self {
        Self {
            model,
            cameras: Vec::new(),
            camera_constant: Vec::new(),
            camera_group: Vec::new(),
            groups: Vec::new(),
            group_free: Vec::new(),
            group_priors: Vec::new(),
            points: Vec::new(),
            obs_camera: Vec::new(),
            obs_point: Vec::new(),
            obs_xy: Vec::new(),
            obs_sigma: Vec::new(),
            camera_velocity: Vec::new(),
            obs_basis: Vec::new(),
        }
    }

    pub fn num_observations(&self) -> usize {
        self.obs_xy.len()
    }

    /// Checks array lengths and indices, and that every value is finite.
    pub fn validate(&self) -> Result<(), BundleError> {
        let bad = |m: String| Err(BundleError::InvalidInput(m));
        let (nc, np, no) = (self.cameras.len(), self.points.len(), self.obs_xy.len());
        if self.camera_constant.len() != nc
            || self.obs_camera.len() != no
            || self.obs_point.len() != no
        {
            return bad(
                "array lengths disagree (cameras/camera_constant or observation arrays)".into(),
            );
        }
        if !self.obs_sigma.is_empty() && self.obs_sigma.len() != no {
            return bad(format!(
                "{} observation sigmas for {no} observations",
                self.obs_sigma.len()
            ));
        }
        if !self.camera_velocity.is_empty()
            && (self.camera_velocity.len() != nc || self.obs_basis.len() != no)
        {
            return bad(format!(
                "{} camera velocities and {} read-out bases for {nc} cameras and {no} observations",
                self.camera_velocity.len(),
                self.obs_basis.len()
            ));
        }
        if let Some(o) = self
            .obs_sigma
            .iter()
            .position(|s| !(s.is_finite() && *s > 0.0))
        {
            return bad(format!(
                "observation {o} has a non-positive or non-finite sigma"
            ));
        }
        if self.model == CameraModel::Metric {
            let ng = self.groups.len();
            if self.camera_group.len() != nc
                || self.group_free.len() != ng
                || self.group_priors.len() != ng
            {
                return bad("array lengths disagree (camera_group or group arrays)".into());
            }
            if let Some(c) = self.camera_group.iter().position(|g| *g >= ng) {
                return bad(format!(
                    "camera {c} uses intrinsics group {} of {ng}",
                    self.camera_group[c]
                ));
            }
            for (g, pri) in self.group_priors.iter().enumerate() {
                if pri
                    .iter()
                    .flatten()
                    .any(|p| !(p.sigma > 0.0 && p.sigma.is_finite() && p.mean.is_finite()))
                {
                    return bad(format!(
                        "intrinsics group {g} has a prior with a non-positive or non-finite sigma"
                    ));
                }
            }
        }
        for o in 0..no {
            if self.obs_camera[o] as usize >= nc || self.obs_point[o] as usize >= np {
                return bad(format!(
                    "observation {o} refers to camera {} / point {} (of {nc} / {np})",
                    self.obs_camera[o], self.obs_point[o]
                ));
            }
        }
        let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
        if !self.cameras.iter().all(|c| finite(c))
            || !self.groups.iter().all(|g| finite(g))
            || !self.points.iter().all(|p| finite(p))
            || !self.obs_xy.iter().all(|p| finite(p))
        {
            return bad("a parameter or observation is not finite".into());
        }
        Ok(())
    }

    /// Unweighted residual (pixels, predicted − observed) of observation `o`.
    #[inline]
    pub fn residual(&self, o: usize) -> [f64; 2] {
        let c = self.obs_camera[o] as usize;
        let x = &self.points[self.obs_point[o] as usize];
        match self.model {
            CameraModel::Metric => metric_residual(
                &self.cameras[c],
                &self.groups[self.camera_group[c]],
                x,
                self.obs_xy[o],
                &self.motion(o),
            ),
            CameraModel::Projective => projective_residual(&self.cameras[c], x, self.obs_xy[o]),
        }
    }

    /// Observation `o`'s rolling-shutter motion (a still camera without velocities).
    #[inline]
    pub fn motion(&self, o: usize) -> Motion {
        match self.camera_velocity.get(self.obs_camera[o] as usize) {
            Some(&velocity) => Motion {
                velocity,
                basis: self.obs_basis[o],
            },
            None => Motion::default(),
        }
    }

    /// `1 / σ` of observation `o` (1 without [`Problem::obs_sigma`]).
    #[inline]
    pub fn obs_weight(&self, o: usize) -> f64 {
        self.obs_sigma.get(o).map_or(1.0, |s| 1.0 / s)
    }

    /// Residual of observation `o` divided by its σ (pixels when σ is 1).
    #[inline]
    pub fn weighted_residual(&self, o: usize) -> [f64; 2] {
        let r = self.residual(o);
        let w = self.obs_weight(o);
        [r[0] * w, r[1] * w]
    }

    /// The cost `½ Σ ρ(‖r/σ‖²) + ½ Σ ((x − mean)/sigma)²` over observations and priors on free
    /// intrinsics.
    pub fn cost(&self, loss: &RobustLoss) -> f64 {
        let data: f64 = (0..self.num_observations())
            .into_par_iter()
            .with_min_len(1024)
            .map(|o| {
                let r = self.weighted_residual(o);
                loss.evaluate(r[0] * r[0] + r[1] * r[1])[0]
            })
            .collect::<Vec<f64>>()
            .iter()
            .sum();
        0.5 * data + self.prior_cost()
    }

    pub(crate) fn prior_cost(&self) -> f64 {
        let mut c = 0.0;
        if self.model == CameraModel::Metric {
            for ((vals, free), pri) in self
                .groups
                .iter()
                .zip(&self.group_free)
                .zip(&self.group_priors)
            {
                for k in 0..NUM_INTRINSICS {
                    if let (true, Some(p)) = (free[k], pri[k]) {
                        let z = (vals[k] - p.mean) / p.sigma;
                        c += 0.5 * z * z;
                    }
                }
            }
        }
        c
    }

    /// Root mean square reprojection error in pixels (`sqrt(Σ‖r‖² / #obs)`), 0 without observations.
    pub fn rms_px(&self) -> f64 {
        let n = self.num_observations();
        if n == 0 {
            return 0.0;
        }
        let s: f64 = (0..n)
            .into_par_iter()
            .with_min_len(1024)
            .map(|o| {
                let r = self.residual(o);
                r[0] * r[0] + r[1] * r[1]
            })
            .collect::<Vec<f64>>()
            .iter()
            .sum();
        (s / n as f64).sqrt()
    }
}
