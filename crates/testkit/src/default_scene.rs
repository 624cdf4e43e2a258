//! The default synthetic scene: a 6 m × 6 m textured ground at `z = 0`, a 6 m × 2.5 m back wall at
//! `y = 2.5` facing `−y`, and 2–3 boxes (random size and yaw) plus 1–2 spheres resting on the ground
//! without overlapping, all inside about `|x| < 1.5, −1.1 < y < 1.3` — object-centred at the origin,
//! meant to be seen from the `−y` side by the paths of [`crate::path`].

use nalgebra::{Point3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::scene::{Primitive, Scene};

impl Scene {
    /// The default scene for `seed`: ground, back wall, 2–3 boxes and 1–2 spheres on the ground.
    pub fn default_scene(seed: u64) -> Self {
        Self::objects(seed, true)
    }

    /// The default scene's objects for `seed` (the same boxes and spheres) on a 12 m × 12 m
    /// ground without the back wall, to be walked around ([`crate::CameraPath::Ring`],
    /// [`crate::CameraPath::Hemisphere`]): what lies beyond the ground is the renderer's empty
    /// background.
    pub fn turntable_scene(seed: u64) -> Self {
        Self::objects(seed, false)
    }

    fn objects(seed: u64, walled: bool) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5CE2_E000);
        let (ground_texture, wall_texture) = (rng.random(), rng.random());
        let mut prims = if walled {
            vec![
                Primitive::Plane {
                    origin: Point3::new(-3.0, -3.5, 0.0),
                    edge_u: Vector3::new(6.0, 0.0, 0.0),
                    edge_v: Vector3::new(0.0, 6.0, 0.0),
                    texture: ground_texture,
                },
                Primitive::Plane {
                    origin: Point3::new(-3.0, 2.5, 0.0),
                    edge_u: Vector3::new(6.0, 0.0, 0.0),
                    edge_v: Vector3::new(0.0, 0.0, 2.5),
                    texture: wall_texture,
                },
            ]
        } else {
            vec![Primitive::Plane {
                origin: Point3::new(-6.0, -6.0, 0.0),
                edge_u: Vector3::new(12.0, 0.0, 0.0),
                edge_v: Vector3::new(0.0, 12.0, 0.0),
                texture: ground_texture,
            }]
        };
        let n_boxes = rng.random_range(2..=3);
        let n_spheres = rng.random_range(1..=2);
        let mut placed: Vec<(f64, f64, f64)> = Vec::new(); // footprint circles (x, y, radius)
        for i in 0..(n_boxes + n_spheres) {
            let is_box = i < n_boxes;
            for _attempt in 0..1000 {
                let (half, radius) = if is_box {
                    let h: Vector3<f64> = Vector3::new(
                        rng.random_range(0.18..0.45),
                        rng.random_range(0.18..0.45),
                        rng.random_range(0.15..0.5),
                    );
                    (h, h.x.hypot(h.y))
                } else {
                    let r = rng.random_range(0.22..0.4);
                    (Vector3::repeat(r), r)
                };
                let x = rng.random_range(-1.5 + radius..1.5 - radius);
                let y = rng.random_range(-1.1 + radius..1.3 - radius);
                let yaw = rng.random_range(0.0..std::f64::consts::PI);
                if placed
                    .iter()
                    .any(|&(px, py, pr)| (px - x).hypot(py - y) < pr + radius + 0.15)
                {
                    continue;
                }
                placed.push((x, y, radius));
                let texture = rng.random();
                prims.push(if is_box {
                    Primitive::Box {
                        center: Point3::new(x, y, half.z),
                        half_extents: half,
                        rotation: UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw),
                        texture,
                    }
                } else {
                    Primitive::Sphere {
                        center: Point3::new(x, y, half.z),
                        radius: half.z,
                        texture,
                    }
                });
                break;
            }
        }
        // The primitives above are valid by construction.
        Self::new(prims).unwrap_or_else(|e| panic!("default scene is invalid: {e}"))
    }
}

impl Scene {
    /// A phone's view of a wall-mounted object: a 6 m × 4 m patterned wall at `y = 0.5` facing
    /// `−y`, which fills most of every frame (a dominant plane), with a box and a sphere mounted on
    /// it, 0.2–0.45 m proud of it, around `(0, 0.3, 1.4)`. Seen by [`crate::PathOptions::wall_orbit`].
    pub fn wall_scene(seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x3A11_0000);
        let yaw = rng.random_range(-0.4..0.4);
        let prims = vec![
            Primitive::Plane {
                origin: Point3::new(-3.0, 0.5, -0.6),
                edge_u: Vector3::new(6.0, 0.0, 0.0),
                edge_v: Vector3::new(0.0, 0.0, 4.0),
                texture: rng.random(),
            },
            Primitive::Box {
                center: Point3::new(-0.1, 0.28, 1.45),
                half_extents: Vector3::new(
                    rng.random_range(0.16..0.24),
                    0.2,
                    rng.random_range(0.2..0.3),
                ),
                rotation: UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw * 0.2),
                texture: rng.random(),
            },
            Primitive::Sphere {
                center: Point3::new(0.35, 0.35, 1.05),
                radius: rng.random_range(0.12..0.17),
                texture: rng.random(),
            },
        ];
        Self::new(prims).unwrap_or_else(|e| panic!("wall scene is invalid: {e}"))
    }

    /// [`Scene::wall_scene`] with the wall papered: a motif about 0.3 m square repeated in a
    /// half-drop ([`crate::Finish::Wallpaper`]), so that most of every frame is a repeated pattern.
    pub fn wallpaper_scene(seed: u64) -> Self {
        let period = 0.24 + 0.12 * ChaCha8Rng::seed_from_u64(seed ^ 0x3A11_0001).random::<f64>();
        Self::wall_scene(seed).with_finish(0, crate::finish::Finish::Wallpaper { period })
    }
}
