//! A long walk for structure-from-motion scaling tests, without rendering: one uncalibrated camera
//! carried along a closed loop (a street block walked round), looking out at the facades with its
//! aim wandering left, right, up and down, as a hand-held camera's does. The facades are a band of
//! points with depth (a metre and a half either side of the wall), so no view sees a plane.
//!
//! Neighbouring views are the same distance apart whatever their number, so a view sees about
//! `points_per_view` points and overlaps with a few dozen neighbours: the work of an incremental
//! reconstruction grows with the number of views, not with its square, as it does on a street
//! filmed from a car or a building walked for an hour. The loop closes: the last views see what
//! the first ones saw.
//!
//! [`street_set`] returns the exact cameras, poses and points with **noisy** observations (the
//! keypoints), and the verified pairs a matcher would give between views at most `pair_window`
//! apart along the loop: their common points as inlier matches, and the exact fundamental matrix.

use std::collections::BTreeMap;

use handheld_core::pose::cam_from_world_from_center;
use handheld_core::{
    Camera, CameraId, ImageId, Intrinsics, MetricReconstruction, Observation, Point3D, PointId,
    Track, TrackElement, View,
};
use nalgebra::{Matrix3, Point3, Rotation3, Vector2, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::util::gaussian;

/// Options of [`street_set`].
#[derive(Clone, Debug, PartialEq)]
pub struct StreetOptions {
    pub num_views: usize,
    /// About how many points a view sees (default 300).
    pub points_per_view: usize,
    /// Observation noise, pixels (default 0.5).
    pub noise_px: f64,
    /// Views at most this far apart along the loop are matched (default 8).
    pub pair_window: usize,
    /// Fewest common points a verified pair has (default 16).
    pub min_matches: usize,
    pub seed: u64,
}

impl Default for StreetOptions {
    fn default() -> Self {
        Self {
            num_views: 250,
            points_per_view: 300,
            noise_px: 0.5,
            pair_window: 8,
            min_matches: 16,
            seed: 0,
        }
    }
}

/// One verified pair: view indices `a < b` (in [`StreetSet::truth`]'s view order), the inlier
/// matches as keypoint indices, and `F` with `x_bᵀ F x_a = 0` in pixels.
#[derive(Clone, Debug)]
pub struct StreetPair {
    pub a: usize,
    pub b: usize,
    pub matches: Vec<(u32, u32)>,
    pub f: Matrix3<f64>,
}

/// The scene: exact cameras, poses and points; the views' observations are the noisy keypoints.
#[derive(Clone, Debug)]
pub struct StreetSet {
    pub truth: MetricReconstruction,
    pub pairs: Vec<StreetPair>,
}

const WIDTH: u32 = 640;
const HEIGHT: u32 = 480;
/// Distance between neighbouring views, metres.
const STEP: f64 = 0.3;
/// Distance from the path to the facades, metres, and the depth of the facade band either side.
const WALL: f64 = 6.0;
const RELIEF: f64 = 1.5;
/// Half the height of the facade band, metres.
const HALF_HEIGHT: f64 = 2.5;

/// Generates the walk.
pub fn street_set(opts: &StreetOptions) -> Result<StreetSet, String> {
    let n = opts.num_views;
    if n < 8 || opts.points_per_view == 0 || opts.pair_window == 0 {
        return Err("a street needs at least 8 views, some points and a pair window".into());
    }
    if !(opts.noise_px >= 0.0 && opts.noise_px.is_finite()) {
        return Err("noise_px must be non-negative".into());
    }
    let mut rng = ChaCha8Rng::seed_from_u64(opts.seed ^ 0x5354_5245);
    let radius = (n as f64 * STEP / std::f64::consts::TAU).max(4.0);
    let intrinsics = Intrinsics {
        f: 0.9 * WIDTH as f64,
        aspect: 1.0,
        skew: 0.0,
        pp: Vector2::new(WIDTH as f64 / 2.0 - 0.5, HEIGHT as f64 / 2.0 - 0.5),
        k1: 0.0,
        k2: 0.0,
    };
    let mut truth = MetricReconstruction::default();
    let camera = Camera {
        id: CameraId(0),
        width: WIDTH,
        height: HEIGHT,
        intrinsics,
    };
    truth.cameras.insert(CameraId(0), camera.clone());
    for i in 0..n {
        let th = std::f64::consts::TAU * (i as f64 + rng.random_range(-0.2..0.2)) / n as f64;
        let yaw = 25f64.to_radians() * (std::f64::consts::TAU * i as f64 / 17.0).sin()
            + rng.random_range(-3.0f64..3.0).to_radians();
        let pitch = 8f64.to_radians() * (std::f64::consts::TAU * i as f64 / 11.0).sin();
        let roll = rng.random_range(-2.0f64..2.0).to_radians();
        // Camera z outwards (turned by the yaw and the pitch), y down (world −z).
        let out = Vector3::new(th.cos(), th.sin(), 0.0);
        let z0 = Rotation3::from_axis_angle(&Vector3::z_axis(), yaw) * out;
        let side = z0.cross(&Vector3::z()).normalize();
        let z = Rotation3::from_axis_angle(&nalgebra::Unit::new_normalize(side), pitch) * z0;
        let x = Vector3::z().cross(&z).normalize();
        let y = z.cross(&x);
        let world_from_cam = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, y, z]));
        let world_from_cam = world_from_cam * Rotation3::from_axis_angle(&Vector3::z_axis(), roll);
        let centre = Point3::from(out * radius + Vector3::z() * rng.random_range(-0.1..0.1));
        let vid = ImageId(i as u32);
        truth.views.insert(
            vid,
            View {
                id: vid,
                name: format!("street_{i:05}.png"),
                camera_id: CameraId(0),
                cam_from_world: cam_from_world_from_center(&world_from_cam, &centre),
                observations: Vec::new(),
                frame: None,
            },
        );
    }
    // A view sees about 2·WALL·tan(hfov/2) metres of facade, so the band needs this many points.
    let footprint = 2.0 * WALL * (WIDTH as f64 / (2.0 * intrinsics.f)).atan().tan();
    let wall_radius = radius + WALL;
    let num_points = (opts.points_per_view as f64 * std::f64::consts::TAU * wall_radius / footprint)
        .ceil() as usize;
    // Views whose angle is within this of a point's may see it.
    let reach = ((footprint + 2.0 * RELIEF) / radius).min(std::f64::consts::PI) + 0.3;
    let by_angle = |phi: f64| -> Vec<usize> {
        let k = (phi / std::f64::consts::TAU * n as f64).round() as i64;
        let span = (reach / std::f64::consts::TAU * n as f64).ceil() as i64 + 2;
        let span = span.min(n as i64 / 2);
        (-span..=span)
            .map(|d| (k + d).rem_euclid(n as i64) as usize)
            .collect::<std::collections::BTreeSet<_>>()
            .into_iter()
            .collect()
    };
    let mut next = 0u64;
    for _ in 0..num_points {
        let phi = rng.random_range(0.0..std::f64::consts::TAU);
        let r = wall_radius + rng.random_range(-RELIEF..RELIEF);
        let xw = Point3::new(
            r * phi.cos(),
            r * phi.sin(),
            rng.random_range(-HALF_HEIGHT..HALF_HEIGHT),
        );
        let mut seen = Vec::new();
        for i in by_angle(phi) {
            let view = &truth.views[&ImageId(i as u32)];
            let pc = view.cam_from_world.transform_point(&xw);
            if pc.z < 1.0 || pc.z > 3.0 * WALL {
                continue;
            }
            let Some(px) = camera.project(&view.cam_from_world, &xw) else {
                continue;
            };
            if camera.contains(&px) {
                seen.push((i, px));
            }
        }
        if seen.len() < 2 {
            continue;
        }
        let pid = PointId(next);
        next += 1;
        let mut elements = Vec::with_capacity(seen.len());
        for (i, px) in seen {
            let id = ImageId(i as u32);
            let Some(view) = truth.views.get_mut(&id) else {
                continue;
            };
            elements.push(TrackElement {
                image_id: id,
                point2d_idx: view.observations.len() as u32,
            });
            view.observations.push(Observation {
                xy: px + Vector2::new(gaussian(&mut rng), gaussian(&mut rng)) * opts.noise_px,
                point_id: Some(pid),
            });
        }
        truth.points.insert(
            pid,
            Point3D {
                xyz: xw,
                color: [128; 3],
                error: -1.0,
                track: Track { elements },
            },
        );
    }
    let pairs = pairs(&truth, &camera, n, opts);
    Ok(StreetSet { truth, pairs })
}

