//! Cheap synthetic correspondence sets for solver tests, without rendering.
//!
//! * [`two_view_set`]: `n` pixel correspondences between two pinhole cameras (different focal lengths
//!   and principal points, no distortion) for a general 3D scene, a plane, a pure rotation (no
//!   baseline) or pure forward translation, with the exact fundamental matrix and, where it exists,
//!   the homography.
//! * [`resection_set`]: `n` 3D–2D pairs for one camera (optionally distorted, optionally planar).
//!
//! Inliers get i.i.d. Gaussian noise of `noise_px` per coordinate. Exactly
//! `round(outlier_fraction · n)` randomly chosen correspondences are outliers: their image-2 point
//! (or image point, for resection) is replaced by a uniform random pixel at least
//! [`OUTLIER_MIN_ERROR_PX`] (or 10·noise) away from every exact model. World frame: the points lie
//! around the origin, cameras about 6 m away.

use handheld_core::pose::{cam_from_world_from_center, center_of};
use handheld_core::{Camera, CameraId, Intrinsics, Rigid3};
use nalgebra::{Matrix3, Matrix3x4, Point3, Rotation3, Vector2, Vector3};
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::util::{gaussian, look_at};

/// Minimum model error of an outlier, in pixels.
pub const OUTLIER_MIN_ERROR_PX: f64 = 10.0;

/// The geometric configuration of a two-view set.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TwoViewKind {
    /// Points in a 3 m cube, ~1.2 m baseline: F is well defined.
    General,
    /// Points on one plane: F is degenerate for estimation, `homography()` exists.
    Planar,
    /// Same centre, rotated camera: `fundamental_matrix()` is `None`, `homography()` exists.
    PureRotation,
    /// Same orientation, camera moved 1.5 m along its optical axis (forward motion).
    PureTranslation,
}

#[derive(Clone, Debug, PartialEq)]
pub struct TwoViewOptions {
    pub n: usize,
    pub noise_px: f64,
    pub outlier_fraction: f64,
    pub kind: TwoViewKind,
    pub seed: u64,
    pub width: u32,
    pub height: u32,
}

impl Default for TwoViewOptions {
    fn default() -> Self {
        Self {
            n: 200,
            noise_px: 0.5,
            outlier_fraction: 0.0,
            kind: TwoViewKind::General,
            seed: 0,
            width: 640,
            height: 480,
        }
    }
}

/// Two views of `n` points. `pose*` are `cam_from_world`.
#[derive(Clone, Debug, PartialEq)]
pub struct TwoViewSet {
    pub camera1: Camera,
    pub camera2: Camera,
    pub pose1: Rigid3,
    pub pose2: Rigid3,
    pub points3d: Vec<Point3<f64>>,
    /// Observed (noisy; outliers replaced) pixels.
    pub x1: Vec<Vector2<f64>>,
    pub x2: Vec<Vector2<f64>>,
    /// Exact projections of `points3d`.
    pub x1_exact: Vec<Vector2<f64>>,
    pub x2_exact: Vec<Vector2<f64>>,
    pub is_inlier: Vec<bool>,
    pub kind: TwoViewKind,
    /// For [`TwoViewKind::Planar`]: the world plane `n·X = d` as `(n, d)`, `|n| = 1`.
    pub plane: Option<(Vector3<f64>, f64)>,
}

fn skew(t: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -t.z, t.y, t.z, 0.0, -t.x, -t.y, t.x, 0.0)
}

fn normalized(m: Matrix3<f64>) -> Matrix3<f64> {
    let n = m.norm();
    if n > 0.0 {
        m / n
    } else {
        m
    }
}

/// Distance of `x2` from the epipolar line `F x1`, in pixels.
pub fn epipolar_distance(f: &Matrix3<f64>, x1: &Vector2<f64>, x2: &Vector2<f64>) -> f64 {
    let l = f * x1.push(1.0);
    (x2.push(1.0).dot(&l)).abs() / l.xy().norm().max(1e-300)
}

