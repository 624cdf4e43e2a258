//! Combined image- and geometry-based rendering (§5.2): new views rendered straight from the
//! recorded images and their depth maps, with view-dependent geometry and no global surface.
//!
//! For each virtual view, [`support::build`] projects the recorded camera centres into it and
//! triangulates them with the image corners; every pixel is then coloured from the three
//! cameras of its triangle, with weights 1 at their own vertex and 0 at the others, interpolated
//! linearly (the paper's "sum of three triangles"), through one of the paper's geometries:
//! - [`IbrMethod::Plane`]: one fixed plane L, least-squares fitted to the scene (a homography
//!   `H_iV` per view);
//! - [`IbrMethod::Planes`]: one plane per triangle, through its corners' eq. 29 points;
//! - [`IbrMethod::Subdivided`]: triangles split into four while the depth inside departs from
//!   their plane;
//! - [`IbrMethod::Ulr`]: the subdivided geometry with the unstructured-lumigraph weights of
//!   Buehler et al. (2001) in place of the barycentric ones: angle and resolution penalties,
//!   field of view, the k best views, evaluated on a grid and interpolated.
//!
//! Colours are looked up bilinearly in the original (distorted) images: the radial distortion is
//! applied when a scene point is projected into a recorded view. A sample whose scene point is
//! hidden in that view (its depth map has a nearer surface there) is dropped.

pub mod source;
pub mod support;

use handheld_core::{Camera, FloatMap, PosedView, Rigid3};
use image::RgbImage;
use nalgebra::{Point3, Vector2, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use thiserror::Error;

pub use source::{fill_by_diffusion, Source};
use support::{Blend, Leaf, Root, SupportStats, Vertex, Virtual};

use crate::raster::Rendered;

/// The geometry and weights of a rendering.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum IbrMethod {
    /// One fixed plane for the whole scene (§5.2, "fixed plane approximation").
    Plane,
    /// One plane per triangle of the support mesh (eq. 29).
    Planes,
    /// Planes adaptively subdivided where the scene departs from them.
    Subdivided,
    /// Subdivided geometry, unstructured-lumigraph weights (Buehler et al. 2001).
    Ulr,
}

impl IbrMethod {
    pub const ALL: [IbrMethod; 4] = [Self::Plane, Self::Planes, Self::Subdivided, Self::Ulr];

    pub fn name(self) -> &'static str {
        match self {
            Self::Plane => "plane",
            Self::Planes => "planes",
            Self::Subdivided => "subdivided",
            Self::Ulr => "ulr",
        }
    }
}

/// Options of image-based rendering.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(default)]
pub struct IbrOptions {
    /// Split a triangle when its plane is off the scene by more than this, in source pixels.
    pub subdivision_px: f64,
    /// The deepest subdivision level (each level splits a triangle into four).
    pub max_subdivision: u32,
    /// Triangles are not split below this edge length (virtual pixels).
    pub min_triangle_px: f64,
    /// Iterations of the depth search along a virtual ray (§5.2: "computed iteratively").
    pub depth_iterations: usize,
    /// Samples of the ray march that takes over when the iteration does not settle.
    pub march_steps: usize,
    /// A sample is hidden in its view when its depth there exceeds the view's depth map by more
    /// than this fraction.
    pub occlusion_tolerance: f64,
    /// The k best views of the unstructured-lumigraph weights.
    pub ulr_k: usize,
    /// Weight of the resolution penalty against the angle penalty (Buehler's α).
    pub ulr_resolution_weight: f64,
    /// Spacing of the grid on which the unstructured-lumigraph weights are evaluated (pixels).
    pub ulr_grid_px: u32,
}

impl Default for IbrOptions {
    fn default() -> Self {
        Self {
            subdivision_px: 1.0,
            max_subdivision: 6,
            min_triangle_px: 4.0,
            depth_iterations: 12,
            march_steps: 96,
            occlusion_tolerance: 0.03,
            ulr_k: 3,
            ulr_resolution_weight: 0.1,
            ulr_grid_px: 16,
        }
    }
}

