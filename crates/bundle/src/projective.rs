//! Projective bundle adjustment (§3.3, eq. 19): cameras `P` and homogeneous points `X` on unit spheres,
//! the first camera held constant; the remaining four gauge freedoms (the plane at infinity) are left
//! to the Levenberg–Marquardt damping.

use std::collections::{BTreeMap, BTreeSet};

use handheld_core::{ImageId, ProjectiveReconstruction};
use nalgebra::{Matrix3x4, Vector2, Vector4};

use crate::options::{BundleError, BundleOptions, BundleSummary};
use crate::problem::{CameraModel, Problem};

/// What projective bundle adjustment may change.
#[derive(Clone, Debug, PartialEq)]
pub struct ProjectiveBundleConfig {
    /// Hold the first camera (smallest id) constant. Default true.
    pub fix_first_camera: bool,
    /// Further cameras held constant. Default none.
    pub constant_cameras: BTreeSet<ImageId>,
}

impl Default for ProjectiveBundleConfig {
    fn default() -> Self {
        Self {
            fix_first_camera: true,
            constant_cameras: BTreeSet::new(),
        }
    }
}

/// Projective bundle adjustment in place. `keypoints[image][k]` is the pixel position of keypoint `k`,
/// referred to by the tracks' `point2d_idx`. Cameras and points come back with unit norm.
pub fn bundle_adjust_projective(
    rec: &mut ProjectiveReconstruction,
    keypoints: &BTreeMap<ImageId, Vec<Vector2<f64>>>,
    config: &ProjectiveBundleConfig,
    options: &BundleOptions,
) -> Result<BundleSummary, BundleError> {
    let mut p = Problem::new(CameraModel::Projective);
    let views: Vec<ImageId> = rec.cameras.keys().copied().collect();
    let view_of: BTreeMap<ImageId, usize> =
        views.iter().enumerate().map(|(i, v)| (*v, i)).collect();
    for (i, (id, cam)) in rec.cameras.iter().enumerate() {
        let n = cam.P.norm();
        if !(n > 0.0 && n.is_finite()) {
            return Err(BundleError::InvalidInput(format!(
                "camera {id} has a zero or non-finite matrix"
            )));
        }
        let mut b = [0.0; 12];
        for r in 0..3 {
            for c in 0..4 {
                b[4 * r + c] = cam.P[(r, c)] / n;
            }
        }
        p.cameras.push(b);
        p.camera_constant
            .push((config.fix_first_camera && i == 0) || config.constant_cameras.contains(id));
    }
    let mut point_ids = Vec::new();
    for (pid, (x, track)) in &rec.points {
        let n = x.X.norm();
        if track.is_empty() || !(n > 0.0 && n.is_finite()) {
            continue;
        }
        let idx = point_ids.len() as u32;
        for el in &track.elements {
            let vi = *view_of.get(&el.image_id).ok_or_else(|| {
                BundleError::InvalidInput(format!(
                    "point {pid} is seen by unregistered view {}",
                    el.image_id
                ))
            })?;
            let xy = keypoints
                .get(&el.image_id)
                .and_then(|k| k.get(el.point2d_idx as usize))
                .ok_or_else(|| {
                    BundleError::InvalidInput(format!(
                        "point {pid}: view {} has no keypoint {}",
                        el.image_id, el.point2d_idx
                    ))
                })?;
            p.obs_camera.push(vi as u32);
            p.obs_point.push(idx);
            p.obs_xy.push([xy.x, xy.y]);
        }
        p.points
            .push([x.X[0] / n, x.X[1] / n, x.X[2] / n, x.X[3] / n]);
        point_ids.push(*pid);
    }
    let summary = crate::solve(&mut p, options)?;
    for (i, id) in views.iter().enumerate() {
        if let Some(cam) = rec.cameras.get_mut(id) {
            cam.P = Matrix3x4::from_row_slice(&p.cameras[i]);
        }
    }
    for (i, id) in point_ids.iter().enumerate() {
        if let Some((x, _)) = rec.points.get_mut(id) {
            x.X = Vector4::from_column_slice(&p.points[i]);
        }
    }
    Ok(summary)
}
