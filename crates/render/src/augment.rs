//! Augmented video (§5.3): a virtual object placed in the reconstructed scene and rendered into
//! every frame through that frame's camera, radial distortion included, so that it stays put in
//! the original (distorted) footage.
//!
//! - [`Placement`]: the similarity from the object's frame to the model's, automatic
//!   ([`auto_place`]: the dominant supporting plane of the sparse points by RANSAC on
//!   [`handheld_robust::run`], the object standing upright on it near the points most frames see,
//!   scaled to the scene) or given.
//! - [`Compositor`]: renders the object with `SUB × SUB` samples per pixel (anti-aliased edges),
//!   Lambert-shaded with a light whose colour is the frame's average colour, hidden where the
//!   real scene (a depth map in the frame's camera: the mesh or the dense depth) is nearer, and
//!   composites it over the frame.
//! - [`object_box`], [`object_axes`]: the two objects the project ships, made here.

use handheld_core::{Camera, FloatMap, PointCloud, Rigid3, TriMesh};
use handheld_robust::{run, Estimator, InlierCount, RansacOptions, UniformSampler};
use image::RgbImage;
use nalgebra::{Matrix3, Point3, Rotation3, UnitQuaternion, Vector2, Vector3};
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::raster::{fragment_colour, rasterise};

/// What went wrong in augmenting.
#[derive(Debug, Error)]
pub enum AugmentError {
    #[error("no supporting plane: {0}")]
    NoPlane(String),
    #[error("the object has no triangles")]
    EmptyObject,
    #[error("the placement puts the object behind every camera (or outside every image); give another --transform")]
    Invisible,
    #[error("placement: {0}")]
    Placement(String),
}

/// `X_model = scale · R · X_object + translation`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Placement {
    pub scale: f64,
    /// Unit quaternion (w, x, y, z).
    pub rotation: [f64; 4],
    pub translation: [f64; 3],
}

impl Placement {
    pub fn new(scale: f64, r: &Rotation3<f64>, t: &Vector3<f64>) -> Self {
        let q = UnitQuaternion::from_rotation_matrix(r).into_inner();
        Self {
            scale,
            rotation: [q.w, q.i, q.j, q.k],
            translation: [t.x, t.y, t.z],
        }
    }

    /// Checks a placement read from a file: positive finite scale, unit quaternion, finite.
    pub fn validate(&self) -> Result<(), AugmentError> {
        let q = self.rotation;
        let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
        if !(self.scale.is_finite() && self.scale > 0.0) {
            return Err(AugmentError::Placement(format!(
                "scale must be positive, got {}",
                self.scale
            )));
        }
        if !(n.is_finite() && (n - 1.0).abs() < 1e-3) {
            return Err(AugmentError::Placement(format!(
                "rotation must be a unit quaternion [w, x, y, z], |q| = {n}"
            )));
        }
        if self.translation.iter().any(|v| !v.is_finite()) {
            return Err(AugmentError::Placement("translation must be finite".into()));
        }
        Ok(())
    }

    pub fn rotation_matrix(&self) -> Matrix3<f64> {
        let [w, x, y, z] = self.rotation;
        *UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z))
            .to_rotation_matrix()
            .matrix()
    }

    /// An object point in the model frame.
    pub fn apply(&self, p: &Point3<f64>) -> Point3<f64> {
        Point3::from(
            self.rotation_matrix() * p.coords * self.scale + Vector3::from(self.translation),
        )
    }

    /// The object mesh in the model frame (normals rotated).
    pub fn transform(&self, object: &TriMesh) -> TriMesh {
        let r = self.rotation_matrix();
        let mut m = object.clone();
        for p in &mut m.vertices.positions {
            let q = self.apply(&Point3::new(
                f64::from(p[0]),
                f64::from(p[1]),
                f64::from(p[2]),
            ));
            *p = [q.x as f32, q.y as f32, q.z as f32];
        }
        for n in &mut m.vertices.normals {
            let v = r * Vector3::new(f64::from(n[0]), f64::from(n[1]), f64::from(n[2]));
            *n = [v.x as f32, v.y as f32, v.z as f32];
        }
        m
    }
}

/// A plane `n · X = d` (unit `n`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SupportPlane {
    pub normal: [f64; 3],
    pub d: f64,
    pub inliers: usize,
    /// Angle between the plane's normal and the cameras' mean up direction (degrees).
    pub tilt_deg: f64,
}