impl IbrOptions {
    /// Checks every option; the error names it.
    pub fn validate(&self) -> Result<(), IbrError> {
        let bad = |option: &'static str, reason: String| Err(IbrError::Option { option, reason });
        if !(self.subdivision_px.is_finite() && self.subdivision_px > 0.0) {
            return bad(
                "subdivision_px",
                format!("must be positive, got {}", self.subdivision_px),
            );
        }
        if self.max_subdivision > 10 {
            return bad(
                "max_subdivision",
                format!("must be at most 10, got {}", self.max_subdivision),
            );
        }
        if !(self.min_triangle_px.is_finite() && self.min_triangle_px >= 1.0) {
            return bad(
                "min_triangle_px",
                format!("must be at least 1, got {}", self.min_triangle_px),
            );
        }
        if !(1..=support::MAX_BLEND).contains(&self.ulr_k) {
            return bad(
                "ulr_k",
                format!(
                    "must be between 1 and {}, got {}",
                    support::MAX_BLEND,
                    self.ulr_k
                ),
            );
        }
        if !(self.occlusion_tolerance.is_finite() && self.occlusion_tolerance >= 0.0) {
            return bad(
                "occlusion_tolerance",
                format!("must be zero or positive, got {}", self.occlusion_tolerance),
            );
        }
        if self.ulr_grid_px < 2 {
            return bad(
                "ulr_grid_px",
                format!("must be at least 2, got {}", self.ulr_grid_px),
            );
        }
        Ok(())
    }
}

/// What went wrong in image-based rendering.
#[derive(Debug, Error)]
pub enum IbrError {
    #[error("option {option}: {reason}")]
    Option {
        option: &'static str,
        reason: String,
    },
    #[error("image-based rendering needs at least one recorded view")]
    NoViews,
    #[error("{0}")]
    View(#[from] handheld_core::ViewError),
    #[error("no scene plane: fewer than three scene points and no depth map")]
    NoPlane,
    #[error("virtual camera: {0}")]
    Camera(String),
}

/// A plane `n · X + d = 0`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Plane {
    pub n: Vector3<f64>,
    pub d: f64,
}

impl Plane {
    /// The plane through three points; `None` when they are (nearly) collinear.
    pub fn through(p: &[Vector3<f64>; 3]) -> Option<Self> {
        let n = (p[1] - p[0]).cross(&(p[2] - p[0]));
        let scale = (p[1] - p[0]).norm() * (p[2] - p[0]).norm();
        if !(n.norm() > 1e-9 * scale && scale > 0.0) {
            return None;
        }
        let n = n.normalize();
        Some(Self {
            n,
            d: -n.dot(&p[0]),
        })
    }

    /// `λ > 0` with `n · (c + λ dir) + d = 0`.
    #[inline]
    pub fn ray_parameter(&self, c: &Vector3<f64>, dir: &Vector3<f64>) -> Option<f64> {
        let den = self.n.dot(dir);
        let lambda = -(self.n.dot(c) + self.d) / den;
        (lambda.is_finite() && lambda > 0.0).then_some(lambda)
    }
}

/// The recorded views of a scene, prepared for rendering, and its fixed plane L.
pub struct IbrScene {
    pub sources: Vec<Source>,
    pub plane: Plane,
    /// A box around the scene (2nd to 98th percentiles of its points, widened by a quarter).
    pub bounds: (Point3<f64>, Point3<f64>),
    /// Whether any view has a depth map (without, only [`IbrMethod::Plane`] is meaningful).
    pub has_depth: bool,
}

