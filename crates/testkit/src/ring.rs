//! A large, sparse bundle-adjustment scene for scaling tests: cameras on a circle looking outwards
//! (a walk around the inside of a courtyard), each with its own focal length and radial distortion
//! as in BAL problems, and points a few metres in front of them seen by 2–8 neighbouring cameras.
//! Unlike [`crate::multi_view_set`], where every point is seen by almost every view, the number of
//! observations grows linearly, so 1000 cameras and 200 000 points stay about a million observations.

use handheld_core::pose::cam_from_world_from_center;
use handheld_core::{
    Camera, CameraId, ImageId, Intrinsics, MetricReconstruction, Observation, Point3D, PointId,
    Track, TrackElement, View,
};
use nalgebra::{Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector2, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::util::gaussian;

/// Options of [`ring_set`].
#[derive(Clone, Debug, PartialEq)]
pub struct RingOptions {
    pub num_views: usize,
    pub num_points: usize,
    /// Observation noise, pixels (default 0.5).
    pub noise_px: f64,
    /// Rotation perturbation of the initial poses, radians (default 0.002).
    pub pose_noise_rad: f64,
    /// Translation and point perturbation of the initial state, scene units (default 0.05).
    pub position_noise: f64,
    /// Relative perturbation of the initial focal lengths (default 0.01).
    pub focal_noise: f64,
    pub seed: u64,
}

impl Default for RingOptions {
    fn default() -> Self {
        Self {
            num_views: 100,
            num_points: 10_000,
            noise_px: 0.5,
            pose_noise_rad: 0.002,
            position_noise: 0.05,
            focal_noise: 0.01,
            seed: 0,
        }
    }
}

/// The exact scene and a perturbed starting point for bundle adjustment (same tracks and
/// observations; the observations carry the noise).
#[derive(Clone, Debug)]
pub struct RingSet {
    pub truth: MetricReconstruction,
    pub initial: MetricReconstruction,
}

const WIDTH: u32 = 640;
const HEIGHT: u32 = 480;

/// Generates the scene.
pub fn ring_set(opts: &RingOptions) -> Result<RingSet, String> {
    if opts.num_views < 3 || opts.num_points == 0 {
        return Err("a ring needs at least 3 views and 1 point".into());
    }
    let mut rng = ChaCha8Rng::seed_from_u64(opts.seed ^ 0x5249_4E47);
    let nc = opts.num_views;
    // Neighbouring cameras 0.63 units apart whatever their number (radius 100 for 1000 views).
    let radius = nc as f64 / std::f64::consts::TAU * 0.628;
    let mut truth = MetricReconstruction::default();
    for i in 0..nc {
        let th = std::f64::consts::TAU * i as f64 / nc as f64;
        // Camera z radial outwards, y down (world −z), x = y × z; rows of R are the camera axes.
        let z = Vector3::new(th.cos(), th.sin(), 0.0);
        let y = Vector3::new(0.0, 0.0, -1.0);
        let r_cam_from_world =
            Matrix3::from_rows(&[y.cross(&z).transpose(), y.transpose(), z.transpose()]);
        let rot = Rotation3::from_matrix_unchecked(r_cam_from_world);
        let pose = cam_from_world_from_center(&rot.inverse(), &Point3::from(z * radius));
        let intrinsics = Intrinsics {
            f: 500.0 * (1.0 + 0.05 * gaussian(&mut rng)),
            aspect: 1.0,
            skew: 0.0,
            pp: Vector2::new(WIDTH as f64 / 2.0 - 0.5, HEIGHT as f64 / 2.0 - 0.5),
            k1: -0.05,
            k2: 0.01,
        };
        let id = CameraId(i as u32);
        truth.cameras.insert(
            id,
            Camera {
                id,
                width: WIDTH,
                height: HEIGHT,
                intrinsics,
            },
        );
        let vid = ImageId(i as u32);
        truth.views.insert(
            vid,
            View {
                id: vid,
                name: format!("ring_{i:05}.png"),
                camera_id: id,
                cam_from_world: pose,
                observations: Vec::new(),
                frame: None,
            },
        );
    }
    let mut next = 0u64;
    for _ in 0..opts.num_points {
        let c0 = rng.random_range(0..nc);
        let v0 = &truth.views[&ImageId(c0 as u32)];
        let depth = rng.random_range(8.0..12.0);
        let p_cam = Point3::new(
            rng.random_range(-0.4..0.4) * depth,
            rng.random_range(-0.3..0.3) * depth,
            depth,
        );
        let xw = v0.cam_from_world.inverse_transform_point(&p_cam);
        let len = rng.random_range(3..9usize);
        let mut obs = Vec::new();
        for k in 0..len {
            let c = (c0 + nc + k - len / 2) % nc;
            let view = &truth.views[&ImageId(c as u32)];
            let cam = &truth.cameras[&view.camera_id];
            let Some(px) = cam.project(&view.cam_from_world, &xw) else {
                continue;
            };
            if view.cam_from_world.transform_point(&xw).z < 1.0 || !cam.contains(&px) {
                continue;
            }
            obs.push((
                c,
                px + Vector2::new(gaussian(&mut rng), gaussian(&mut rng)) * opts.noise_px,
            ));
        }
        if obs.len() < 2 {
            continue;
        }
        let pid = PointId(next);
        next += 1;
        let mut track = Track::default();
        for (c, px) in obs {
            let view = truth
                .views
                .get_mut(&ImageId(c as u32))
                .ok_or("view vanished")?;
            track.elements.push(TrackElement {
                image_id: view.id,
                point2d_idx: view.observations.len() as u32,
            });
            view.observations.push(Observation {
                xy: px,
                point_id: Some(pid),
            });
        }
        truth.points.insert(
            pid,
            Point3D {
                xyz: xw,
                color: [128, 128, 128],
                error: -1.0,
                track,
            },
        );
    }
    let mut initial = truth.clone();
    for view in initial.views.values_mut() {
        let d = Vector3::new(gaussian(&mut rng), gaussian(&mut rng), gaussian(&mut rng))
            * opts.pose_noise_rad;
        let rot = UnitQuaternion::from_scaled_axis(d) * view.cam_from_world.rotation;
        let t = view.cam_from_world.translation.vector
            + Vector3::new(gaussian(&mut rng), gaussian(&mut rng), gaussian(&mut rng))
                * opts.position_noise;
        view.cam_from_world = nalgebra::Isometry3::from_parts(Translation3::from(t), rot);
    }
    for cam in initial.cameras.values_mut() {
        cam.intrinsics.f *= 1.0 + opts.focal_noise * gaussian(&mut rng);
        cam.intrinsics.k1 = 0.0;
        cam.intrinsics.k2 = 0.0;
    }
    for p in initial.points.values_mut() {
        p.xyz += Vector3::new(gaussian(&mut rng), gaussian(&mut rng), gaussian(&mut rng))
            * opts.position_noise;
    }
    Ok(RingSet { truth, initial })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn observations_grow_linearly_and_truth_is_exact_up_to_noise() {
        let set = ring_set(&RingOptions {
            num_views: 50,
            num_points: 2000,
            noise_px: 0.0,
            ..Default::default()
        })
        .unwrap();
        set.truth.validate().unwrap();
        let n_obs: usize = set.truth.views.values().map(|v| v.observations.len()).sum();
        assert!(set.truth.points.len() > 1500, "{}", set.truth.points.len());
        assert!(n_obs < 9 * set.truth.points.len());
        assert!(set.truth.mean_reprojection_error() < 1e-9);
        assert!(set.initial.mean_reprojection_error() > 1.0);
    }
}
