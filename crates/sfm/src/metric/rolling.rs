//! A phone's rolling shutter, adjusted with the video's metric model.
//!
//! A phone's sensor reads its rows one after another, in about 0.5–0.9 of a 30 fps frame interval,
//! so a frame's rows see the scene from poses along the camera's motion. A global-shutter model
//! absorbs the resulting skew into the intrinsics: on the testkit wallpaper orbit as a phone video
//! with a read-out of 0.07 frame intervals between its frames (`handheld demo --rolling-shutter`),
//! both Handheld and COLMAP 4.2 put the focal length 1.7–1.8 % off and k1 at half its value.
//!
//! Video frames move smoothly, so each frame's velocity is known from its registered neighbours'
//! poses (the central difference over their decoded frame indices; Klingner et al., *Street View
//! Motion-from-Structure-from-Motion*, ICCV 2013, interpolate each row's pose the same way), and
//! one read-out per camera is left to find: `[ρx, ρy]`, the time across the image along each axis
//! in decoded frame intervals (a portrait phone video is read along x or y depending on how the
//! sensor sat). The observations at a row are projected from the pose moved on by that row's
//! time (`handheld_bundle::residual`'s rolling-shutter model; Hedborg et al., *Rolling shutter
//! bundle adjustment*, CVPR 2012). The final adjustment runs with the read-out free under a wide
//! zero-mean prior; the velocities follow the adjusted poses for a few rounds.
//!
//! The read-out is kept only where the images ask for it: the first round starts from the
//! global-shutter optimum (a read-out of zero), so twice the fall of its robust cost over the
//! noise variance is the likelihood-ratio statistic of the two nested models, χ² with two degrees
//! of freedom per camera where the shutter is global. The observations are not independent (a
//! point's observations share its position, a video's compression blocks their errors), so the
//! statistic is overdispersed: four global-shutter videos of the testkit wallpaper gave 3.6, 6.3,
//! 17.9 and 22.0, two of them above χ²'s 0.999 quantile (13.8), while real read-outs give 10⁴ and
//! more (0.07 frame intervals: 2.6·10⁵; kitti-seq1 as a video, −0.026 along x: 1.1·10⁴). The
//! test is therefore made at 10⁻⁶. Below it the global-shutter model is kept as it was (a
//! global-shutter video lost 0.5 AUC@1 to the extra adjustment and filter of a read-out of
//! 0.001).

use std::collections::BTreeMap;

use handheld_bundle::RollingShutter;
use handheld_core::{Camera, ImageId, MetricReconstruction, PointId, Rigid3, TrackElement, View};
use nalgebra::{Translation3, UnitQuaternion, Vector2, Vector3};
use serde::{Deserialize, Serialize};

use crate::context::Context;
use crate::metric::ba::{final_adjustment_rolling, MetricBaRecord};

/// The read-out prior's σ (decoded frame intervals): a phone reads a frame out within one.
pub const READOUT_PRIOR_SIGMA: f64 = 1.0;
/// Rounds of velocities from the adjusted poses, then the adjustment.
const ROUNDS: usize = 3;
/// The rounds stop when the read-out moves less than this (frame intervals).
const READOUT_TOLERANCE: f64 = 1e-3;

/// What the rolling-shutter adjustment found (`summary.json`, `rolling_shutter`).
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct RollingShutterReport {
    /// Each camera's read-out `[along x, along y]` across the image, in decoded frame intervals.
    pub readout: BTreeMap<String, [f64; 2]>,
    /// Frames with a velocity (a registered neighbour on either side, by frame index).
    pub frames_with_velocity: usize,
    pub rounds: usize,
    /// The likelihood-ratio statistic of the read-out against a global shutter (module notes),
    /// and the `1 − 10⁻⁶` quantile of its χ² distribution under a global shutter.
    #[serde(default)]
    pub statistic: f64,
    #[serde(default)]
    pub threshold: f64,
    /// Whether the rolling-shutter model was kept; when not, the model is the global-shutter one
    /// and `readout` what the first round found.
    #[serde(default)]
    pub kept: bool,
}