/// How [`auto_place`] decided.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct PlacementReport {
    pub plane: SupportPlane,
    /// The point of the plane the object stands on.
    pub anchor: [f64; 3],
    /// The object's height in model units.
    pub height: f64,
    /// The plane was not close to horizontal for the cameras (a warning).
    pub warnings: Vec<String>,
}

/// Options of [`auto_place`].
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(default)]
pub struct PlaceOptions {
    /// The object's height as a fraction of the median camera distance to the anchor.
    pub height_fraction: f64,
    /// RANSAC inlier distance as a fraction of the median camera-to-point distance.
    pub plane_tolerance: f64,
    /// Planes tilted more than this from the cameras' up direction are not "supporting".
    pub max_tilt_deg: f64,
    pub seed: u64,
}

impl Default for PlaceOptions {
    fn default() -> Self {
        Self {
            height_fraction: 0.12,
            plane_tolerance: 0.004,
            max_tilt_deg: 30.0,
            seed: 7,
        }
    }
}

/// A plane through three points that is close to horizontal (within `max_tilt` of `up`); the
/// residual is the distance in units of `tolerance`. Three-point fit (Fischler & Bolles 1981),
/// total-least-squares refit.
struct GroundEstimator {
    up: Vector3<f64>,
    cos_max_tilt: f64,
    tolerance: f64,
}

impl Estimator for GroundEstimator {
    type Model = (Vector3<f64>, f64);
    type Sample = Vector3<f64>;
    const SAMPLE_SIZE: usize = 3;

    fn fit(&self, s: &[Vector3<f64>], out: &mut Vec<Self::Model>) {
        let n = (s[1] - s[0]).cross(&(s[2] - s[0]));
        let len = n.norm();
        if len < 1e-12 {
            return;
        }
        let n = n / len;
        if n.dot(&self.up).abs() >= self.cos_max_tilt {
            out.push((n, n.dot(&s[0])));
        }
    }

    fn residual(&self, (n, d): &Self::Model, p: &Vector3<f64>) -> f64 {
        (n.dot(p) - d).abs() / self.tolerance
    }

    fn refit(&self, s: &[Vector3<f64>], (n, _): &Self::Model) -> Option<Self::Model> {
        if s.len() < 3 {
            return None;
        }
        let c = s.iter().sum::<Vector3<f64>>() / s.len() as f64;
        let cov = s
            .iter()
            .fold(Matrix3::zeros(), |a, p| a + (p - c) * (p - c).transpose());
        let eig = cov.symmetric_eigen();
        let mut m: Vector3<f64> = eig.eigenvectors.column(eig.eigenvalues.imin()).into_owned();
        if m.dot(n) < 0.0 {
            m = -m;
        }
        (m.dot(&self.up).abs() >= self.cos_max_tilt).then(|| (m, m.dot(&c)))
    }
}

