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

mod scene;
mod shade;
pub mod source;
pub mod support;
mod ulr;

use handheld_core::{Camera, FloatMap, PosedCamera};
use image::RgbImage;
use nalgebra::{Matrix3, Vector2, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use thiserror::Error;

use scene::depth_range;
pub use scene::IbrScene;
use shade::{raster_ids, Shade};
pub use source::{fill_by_diffusion, Source};
use support::{Blend, Leaf, Root, Vertex, Virtual};
use ulr::ulr_blend;

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

    /// Renders `scene` seen by `view` into `out` (resized to the camera).
    pub fn render_into(
        &mut self,
        scene: &IbrScene,
        view: &PosedCamera,
        method: IbrMethod,
        opts: &IbrOptions,
        out: &mut Rendered,
    ) -> Result<FrameStats, IbrError> {
        self.render_with_proxy(scene, view, method, opts, None, out)
    }

    /// [`Self::render_into`] with a geometric proxy: the camera-frame depth of every output
    /// pixel (e.g. the reconstructed mesh rendered from the virtual camera; `NaN` where it has
    /// none). Where the proxy has a depth, it replaces the support mesh's planes (Buehler et al.
    /// 2001 render with such a proxy); elsewhere the planes stay.
    pub fn render_with_proxy(
        &mut self,
        scene: &IbrScene,
        view: &PosedCamera,
        method: IbrMethod,
        opts: &IbrOptions,
        proxy: Option<&FloatMap>,
        out: &mut Rendered,
    ) -> Result<FrameStats, IbrError> {
        let camera = &view.camera;
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
        let virt = virtual_of(view)?;
        // The ideal pixels of the output pixels, and their bounding rectangle.
        let distorted = !camera.intrinsics.is_undistorted();
        let (lo, hi) = self.ideal_bounds(camera, &virt.k, distorted);
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
            self.ulr_grid(scene, &virt, opts, lo, (dw, dh), (gw, gh));
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
        let rows: &mut [u8] = image;
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
            cameras: support.cameras,
            triangles: support.roots,
            leaves: support.leaves,
            covered_fraction: covered_n as f64 / (w * h) as f64,
            seconds: start.elapsed().as_secs_f64(),
            seconds_support,
        })
    }

    /// The ideal (undistorted) pixel of every output pixel, kept while the camera is the same, and
    /// the bounding rectangle of the ideal pixels, one pixel wider on each side.
    fn ideal_bounds(
        &mut self,
        camera: &Camera,
        km: &Matrix3<f64>,
        distorted: bool,
    ) -> (Vector2<f64>, Vector2<f64>) {
        let (w, h) = (camera.width as usize, camera.height as usize);
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
        (lo.map(|v| v.floor() - 1.0), hi.map(|v| v.ceil() + 1.0))
    }

    /// The unstructured-lumigraph blend at every `g`-th ideal pixel (the ULR grid), on the plane of
    /// the support-mesh leaf under it.
    fn ulr_grid(
        &mut self,
        scene: &IbrScene,
        virt: &Virtual,
        opts: &IbrOptions,
        lo: Vector2<f64>,
        (dw, dh): (usize, usize),
        (gw, gh): (usize, usize),
    ) {
        let g = opts.ulr_grid_px as usize;
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
                *b = ulr_blend(virt, &x, &scene.sources, opts);
            }
        });
    }

    /// Renders one view into a new image.
    pub fn render(
        &mut self,
        scene: &IbrScene,
        view: &PosedCamera,
        method: IbrMethod,
        opts: &IbrOptions,
    ) -> Result<(Rendered, FrameStats), IbrError> {
        let mut out = Rendered {
            image: RgbImage::new(0, 0),
            covered: Vec::new(),
            depth: FloatMap::filled(0, 0, 1, 0.0),
        };
        let s = self.render_into(scene, view, method, opts, &mut out)?;
        Ok((out, s))
    }
}

/// The virtual camera as matrices in ideal (undistorted) pixels.
fn virtual_of(view: &PosedCamera) -> Result<Virtual, IbrError> {
    let (camera, cam_from_world) = (&view.camera, &view.cam_from_world);
    let mut k = camera.intrinsics;
    k.k1 = 0.0;
    k.k2 = 0.0;
    let km = k.k_matrix();
    let k_inv = km
        .try_inverse()
        .ok_or_else(|| IbrError::Camera("singular calibration matrix".into()))?;
    let r = *cam_from_world.rotation.to_rotation_matrix().matrix();
    let t = cam_from_world.translation.vector;
    Ok(Virtual {
        k: km,
        r,
        t,
        center: -(r.transpose() * t),
        d: r.transpose() * k_inv,
    })
}