/// The `1 − 10⁻⁶` quantile of χ² with `k` degrees of freedom (Wilson and Hilferty, 1931: 30.3
/// for k = 2, where the exact one is 27.6; the approximation errs on the side of the global
/// shutter).
fn chi2_quantile(k: usize) -> f64 {
    // The standard normal's 1 − 10⁻⁶ quantile.
    const Z: f64 = 4.753_424;
    let k = k.max(1) as f64;
    let a = 2.0 / (9.0 * k);
    k * (1.0 - a + Z * a.sqrt()).powi(3)
}

/// The likelihood-ratio statistic of a first rolling-shutter round's records: twice the fall of
/// the robust cost of its first adjustment (from the global-shutter optimum) over the noise
/// variance (the measured σ̂, else the starting RMS).
fn likelihood_ratio(first: &MetricBaRecord) -> f64 {
    let sigma = first
        .noise_px
        .filter(|s| s.is_finite() && *s > 0.0)
        .unwrap_or(first.initial_rms_px);
    if !(sigma.is_finite() && sigma > 0.0) {
        return 0.0;
    }
    (2.0 * (first.initial_cost - first.final_cost) / (sigma * sigma)).max(0.0)
}

/// Adjusts a video's model with a rolling-shutter camera (module notes); `None` (the model as it
/// was) for photos, or when fewer than three frames have velocities.
pub(crate) fn rolling_shutter_step(
    ctx: &Context,
    rec: &mut MetricReconstruction,
    estimate_aspect: bool,
    records: &mut Vec<MetricBaRecord>,
) -> Option<RollingShutterReport> {
    if !ctx.input.video {
        return None;
    }
    let index: BTreeMap<ImageId, u64> = ctx
        .input
        .images
        .iter()
        .filter_map(|im| Some((im.id, im.frame.as_ref()?.index)))
        .collect();
    let mut rolling = RollingShutter {
        refine_sigma: Some(READOUT_PRIOR_SIGMA),
        ..Default::default()
    };
    let before = rec.clone();
    let records_before = records.len();
    let mut report = RollingShutterReport {
        threshold: chi2_quantile(2 * rec.cameras.len()),
        ..Default::default()
    };
    for round in 0..ROUNDS {
        rolling.velocity = velocities(rec, &index);
        if rolling.velocity.len() < 3 {
            return None;
        }
        let start = rolling.readout.clone();
        match final_adjustment_rolling(ctx, rec, estimate_aspect, &mut rolling) {
            Ok(r) => records.extend(r),
            Err(e) => {
                tracing::warn!(
                    "the rolling-shutter adjustment failed ({e}); the global-shutter model is kept"
                );
                *rec = before;
                return None;
            }
        }
        report.frames_with_velocity = rolling.velocity.len();
        report.rounds = round + 1;
        if round == 0 {
            report.statistic = records.get(records_before).map_or(0.0, likelihood_ratio);
            if report.statistic < report.threshold {
                break;
            }
        }
        let moved = rolling
            .readout
            .iter()
            .map(|(id, r)| {
                let s = start.get(id).copied().unwrap_or([0.0; 2]);
                (r[0] - s[0]).abs().max((r[1] - s[1]).abs())
            })
            .fold(0.0, f64::max);
        if moved < READOUT_TOLERANCE {
            break;
        }
    }
    report.readout = rolling
        .readout
        .iter()
        .map(|(id, r)| (id.to_string(), *r))
        .collect();
    report.kept = report.statistic >= report.threshold;
    if !report.kept {
        tracing::info!(
            "no rolling shutter: the read-out explains the images no better than a global shutter \
             (likelihood ratio {:.1} < {:.1}); the global-shutter model is kept",
            report.statistic,
            report.threshold
        );
        *rec = before;
        records.truncate(records_before);
        return Some(report);
    }
    for (camera, r) in &report.readout {
        tracing::info!(
            "rolling shutter of camera {camera}: read-out {:.3} (along x), {:.3} (along y) frame intervals across the image",
            r[0],
            r[1]
        );
    }
    Some(report)
}

