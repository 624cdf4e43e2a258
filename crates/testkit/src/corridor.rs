//! An indoor walk with exact ground truth (issue #37's corridor): a U-shaped corridor 2 m wide and
//! 2.6 m high, with plain painted walls and ceiling, a tiled floor, a few doors, posters and
//! cabinets, walked by a hand-held camera that turns quickly at both corners
//! ([`PathOptions::corridor_walk`]). Most frames see planes only (a floor and walls: GRIC prefers a
//! homography), with little texture, and the turns rotate the view by about 7° a frame.
//!
//! World frame as in [`crate::default_scene`]: `z` up, floor at `z = 0`. The walk goes up the first
//! leg along `+y` at `x = 0`, turns left along `y = 5.6`, turns left again down `x = −5`, and stops
//! 2 m before the end wall.

use nalgebra::{Point3, UnitQuaternion, Vector2, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::path::{CameraPath, PathOptions};
use crate::scene::{Finish, Primitive, Scene};

/// Height of the ceiling (m).
pub const CEILING: f64 = 2.6;
/// Radius of the walk's turns at the corners (m).
const TURN_RADIUS: f64 = 0.6;
/// The walk's straight legs: (start, unit direction, length).
const LEG1: ([f64; 2], [f64; 2], f64) = ([0.0, 0.0], [0.0, 1.0], 5.0);
const LEG2: ([f64; 2], [f64; 2], f64) = ([-0.6, 5.6], [-1.0, 0.0], 3.8);
const LEG3: ([f64; 2], [f64; 2], f64) = ([-5.0, 5.0], [0.0, -1.0], 4.0);

impl Scene {
    /// The corridor for `seed` (see the module documentation); the doors, posters and cabinets
    /// move with the seed.
    pub fn corridor_scene(seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0xC0_2217_0000);
        let h = CEILING;
        let plane = |o: [f64; 3], u: [f64; 3], v: [f64; 3], t: u64| Primitive::Plane {
            origin: Point3::from(o),
            edge_u: Vector3::from(u),
            edge_v: Vector3::from(v),
            texture: t,
        };
        // Outer walls, the end wall behind both ends, the inner block between legs 1 and 3.
        let mut prims = vec![
            plane(
                [-6.0, -1.0, 0.0],
                [7.0, 0.0, 0.0],
                [0.0, 7.6, 0.0],
                rng.random(),
            ),
            plane(
                [-6.0, -1.0, h],
                [0.0, 7.6, 0.0],
                [7.0, 0.0, 0.0],
                rng.random(),
            ),
            plane(
                [1.0, -1.0, 0.0],
                [0.0, 7.6, 0.0],
                [0.0, 0.0, h],
                rng.random(),
            ),
            plane(
                [1.0, 6.6, 0.0],
                [-7.0, 0.0, 0.0],
                [0.0, 0.0, h],
                rng.random(),
            ),
            plane(
                [-6.0, 6.6, 0.0],
                [0.0, -7.6, 0.0],
                [0.0, 0.0, h],
                rng.random(),
            ),
            plane(
                [-6.0, -1.0, 0.0],
                [7.0, 0.0, 0.0],
                [0.0, 0.0, h],
                rng.random(),
            ),
            Primitive::Box {
                center: Point3::new(-2.5, 1.8, h / 2.0),
                half_extents: Vector3::new(1.5, 2.8, h / 2.0),
                rotation: UnitQuaternion::identity(),
                texture: rng.random(),
            },
        ];
        let floor = 0;
        let plain = prims.len();
        // Doors (medium contrast) and posters (rich texture), 1 cm proud of the walls: on the
        // outer wall of each leg and on the inner block, at seeded places.
        let mut textured = Vec::new();
        // (a point of the wall at floor level, along the wall, into the corridor, length)
        type Wall = (Point3<f64>, Vector3<f64>, Vector3<f64>, f64);
        let walls: [Wall; 6] = [
            (
                Point3::new(1.0, -0.5, 0.0),
                Vector3::y(),
                -Vector3::x(),
                6.5,
            ),
            (
                Point3::new(0.5, 6.6, 0.0),
                -Vector3::x(),
                -Vector3::y(),
                6.0,
            ),
            (
                Point3::new(-6.0, 6.1, 0.0),
                -Vector3::y(),
                Vector3::x(),
                6.5,
            ),
            (
                Point3::new(-1.0, 4.0, 0.0),
                -Vector3::y(),
                -Vector3::x(),
                4.5,
            ),
            // The end wall, where leg 1 starts and leg 3 ends.
            (
                Point3::new(-1.0, -1.0, 0.0),
                Vector3::x(),
                Vector3::y(),
                2.0,
            ),
            (
                Point3::new(-6.0, -1.0, 0.0),
                Vector3::x(),
                Vector3::y(),
                2.0,
            ),
        ];
        for (at, along, into, len) in walls {
            let mut s: f64 = rng.random_range(0.3..1.5);
            s = s.min(len - 1.6);
            while s < len - 1.0 {
                let door = rng.random_bool(0.4);
                let (w, z0, z1) = if door {
                    (0.9, 0.0, 2.05)
                } else {
                    (
                        rng.random_range(0.4..0.8),
                        1.1,
                        1.1 + rng.random_range(0.5..0.9),
                    )
                };
                let o = at + along * s + into * 0.01 + Vector3::z() * z0;
                prims.push(Primitive::Plane {
                    origin: o,
                    edge_u: along * w,
                    edge_v: Vector3::z() * (z1 - z0),
                    texture: rng.random(),
                });
                if door {
                    textured.push((prims.len() - 1, Finish::Plain { contrast: 0.35 }));
                }
                s += w + rng.random_range(1.2..3.0);
            }
        }
        // Two cabinets against the outer walls.
        for (c, half) in [
            (Point3::new(0.75, 2.5, 0.45), Vector3::new(0.25, 0.5, 0.45)),
            (Point3::new(-3.0, 6.35, 0.5), Vector3::new(0.6, 0.25, 0.5)),
        ] {
            prims.push(Primitive::Box {
                center: c + Vector3::new(rng.random_range(-0.02..0.02), 0.0, 0.0),
                half_extents: half,
                rotation: UnitQuaternion::identity(),
                texture: rng.random(),
            });
        }
        // The primitives above are valid by construction.
        let mut scene =
            Self::new(prims).unwrap_or_else(|e| panic!("corridor scene is invalid: {e}"));
        scene = scene.with_finish(floor, Finish::Tiles { size: 0.3 });
        for k in 1..plain {
            scene = scene.with_finish(k, Finish::Plain { contrast: 0.08 });
        }
        for (k, f) in textured {
            scene = scene.with_finish(k, f);
        }
        scene
    }
}