impl IbrScene {
    /// Prepares `views` (depth maps optional) for rendering. The fixed plane L is least-squares
    /// fitted to `points` (the sparse points), or to the depth maps' points when fewer than 3 are
    /// given.
    pub fn new(views: &[PosedView], points: &[Point3<f64>]) -> Result<Self, IbrError> {
        if views.is_empty() {
            return Err(IbrError::NoViews);
        }
        for v in views {
            v.validate()?;
        }
        let sources: Vec<Source> = views.par_iter().map(Source::new).collect();
        let has_depth = sources.iter().any(Source::has_depth);
        let samples = if points.len() >= 3 {
            points.to_vec()
        } else {
            depth_samples(views)
        };
        let bounds = robust_bounds(&samples);
        // The least-squares plane of the points inside the percentile box (far outliers of a
        // sparse model would tilt it).
        let inner: Vec<Point3<f64>> = {
            let (lo, hi) = (bounds.0, bounds.1);
            let m = (hi - lo) / 6.0; // undo the widening by a quarter on each side
            samples
                .iter()
                .filter(|p| (0..3).all(|k| p[k] >= lo[k] + m[k] && p[k] <= hi[k] - m[k]))
                .copied()
                .collect()
        };
        let plane = support::fit_plane(if inner.len() >= 3 { &inner } else { &samples })
            .ok_or(IbrError::NoPlane)?;
        Ok(Self {
            sources,
            plane,
            bounds,
            has_depth,
        })
    }

    /// The centroid of the scene points used for paths: the median of the depth maps' points
    /// when there are some, else the point of the plane nearest the cameras' centroid.
    pub fn focus(&self, points: &[Point3<f64>]) -> Point3<f64> {
        if points.is_empty() {
            let c = self
                .sources
                .iter()
                .fold(Vector3::zeros(), |a, s| a + s.center.coords)
                / self.sources.len() as f64;
            let off = self.plane.n.dot(&c) + self.plane.d;
            return Point3::from(c - self.plane.n * off);
        }
        let med = |k: usize| {
            let mut v: Vec<f64> = points.iter().map(|p| p[k]).collect();
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        Point3::new(med(0), med(1), med(2))
    }
}

/// The 2nd and 98th percentiles of the points along each axis, widened by a quarter of the
/// extent on each side.
fn robust_bounds(points: &[Point3<f64>]) -> (Point3<f64>, Point3<f64>) {
    let mut lo = Point3::origin();
    let mut hi = Point3::origin();
    for k in 0..3 {
        let mut v: Vec<f64> = points.iter().map(|p| p[k]).collect();
        v.sort_by(f64::total_cmp);
        let a = v[v.len() * 2 / 100];
        let b = v[(v.len() * 98 / 100).min(v.len() - 1)];
        let m = 0.25 * (b - a);
        lo[k] = a - m;
        hi[k] = b + m;
    }
    (lo, hi)
}

/// The range of virtual-camera depths of the scene box: (near, far).
fn depth_range(virt: &Virtual, bounds: &(Point3<f64>, Point3<f64>)) -> (f64, f64) {
    let (lo, hi) = bounds;
    let mut zmin = f64::INFINITY;
    let mut zmax = f64::NEG_INFINITY;
    for i in 0..8 {
        let c = Vector3::new(
            if i & 1 == 0 { lo.x } else { hi.x },
            if i & 2 == 0 { lo.y } else { hi.y },
            if i & 4 == 0 { lo.z } else { hi.z },
        );
        let z = (virt.r * c + virt.t).z;
        zmin = zmin.min(z);
        zmax = zmax.max(z);
    }
    let diag = (hi - lo).norm();
    let far = zmax.max(1e-3 * diag);
    (zmin.max(1e-2 * far), far)
}

/// Points of the views' depth maps on a coarse grid.
fn depth_samples(views: &[PosedView]) -> Vec<Point3<f64>> {
    let mut out = Vec::new();
    for v in views {
        let Some(d) = &v.depth else { continue };
        let step = (d.width.max(d.height) / 32).max(1);
        let world_from_cam = v.cam_from_world.inverse();
        for y in (0..d.height).step_by(step) {
            for x in (0..d.width).step_by(step) {
                let z = f64::from(d.get(x, y, 0));
                if z.is_finite() && z > 0.0 {
                    let ray = v.camera.ray_in_cam(Vector2::new(x as f64, y as f64));
                    let p = Point3::from(ray / ray.z * z);
                    out.push(world_from_cam.transform_point(&p));
                }
            }
        }
    }
    out
}

/// What one rendering did.
#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize)]
pub struct FrameStats {
    /// Recorded camera centres that became vertices.
    pub cameras: usize,
    /// Delaunay triangles and drawn triangles (after subdivision).
    pub triangles: usize,
    pub leaves: usize,
    pub covered_fraction: f64,
    pub seconds: f64,
    /// Of which the support mesh (triangulation, depth searches, subdivision).
    pub seconds_support: f64,
}

/// Renders virtual views of one scene; keeps its buffers from frame to frame.
#[derive(Default)]
pub struct Renderer {
    vertices: Vec<Vertex>,
    roots: Vec<Root>,
    leaves: Vec<Leaf>,
    /// Leaf index per ideal pixel of the domain.
    ids: Vec<u32>,
    /// Ideal pixel of each output pixel, for a distorted virtual camera (keyed by its camera).
    ideal: Vec<Vector2<f32>>,
    ideal_of: Option<Camera>,
    /// Unstructured-lumigraph weights on a grid.
    grid: Vec<Blend>,
    /// Sources by distance from the virtual centre (the fallback order).
    order: Vec<usize>,
}

impl Renderer {
    pub fn new() -> Self {
        Self::default()
    }

