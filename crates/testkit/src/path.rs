//! Hand-held camera paths looking at the scene of [`crate::scene::Scene::default_scene`].
//!
//! * [`CameraPath::Orbit`]: an arc of `sweep` degrees around `target` at horizontal radius
//!   `distance`, centred on the `−y` side, always looking at `target`.
//! * [`CameraPath::WalkThrough`]: a lateral walk of `sweep` metres along `x` at `distance` in front of
//!   `target`, panning a little (the look-at point moves half as far as the camera).
//! * [`CameraPath::Forward`]: forward motion of `sweep` metres straight towards `target` (along the
//!   optical axis, so the epipole is at the image centre up to jitter), starting `distance` in front of
//!   it at `height`.
//!
//! * [`CameraPath::Ring`]: a full turn around `target` at horizontal radius `distance` (frame `i` at
//!   azimuth `i · 360° / n`, so the ring closes without repeating a view), always looking at
//!   `target`: an object on a turntable or a sculpture walked around. `sweep` is not used.
//! * [`CameraPath::Hemisphere`]: three such rings at elevations 15°, 40° and 65° seen from
//!   `target` (on a sphere of radius `distance`), each turned by half a step against the one below;
//!   `height` is not used.
//!
//! Cameras start at `height` above the ground. On top of the nominal path each frame gets a small walking
//! bob and seeded i.i.d. Gaussian jitter: `jitter_pos` metres per axis on the centre and `jitter_rot`
//! degrees per axis on the orientation (applied in the camera frame). An optional linear zoom scales
//! the focal length from `zoom.0` to `zoom.1` over the sequence.

use handheld_core::pose::cam_from_world_from_center;
use handheld_core::Rigid3;
use nalgebra::{Point3, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::util::{gaussian_vec3, look_at, small_rotation};

/// The kind of hand-held motion.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum CameraPath {
    Orbit,
    WalkThrough,
    Forward,
    Ring,
    Hemisphere,
    /// The walk through [`crate::Scene::corridor_scene`] (see [`crate::corridor`]): `sweep` metres
    /// of it, at `height`; `distance` and `target` are not used.
    Corridor,
}

/// Parameters of a camera path; see the module documentation for the meaning per kind.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PathOptions {
    pub kind: CameraPath,
    pub num_frames: usize,
    /// Orbit radius, or stand-off distance (along `−y`) from `target` for walk-through and forward.
    pub distance: f64,
    /// Camera height above the ground (metres).
    pub height: f64,
    /// Orbit arc in degrees; walk length or forward travel in metres.
    pub sweep: f64,
    /// Point the cameras look at.
    pub target: Point3<f64>,
    /// Standard deviation of the per-axis position jitter, metres.
    pub jitter_pos: f64,
    /// Standard deviation of the per-axis rotation jitter, degrees.
    pub jitter_rot: f64,
    /// Optional linear zoom: focal factor at the first and last frame.
    pub zoom: Option<(f64, f64)>,
    pub seed: u64,
}

/// The generated path: one `cam_from_world` and one focal factor per frame.
#[derive(Clone, Debug, PartialEq)]
pub struct Trajectory {
    pub cam_from_world: Vec<Rigid3>,
    /// Multiplier of the base focal length per frame (1 without zoom).
    pub focal_factor: Vec<f64>,
}

impl Default for PathOptions {
    fn default() -> Self {
        Self::orbit(20)
    }
}

impl PathOptions {
    fn base(kind: CameraPath, num_frames: usize, distance: f64, height: f64, sweep: f64) -> Self {
        Self {
            kind,
            num_frames,
            distance,
            height,
            sweep,
            target: Point3::new(0.0, 0.0, 0.35),
            jitter_pos: 0.02,
            jitter_rot: 0.7,
            zoom: None,
            seed: 0,
        }
    }

    /// An 80° orbit at 4 m radius, 1.7 m high.
    pub fn orbit(num_frames: usize) -> Self {
        Self::base(CameraPath::Orbit, num_frames, 4.0, 1.7, 80.0)
    }

    /// A phone held in the hand, orbiting a wall-mounted object ([`crate::Scene::wall_scene`]):
    /// a 60° arc at 1.7 m from it, at the object's height, with a hand's jitter.
    pub fn wall_orbit(num_frames: usize) -> Self {
        Self {
            target: Point3::new(0.0, 0.3, 1.3),
            jitter_pos: 0.015,
            jitter_rot: 1.0,
            ..Self::base(CameraPath::Orbit, num_frames, 1.7, 1.35, 60.0)
        }
    }

    /// A full turn at 4 m radius, 2.5 m high (looking down about 20° at the objects).
    pub fn ring(num_frames: usize) -> Self {
        Self::base(CameraPath::Ring, num_frames, 4.0, 2.5, 360.0)
    }

