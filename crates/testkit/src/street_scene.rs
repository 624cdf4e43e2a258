//! A large outdoor scene with exact ground truth (issue #35): a street 160 m long between two rows
//! of façades with relief (window bays and balconies), cars parked along both kerbs, a post near the
//! start, and a building closing the street at the far end. Seen from a car driving down the middle
//! ([`PathOptions::street_drive`]) or from a walk across it ([`PathOptions::street_walk`]), the
//! depths run from about 1.5 m to 150 m, and the sky between the façades has no depth.
//!
//! World frame as in [`crate::default_scene`]: `z` up, ground at `z = 0`; the street runs along
//! `+y` from `y = 0` and its centre line is `x = 0`.

use nalgebra::{Point3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::path::{CameraPath, PathOptions};
use crate::scene::{Primitive, Scene};

/// Length of the street (m).
pub const STREET_LENGTH: f64 = 160.0;
/// Half the distance between the façades (m).
pub const STREET_HALF_WIDTH: f64 = 7.0;
/// Height of the façades (m).
pub const FACADE_HEIGHT: f64 = 14.0;
/// Where the building closing the street stands (m along the street).
pub const FAR_WALL_Y: f64 = 150.0;

impl Scene {
    /// The street for `seed` (see the module documentation); the bays, balconies and cars vary
    /// with the seed.
    pub fn street_scene(seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x57EE_7000);
        let (hw, len, fh) = (STREET_HALF_WIDTH, STREET_LENGTH, FACADE_HEIGHT);
        let mut prims = vec![
            // The road and pavements.
            Primitive::Plane {
                origin: Point3::new(-hw, -10.0, 0.0),
                edge_u: Vector3::new(2.0 * hw, 0.0, 0.0),
                edge_v: Vector3::new(0.0, len + 10.0, 0.0),
                texture: rng.random(),
            },
            // The façades, facing the street.
            Primitive::Plane {
                origin: Point3::new(-hw, -10.0, 0.0),
                edge_u: Vector3::new(0.0, len + 10.0, 0.0),
                edge_v: Vector3::new(0.0, 0.0, fh),
                texture: rng.random(),
            },
            Primitive::Plane {
                origin: Point3::new(hw, -10.0, 0.0),
                edge_u: Vector3::new(0.0, 0.0, fh),
                edge_v: Vector3::new(0.0, len + 10.0, 0.0),
                texture: rng.random(),
            },
            // The building closing the street.
            Primitive::Plane {
                origin: Point3::new(-hw, FAR_WALL_Y, 0.0),
                edge_u: Vector3::new(2.0 * hw, 0.0, 0.0),
                edge_v: Vector3::new(0.0, 0.0, 1.5 * fh),
                texture: rng.random(),
            },
        ];
        let flat = UnitQuaternion::identity();
        // Relief on both façades: bays (deep, ground to first floor) and balconies, every 6–10 m.
        for side in [-1.0, 1.0] {
            let mut y = rng.random_range(0.0..4.0);
            while y < FAR_WALL_Y - 6.0 {
                let depth = rng.random_range(0.3..0.9);
                let (half_y, z0, z1) = if rng.random_bool(0.5) {
                    (rng.random_range(1.0..2.0), 0.0, rng.random_range(3.0..6.0))
                } else {
                    let z0 = rng.random_range(3.0..9.0);
                    (
                        rng.random_range(1.5..3.0),
                        z0,
                        z0 + rng.random_range(0.8..1.4),
                    )
                };
                prims.push(Primitive::Box {
                    center: Point3::new(side * (hw - depth / 2.0), y, (z0 + z1) / 2.0),
                    half_extents: Vector3::new(depth / 2.0, half_y, (z1 - z0) / 2.0),
                    rotation: flat,
                    texture: rng.random(),
                });
                y += 2.0 * half_y + rng.random_range(3.0..7.0);
            }
        }
        // Parked cars along both kerbs.
        for side in [-1.0, 1.0] {
            let mut y = rng.random_range(6.0..12.0);
            while y < FAR_WALL_Y - 10.0 {
                let yaw = rng.random_range(-0.05..0.05);
                prims.push(Primitive::Box {
                    center: Point3::new(side * (hw - 2.8), y, 0.75),
                    half_extents: Vector3::new(0.9, 2.2, 0.75),
                    rotation: UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw),
                    texture: rng.random(),
                });
                y += rng.random_range(8.0..25.0);
            }
        }
        // A post near the start, 1.5–3 m from the cameras.
        prims.push(Primitive::Box {
            center: Point3::new(1.4, 3.0, 0.6),
            half_extents: Vector3::new(0.15, 0.15, 0.6),
            rotation: flat,
            texture: rng.random(),
        });
        // The primitives above are valid by construction.
        Self::new(prims).unwrap_or_else(|e| panic!("street scene is invalid: {e}"))
    }
}

impl PathOptions {
    /// A car driving down the middle of [`Scene::street_scene`]: `travel` metres forward from the
    /// street's start, 1.6 m high, looking down the street (the epipole near the image centre).
    pub fn street_drive(num_frames: usize, travel: f64) -> Self {
        Self {
            kind: CameraPath::Forward,
            num_frames,
            distance: FAR_WALL_Y,
            height: 1.6,
            sweep: travel,
            target: Point3::new(0.0, FAR_WALL_Y, 1.6),
            jitter_pos: 0.01,
            jitter_rot: 0.2,
            zoom: None,
            seed: 0,
        }
    }

    /// A hand-held walk across the start of [`Scene::street_scene`]: `width` metres sideways,
    /// 1.5 m high, looking down the street (panning a little), with a hand's jitter.
    pub fn street_walk(num_frames: usize, width: f64) -> Self {
        Self {
            kind: CameraPath::WalkThrough,
            num_frames,
            distance: FAR_WALL_Y,
            height: 1.5,
            sweep: width,
            target: Point3::new(0.0, FAR_WALL_Y, 1.5),
            jitter_pos: 0.02,
            jitter_rot: 0.7,
            zoom: None,
            seed: 0,
        }
    }
}