/// Places `object` automatically: the dominant supporting plane among `points` (model frame,
/// with the number of frames that see each), found by RANSAC among the planes within
/// `max_tilt_deg` of the cameras' mean up direction; the object stands upright on it (its +Y
/// along the plane's normal, towards the cameras; its +Z facing the cameras), at the point of
/// the plane under the centroid of the inliers most frames see, and its height is a fraction of
/// the cameras' median distance to that point. `cameras`: world → camera of every frame.
pub fn auto_place(
    object: &TriMesh,
    points: &[(Point3<f64>, usize)],
    cameras: &[Rigid3],
    opts: &PlaceOptions,
) -> Result<(Placement, PlacementReport), AugmentError> {
    if object.faces.is_empty() || object.vertices.positions.is_empty() {
        return Err(AugmentError::EmptyObject);
    }
    if points.len() < 3 || cameras.is_empty() {
        return Err(AugmentError::NoPlane(format!(
            "{} points and {} cameras; a supporting plane needs at least 3 points",
            points.len(),
            cameras.len()
        )));
    }
    let centres: Vec<Vector3<f64>> = cameras
        .iter()
        .map(|c| c.inverse().translation.vector)
        .collect();
    let up = cameras
        .iter()
        .map(|c| c.rotation.inverse() * Vector3::new(0.0, -1.0, 0.0))
        .sum::<Vector3<f64>>()
        .try_normalize(1e-9)
        .ok_or_else(|| AugmentError::NoPlane("the cameras have no common up direction".into()))?;
    let mut dists: Vec<f64> = points
        .iter()
        .map(|(p, _)| {
            centres
                .iter()
                .map(|c| (p.coords - c).norm())
                .fold(f64::INFINITY, f64::min)
        })
        .collect();
    dists.sort_by(f64::total_cmp);
    let scale = dists[dists.len() / 2];
    let samples: Vec<Vector3<f64>> = points.iter().map(|(p, _)| p.coords).collect();
    let est = GroundEstimator {
        up,
        cos_max_tilt: opts.max_tilt_deg.to_radians().cos(),
        tolerance: opts.plane_tolerance * scale,
    };
    let ransac = RansacOptions {
        max_error: 1.0,
        max_iterations: 2000,
        min_inlier_ratio: 0.0,
        ..RansacOptions::default()
    };
    let mut sampler = UniformSampler::new(opts.seed);
    let report = run(&est, &InlierCount, &mut sampler, &samples, &ransac).map_err(|e| {
        AugmentError::NoPlane(format!(
            "no near-horizontal plane among the sparse points ({e})"
        ))
    })?;
    let (mut n, mut d) = report.model.ok_or_else(|| {
        AugmentError::NoPlane(format!(
            "no plane within {}° of the cameras' up direction among the sparse points",
            opts.max_tilt_deg
        ))
    })?;
    let inliers: Vec<usize> = (0..samples.len())
        .filter(|&i| est.residual(&(n, d), &samples[i]) <= 1.0)
        .collect();
    if inliers.len() < 3 {
        return Err(AugmentError::NoPlane(
            "fewer than 3 points on the best plane".into(),
        ));
    }
    let cmean = centres.iter().sum::<Vector3<f64>>() / centres.len() as f64;
    if n.dot(&cmean) - d < 0.0 {
        n = -n;
        d = -d;
    }
    // The inliers most frames see: track length at least the 75th percentile.
    let mut lens: Vec<usize> = inliers.iter().map(|&i| points[i].1).collect();
    lens.sort_unstable();
    let cut = lens[lens.len() * 3 / 4];
    let best: Vec<Vector3<f64>> = inliers
        .iter()
        .filter(|&&i| points[i].1 >= cut)
        .map(|&i| samples[i])
        .collect();
    let centroid = best.iter().sum::<Vector3<f64>>() / best.len().max(1) as f64;
    let anchor = centroid - n * (n.dot(&centroid) - d);
    let mut to_anchor: Vec<f64> = centres.iter().map(|c| (anchor - c).norm()).collect();
    to_anchor.sort_by(f64::total_cmp);
    let height = opts.height_fraction * to_anchor[to_anchor.len() / 2];
    // The object's frame: +Y up, +Z its front.
    let (lo, hi) = bounds(object);
    let obj_height = (hi.y - lo.y).max(1e-12);
    let s = height / obj_height;
    let front = {
        let v = cmean - anchor;
        let v = v - n * v.dot(&n);
        v.try_normalize(1e-12)
            .unwrap_or_else(|| n.cross(&Vector3::x()).normalize())
    };
    let x = n.cross(&front);
    let r = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, n, front]));
    let base = Vector3::new((lo.x + hi.x) / 2.0, lo.y, (lo.z + hi.z) / 2.0);
    let t = anchor - r * base * s;
    let tilt = n.dot(&up).clamp(-1.0, 1.0).acos().to_degrees();
    Ok((
        Placement::new(s, &r, &t),
        PlacementReport {
            plane: SupportPlane {
                normal: [n.x, n.y, n.z],
                d,
                inliers: inliers.len(),
                tilt_deg: tilt,
            },
            anchor: [anchor.x, anchor.y, anchor.z],
            height,
            warnings: Vec::new(),
        },
    ))
}

/// The object's axis-aligned bounds in its own frame.
pub fn bounds(object: &TriMesh) -> (Vector3<f64>, Vector3<f64>) {
    let mut lo = Vector3::repeat(f64::INFINITY);
    let mut hi = Vector3::repeat(f64::NEG_INFINITY);
    for p in &object.vertices.positions {
        let v = Vector3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
        lo = lo.inf(&v);
        hi = hi.sup(&v);
    }
    (lo, hi)
}