/// The verified pairs between views at most `pair_window` apart along the loop.
fn pairs(
    truth: &MetricReconstruction,
    camera: &Camera,
    n: usize,
    opts: &StreetOptions,
) -> Vec<StreetPair> {
    let keys: Vec<BTreeMap<PointId, u32>> = (0..n)
        .map(|i| {
            truth.views[&ImageId(i as u32)]
                .observations
                .iter()
                .enumerate()
                .filter_map(|(k, o)| Some((o.point_id?, k as u32)))
                .collect()
        })
        .collect();
    let k = camera.intrinsics.k_matrix();
    let Some(ki) = k.try_inverse() else {
        return Vec::new();
    };
    let mut out = Vec::new();
    let mut seen = std::collections::BTreeSet::new();
    for i in 0..n {
        for d in 1..=opts.pair_window.min(n - 1) {
            let j = (i + d) % n;
            let (a, b) = (i.min(j), i.max(j));
            if !seen.insert((a, b)) {
                continue;
            }
            let matches: Vec<(u32, u32)> = keys[a]
                .iter()
                .filter_map(|(p, &ka)| keys[b].get(p).map(|&kb| (ka, kb)))
                .collect();
            if matches.len() < opts.min_matches {
                continue;
            }
            let (va, vb) = (
                &truth.views[&ImageId(a as u32)],
                &truth.views[&ImageId(b as u32)],
            );
            let rel = vb.cam_from_world * va.cam_from_world.inverse();
            let t = rel.translation.vector;
            let tx = Matrix3::new(0.0, -t.z, t.y, t.z, 0.0, -t.x, -t.y, t.x, 0.0);
            let e = tx * rel.rotation.to_rotation_matrix().matrix();
            out.push(StreetPair {
                a,
                b,
                matches,
                f: ki.transpose() * e * ki,
            });
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn views_see_about_the_points_asked_and_the_loop_closes() {
        let set = street_set(&StreetOptions {
            num_views: 120,
            ..Default::default()
        })
        .unwrap();
        let mut seen: Vec<usize> = set
            .truth
            .views
            .values()
            .map(|v| v.observations.len())
            .collect();
        seen.sort_unstable();
        let median = seen[seen.len() / 2];
        assert!(
            (150..=600).contains(&median),
            "median points per view {median}"
        );
        assert!(seen[0] >= 50, "a view sees only {} points", seen[0]);
        // The loop closes: the first and last views are matched.
        assert!(set.pairs.iter().any(|p| p.a == 0 && p.b == 119));
        // Every pair's matches satisfy its F with the exact projections (noise 0.5 px).
        for p in set.pairs.iter().take(20) {
            let (va, vb) = (
                &set.truth.views[&ImageId(p.a as u32)],
                &set.truth.views[&ImageId(p.b as u32)],
            );
            let mut d: Vec<f64> = p
                .matches
                .iter()
                .map(|&(ka, kb)| {
                    let xa = va.observations[ka as usize].xy;
                    let xb = vb.observations[kb as usize].xy;
                    crate::correspondences::epipolar_distance(&p.f, &xa, &xb)
                })
                .collect();
            d.sort_by(f64::total_cmp);
            assert!(
                d[d.len() / 2] < 1.5,
                "pair {}–{}: {}",
                p.a,
                p.b,
                d[d.len() / 2]
            );
        }
    }
}
