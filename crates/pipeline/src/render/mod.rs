//! Rendering a workspace's new views (§5.2): the recorded views and their depth maps loaded as an
//! [`IbrScene`], one view rendered to a PNG, a camera path rendered to an H.264 video, and the
//! textured mesh through the rasteriser as the geometry-based alternative.
//!
//! A workspace without dense depth maps falls back to the fixed plane, with a warning.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use handheld_core::{Camera, PosedCamera, PosedView, Rigid3, TriMesh};
use handheld_io::dense_folder::{read_views, MapKind};
use handheld_render::{IbrMethod, IbrOptions, IbrScene, Rendered, Renderer};
use image::RgbImage;
use nalgebra::Point3;
use serde::{Deserialize, Serialize};

use crate::error::{PipelineError, Result};
use crate::files::{stage, MODEL_GLB};
use crate::manifest::Workspace;

mod flight;
mod view;

pub use flight::{flight_poses, render_flight, FlightOptions, FlightSummary, PathKind};
pub use view::{render_view, PoseFile, ViewSpec, ViewSummary};

/// How a view is rendered: one of the image-based methods, or the textured mesh.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RenderMethod {
    Plane,
    Planes,
    Subdivided,
    Ulr,
    /// Unstructured-lumigraph weights with the reconstructed mesh as the geometric proxy where
    /// it covers the view (the subdivided planes elsewhere).
    UlrMesh,
    /// The mesh stage's textured model through the rasteriser.
    Mesh,
}

impl RenderMethod {
    pub const ALL: [RenderMethod; 6] = [
        Self::Plane,
        Self::Planes,
        Self::Subdivided,
        Self::Ulr,
        Self::UlrMesh,
        Self::Mesh,
    ];

    pub fn name(self) -> &'static str {
        match (self, self.ibr()) {
            (Self::UlrMesh, _) => "ulr_mesh",
            (_, Some(m)) => m.name(),
            _ => "mesh",
        }
    }

    pub fn ibr(self) -> Option<IbrMethod> {
        match self {
            Self::Plane => Some(IbrMethod::Plane),
            Self::Planes => Some(IbrMethod::Planes),
            Self::Subdivided => Some(IbrMethod::Subdivided),
            Self::Ulr | Self::UlrMesh => Some(IbrMethod::Ulr),
            Self::Mesh => None,
        }
    }

    pub fn parse(s: &str) -> Result<Self> {
        Self::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| {
                PipelineError::option(
                    "--method",
                    format!("unknown method `{s}`; use plane, planes, subdivided, ulr, ulr_mesh or mesh"),
                )
            })
    }
}

/// The default method (measured by `handheld bench render`; see the README).
pub const DEFAULT_METHOD: RenderMethod = RenderMethod::UlrMesh;

/// The recorded views of a workspace, ready for rendering.
pub struct RenderScene {
    pub scene: IbrScene,
    /// Every recorded view: name, camera (at the rendering resolution) and pose, in name order.
    pub views: Vec<(String, Camera, Rigid3)>,
    /// The sparse points (paths look at their median).
    pub points: Vec<Point3<f64>>,
    /// The textured mesh, when the mesh stage ran.
    pub mesh: Option<(TriMesh, Option<RgbImage>)>,
    pub warnings: Vec<String>,
}

impl RenderScene {
    /// Loads the workspace's dense views (or, without a dense stage, the sparse model's views and
    /// images at most `max_size` pixels wide, with the fixed plane only) and its textured mesh,
    /// leaving out `exclude`.
    pub fn load(ws: &Workspace, exclude: &[String], max_size: u32) -> Result<Self> {
        let rec = ws.read_sparse_model()?;
        let paths = ws.image_paths()?;
        Self::from_folders(
            &rec,
            &paths,
            &ws.root.join(stage::DENSE),
            Some(&ws.path(stage::MESH, MODEL_GLB)),
            exclude,
            max_size,
        )
    }

    /// [`Self::load`] on a sparse model, its images, a dense folder and a textured model (each
    /// used when it exists).
    pub fn from_folders(
        rec: &handheld_core::MetricReconstruction,
        paths: &BTreeMap<String, PathBuf>,
        dense: &Path,
        mesh_glb: Option<&Path>,
        exclude: &[String],
        max_size: u32,
    ) -> Result<Self> {
        let points: Vec<Point3<f64>> = rec.points.values().map(|p| p.xyz).collect();
        let mut warnings = Vec::new();
        let views: Vec<PosedView> = if dense.join(handheld_io::dense_folder::CAMERAS_FILE).exists()
        {
            read_views(dense, |n| paths.get(n).cloned(), &[MapKind::Depth])?
        } else {
            warnings.push(
                "no dense depth maps in the workspace (run `handheld reconstruct` through the dense stage): \
                 every method falls back to the fixed plane"
                    .into(),
            );
            load_sparse_views(rec, paths, max_size)?
        };
        let views: Vec<PosedView> = views
            .into_iter()
            .filter(|v| !exclude.contains(&v.name))
            .collect();
        if views.is_empty() {
            return Err(PipelineError::workspace(
                dense,
                "no recorded view to render from (is every view held out?)",
            ));
        }
        let scene = IbrScene::new(&views, &points)
            .map_err(|e| PipelineError::workspace(dense, e.to_string()))?;
        let mut all: Vec<(String, Camera, Rigid3)> = views
            .iter()
            .map(|v| {
                (
                    v.name.clone(),
                    v.posed.camera.clone(),
                    v.posed.cam_from_world,
                )
            })
            .collect();
        all.sort_by(|a, b| a.0.cmp(&b.0));
        let mesh = match mesh_glb {
            Some(glb) if glb.exists() => Some(handheld_io::glb::read_glb(glb)?),
            _ => None,
        };
        Ok(Self {
            scene,
            views: all,
            points,
            mesh,
            warnings,
        })
    }