/// The pixel positions of model-frame points in a frame (distortion applied); `None` behind it.
pub fn project(
    camera: &Camera,
    pose: &Rigid3,
    points: &[Point3<f64>],
) -> Vec<Option<Vector2<f64>>> {
    points.iter().map(|p| camera.project(pose, p)).collect()
}

/// Samples per pixel and axis of the object's anti-aliasing.
pub const SUB: usize = 3;

/// Renders an object into frames; keeps its buffers from frame to frame.
#[derive(Default)]
pub struct Compositor {
    zbuf: Vec<f32>,
    colour: Vec<[f32; 3]>,
    hit: Vec<bool>,
}

/// What one frame's compositing did.
#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize)]
pub struct CompositeStats {
    /// Pixels the object touches (any coverage), and the samples hidden by the scene.
    pub pixels: usize,
    pub hidden_samples: usize,
}

impl Compositor {
    pub fn new() -> Self {
        Self::default()
    }

    /// Composites `object` (already in the model frame, see [`Placement::transform`]) over
    /// `frame`, seen by `camera` at `pose`. `scene_depth`: the real scene's camera-frame depth
    /// per pixel (NaN where unknown) for occlusion. `undistorted`: draw as if the lens had no
    /// distortion (to show what ignoring it does).
    pub fn composite(
        &mut self,
        frame: &mut RgbImage,
        object: &TriMesh,
        texture: Option<&RgbImage>,
        camera: &Camera,
        pose: &Rigid3,
        scene_depth: Option<&FloatMap>,
    ) -> CompositeStats {
        let (w, h) = (frame.width() as usize, frame.height() as usize);
        // The light: the frame's average colour, from above and in front of the camera.
        let mean = average_colour(frame);
        let grey = (mean[0] + mean[1] + mean[2]) / 3.0;
        let light_colour =
            mean.map(|c| (c / grey.max(1.0)).clamp(0.5, 1.6) * (0.55 + grey / 255.0));
        let light_dir = pose.rotation.inverse() * Vector3::new(-0.3, -0.8, -0.5).normalize();
        // The window: the object's projected bounds on the sample grid.
        let Some((x0, y0, x1, y1)) = projected_window(object, camera, pose, w, h) else {
            return CompositeStats::default();
        };
        let (sx0, sy0, sx1, sy1) = (x0 * SUB, y0 * SUB, x1 * SUB, y1 * SUB);
        let ww = sx1 - sx0;
        let n = ww * (sy1 - sy0);
        self.colour.clear();
        self.colour.resize(n, [0.0; 3]);
        self.hit.clear();
        self.hit.resize(n, false);
        let mut hidden = 0usize;
        let normals: Vec<Vector3<f64>> = object
            .faces
            .iter()
            .map(|f| {
                let p = f.map(|i| {
                    let q = object.vertices.positions[i as usize];
                    Vector3::new(f64::from(q[0]), f64::from(q[1]), f64::from(q[2]))
                });
                (p[1] - p[0])
                    .cross(&(p[2] - p[0]))
                    .try_normalize(1e-20)
                    .unwrap_or(Vector3::z())
            })
            .collect();
        let centre = pose.inverse().translation.vector;
        let (colour, hit) = (&mut self.colour, &mut self.hit);
        rasterise(
            object,
            camera,
            pose,
            SUB,
            (sx0, sy0, sx1, sy1),
            &mut self.zbuf,
            |f| {
                let k = (f.sy - sy0) * ww + (f.sx - sx0);
                let (px, py) = (f.sx / SUB, f.sy / SUB);
                if let Some(d) = scene_depth {
                    let z = d.data[py * d.width + px];
                    if z.is_finite() && z > 0.0 && f64::from(z) < f.z * 0.99 {
                        hit[k] = false;
                        hidden += 1;
                        return;
                    }
                }
                let albedo = fragment_colour(object, texture, f);
                // Two-sided Lambert, the normal turned towards the camera.
                let mut nrm = normals[f.face];
                let idx = object.faces[f.face][0] as usize;
                let q = object.vertices.positions[idx];
                let to_cam =
                    centre - Vector3::new(f64::from(q[0]), f64::from(q[1]), f64::from(q[2]));
                if nrm.dot(&to_cam) < 0.0 {
                    nrm = -nrm;
                }
                let lambert = 0.45 + 0.55 * nrm.dot(&-light_dir).max(0.0);
                colour[k] = [0, 1, 2].map(|c| (albedo[c] * light_colour[c] * lambert) as f32);
                hit[k] = true;
            },
        );
        // Resolve: coverage-weighted average of the visible samples over the frame.
        let mut pixels = 0;
        let s2 = (SUB * SUB) as f32;
        for py in y0..y1 {
            for px in x0..x1 {
                let mut acc = [0.0f32; 3];
                let mut cnt = 0.0f32;
                for j in 0..SUB {
                    for i in 0..SUB {
                        let k = (py * SUB + j - sy0) * ww + (px * SUB + i - sx0);
                        if self.hit[k] {
                            for c in 0..3 {
                                acc[c] += self.colour[k][c];
                            }
                            cnt += 1.0;
                        }
                    }
                }
                if cnt == 0.0 {
                    continue;
                }
                pixels += 1;
                let alpha = cnt / s2;
                let p = frame.get_pixel_mut(px as u32, py as u32);
                for c in 0..3 {
                    let v = f32::from(p.0[c]) * (1.0 - alpha) + acc[c] / s2;
                    p.0[c] = v.round().clamp(0.0, 255.0) as u8;
                }
            }
        }
        CompositeStats {
            pixels,
            hidden_samples: hidden,
        }
    }
}