    /// Renders `scene` through `camera` at `cam_from_world` into `out` (resized to the camera).
    pub fn render_into(
        &mut self,
        scene: &IbrScene,
        camera: &Camera,
        cam_from_world: &Rigid3,
        method: IbrMethod,
        opts: &IbrOptions,
        out: &mut Rendered,
    ) -> Result<FrameStats, IbrError> {
        self.render_with_proxy(scene, camera, cam_from_world, method, opts, None, out)
    }

    /// [`Self::render_into`] with a geometric proxy: the camera-frame depth of every output
    /// pixel (e.g. the reconstructed mesh rendered from the virtual camera; `NaN` where it has
    /// none). Where the proxy has a depth, it replaces the support mesh's planes (Buehler et al.
    /// 2001 render with such a proxy); elsewhere the planes stay.
    #[allow(clippy::too_many_arguments)]
    pub fn render_with_proxy(
        &mut self,
        scene: &IbrScene,
        camera: &Camera,
        cam_from_world: &Rigid3,
        method: IbrMethod,
        opts: &IbrOptions,
        proxy: Option<&FloatMap>,
        out: &mut Rendered,
    ) -> Result<FrameStats, IbrError> {
        if let Some(p) = proxy {
            if (p.width, p.height) != (camera.width as usize, camera.height as usize) {
                return Err(IbrError::Camera(format!(
                    "the proxy depth is {}x{} but the camera {}x{}",
                    p.width, p.height, camera.width, camera.height
                )));
            }
        }
        let start = std::time::Instant::now();
        camera.intrinsics.validate().map_err(IbrError::Camera)?;
        let (w, h) = (camera.width as usize, camera.height as usize);
        if w == 0 || h == 0 {
            return Err(IbrError::Camera("zero-sized image".into()));
        }
        let mut k = camera.intrinsics;
        k.k1 = 0.0;
        k.k2 = 0.0;
        let km = k.k_matrix();
        let k_inv = km
            .try_inverse()
            .ok_or_else(|| IbrError::Camera("singular calibration matrix".into()))?;
        let r = *cam_from_world.rotation.to_rotation_matrix().matrix();
        let t = cam_from_world.translation.vector;
        let virt = Virtual {
            k: km,
            r,
            t,
            center: -(r.transpose() * t),
            d: r.transpose() * k_inv,
        };
        // The ideal pixels of the output pixels, and their bounding rectangle.
        let distorted = !camera.intrinsics.is_undistorted();
        if distorted && self.ideal_of.as_ref() != Some(camera) {
            self.ideal = (0..w * h)
                .into_par_iter()
                .map(|i| {
                    let px = Vector2::new((i % w) as f64, (i / w) as f64);
                    let n = camera.intrinsics.pixel_to_normalized(px);
                    let q = km * Vector3::new(n.x, n.y, 1.0);
                    Vector2::new(q.x as f32, q.y as f32)
                })
                .collect();
            self.ideal_of = Some(camera.clone());
        }
        let (lo, hi) = if distorted {
            self.ideal.iter().fold(
                (
                    Vector2::repeat(f64::INFINITY),
                    Vector2::repeat(f64::NEG_INFINITY),
                ),
                |(lo, hi), p| {
                    let p = p.cast::<f64>();
                    (lo.inf(&p), hi.sup(&p))
                },
            )
        } else {
            (
                Vector2::zeros(),
                Vector2::new((w - 1) as f64, (h - 1) as f64),
            )
        };
        let (lo, hi) = (lo.map(|v| v.floor() - 1.0), hi.map(|v| v.ceil() + 1.0));
        let t_support = std::time::Instant::now();
        let support = support::build(
            &virt,
            (lo, hi),
            &scene.sources,
            &scene.plane,
            depth_range(&virt, &scene.bounds),
            method,
            opts,
            &mut self.vertices,
            &mut self.roots,
            &mut self.leaves,
        );
        let seconds_support = t_support.elapsed().as_secs_f64();
        // Leaf index per ideal pixel.
        let (dw, dh) = ((hi.x - lo.x) as usize + 1, (hi.y - lo.y) as usize + 1);
        self.ids.clear();
        self.ids.resize(dw * dh, u32::MAX);
        for (li, leaf) in self.leaves.iter().enumerate() {
            raster_ids(leaf, li as u32, lo, dw, dh, &mut self.ids);
        }
        // The fallback order: sources by distance.
        self.order.clear();
        self.order.extend(0..scene.sources.len());
        let c = virt.center;
        self.order.sort_by(|&a, &b| {
            let da = (scene.sources[a].center.coords - c).norm_squared();
            let db = (scene.sources[b].center.coords - c).norm_squared();
            da.total_cmp(&db)
        });
        let g = opts.ulr_grid_px as usize;
        let (gw, gh) = (dw.div_ceil(g) + 1, dh.div_ceil(g) + 1);
        if method == IbrMethod::Ulr {
            self.grid.clear();
            self.grid.resize(gw * gh, Blend::default());
            let ids = &self.ids;
            let leaves = &self.leaves;
            self.grid.par_iter_mut().enumerate().for_each(|(i, b)| {
                let p = Vector2::new(lo.x + ((i % gw) * g) as f64, lo.y + ((i / gw) * g) as f64);
                let cx = ((p.x - lo.x) as usize).min(dw - 1);
                let cy = ((p.y - lo.y) as usize).min(dh - 1);
                let leaf = ids[cy * dw + cx];
                let plane = leaves.get(leaf as usize).map_or(scene.plane, |l| l.plane);
                if let Some((x, _)) = virt.hit(&p, &plane) {
                    *b = ulr_blend(&virt, &x, &scene.sources, opts);
                }
            });
        }
        // Shade.
        if out.image.width() != camera.width || out.image.height() != camera.height {
            out.image = RgbImage::new(camera.width, camera.height);
            out.covered = vec![false; w * h];
            out.depth = FloatMap::filled(w, h, 1, f32::NAN);
        }
        let ctx = Shade {
            scene,
            virt: &virt,
            method,
            opts,
            lo,
            dw,
            dh,
            ids: &self.ids,
            leaves: &self.leaves,
            roots: &self.roots,
            vertices: &self.vertices,
            grid: (&self.grid, gw, g),
            order: &self.order,
            ideal: distorted.then_some(&self.ideal[..]),
            proxy,
        };
        let Rendered {
            image,
            covered,
            depth,
        } = out;
        let rows: &mut [u8] = &mut **image;
        rows.par_chunks_mut(3 * w)
            .zip(covered.par_chunks_mut(w))
            .zip(depth.data.par_chunks_mut(w))
            .enumerate()
            .for_each(|(y, ((rgb, cov), dep))| {
                for x in 0..w {
                    match ctx.pixel(x, y, w) {
                        Some((c, z)) => {
                            for k in 0..3 {
                                rgb[3 * x + k] = c[k].round().clamp(0.0, 255.0) as u8;
                            }
                            cov[x] = true;
                            dep[x] = z as f32;
                        }
                        None => {
                            rgb[3 * x..3 * x + 3].fill(0);
                            cov[x] = false;
                            dep[x] = f32::NAN;
                        }
                    }
                }
            });
        let covered_n = out.covered.iter().filter(|c| **c).count();
        Ok(FrameStats {
            cameras: support_cameras(&support),
            triangles: support.roots,
            leaves: support.leaves,
            covered_fraction: covered_n as f64 / (w * h) as f64,
            seconds: start.elapsed().as_secs_f64(),
            seconds_support,
        })
    }