    /// Three rings on a hemisphere of 4.5 m radius around the objects.
    pub fn hemisphere(num_frames: usize) -> Self {
        Self::base(CameraPath::Hemisphere, num_frames, 4.5, 0.0, 360.0)
    }

    /// A 2.4 m lateral walk, 3.8 m in front of the objects, 1.5 m high.
    pub fn walk_through(num_frames: usize) -> Self {
        Self::base(CameraPath::WalkThrough, num_frames, 3.8, 1.5, 2.4)
    }

    /// 1.6 m of forward motion starting 4.8 m in front of the objects, 1.4 m high.
    pub fn forward(num_frames: usize) -> Self {
        Self::base(CameraPath::Forward, num_frames, 4.8, 1.4, 1.6)
    }

    pub fn validate(&self) -> Result<(), String> {
        if self.num_frames == 0 {
            return Err("a path needs at least one frame".into());
        }
        let vals = [
            self.distance,
            self.height,
            self.sweep,
            self.jitter_pos,
            self.jitter_rot,
            self.target.x,
            self.target.y,
            self.target.z,
        ];
        if vals.iter().any(|v| !v.is_finite()) {
            return Err("path parameters must be finite".into());
        }
        if self.distance <= 0.0 {
            return Err(format!("distance must be positive, got {}", self.distance));
        }
        if self.jitter_pos < 0.0 || self.jitter_rot < 0.0 {
            return Err("jitter must be non-negative".into());
        }
        let start_range = (self.distance.powi(2) + (self.height - self.target.z).powi(2)).sqrt();
        if self.kind == CameraPath::Forward && start_range - self.sweep < 0.5 {
            return Err(format!(
                "forward travel {} leaves less than 0.5 m to the target at {start_range}",
                self.sweep
            ));
        }
        if self.kind == CameraPath::Orbit && self.sweep.abs() >= 360.0 {
            return Err("an orbit sweep must be below 360 degrees".into());
        }
        if let Some((a, b)) = self.zoom {
            if !(a > 0.0 && b > 0.0 && a.is_finite() && b.is_finite()) {
                return Err(format!("zoom factors must be positive, got ({a}, {b})"));
            }
        }
        Ok(())
    }