fn average_colour(frame: &RgbImage) -> [f64; 3] {
    let mut acc = [0u64; 3];
    // Every 4th pixel of every 4th row is plenty for a mean.
    let (w, h) = (frame.width(), frame.height());
    let mut n = 0u64;
    for y in (0..h).step_by(4) {
        for x in (0..w).step_by(4) {
            let p = frame.get_pixel(x, y).0;
            for c in 0..3 {
                acc[c] += u64::from(p[c]);
            }
            n += 1;
        }
    }
    acc.map(|v| v as f64 / n.max(1) as f64)
}

/// The pixel window (x0, y0, x1, y1; exclusive ends) the object can cover, one pixel of margin;
/// `None` when it is entirely behind the camera or outside the image.
fn projected_window(
    object: &TriMesh,
    camera: &Camera,
    pose: &Rigid3,
    w: usize,
    h: usize,
) -> Option<(usize, usize, usize, usize)> {
    let mut lo = Vector2::repeat(f64::INFINITY);
    let mut hi = Vector2::repeat(f64::NEG_INFINITY);
    let mut any = false;
    for p in &object.vertices.positions {
        let q = pose.transform_point(&Point3::new(
            f64::from(p[0]),
            f64::from(p[1]),
            f64::from(p[2]),
        ));
        if q.z <= 1e-9 {
            // A vertex behind the camera: the object may span the whole image.
            lo = Vector2::zeros();
            hi = Vector2::new(w as f64, h as f64);
            any = true;
            continue;
        }
        let m = camera
            .intrinsics
            .normalized_to_pixel(Vector2::new(q.x / q.z, q.y / q.z));
        lo = lo.inf(&m);
        hi = hi.sup(&m);
        any = true;
    }
    if !any {
        return None;
    }
    let x0 = (lo.x.floor() - 1.0).max(0.0) as usize;
    let y0 = (lo.y.floor() - 1.0).max(0.0) as usize;
    let x1 = ((hi.x.ceil() + 2.0).max(0.0) as usize).min(w);
    let y1 = ((hi.y.ceil() + 2.0).max(0.0) as usize).min(h);
    (x0 < x1 && y0 < y1).then_some((x0, y0, x1, y1))
}