    /// Whether a method can use its geometry here (else it falls back to the fixed plane).
    pub fn effective(&self, method: RenderMethod) -> RenderMethod {
        match method {
            RenderMethod::Mesh => method,
            _ if !self.scene.has_depth => RenderMethod::Plane,
            RenderMethod::UlrMesh if self.mesh.is_none() => RenderMethod::Ulr,
            _ => method,
        }
    }

    /// Renders one view with `method` into `out`.
    pub fn render(
        &self,
        renderer: &mut Renderer,
        camera: &Camera,
        pose: &Rigid3,
        method: RenderMethod,
        opts: &IbrOptions,
        out: &mut Rendered,
    ) -> Result<Option<handheld_render::FrameStats>> {
        let method = self.effective(method);
        let view = PosedCamera::new(camera.clone(), *pose);
        match method.ibr() {
            Some(m) => {
                let proxy = match (&self.mesh, method) {
                    (Some((mesh, _)), RenderMethod::UlrMesh) => {
                        Some(handheld_render::render_mesh(mesh, None, &view).depth)
                    }
                    _ => None,
                };
                let stats = renderer
                    .render_with_proxy(&self.scene, &view, m, opts, proxy.as_ref(), out)
                    .map_err(|e| PipelineError::option("--method", e.to_string()))?;
                Ok(Some(stats))
            }
            None => {
                let (mesh, tex) = self.mesh.as_ref().ok_or_else(|| {
                    PipelineError::option(
                        "--method",
                        "mesh: the workspace has no textured mesh (run the mesh stage first)",
                    )
                })?;
                *out = handheld_render::render_mesh(mesh, tex.as_ref(), &view);
                Ok(None)
            }
        }
    }
}

/// The sparse model's views with their images (no depth), downscaled to `max_size`.
fn load_sparse_views(
    rec: &handheld_core::MetricReconstruction,
    paths: &BTreeMap<String, PathBuf>,
    max_size: u32,
) -> Result<Vec<PosedView>> {
    let opts = handheld_io::images::ImageIngestOptions {
        min_dimension: 1,
        ..Default::default()
    };
    rec.views
        .values()
        .map(|v| {
            let path = paths.get(&v.name).ok_or_else(|| PipelineError::Input {
                path: v.name.clone().into(),
                reason: "no such image among the inputs".into(),
            })?;
            let cam = rec.cameras.get(&v.camera_id).ok_or_else(|| {
                PipelineError::workspace(&v.name, "camera missing from the sparse model")
            })?;
            let img = handheld_io::images::load_image(path, &opts)?
                .image
                .to_rgb8();
            let longer = img.width().max(img.height());
            let (img, cam) = if max_size > 0 && longer > max_size {
                let s = f64::from(max_size) / f64::from(longer);
                let (w, h) = (
                    (f64::from(img.width()) * s).round() as u32,
                    (f64::from(img.height()) * s).round() as u32,
                );
                let small =
                    image::imageops::resize(&img, w, h, image::imageops::FilterType::Triangle);
                let sx = f64::from(w) / f64::from(img.width());
                let sy = f64::from(h) / f64::from(img.height());
                (small, cam.scaled(sx, sy))
            } else {
                (img, cam.clone())
            };
            Ok(PosedView::new(v.name.clone(), cam, v.cam_from_world, img))
        })
        .collect()
}

/// A virtual camera: `camera` without distortion, resized to `width` (0: unchanged; the height
/// follows the aspect, rounded to even sizes for video).
pub fn virtual_camera(camera: &Camera, width: u32) -> Camera {
    let mut c = camera.clone();
    c.intrinsics.k1 = 0.0;
    c.intrinsics.k2 = 0.0;
    if width == 0 || width == c.width {
        return c;
    }
    let s = f64::from(width) / f64::from(c.width);
    let w = width & !1;
    let h = ((f64::from(c.height) * s).round() as u32).max(2) & !1;
    c.scaled(
        f64::from(w) / f64::from(c.width),
        f64::from(h) / f64::from(c.height),
    )
}

/// Writes a rendering as PNG, atomically.
pub fn write_png(path: &Path, image: &RgbImage) -> Result<()> {
    let bytes = handheld_io::obj::encode_png(path, image)?;
    handheld_io::atomic::write_bytes_atomic(path, &bytes)?;
    Ok(())
}
