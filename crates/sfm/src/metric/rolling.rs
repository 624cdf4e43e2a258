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
//! zero-mean prior; the velocities follow the adjusted poses for a few rounds. A global-shutter
//! video finds a read-out near zero and keeps its model.

use std::collections::BTreeMap;

use handheld_bundle::RollingShutter;
use handheld_core::{Camera, ImageId, MetricReconstruction, Rigid3, View};
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
    let mut report = RollingShutterReport::default();
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