/// The walk's point and heading at arc length `d` metres from its start (clamped to the walk).
pub(crate) fn corridor_walk_at(d: f64) -> (Vector2<f64>, Vector2<f64>) {
    let quarter = std::f64::consts::FRAC_PI_2 * TURN_RADIUS;
    let leg = |(o, u, len): ([f64; 2], [f64; 2], f64), t: f64| {
        let u = Vector2::from(u);
        (Vector2::from(o) + u * t.clamp(0.0, len), u)
    };
    // A left turn of 90° round `centre`, starting at angle `a0`.
    let turn = |centre: [f64; 2], a0: f64, t: f64| {
        let a = a0 + t / TURN_RADIUS;
        let c = Vector2::from(centre);
        (
            c + TURN_RADIUS * Vector2::new(a.cos(), a.sin()),
            Vector2::new(-a.sin(), a.cos()),
        )
    };
    let mut d = d.max(0.0);
    if d <= LEG1.2 {
        return leg(LEG1, d);
    }
    d -= LEG1.2;
    if d <= quarter {
        return turn([-0.6, 5.0], 0.0, d);
    }
    d -= quarter;
    if d <= LEG2.2 {
        return leg(LEG2, d);
    }
    d -= LEG2.2;
    if d <= quarter {
        return turn([-4.4, 5.0], std::f64::consts::FRAC_PI_2, d);
    }
    leg(LEG3, d - quarter)
}

/// The length of the corridor walk (m).
pub fn corridor_walk_length() -> f64 {
    LEG1.2 + LEG2.2 + LEG3.2 + std::f64::consts::PI * TURN_RADIUS
}

impl PathOptions {
    /// A hand-held walk through [`Scene::corridor_scene`]: the whole U (about 14.7 m, two quick
    /// left turns) at 1.6 m, looking ahead and a little down at the floor, with a hand's jitter.
    pub fn corridor_walk(num_frames: usize) -> Self {
        Self {
            kind: CameraPath::Corridor,
            num_frames,
            distance: 1.0,
            height: 1.6,
            sweep: corridor_walk_length(),
            target: Point3::new(0.0, 0.0, 1.6),
            jitter_pos: 0.01,
            jitter_rot: 0.7,
            zoom: None,
            seed: 0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use handheld_core::pose::center_of;

    #[test]
    fn the_walk_is_continuous_and_stays_in_the_corridor() {
        let n = 400;
        let len = corridor_walk_length();
        let mut last = corridor_walk_at(0.0).0;
        for i in 1..=n {
            let (p, u) = corridor_walk_at(len * i as f64 / n as f64);
            let step = (p - last).norm();
            assert!((step - len / n as f64).abs() < 1e-4, "{i}: {step}");
            assert!((u.norm() - 1.0).abs() < 1e-12);
            // Inside one of the three legs, at least 0.4 m from every wall.
            let leg1 = p.x.abs() <= 0.6 && (-0.6..=6.2).contains(&p.y);
            let leg2 = (5.0..=6.2).contains(&p.y) && (-5.6..=0.6).contains(&p.x);
            let leg3 = (p.x + 5.0).abs() <= 0.6 && (-0.6..=6.2).contains(&p.y);
            assert!(leg1 || leg2 || leg3, "{i}: {p:?}");
            last = p;
        }
        assert!((last - Vector2::new(-5.0, 1.0)).norm() < 1e-9, "{last:?}");
        let scene = Scene::corridor_scene(1);
        let traj = PathOptions::corridor_walk(60).generate().expect("valid");
        for pose in &traj.cam_from_world {
            let c = center_of(pose);
            // Every view looks at a surface within the corridor.
            let dir = pose.rotation.inverse() * Vector3::z();
            let hit = scene.intersect(&c, &dir).expect("a closed corridor");
            assert!(hit.t > 0.3 && hit.t < 9.0, "{}", hit.t);
        }
    }
}
