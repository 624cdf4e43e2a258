//! Tiny exact synthetic scenes for the solver tests: random points in front of two (or more)
//! pinhole cameras, projected without noise, plus a seeded Gaussian for noisy variants.

use handheld_core::pose::{cam_from_world_from_center, to_matrix3x4};
use handheld_core::Intrinsics;
use nalgebra::{Matrix3, Matrix3x4, Point3, Rotation3, Vector2, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

pub fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

/// Standard normal sample (Box–Muller).
pub fn gauss(rng: &mut ChaCha8Rng) -> f64 {
    let u1: f64 = rng.random_range(f64::EPSILON..1.0);
    let u2: f64 = rng.random_range(0.0..1.0);
    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
}

pub fn project(p: &Matrix3x4<f64>, x: &Point3<f64>) -> Vector2<f64> {
    let m = p * x.to_homogeneous();
    m.xy() / m.z
}

/// Two views of random points: `(P1, P2, points, x1, x2)`, 640×480 images, f = 600.
pub struct TwoView {
    pub p1: Matrix3x4<f64>,
    pub p2: Matrix3x4<f64>,
    pub points: Vec<Point3<f64>>,
    pub x1: Vec<Vector2<f64>>,
    pub x2: Vec<Vector2<f64>>,
}

pub fn camera_matrix(
    k: &Matrix3<f64>,
    rot_world_from_cam: Rotation3<f64>,
    center: Point3<f64>,
) -> Matrix3x4<f64> {
    k * to_matrix3x4(&cam_from_world_from_center(&rot_world_from_cam, &center))
}

pub fn two_view(seed: u64, n: usize) -> TwoView {
    let mut r = rng(seed);
    let k1 = Intrinsics::pinhole(600.0, 320.0, 240.0).k_matrix();
    let k2 = Intrinsics::pinhole(650.0, 310.0, 250.0).k_matrix();
    let p1 = camera_matrix(&k1, Rotation3::identity(), Point3::origin());
    let c2 = Point3::new(
        r.random_range(0.6..1.2),
        r.random_range(-0.3..0.3),
        r.random_range(-0.2..0.2),
    );
    let rot2 = Rotation3::from_euler_angles(
        r.random_range(-0.1..0.1),
        r.random_range(-0.35..-0.15),
        r.random_range(-0.1..0.1),
    );
    let p2 = camera_matrix(&k2, rot2, c2);
    let mut points = Vec::new();
    let (mut x1, mut x2) = (Vec::new(), Vec::new());
    while points.len() < n {
        let p = Point3::new(
            r.random_range(-2.0..2.0),
            r.random_range(-1.5..1.5),
            r.random_range(4.0..8.0),
        );
        let (a, b) = (project(&p1, &p), project(&p2, &p));
        let inside = |v: &Vector2<f64>| v.x >= 0.0 && v.x < 640.0 && v.y >= 0.0 && v.y < 480.0;
        if inside(&a) && inside(&b) {
            points.push(p);
            x1.push(a);
            x2.push(b);
        }
    }
    TwoView {
        p1,
        p2,
        points,
        x1,
        x2,
    }
}

pub fn add_noise(rng: &mut ChaCha8Rng, pts: &[Vector2<f64>], sigma: f64) -> Vec<Vector2<f64>> {
    pts.iter()
        .map(|p| p + Vector2::new(gauss(rng), gauss(rng)) * sigma)
        .collect()
}

/// `a` and `b` equal up to a non-zero scale (compared after unit Frobenius normalisation).
pub fn equal_up_to_scale(a: &Matrix3<f64>, b: &Matrix3<f64>) -> f64 {
    let a = a / a.norm();
    let b = b / b.norm();
    (a - b).norm().min((a + b).norm())
}

pub fn hom(v: &Vector2<f64>) -> Vector3<f64> {
    Vector3::new(v.x, v.y, 1.0)
}