/// Distance between `H x1` and `x2`, in pixels.
pub fn transfer_error(h: &Matrix3<f64>, x1: &Vector2<f64>, x2: &Vector2<f64>) -> f64 {
    let p = h * x1.push(1.0);
    (p.xy() / p.z - x2).norm()
}

impl TwoViewSet {
    /// `cam2_from_cam1`.
    pub fn relative_pose(&self) -> Rigid3 {
        self.pose2 * self.pose1.inverse()
    }

    /// `E = [t]× R` of the relative pose (unit Frobenius norm), `None` without baseline.
    pub fn essential_matrix(&self) -> Option<Matrix3<f64>> {
        let rel = self.relative_pose();
        let t = rel.translation.vector;
        (t.norm() > 1e-12)
            .then(|| normalized(skew(&t) * rel.rotation.to_rotation_matrix().matrix()))
    }

    /// `F = K2⁻ᵀ E K1⁻¹` in pixels (`x2ᵀ F x1 = 0`), unit Frobenius norm; `None` without baseline.
    pub fn fundamental_matrix(&self) -> Option<Matrix3<f64>> {
        let e = self.essential_matrix()?;
        let k1i = self.camera1.intrinsics.k_matrix().try_inverse()?;
        let k2i = self.camera2.intrinsics.k_matrix().try_inverse()?;
        Some(normalized(k2i.transpose() * e * k1i))
    }

    /// The homography `x2 ~ H x1` (unit Frobenius norm, positive `H[2,2]` when non-zero) for
    /// [`TwoViewKind::Planar`] and [`TwoViewKind::PureRotation`]; `None` for the other kinds.
    pub fn homography(&self) -> Option<Matrix3<f64>> {
        let rel = self.relative_pose();
        let r = *rel.rotation.to_rotation_matrix().matrix();
        let k1i = self.camera1.intrinsics.k_matrix().try_inverse()?;
        let k2 = self.camera2.intrinsics.k_matrix();
        let m = match self.kind {
            TwoViewKind::PureRotation => r,
            TwoViewKind::Planar => {
                let (nw, dw) = self.plane?;
                let n1 = self.pose1.rotation * nw;
                let d1 = dw + n1.dot(&self.pose1.translation.vector);
                if d1.abs() < 1e-12 {
                    return None;
                }
                r + rel.translation.vector * n1.transpose() / d1
            }
            _ => return None,
        };
        let h = normalized(k2 * m * k1i);
        Some(if h[(2, 2)] < 0.0 { -h } else { h })
    }

    pub fn num_inliers(&self) -> usize {
        self.is_inlier.iter().filter(|b| **b).count()
    }
}

/// A camera looking at `target` from `eye` with a roll of `roll` radians about its optical axis.
pub(crate) fn aimed_pose(
    eye: &Point3<f64>,
    target: &Point3<f64>,
    roll: f64,
) -> Result<Rigid3, String> {
    let r = look_at(eye, target, &Vector3::z()).ok_or("degenerate viewing direction")?;
    Ok(cam_from_world_from_center(
        &(r * Rotation3::from_axis_angle(&Vector3::z_axis(), roll)),
        eye,
    ))
}

/// A random viewpoint at `distance` from the origin on the `−y` side, elevation in `elev` degrees.
pub(crate) fn random_eye(rng: &mut ChaCha8Rng, distance: f64, elev: (f64, f64)) -> Point3<f64> {
    let az = rng.random_range(-30f64..30.0).to_radians();
    let el = rng.random_range(elev.0..elev.1).to_radians();
    Point3::new(az.sin() * el.cos(), -az.cos() * el.cos(), el.sin()) * distance
}

pub(crate) fn random_vec(rng: &mut ChaCha8Rng, half: f64) -> Vector3<f64> {
    Vector3::new(
        rng.random_range(-half..half),
        rng.random_range(-half..half),
        rng.random_range(-half..half),
    )
}

