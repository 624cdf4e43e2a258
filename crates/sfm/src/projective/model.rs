//! The growing projective model of §3.1–3.3 (Table 2): cameras, oriented projective points and the
//! keypoint → point index, with the bookkeeping that the initial pair (`init.rs`), resection
//! (`resection.rs`), projective BA (`ba.rs`) and track completion (`tracks.rs`) share.

use std::collections::BTreeMap;

use handheld_geometry::{reprojection_distance, triangulate_iterative};
use nalgebra::{Matrix3x4, Vector2, Vector4};

use crate::context::Context;

/// "No point" in [`ProjectiveModel::kp_point`].
pub(crate) const NONE: u32 = u32::MAX;

/// One projective bundle adjustment, for the summary.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct ProjectiveBaRecord {
    pub registered: usize,
    pub points: usize,
    pub iterations: usize,
    pub initial_rms_px: f64,
    pub final_rms_px: f64,
    pub observations_removed: usize,
}

/// A projective point and its observations `(image index, keypoint index)`; `m` is unit-norm with
/// `p3·m > 0` for every observing camera (oriented projective geometry).
#[derive(Clone, Debug)]
pub(crate) struct PPoint {
    pub m: Vector4<f64>,
    pub obs: Vec<(u32, u32)>,
}

/// The growing projective model.
pub(crate) struct ProjectiveModel {
    pub cams: Vec<Option<Matrix3x4<f64>>>,
    pub kp_point: Vec<Vec<u32>>,
    pub points: Vec<Option<PPoint>>,
    /// Registration order (the initial pair first).
    pub order: Vec<usize>,
    pub init_pair: (usize, usize),
    pub ba: Vec<ProjectiveBaRecord>,
    /// Images whose resection failed, with the reason (the last attempt).
    pub failures: BTreeMap<usize, String>,
    /// Images resected on a plane and completed by the matches off it (`planar.rs`).
    pub planar_completed: Vec<usize>,
}

impl ProjectiveModel {
    pub(crate) fn new(ctx: &Context) -> Self {
        let n = ctx.input.images.len();
        Self {
            cams: vec![None; n],
            kp_point: ctx
                .input
                .images
                .iter()
                .map(|im| vec![NONE; im.keypoints.len()])
                .collect(),
            points: Vec::new(),
            order: Vec::new(),
            init_pair: (0, 0),
            ba: Vec::new(),
            failures: BTreeMap::new(),
            planar_completed: Vec::new(),
        }
    }

    pub fn num_points(&self) -> usize {
        self.points.iter().filter(|p| p.is_some()).count()
    }

    pub(crate) fn add_point(&mut self, m: Vector4<f64>, obs: Vec<(u32, u32)>) {
        let id = self.points.len() as u32;
        for &(i, k) in &obs {
            self.kp_point[i as usize][k as usize] = id;
        }
        self.points.push(Some(PPoint { m, obs }));
    }

    pub(crate) fn remove_point(&mut self, id: usize) {
        if let Some(p) = self.points[id].take() {
            for (i, k) in p.obs {
                self.kp_point[i as usize][k as usize] = NONE;
            }
        }
    }

    /// The observations of `pt` that its position does not reproject within the threshold.
    pub(crate) fn unexplained(&self, ctx: &Context, pt: &PPoint) -> Vec<(u32, u32)> {
        pt.obs
            .iter()
            .copied()
            .filter(|&(i, k)| self.obs_error(ctx, &pt.m, i, k) >= ctx.threshold(i as usize))
            .collect()
    }

    /// Reprojection error (normalised units) and orientation of one observation.
    pub(crate) fn obs_error(&self, ctx: &Context, m: &Vector4<f64>, image: u32, kp: u32) -> f64 {
        let Some(p) = &self.cams[image as usize] else {
            return f64::INFINITY;
        };
        if (p.row(2) * m)[0] <= 0.0 {
            return f64::INFINITY;
        }
        reprojection_distance(p, m, &ctx.kps[image as usize][kp as usize])
    }

    /// Re-triangulates a point from all its observations (eq. 20); keeps the new position only if every
    /// observation stays within the threshold, else drops the worst observations.
    pub(crate) fn refine_point(&mut self, ctx: &Context, pid: usize) {
        let Some(pt) = self.points[pid].clone() else {
            return;
        };
        let cams: Vec<Matrix3x4<f64>> = pt
            .obs
            .iter()
            .filter_map(|&(i, _)| self.cams[i as usize])
            .collect();
        let xs: Vec<Vector2<f64>> = pt
            .obs
            .iter()
            .map(|&(i, k)| ctx.kps[i as usize][k as usize])
            .collect();
        if cams.len() != xs.len() {
            return;
        }
        if let Ok(m) = triangulate_iterative(&cams, &xs, ctx.opts.triangulation_iterations) {
            if pt
                .obs
                .iter()
                .all(|&(i, k)| self.obs_error(ctx, &m, i, k) < ctx.threshold(i as usize))
            {
                if let Some(p) = self.points[pid].as_mut() {
                    p.m = m;
                }
                return;
            }
        }
        // Keep the old position; drop observations that it does not explain.
        let bad = self.unexplained(ctx, &pt);
        for (i, k) in bad {
            self.kp_point[i as usize][k as usize] = NONE;
            if let Some(p) = self.points[pid].as_mut() {
                p.obs.retain(|&(a, b)| (a, b) != (i, k));
            }
        }
        if self.points[pid].as_ref().is_some_and(|p| p.obs.len() < 2) {
            self.remove_point(pid);
        }
    }
}

/// The projective cameras (normalised coordinates) in registration order.
pub(crate) fn cameras_in_order(model: &ProjectiveModel) -> Vec<(usize, Matrix3x4<f64>)> {
    model
        .order
        .iter()
        .filter_map(|&i| model.cams[i].map(|p| (i, p)))
        .collect()
}