    /// Renders one view into a new image.
    pub fn render(
        &mut self,
        scene: &IbrScene,
        camera: &Camera,
        cam_from_world: &Rigid3,
        method: IbrMethod,
        opts: &IbrOptions,
    ) -> Result<(Rendered, FrameStats), IbrError> {
        let mut out = Rendered {
            image: RgbImage::new(0, 0),
            covered: Vec::new(),
            depth: FloatMap::filled(0, 0, 1, 0.0),
        };
        let s = self.render_into(scene, camera, cam_from_world, method, opts, &mut out)?;
        Ok((out, s))
    }
}

fn support_cameras(s: &SupportStats) -> usize {
    s.cameras
}

/// Writes `id` into every ideal pixel (integer positions offset by `lo`) inside `leaf`.
fn raster_ids(leaf: &Leaf, id: u32, lo: Vector2<f64>, dw: usize, dh: usize, ids: &mut [u32]) {
    let [a, b, c] = leaf.p.map(|p| p - lo);
    let area = (b - a).perp(&(c - a));
    if area.abs() < 1e-12 {
        return;
    }
    let x0 = a.x.min(b.x).min(c.x).floor().max(0.0) as usize;
    let y0 = a.y.min(b.y).min(c.y).floor().max(0.0) as usize;
    let x1 = (a.x.max(b.x).max(c.x).ceil().max(0.0) as usize).min(dw - 1);
    let y1 = (a.y.max(b.y).max(c.y).ceil().max(0.0) as usize).min(dh - 1);
    let eps = -1e-9 * area.abs();
    for y in y0..=y1 {
        for x in x0..=x1 {
            let p = Vector2::new(x as f64, y as f64);
            let l0 = (b - p).perp(&(c - p)) * area.signum();
            let l1 = (c - p).perp(&(a - p)) * area.signum();
            let l2 = (a - p).perp(&(b - p)) * area.signum();
            if l0 >= eps && l1 >= eps && l2 >= eps {
                ids[y * dw + x] = id;
            }
        }
    }
}

/// Buehler et al. (2001), §4: the penalty of each view at a scene point is its angle to the
/// virtual ray plus α times its resolution penalty (how much farther it is than the virtual
/// camera, relative); views that do not see the point are out. The k best keep weights
/// `1 − p / p_k+1`, normalised.
fn ulr_blend(virt: &Virtual, x: &Vector3<f64>, sources: &[Source], opts: &IbrOptions) -> Blend {
    let dv = x - virt.center;
    let lv = dv.norm();
    let mut best: [(f64, usize); support::MAX_BLEND + 1] =
        [(f64::INFINITY, usize::MAX); support::MAX_BLEND + 1];
    let k = opts.ulr_k;
    for (i, s) in sources.iter().enumerate() {
        let y = s.to_cam(x);
        let Some(px) = s.pixel_of_cam(&y) else {
            continue;
        };
        if let Some(d) = s.depth_at(&px) {
            if y.z > d * (1.0 + opts.occlusion_tolerance) {
                continue;
            }
        }
        let ds = x - s.center.coords;
        let ls = ds.norm();
        let angle = (dv.dot(&ds) / (lv * ls)).clamp(-1.0, 1.0).acos();
        let res = ((ls - lv) / lv).max(0.0);
        let p = (1.0 - opts.ulr_resolution_weight) * angle + opts.ulr_resolution_weight * res;
        // Insert into the sorted k+1 best.
        let mut j = k;
        if p >= best[j].0 {
            continue;
        }
        best[j] = (p, i);
        while j > 0 && best[j].0 < best[j - 1].0 {
            best.swap(j, j - 1);
            j -= 1;
        }
    }
    let mut b = Blend::default();
    let thresh = best[k].0;
    let mut sum = 0.0;
    let mut raw = [0.0f64; support::MAX_BLEND];
    for j in 0..k {
        if best[j].1 == usize::MAX {
            break;
        }
        raw[j] = if thresh.is_finite() {
            (1.0 - best[j].0 / thresh.max(1e-12)).max(0.0)
        } else {
            1.0
        };
        sum += raw[j];
    }
    if sum <= 0.0 {
        if best[0].1 != usize::MAX {
            b.push(best[0].1, 1.0);
        }
        return b;
    }
    for j in 0..k {
        if best[j].1 != usize::MAX && raw[j] > 0.0 {
            b.push(best[j].1, (raw[j] / sum) as f32);
        }
    }
    b
}

/// A weighted colour sum.
#[derive(Clone, Copy, Default)]
struct Sum {
    colour: [f32; 3],
    weight: f32,
}

impl Sum {
    #[inline]
    fn add(&mut self, c: [f32; 3], w: f32) {
        for k in 0..3 {
            self.colour[k] += w * c[k];
        }
        self.weight += w;
    }
}

#[derive(Clone, Copy, Default)]
struct Acc {
    visible: Sum,
    all: Sum,
}

/// Everything the per-pixel loop reads.
struct Shade<'a> {
    scene: &'a IbrScene,
    virt: &'a Virtual,
    method: IbrMethod,
    opts: &'a IbrOptions,
    lo: Vector2<f64>,
    dw: usize,
    dh: usize,
    ids: &'a [u32],
    leaves: &'a [Leaf],
    roots: &'a [Root],
    vertices: &'a [Vertex],
    grid: (&'a [Blend], usize, usize),
    order: &'a [usize],
    ideal: Option<&'a [Vector2<f32>]>,
    proxy: Option<&'a FloatMap>,
}

impl Shade<'_> {
    /// The colour and virtual-camera depth of output pixel (x, y).
    #[inline]
    fn pixel(&self, x: usize, y: usize, w: usize) -> Option<([f32; 3], f64)> {
        let p = match self.ideal {
            Some(t) => t[y * w + x].cast::<f64>(),
            None => Vector2::new(x as f64, y as f64),
        };
        let cx = ((p.x - self.lo.x).round().max(0.0) as usize).min(self.dw - 1);
        let cy = ((p.y - self.lo.y).round().max(0.0) as usize).min(self.dh - 1);
        let li = self.ids[cy * self.dw + cx];
        let leaf = self.leaves.get(li as usize)?;
        let dir = self.virt.ray(&p);
        let from_proxy = self
            .proxy
            .map(|d| f64::from(d.data[y * w + x]))
            .filter(|z| z.is_finite() && *z > 0.0);
        let lambda = match from_proxy {
            Some(z) => z,
            None => leaf.plane.ray_parameter(&self.virt.center, &dir)?,
        };
        let xw = self.virt.center + dir * lambda;
        let z = lambda; // ray direction has unit z in the virtual camera (K⁻¹ p̃).
                        // Samples whose point is visible in their view, and all samples (used when every view
                        // hides the point: the geometry is then off, and a ghost beats a hole).
        let mut acc = Acc::default();
        let check = matches!(self.method, IbrMethod::Subdivided | IbrMethod::Ulr);
        let sample = |s: usize, wt: f32, acc: &mut Acc| {
            if wt <= 1e-4 {
                return;
            }
            let src = &self.scene.sources[s];
            let yc = src.to_cam(&xw);
            let Some(px) = src.pixel_of_cam(&yc) else {
                return;
            };
            let c = src.colour(&px);
            acc.all.add(c, wt);
            if check {
                if let Some(d) = src.depth_at(&px) {
                    if yc.z > d * (1.0 + self.opts.occlusion_tolerance) {
                        return;
                    }
                }
            }
            acc.visible.add(c, wt);
        };
        if self.method == IbrMethod::Ulr {
            let (grid, gw, g) = self.grid;
            let gx = (p.x - self.lo.x) / g as f64;
            let gy = (p.y - self.lo.y) / g as f64;
            let (ix, iy) = (gx.floor().max(0.0) as usize, gy.floor().max(0.0) as usize);
            let ix = ix.min(gw - 2);
            let iy = iy.min(grid.len() / gw - 2);
            let (fx, fy) = ((gx - ix as f64) as f32, (gy - iy as f64) as f32);
            let corners = [
                (ix, iy, (1.0 - fx) * (1.0 - fy)),
                (ix + 1, iy, fx * (1.0 - fy)),
                (ix, iy + 1, (1.0 - fx) * fy),
                (ix + 1, iy + 1, fx * fy),
            ];
            // Merge the corners' views (each sampled once).
            let mut srcs = [(usize::MAX, 0.0f32); 4 * support::MAX_BLEND];
            let mut n = 0;
            for (gx, gy, cw) in corners {
                for (s, wt) in grid[gy * gw + gx].iter() {
                    match srcs[..n].iter_mut().find(|e| e.0 == s) {
                        Some(e) => e.1 += cw * wt,
                        None => {
                            srcs[n] = (s, cw * wt);
                            n += 1;
                        }
                    }
                }
            }
            for &(s, wt) in &srcs[..n] {
                sample(s, wt, &mut acc);
            }
        } else {
            let root = &self.roots[leaf.root as usize];
            let bary = root.bary * Vector3::new(p.x, p.y, 1.0);
            // Corners that share a view are sampled once, with their weights summed.
            let mut srcs = [(usize::MAX, 0.0f32); 3 * support::MAX_BLEND];
            let mut n = 0;
            for (j, &vi) in root.v.iter().enumerate() {
                let wv = bary[j].clamp(0.0, 1.0) as f32;
                for (s, wt) in self.vertices[vi].blend.iter() {
                    match srcs[..n].iter_mut().find(|e| e.0 == s) {
                        Some(e) => e.1 += wv * wt,
                        None => {
                            srcs[n] = (s, wv * wt);
                            n += 1;
                        }
                    }
                }
            }
            for &(s, wt) in &srcs[..n] {
                sample(s, wt, &mut acc);
            }
        }
        if acc.visible.weight <= 1e-3 {
            // No triangle camera sees the point: the nearest view that does.
            let all = acc.all;
            acc = Acc::default();
            for &s in self.order.iter().take(8) {
                sample(s, 1.0, &mut acc);
                if acc.visible.weight > 0.0 {
                    break;
                }
            }
            if acc.visible.weight <= 0.0 {
                acc.visible = if all.weight > 1e-3 { all } else { acc.all };
            }
        }
        let v = acc.visible;
        (v.weight > 0.0).then(|| (v.colour.map(|c| c / v.weight), z))
    }
}