/// A textured unit box standing on y = 0 (x, z in [−0.5, 0.5], y in [0, 1]): each face its own
/// colour with a darker frame and a grid, in one 256×256 texture (2×3 tiles).
pub fn object_box() -> (TriMesh, RgbImage) {
    let tile = 128u32;
    let colours: [[u8; 3]; 6] = [
        [220, 60, 50],
        [60, 170, 80],
        [60, 100, 220],
        [230, 190, 40],
        [200, 80, 200],
        [60, 200, 210],
    ];
    let mut tex = RgbImage::new(3 * tile, 2 * tile);
    for (f, c) in colours.iter().enumerate() {
        let (ox, oy) = ((f as u32 % 3) * tile, (f as u32 / 3) * tile);
        for y in 0..tile {
            for x in 0..tile {
                let edge = x < 10 || y < 10 || x >= tile - 10 || y >= tile - 10;
                let grid = x % 32 < 3 || y % 32 < 3;
                let k = if edge {
                    0.35
                } else if grid {
                    0.75
                } else {
                    1.0
                };
                let px = c.map(|v| (f64::from(v) * k) as u8);
                tex.put_pixel(ox + x, oy + y, image::Rgb(px));
            }
        }
    }
    // Faces: (+x, −x, +y, −y, +z, −z), each with its outward normal and two in-plane axes.
    let faces: [([f32; 3], [f32; 3], [f32; 3]); 6] = [
        ([1., 0., 0.], [0., 0., -1.], [0., 1., 0.]),
        ([-1., 0., 0.], [0., 0., 1.], [0., 1., 0.]),
        ([0., 1., 0.], [1., 0., 0.], [0., 0., -1.]),
        ([0., -1., 0.], [1., 0., 0.], [0., 0., 1.]),
        ([0., 0., 1.], [1., 0., 0.], [0., 1., 0.]),
        ([0., 0., -1.], [-1., 0., 0.], [0., 1., 0.]),
    ];
    let mut positions = Vec::new();
    let mut normals = Vec::new();
    let mut uvs = Vec::new();
    let mut tris = Vec::new();
    for (f, (n, u, v)) in faces.iter().enumerate() {
        let base = positions.len() as u32;
        let (tu, tv) = ((f % 3) as f32 / 3.0, (f / 3) as f32 / 2.0);
        for (a, b) in [(-0.5f32, -0.5f32), (0.5, -0.5), (0.5, 0.5), (-0.5, 0.5)] {
            let p = [
                0.5 * n[0] + a * u[0] + b * v[0],
                0.5 * n[1] + a * u[1] + b * v[1] + 0.5,
                0.5 * n[2] + a * u[2] + b * v[2],
            ];
            positions.push(p);
            normals.push(*n);
            uvs.push([tu + (a + 0.5) / 3.0, tv + (0.5 - b) / 2.0]);
        }
        tris.push([base, base + 1, base + 2]);
        tris.push([base, base + 2, base + 3]);
    }
    let mesh = TriMesh {
        vertices: PointCloud {
            colors: vec![[255, 255, 255]; positions.len()],
            positions,
            normals,
        },
        uvs,
        faces: tris,
    };
    (mesh, tex)
}