    /// Generates the path.
    pub fn generate(&self) -> Result<Trajectory, String> {
        self.validate()?;
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed ^ 0x9A7B_0000);
        let n = self.num_frames;
        let up = Vector3::z();
        let t = self.target;
        let start = Point3::new(t.x, t.y - self.distance, self.height);
        let forward_dir = t - start;
        let mut poses = Vec::with_capacity(n);
        let mut factors = Vec::with_capacity(n);
        for i in 0..n {
            let s = if n > 1 {
                i as f64 / (n - 1) as f64
            } else {
                0.5
            };
            let (eye, look) = match self.kind {
                CameraPath::Orbit => {
                    let az = (s - 0.5) * self.sweep.to_radians();
                    (
                        Point3::new(
                            t.x + self.distance * az.sin(),
                            t.y - self.distance * az.cos(),
                            self.height,
                        ),
                        t,
                    )
                }
                CameraPath::WalkThrough => {
                    let x = (s - 0.5) * self.sweep;
                    (
                        Point3::new(t.x + x, t.y - self.distance, self.height),
                        t + Vector3::new(0.5 * x, 0.0, 0.0),
                    )
                }
                CameraPath::Forward => {
                    let eye = start + forward_dir * (s * self.sweep / forward_dir.norm());
                    (eye, eye + forward_dir)
                }
                CameraPath::Ring => {
                    let az = i as f64 / n as f64 * std::f64::consts::TAU;
                    (
                        Point3::new(
                            t.x + self.distance * az.sin(),
                            t.y - self.distance * az.cos(),
                            self.height,
                        ),
                        t,
                    )
                }
                CameraPath::Hemisphere => {
                    // Frames split over three rings, the lower rings taking the extra ones.
                    let ring = (i * 3) / n;
                    let first = (ring * n).div_ceil(3);
                    let count = ((ring + 1) * n).div_ceil(3) - first;
                    let k = i - first;
                    let elevation = (15.0 + 25.0 * ring as f64).to_radians();
                    let az = (k as f64 + 0.5 * ring as f64) / count.max(1) as f64
                        * std::f64::consts::TAU;
                    let r = self.distance * elevation.cos();
                    (
                        Point3::new(
                            t.x + r * az.sin(),
                            t.y - r * az.cos(),
                            t.z + self.distance * elevation.sin(),
                        ),
                        t,
                    )
                }
                CameraPath::Corridor => {
                    let (p, u) = crate::corridor::corridor_walk_at(s * self.sweep);
                    let eye = Point3::new(p.x, p.y, self.height);
                    (eye, eye + Vector3::new(u.x, u.y, -0.18))
                }
            };
            let bob = Vector3::new(0.0, 0.0, 0.01 * (std::f64::consts::TAU * 3.0 * s).sin());
            let eye = eye + bob + gaussian_vec3(&mut rng, self.jitter_pos);
            let r = look_at(&eye, &look, &up)
                .ok_or_else(|| format!("frame {i}: degenerate viewing direction"))?;
            let r = r * small_rotation(&gaussian_vec3(&mut rng, self.jitter_rot.to_radians()));
            poses.push(cam_from_world_from_center(&r, &eye));
            factors.push(match self.zoom {
                Some((a, b)) => a + (b - a) * s,
                None => 1.0,
            });
        }
        Ok(Trajectory {
            cam_from_world: poses,
            focal_factor: factors,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use handheld_core::pose::center_of;

    #[test]
    fn every_kind_looks_at_the_target() {
        for opts in [
            PathOptions::orbit(9),
            PathOptions::walk_through(9),
            PathOptions::forward(9),
            PathOptions::ring(9),
            PathOptions::hemisphere(9),
        ] {
            let traj = opts.generate().expect("valid");
            assert_eq!(traj.cam_from_world.len(), 9);
            for pose in &traj.cam_from_world {
                let p = pose.transform_point(&opts.target);
                assert!(p.z > 2.0, "{:?}: target at depth {}", opts.kind, p.z);
                // Within ~25° of the optical axis.
                assert!((p.x.hypot(p.y) / p.z) < 0.5, "{:?}", opts.kind);
                let c = center_of(pose);
                if opts.kind != CameraPath::Hemisphere {
                    assert!((c.z - opts.height).abs() < 0.4);
                }
            }
        }
    }

    #[test]
    fn a_ring_closes_and_a_hemisphere_climbs() {
        let mut ring = PathOptions::ring(8);
        ring.jitter_pos = 0.0;
        ring.jitter_rot = 0.0;
        let centres_of = |o: &PathOptions| -> Vec<Point3<f64>> {
            let traj = o.generate().expect("valid");
            traj.cam_from_world.iter().map(center_of).collect()
        };
        let centres = centres_of(&ring);
        // Eight views 45° apart: every step the same chord, the last view next to the first.
        let chord = 2.0 * ring.distance * (std::f64::consts::PI / 8.0).sin();
        for k in 0..8 {
            let d = (centres[(k + 1) % 8] - centres[k]).xy().norm();
            assert!((d - chord).abs() < 0.05, "{k}: {d} against {chord}");
        }
        let mut hemi = PathOptions::hemisphere(10);
        hemi.jitter_pos = 0.0;
        let heights: Vec<f64> = centres_of(&hemi)
            .iter()
            .map(|c| c.z - hemi.target.z)
            .collect();
        // 4 + 3 + 3 frames at 15°, 40° and 65°.
        let expect = [
            15.0_f64, 15.0, 15.0, 15.0, 40.0, 40.0, 40.0, 65.0, 65.0, 65.0,
        ]
        .map(|e| hemi.distance * e.to_radians().sin());
        for (h, e) in heights.iter().zip(expect) {
            assert!((h - e).abs() < 0.05, "{heights:?}");
        }
    }

    #[test]
    fn forward_moves_along_the_axis_and_zoom_interpolates() {
        let mut opts = PathOptions::forward(5);
        opts.jitter_pos = 0.0;
        opts.jitter_rot = 0.0;
        opts.zoom = Some((1.0, 1.5));
        let traj = opts.generate().expect("valid");
        let c0 = center_of(&traj.cam_from_world[0]);
        let c4 = center_of(&traj.cam_from_world[4]);
        let axis = traj.cam_from_world[0].rotation.inverse() * Vector3::z();
        let motion = (c4 - c0).normalize();
        assert!(motion.dot(&axis) > 0.99);
        assert_eq!(traj.focal_factor, vec![1.0, 1.125, 1.25, 1.375, 1.5]);
    }

    #[test]
    fn seeds_change_jitter_only() {
        let a = PathOptions::orbit(4).generate().expect("valid");
        let mut o = PathOptions::orbit(4);
        o.seed = 1;
        let b = o.generate().expect("valid");
        assert_ne!(a, b);
        let d = (center_of(&a.cam_from_world[2]) - center_of(&b.cam_from_world[2])).norm();
        assert!(d < 0.2, "{d}");
        assert!(PathOptions {
            num_frames: 0,
            ..PathOptions::default()
        }
        .validate()
        .is_err());
    }
}