/// A uniform random pixel whose error under `bad` exceeds `min_err` (50 tries, then the last one).
pub(crate) fn outlier_pixel(
    rng: &mut ChaCha8Rng,
    cam: &Camera,
    min_err: f64,
    err: impl Fn(&Vector2<f64>) -> f64,
) -> Vector2<f64> {
    let mut p = Vector2::zeros();
    for _ in 0..50 {
        p = Vector2::new(
            rng.random_range(0.0..cam.width as f64 - 1.0),
            rng.random_range(0.0..cam.height as f64 - 1.0),
        );
        if err(&p) > min_err {
            break;
        }
    }
    p
}

fn check_common(n: usize, noise: f64, outliers: f64) -> Result<(), String> {
    if n == 0 {
        return Err("n must be positive".into());
    }
    if !(noise >= 0.0 && noise.is_finite()) {
        return Err("noise_px must be finite and non-negative".into());
    }
    if !(0.0..=1.0).contains(&outliers) {
        return Err(format!(
            "outlier_fraction must be in [0, 1], got {outliers}"
        ));
    }
    Ok(())
}

fn inside(cam: &Camera, p: &Option<Vector2<f64>>) -> bool {
    p.is_some_and(|p| {
        p.x >= 2.0 && p.y >= 2.0 && p.x <= cam.width as f64 - 3.0 && p.y <= cam.height as f64 - 3.0
    })
}

/// Generates a two-view correspondence set.
pub fn two_view_set(opts: &TwoViewOptions) -> Result<TwoViewSet, String> {
    check_common(opts.n, opts.noise_px, opts.outlier_fraction)?;
    let mut rng = ChaCha8Rng::seed_from_u64(opts.seed ^ 0x2F1E_0000);
    let (w, h) = (opts.width as f64, opts.height as f64);
    let camera1 = Camera {
        id: CameraId(0),
        width: opts.width,
        height: opts.height,
        intrinsics: Intrinsics::pinhole(0.95 * w, w / 2.0 + 2.0, h / 2.0 - 1.5),
    };
    let camera2 = Camera {
        id: CameraId(1),
        width: opts.width,
        height: opts.height,
        intrinsics: Intrinsics::pinhole(0.88 * w, w / 2.0 - 3.0, h / 2.0 + 1.0),
    };
    let c1 = random_eye(&mut rng, 6.0, (5.0, 30.0));
    let pose1 = aimed_pose(
        &c1,
        &Point3::from(random_vec(&mut rng, 0.2)),
        rng.random_range(-0.15..0.15),
    )?;
    let axis1 = pose1.rotation.inverse() * Vector3::z();
    let pose2 = match opts.kind {
        TwoViewKind::General | TwoViewKind::Planar => {
            let mut b = random_vec(&mut rng, 1.0);
            b -= axis1 * (0.8 * b.dot(&axis1));
            let b = b.normalize() * rng.random_range(1.0..1.5);
            aimed_pose(
                &(c1 + b),
                &Point3::from(random_vec(&mut rng, 0.3)),
                rng.random_range(-0.15..0.15),
            )?
        }
        TwoViewKind::PureRotation => {
            let mut off = random_vec(&mut rng, 1.0);
            off -= axis1 * off.dot(&axis1);
            let target = Point3::origin() + off.normalize() * rng.random_range(0.5..0.8);
            aimed_pose(&c1, &target, rng.random_range(-0.1..0.1))?
        }
        TwoViewKind::PureTranslation => {
            let c2 = c1 + axis1 * 1.5;
            Rigid3::from_parts((-(pose1.rotation * c2.coords)).into(), pose1.rotation)
        }
    };
    let plane = (opts.kind == TwoViewKind::Planar).then(|| {
        let n = (c1.coords.normalize() + random_vec(&mut rng, 0.4)).normalize();
        let p0 = Point3::from(random_vec(&mut rng, 0.3));
        (n, n.dot(&p0.coords))
    });
    let mut points3d = Vec::with_capacity(opts.n);
    let mut x1_exact = Vec::with_capacity(opts.n);
    let mut x2_exact = Vec::with_capacity(opts.n);
    let mut tries = 0usize;
    while points3d.len() < opts.n {
        tries += 1;
        if tries > 1000 * opts.n + 10000 {
            return Err("could not place points visible in both views".into());
        }
        let x = match plane {
            Some((n, d)) => {
                let u = n
                    .cross(&Vector3::z())
                    .try_normalize(1e-9)
                    .unwrap_or_else(Vector3::x);
                let v = n.cross(&u);
                Point3::from(
                    n * d + u * rng.random_range(-2.5..2.5) + v * rng.random_range(-2.5..2.5),
                )
            }
            None => Point3::from(random_vec(&mut rng, 1.5)),
        };
        let (p1, p2) = (camera1.project(&pose1, &x), camera2.project(&pose2, &x));
        if !inside(&camera1, &p1)
            || !inside(&camera2, &p2)
            || pose1.transform_point(&x).z < 0.5
            || pose2.transform_point(&x).z < 0.5
        {
            continue;
        }
        if let (Some(p1), Some(p2)) = (p1, p2) {
            points3d.push(x);
            x1_exact.push(p1);
            x2_exact.push(p2);
        }
    }
    let mut set = TwoViewSet {
        camera1,
        camera2,
        pose1,
        pose2,
        points3d,
        x1: Vec::new(),
        x2: Vec::new(),
        x1_exact,
        x2_exact,
        is_inlier: vec![true; opts.n],
        kind: opts.kind,
        plane,
    };
    let (f, hmg) = (set.fundamental_matrix(), set.homography());
    let noise = opts.noise_px;
    set.x1 = set
        .x1_exact
        .iter()
        .map(|p| p + Vector2::new(gaussian(&mut rng), gaussian(&mut rng)) * noise)
        .collect();
    set.x2 = set
        .x2_exact
        .iter()
        .map(|p| p + Vector2::new(gaussian(&mut rng), gaussian(&mut rng)) * noise)
        .collect();
    let n_out = (opts.outlier_fraction * opts.n as f64).round() as usize;
    let mut idx: Vec<usize> = (0..opts.n).collect();
    idx.shuffle(&mut rng);
    let min_err = OUTLIER_MIN_ERROR_PX.max(10.0 * noise);
    for &i in &idx[..n_out] {
        let x1 = set.x1_exact[i];
        let err = |p: &Vector2<f64>| {
            let ef = f.map_or(f64::INFINITY, |f| epipolar_distance(&f, &x1, p));
            let eh = hmg.map_or(f64::INFINITY, |h| transfer_error(&h, &x1, p));
            ef.min(eh).min((p - set.x2_exact[i]).norm())
        };
        set.x2[i] = outlier_pixel(&mut rng, &set.camera2, min_err, err);
        set.is_inlier[i] = false;
    }
    Ok(set)
}