/// A coordinate-axes marker: three square bars along +X (red), +Y (green) and +Z (blue) from
/// the origin, length 1, vertex-coloured.
pub fn object_axes() -> TriMesh {
    let mut positions = Vec::new();
    let mut colors = Vec::new();
    let mut faces = Vec::new();
    let t = 0.06f32;
    for axis in 0..3 {
        let colour = match axis {
            0 => [230, 40, 40],
            1 => [40, 200, 60],
            _ => [50, 80, 240],
        };
        let mut lo = [-t; 3];
        let mut hi = [t; 3];
        lo[axis] = 0.0;
        hi[axis] = 1.0;
        let base = positions.len() as u32;
        for i in 0..8u32 {
            positions.push([
                if i & 1 == 0 { lo[0] } else { hi[0] },
                if i & 2 == 0 { lo[1] } else { hi[1] },
                if i & 4 == 0 { lo[2] } else { hi[2] },
            ]);
            colors.push(colour);
        }
        for q in [
            [0, 2, 3, 1],
            [4, 5, 7, 6],
            [0, 1, 5, 4],
            [2, 6, 7, 3],
            [0, 4, 6, 2],
            [1, 3, 7, 5],
        ] {
            faces.push([base + q[0], base + q[1], base + q[2]]);
            faces.push([base + q[0], base + q[2], base + q[3]]);
        }
    }
    TriMesh {
        vertices: PointCloud {
            positions,
            colors,
            normals: Vec::new(),
        },
        uvs: Vec::new(),
        faces,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use handheld_core::{CameraId, Intrinsics};

    /// A real box face (a plane at z = 3, for x < edge) passes in front of the virtual box (at
    /// z ≈ 5): the object's pixels are hidden exactly where the real surface is nearer, to
    /// within one pixel of the true occlusion edge, for three positions of the edge.
    #[test]
    fn a_real_box_in_front_hides_the_object_up_to_its_edge() {
        let mut intr = Intrinsics::pinhole(300.0, 159.5, 119.5);
        intr.k1 = -0.05;
        let camera = Camera {
            id: CameraId(0),
            width: 320,
            height: 240,
            intrinsics: intr,
        };
        let pose = Rigid3::identity();
        let (obj, tex) = object_box();
        let placement = Placement::new(
            2.0,
            &Rotation3::from_axis_angle(&Vector3::y_axis(), 0.4),
            &Vector3::new(0.0, -1.0, 5.0),
        );
        let placed = placement.transform(&obj);
        let (w, h) = (320usize, 240usize);
        for edge_x in [-0.6, -0.1, 0.35] {
            // The occluder's depth per pixel centre: z = 3 where x < edge_x on that plane.
            let mut depth = FloatMap::filled(w, h, 1, f32::NAN);
            let mut edge_px = f64::NAN;
            for y in 0..h {
                for x in 0..w {
                    let n = intr.pixel_to_normalized(Vector2::new(x as f64, y as f64));
                    if n.x * 3.0 < edge_x {
                        depth.data[y * w + x] = 3.0;
                    }
                }
            }
            let mut frame = RgbImage::new(320, 240);
            let mut unoccluded = RgbImage::new(320, 240);
            let mut c = Compositor::new();
            let s = c.composite(
                &mut frame,
                &placed,
                Some(&tex),
                &camera,
                &pose,
                Some(&depth),
            );
            c.composite(&mut unoccluded, &placed, Some(&tex), &camera, &pose, None);
            assert!(
                s.hidden_samples > 0 || edge_x < -0.5,
                "{edge_x}: nothing hidden"
            );
            for y in 0..h {
                for x in 0..w {
                    let drawn = frame.get_pixel(x as u32, y as u32).0 != [0, 0, 0];
                    let full = unoccluded.get_pixel(x as u32, y as u32).0 != [0, 0, 0];
                    // The true edge through this row, in pixels (distortion included).
                    let n = intr.pixel_to_normalized(Vector2::new(x as f64, y as f64));
                    let at_edge = intr.normalized_to_pixel(Vector2::new(edge_x / 3.0, n.y));
                    edge_px = at_edge.x;
                    let d = x as f64 - at_edge.x;
                    if d < -1.0 {
                        assert!(!drawn, "{edge_x}: ({x}, {y}) drawn behind the real box");
                    } else if d > 1.0 {
                        assert_eq!(drawn, full, "{edge_x}: ({x}, {y}) hidden in the open");
                    }
                }
            }
            assert!(edge_px.is_finite());
        }
    }

    /// The automatic placement stands the object on the ground plane of a point set, upright,
    /// at the point most cameras see, with the requested height.
    #[test]
    fn auto_placement_stands_on_the_ground() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        // Ground z = 0 (world up +z), a wall at y = 4, cameras at z = 1.5 looking along +y.
        let mut points = Vec::new();
        for _ in 0..600 {
            let p = Point3::new(rng.random_range(-3.0..3.0), rng.random_range(0.0..4.0), 0.0);
            points.push((p, 5));
        }
        for _ in 0..900 {
            let p = Point3::new(rng.random_range(-3.0..3.0), 4.0, rng.random_range(0.0..2.5));
            points.push((p, 8));
        }
        let cams: Vec<Rigid3> = (0..5)
            .map(|i| {
                let c = Point3::new(-1.0 + 0.5 * f64::from(i), -3.0, 1.5);
                crate::path::look_at(&c, &Point3::new(0.0, 2.0, 0.3), &Vector3::z()).unwrap()
            })
            .collect();
        let (obj, _) = object_box();
        let (p, r) = auto_place(&obj, &points, &cams, &PlaceOptions::default()).unwrap();
        // The ground (a few wall points at its foot tilt the refit by a fraction of a degree).
        let n = Vector3::from(r.plane.normal);
        assert!((n - Vector3::z()).norm() < 0.01, "{n}");
        assert!(r.anchor[2].abs() < 0.01);
        // Upright on that plane: the object's +Y along its normal, its base on it.
        let up = p.rotation_matrix() * Vector3::y();
        assert!((up - n).norm() < 1e-9);
        let base = p.apply(&Point3::new(0.0, 0.0, 0.0));
        assert!((n.dot(&base.coords) - r.plane.d).abs() < 1e-9);
        let top = p.apply(&Point3::new(0.0, 1.0, 0.0));
        assert!((n.dot(&top.coords) - r.plane.d - r.height).abs() < 1e-9);
    }
}
