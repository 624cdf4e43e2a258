//! The rolling-shutter camera of metric bundle adjustment (`residual.rs`'s notes): observations made
//! row by row from a moving camera are fitted with the read-out free, the velocities given.

use std::collections::BTreeMap;

use handheld_bundle::{
    bundle_adjust_metric_rolling, BundleOptions, IntrinsicsMask, MetricBundleConfig, RollingShutter,
};
use handheld_core::{pose::rotation_angle_deg, ImageId, MetricReconstruction, Rigid3};
use handheld_testkit::multiview::{multi_view_set, MultiViewOptions};
use nalgebra::{Translation3, UnitQuaternion, Vector2, Vector3};

/// The read-out along y (frame intervals across the image) the observations are made with.
const READOUT_Y: f64 = 0.6;

/// `pose` moved on by `tau` along `velocity` (`[ω, ν]` in the camera frame).
fn moved(pose: &Rigid3, velocity: &[f64; 6], tau: f64) -> Rigid3 {
    let v = velocity;
    Rigid3::from_parts(
        Translation3::from(pose.translation.vector + Vector3::new(v[3], v[4], v[5]) * tau),
        UnitQuaternion::from_scaled_axis(Vector3::new(v[0], v[1], v[2]) * tau) * pose.rotation,
    )
}

/// A 16-view scene whose observations a rolling shutter made: each row seen from the pose of its
/// read-out time, each view turning and moving at its own velocity. Returns the scene (exact
/// cameras and points) and the velocities.
fn rolling_scene() -> (MetricReconstruction, BTreeMap<ImageId, [f64; 6]>) {
    let set = multi_view_set(&MultiViewOptions {
        num_views: 16,
        num_points: 800,
        noise_px: 0.0,
        radial_distortion: true,
        shared_intrinsics: true,
        seed: 11,
        ..Default::default()
    })
    .expect("valid options");
    let mut rec = set.ground_truth();
    let velocity: BTreeMap<ImageId, [f64; 6]> = rec
        .views
        .keys()
        .enumerate()
        .map(|(i, id)| {
            let s = i as f64;
            // About 1.5° a frame interval about a tilted vertical axis, 2 % of the scene across.
            let w = Vector3::new(0.2 * (s * 0.7).sin(), 1.0, 0.1).normalize() * 0.026;
            (*id, [w.x, w.y, w.z, 0.02, 0.004 * s.cos(), 0.0])
        })
        .collect();
    let points = rec.points.clone();
    for (id, view) in rec.views.iter_mut() {
        let camera = &rec.cameras[&view.camera_id];
        let h = f64::from(camera.height);
        for obs in view.observations.iter_mut() {
            let Some(p) = obs.point_id.and_then(|p| points.get(&p)) else {
                continue;
            };
            // The row the point is seen at depends on the pose of that row: a few fixed-point steps.
            let mut xy: Vector2<f64> = obs.xy;
            for _ in 0..8 {
                let tau = READOUT_Y * (xy.y / h - 0.5);
                if let Some(px) =
                    camera.project(&moved(&view.cam_from_world, &velocity[id], tau), &p.xyz)
                {
                    xy = px;
                }
            }
            obs.xy = xy;
        }
    }
    (rec, velocity)
}

fn focal_and_rotation_error(est: &MetricReconstruction, gt: &MetricReconstruction) -> (f64, f64) {
    let f = |r: &MetricReconstruction| r.cameras.values().next().map_or(0.0, |c| c.intrinsics.f);
    // The first view is held, so the frames agree without an alignment.
    let rot = gt
        .views
        .iter()
        .map(|(id, v)| {
            rotation_angle_deg(
                &(est.views[id].cam_from_world.rotation * v.cam_from_world.rotation.inverse()),
            )
        })
        .fold(0.0, f64::max);
    ((f(est) / f(gt) - 1.0).abs(), rot)
}

#[test]
fn the_read_out_is_found_and_the_focal_length_no_longer_absorbs_it() {
    let (gt, velocity) = rolling_scene();
    let opts = BundleOptions {
        max_iterations: 100,
        num_threads: 2,
        ..Default::default()
    };
    let refine = IntrinsicsMask::focal_and_radial();
    // A global-shutter camera fitted to the same observations, from the exact start.
    let mut global = gt.clone();
    let config = MetricBundleConfig {
        refine,
        ..Default::default()
    };
    let (_, readout) = bundle_adjust_metric_rolling(&mut global, &config, &opts).expect("runs");
    assert!(readout.values().all(|r| *r == [0.0, 0.0]), "{readout:?}");
    let (f_global, rot_global) = focal_and_rotation_error(&global, &gt);
    // The rolling-shutter camera, the read-out starting at zero under a wide prior.
    let mut rolling = gt.clone();
    let config = MetricBundleConfig {
        refine,
        rolling_shutter: Some(RollingShutter {
            velocity: velocity.clone(),
            readout: BTreeMap::new(),
            // Wide: with exact observations any prior pulls the read-out measurably.
            refine_sigma: Some(100.0),
        }),
        ..Default::default()
    };
    let (s, readout) = bundle_adjust_metric_rolling(&mut rolling, &config, &opts).expect("runs");
    let (f_rolling, rot_rolling) = focal_and_rotation_error(&rolling, &gt);
    let r = readout.values().next().copied().unwrap_or_default();
    println!(
        "global shutter: focal {:.4} %, rotation {rot_global:.4}°; rolling: read-out {r:?} (true [0, {READOUT_Y}]), focal {:.5} %, rotation {rot_rolling:.5}°, RMS {:.2e} px",
        100.0 * f_global,
        100.0 * f_rolling,
        s.final_rms_px
    );
    assert!(
        r[0].abs() < 1e-3 && (r[1] - READOUT_Y).abs() < 1e-3,
        "{r:?}"
    );
    assert!(
        f_rolling < 1e-4 && rot_rolling < 0.01,
        "{f_rolling} {rot_rolling}"
    );
    // What the global-shutter camera made of the same rows is far off by comparison.
    assert!(
        f_global > 20.0 * f_rolling.max(1e-5) || rot_global > 0.1,
        "{f_global} {rot_global}"
    );
}