#[derive(Clone, Debug, PartialEq)]
pub struct ResectionOptions {
    pub n: usize,
    pub noise_px: f64,
    pub outlier_fraction: f64,
    pub seed: u64,
    pub width: u32,
    pub height: u32,
    /// Radial distortion of the camera (0 for a pinhole).
    pub k1: f64,
    pub k2: f64,
    /// All points on the plane `z = 0` (the planar case of resection).
    pub planar: bool,
}

impl Default for ResectionOptions {
    fn default() -> Self {
        Self {
            n: 100,
            noise_px: 0.5,
            outlier_fraction: 0.0,
            seed: 0,
            width: 640,
            height: 480,
            k1: 0.0,
            k2: 0.0,
            planar: false,
        }
    }
}

/// `n` 3D–2D correspondences of one camera.
#[derive(Clone, Debug, PartialEq)]
pub struct ResectionSet {
    pub camera: Camera,
    /// `cam_from_world`.
    pub pose: Rigid3,
    pub points3d: Vec<Point3<f64>>,
    /// Observed (noisy; outliers replaced) pixels.
    pub x: Vec<Vector2<f64>>,
    pub x_exact: Vec<Vector2<f64>>,
    pub is_inlier: Vec<bool>,
}

impl ResectionSet {
    /// `P = K [R | t]` (ignores distortion).
    pub fn projection_matrix(&self) -> Matrix3x4<f64> {
        self.camera.intrinsics.k_matrix() * handheld_core::pose::to_matrix3x4(&self.pose)
    }

