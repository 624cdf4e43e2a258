//! Projective bundle adjustment (§3.3, eq. 21) of the growing model, followed by the removal of
//! observations that no longer reproject within the threshold.

use std::collections::BTreeMap;

use handheld_bundle::{
    bundle_adjust_projective, BundleOptions, ProjectiveBundleConfig, RobustLoss,
};
use handheld_core::{
    ImageId, PointId, ProjectiveCamera, ProjectivePoint, ProjectiveReconstruction, Track,
    TrackElement,
};
use nalgebra::Vector2;

use crate::context::Context;
use crate::projective::model::{ProjectiveBaRecord, ProjectiveModel, NONE};

impl ProjectiveModel {
    /// Removes observations outside the threshold (or behind a camera) and points left with < 2 views.
    pub(crate) fn filter(&mut self, ctx: &Context) -> usize {
        let mut removed = 0;
        for pid in 0..self.points.len() {
            let Some(pt) = self.points[pid].clone() else {
                continue;
            };
            let bad = self.unexplained(ctx, &pt);
            if bad.is_empty() {
                continue;
            }
            removed += bad.len();
            if pt.obs.len() - bad.len() < 2 {
                self.remove_point(pid);
                continue;
            }
            for (i, k) in bad {
                self.kp_point[i as usize][k as usize] = NONE;
            }
            if let Some(p) = self.points[pid].as_mut() {
                p.obs
                    .retain(|&(i, k)| self.kp_point[i as usize][k as usize] == pid as u32);
            }
        }
        removed
    }

    /// Projective bundle adjustment (eq. 21) of everything registered, then [`Self::filter`].
    pub fn bundle(&mut self, ctx: &Context, max_iterations: usize) -> Result<(), String> {
        let mut rec = ProjectiveReconstruction::default();
        for &i in &self.order {
            if let Some(p) = self.cams[i] {
                rec.cameras
                    .insert(ImageId(i as u32), ProjectiveCamera { P: p });
            }
        }
        for (pid, pt) in self.points.iter().enumerate() {
            if let Some(pt) = pt {
                let track = Track {
                    elements: pt
                        .obs
                        .iter()
                        .map(|&(i, k)| TrackElement {
                            image_id: ImageId(i),
                            point2d_idx: k,
                        })
                        .collect(),
                };
                rec.points
                    .insert(PointId(pid as u64), (ProjectivePoint { X: pt.m }, track));
            }
        }
        let keypoints: BTreeMap<ImageId, Vec<Vector2<f64>>> = self
            .order
            .iter()
            .map(|&i| (ImageId(i as u32), ctx.kps[i].clone()))
            .collect();
        let config = ProjectiveBundleConfig {
            fix_first_camera: false,
            constant_cameras: [ImageId(self.init_pair.0 as u32)].into_iter().collect(),
        };
        let bopts = BundleOptions {
            max_iterations,
            loss: RobustLoss::Huber(ctx.opts.loss_scale_px * ctx.median_scale()),
            // The projective frame drifts slowly along its near-gauge directions, at a cost change
            // of ~1e-5 per iteration that does not improve the cameras; the metric BA has the last
            // word on accuracy anyway.
            function_tolerance: 1e-4,
            ..Default::default()
        };
        let summary = bundle_adjust_projective(&mut rec, &keypoints, &config, &bopts)
            .map_err(|e| e.to_string())?;
        for (id, cam) in &rec.cameras {
            self.cams[id.0 as usize] = Some(cam.P);
        }
        for (pid, (x, _)) in &rec.points {
            if let Some(p) = self.points[pid.0 as usize].as_mut() {
                p.m = x.X;
            }
        }
        let removed = self.filter(ctx);
        let to_px = 1.0 / ctx.median_scale();
        self.ba.push(ProjectiveBaRecord {
            registered: self.order.len(),
            points: self.num_points(),
            iterations: summary.iterations,
            initial_rms_px: summary.initial_rms_px * to_px,
            final_rms_px: summary.final_rms_px * to_px,
            observations_removed: removed,
        });
        Ok(())
    }
}