/// Each registered frame's velocity `[ω, ν]` per decoded frame interval in its camera frame
/// (`handheld_bundle::RollingShutter::velocity`): the mean of the steps to its registered
/// neighbours by frame index, each divided by the frames between; one side at the ends.
fn velocities(
    rec: &MetricReconstruction,
    index: &BTreeMap<ImageId, u64>,
) -> BTreeMap<ImageId, [f64; 6]> {
    let mut frames: Vec<(u64, ImageId, Rigid3)> = rec
        .views
        .iter()
        .filter_map(|(id, v)| Some((*index.get(id)?, *id, v.cam_from_world)))
        .collect();
    frames.sort_by_key(|f| f.0);
    let step = |a: &(u64, ImageId, Rigid3), b: &(u64, ImageId, Rigid3)| {
        let dt = b.0.saturating_sub(a.0).max(1) as f64;
        let w = (b.2.rotation * a.2.rotation.inverse()).scaled_axis() / dt;
        let v = (b.2.translation.vector - a.2.translation.vector) / dt;
        [w.x, w.y, w.z, v.x, v.y, v.z]
    };
    let mut out = BTreeMap::new();
    for (k, f) in frames.iter().enumerate() {
        let back = k.checked_sub(1).map(|p| step(&frames[p], f));
        let ahead = frames.get(k + 1).map(|n| step(f, n));
        let v = match (back, ahead) {
            (Some(b), Some(a)) => std::array::from_fn(|i| 0.5 * (b[i] + a[i])),
            (Some(s), None) | (None, Some(s)) => s,
            (None, None) => continue,
        };
        out.insert(f.1, v);
    }
    out
}

/// The pose from which `view` saw pixel `xy` under `rolling`: moved on along the frame's velocity
/// by the row's read-out time (`handheld_bundle::residual`'s model; the rotation by its exponential,
/// which the adjustment's first-order model agrees with to `(τ ω)²`). The view's own pose where it
/// has no velocity.
pub(crate) fn row_pose(
    rolling: &RollingShutter,
    view: &View,
    camera: &Camera,
    xy: Vector2<f64>,
) -> Rigid3 {
    let (Some(v), Some(r)) = (
        rolling.velocity.get(&view.id),
        rolling.readout.get(&camera.id),
    ) else {
        return view.cam_from_world;
    };
    let tau = r[0] * (xy.x / f64::from(camera.width.max(1)) - 0.5)
        + r[1] * (xy.y / f64::from(camera.height.max(1)) - 0.5);
    let pose = &view.cam_from_world;
    let turn = UnitQuaternion::from_scaled_axis(Vector3::new(v[0], v[1], v[2]) * tau);
    Rigid3::from_parts(
        Translation3::from(pose.translation.vector + Vector3::new(v[3], v[4], v[5]) * tau),
        turn * pose.rotation,
    )
}