    pub fn center(&self) -> Point3<f64> {
        center_of(&self.pose)
    }
}

/// Generates a resection set.
pub fn resection_set(opts: &ResectionOptions) -> Result<ResectionSet, String> {
    check_common(opts.n, opts.noise_px, opts.outlier_fraction)?;
    let mut rng = ChaCha8Rng::seed_from_u64(opts.seed ^ 0x4E5E_0000);
    let (w, h) = (opts.width as f64, opts.height as f64);
    let intrinsics = Intrinsics {
        f: w * rng.random_range(0.85..1.1),
        aspect: 1.0,
        skew: 0.0,
        pp: Vector2::new(
            w / 2.0 + rng.random_range(-5.0..5.0),
            h / 2.0 + rng.random_range(-5.0..5.0),
        ),
        k1: opts.k1,
        k2: opts.k2,
    };
    intrinsics.validate()?;
    let camera = Camera {
        id: CameraId(0),
        width: opts.width,
        height: opts.height,
        intrinsics,
    };
    let dist = rng.random_range(5.0..7.0);
    let eye = random_eye(
        &mut rng,
        dist,
        if opts.planar {
            (25.0, 60.0)
        } else {
            (5.0, 40.0)
        },
    );
    let pose = aimed_pose(
        &eye,
        &Point3::from(random_vec(&mut rng, 0.2)),
        rng.random_range(-0.2..0.2),
    )?;
    let (mut points3d, mut x_exact) = (Vec::with_capacity(opts.n), Vec::with_capacity(opts.n));
    let mut tries = 0usize;
    while points3d.len() < opts.n {
        tries += 1;
        if tries > 1000 * opts.n + 10000 {
            return Err("could not place visible points".into());
        }
        let mut x = Point3::from(random_vec(&mut rng, 1.5));
        if opts.planar {
            x.z = 0.0;
        }
        let p = camera.project(&pose, &x);
        if inside(&camera, &p) && pose.transform_point(&x).z > 0.5 {
            if let Some(p) = p {
                points3d.push(x);
                x_exact.push(p);
            }
        }
    }
    let noise = opts.noise_px;
    let mut x: Vec<Vector2<f64>> = x_exact
        .iter()
        .map(|p| p + Vector2::new(gaussian(&mut rng), gaussian(&mut rng)) * noise)
        .collect();
    let mut is_inlier = vec![true; opts.n];
    let n_out = (opts.outlier_fraction * opts.n as f64).round() as usize;
    let mut idx: Vec<usize> = (0..opts.n).collect();
    idx.shuffle(&mut rng);
    let min_err = OUTLIER_MIN_ERROR_PX.max(10.0 * noise);
    for &i in &idx[..n_out] {
        let exact = x_exact[i];
        x[i] = outlier_pixel(&mut rng, &camera, min_err, |p| (p - exact).norm());
        is_inlier[i] = false;
    }
    Ok(ResectionSet {
        camera,
        pose,
        points3d,
        x,
        x_exact,
        is_inlier,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pure_translation_epipole_is_near_the_principal_point() {
        let set = two_view_set(&TwoViewOptions {
            kind: TwoViewKind::PureTranslation,
            noise_px: 0.0,
            ..Default::default()
        })
        .expect("valid");
        let f = set.fundamental_matrix().expect("has baseline");
        // The epipole in image 1 is the right null vector of F.
        let e = f.svd(false, true).v_t.expect("svd").row(2).transpose();
        let e = e.xy() / e.z;
        assert!((e - set.camera1.intrinsics.pp).norm() < 1.0, "{e:?}");
        assert!(set.homography().is_none());
    }

    #[test]
    fn invalid_options_are_rejected() {
        assert!(two_view_set(&TwoViewOptions {
            n: 0,
            ..Default::default()
        })
        .is_err());
        assert!(two_view_set(&TwoViewOptions {
            outlier_fraction: 1.5,
            ..Default::default()
        })
        .is_err());
        assert!(resection_set(&ResectionOptions {
            noise_px: -1.0,
            ..Default::default()
        })
        .is_err());
    }
}