/// Every track element's point and reprojection error (pixels; `None` behind its view or where
/// the view, its camera or the keypoint is missing), each observation projected from its row's
/// pose under `rolling` when one is given (`MetricReconstruction::residuals` without).
pub(crate) fn residuals<'a>(
    rec: &'a MetricReconstruction,
    rolling: Option<&'a RollingShutter>,
) -> impl Iterator<Item = (PointId, &'a TrackElement, Option<f64>)> + 'a {
    rec.points.iter().flat_map(move |(pid, p)| {
        p.track.elements.iter().map(move |el| {
            let error = (|| {
                let view = rec.views.get(&el.image_id)?;
                let camera = rec.cameras.get(&view.camera_id)?;
                let xy = view.observations.get(el.point2d_idx as usize)?.xy;
                let pose = match rolling {
                    Some(r) => row_pose(r, view, camera, xy),
                    None => view.cam_from_world,
                };
                Some((camera.project(&pose, &p.xyz)? - xy).norm())
            })();
            (*pid, el, error)
        })
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use handheld_bundle::residual::{metric_residual, Motion};
    use handheld_core::pose::cam_from_world_from_center;
    use handheld_core::{CameraId, Intrinsics};
    use nalgebra::{Point3, Rotation3};

    fn view(id: u32, angle: f64, x: f64) -> View {
        View {
            id: ImageId(id),
            name: format!("frame_{id:04}.png"),
            camera_id: CameraId(1),
            cam_from_world: cam_from_world_from_center(
                &Rotation3::from_axis_angle(&Vector3::y_axis(), angle),
                &Point3::new(x, 0.1 * x * x, -4.0),
            ),
            observations: Vec::new(),
            frame: None,
        }
    }

    #[test]
    fn the_quantile_is_chi_squares() {
        // χ²'s 1 − 10⁻⁶ quantiles for 2, 4 and 10 degrees of freedom: 27.63, 33.38, 46.86.
        for (k, exact) in [(2, 27.63), (4, 33.38), (10, 46.86)] {
            let q = chi2_quantile(k);
            assert!(q >= exact && q < 1.1 * exact, "{k}: {q}");
        }
    }

    #[test]
    fn a_frames_velocity_is_its_neighbours_central_difference_over_their_frame_indices() {
        let mut rec = MetricReconstruction::default();
        // Frames 0, 2 and 3 of a video turning 0.01 rad a frame: frame 2's neighbours are 2 and 1
        // frames away.
        for (id, frame) in [(0u32, 0u64), (1, 2), (2, 3)] {
            rec.views
                .insert(ImageId(id), view(id, 0.01 * frame as f64, 0.0));
        }
        let index = BTreeMap::from([(ImageId(0), 0), (ImageId(1), 2), (ImageId(2), 3)]);
        let v = velocities(&rec, &index);
        for id in 0..3 {
            let w = Vector3::from_row_slice(&v[&ImageId(id)][..3]);
            // The rotation about y of cam_from_world is the inverse of the camera's turn.
            assert!(
                (w - Vector3::new(0.0, -0.01, 0.0)).norm() < 1e-12,
                "{id}: {w}"
            );
        }
    }

    #[test]
    fn a_rows_pose_projects_as_the_adjustments_rolling_shutter_camera_does() {
        let camera = Camera {
            id: CameraId(1),
            width: 640,
            height: 480,
            intrinsics: Intrinsics {
                f: 500.0,
                aspect: 1.0,
                skew: 0.0,
                pp: Vector2::new(319.5, 239.5),
                k1: -0.05,
                k2: 0.0,
            },
        };
        let v = view(1, 0.2, 0.3);
        let velocity = [0.01, -0.03, 0.005, 0.02, 0.0, -0.01];
        let rolling = RollingShutter {
            velocity: BTreeMap::from([(v.id, velocity)]),
            readout: BTreeMap::from([(camera.id, [0.1, 0.6])]),
            refine_sigma: None,
        };
        let x = Point3::new(0.4, -0.3, 1.0);
        let k = &camera.intrinsics;
        let intr = [k.f, k.aspect, k.skew, k.pp.x, k.pp.y, k.k1, k.k2, 0.1, 0.6];
        let block = handheld_bundle::metric::pose_to_block(&v.cam_from_world);
        for xy in [Vector2::new(20.0, 30.0), Vector2::new(600.0, 450.0)] {
            let px = camera
                .project(&row_pose(&rolling, &v, &camera, xy), &x)
                .unwrap();
            let motion = Motion {
                velocity,
                basis: [xy.x / 640.0 - 0.5, xy.y / 480.0 - 0.5],
            };
            let r = metric_residual(&block, &intr, &[x.x, x.y, x.z, 1.0], [xy.x, xy.y], &motion);
            // The adjustment's rotation is first-order in τω: they agree to (τω)² f.
            let d = (Vector2::new(r[0], r[1]) - (px - xy)).norm();
            assert!(d < 0.01, "{xy}: {d} px");
        }
    }
}
