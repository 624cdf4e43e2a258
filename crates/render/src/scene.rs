//! A reconstruction ready for rendering new views (§5.2): the recorded views and their depth maps as
//! an [`IbrScene`], the sparse points, the textured mesh when there is one; the rendering methods
//! ([`RenderMethod`]: the image-based ones, and the textured mesh through the rasteriser), the
//! virtual camera and the camera paths of a fly-through ([`FlightOptions`], [`RenderScene::flight_poses`]).
//!
//! Nothing here reads a file: the pipeline loads the views, points and mesh of a workspace (or of
//! any dense folder) and hands them over.

use handheld_core::{Camera, PosedCamera, PosedView, Rigid3, TriMesh};
use image::RgbImage;
use nalgebra::Point3;
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::ibr::{FrameStats, IbrMethod, IbrOptions, IbrScene, Renderer};
use crate::path;
use crate::raster::{render_mesh, Rendered};

/// Why a scene cannot be built or rendered.
#[derive(Debug, Error)]
pub enum SceneError {
    /// An option out of range or not usable here (names the command-line flag).
    #[error("{option}: {reason}")]
    Option {
        option: &'static str,
        reason: String,
    },
    /// The views do not make a scene.
    #[error("{0}")]
    Scene(String),
}

impl SceneError {
    fn option(option: &'static str, reason: impl Into<String>) -> Self {
        Self::Option {
            option,
            reason: reason.into(),
        }
    }
}

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

    pub fn parse(s: &str) -> Result<Self, SceneError> {
        Self::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| {
                SceneError::option(
                    "--method",
                    format!("unknown method `{s}`; use plane, planes, subdivided, ulr, ulr_mesh or mesh"),
                )
            })
    }
}

/// The default method (measured by `handheld bench render`; see docs/benchmarks.md).
pub const DEFAULT_METHOD: RenderMethod = RenderMethod::UlrMesh;

/// A camera path through or around the recorded views.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PathKind {
    /// Through the recorded cameras in name order.
    Through,
    /// Around the scene, over the arc the cameras cover.
    Orbit,
}

impl PathKind {
    pub fn parse(s: &str) -> Result<Self, SceneError> {
        match s {
            "through" => Ok(Self::Through),
            "orbit" => Ok(Self::Orbit),
            _ => Err(SceneError::option(
                "--path",
                format!("unknown path `{s}`; use orbit or through"),
            )),
        }
    }
}

/// Options of a path rendering (a fly-through).
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(default)]
pub struct FlightOptions {
    pub method: RenderMethod,
    pub path: PathKind,
    pub frames: usize,
    /// Output width (the height follows the recorded camera's aspect).
    pub width: u32,
    pub fps: u32,
    pub ibr: IbrOptions,
}

impl Default for FlightOptions {
    fn default() -> Self {
        Self {
            method: DEFAULT_METHOD,
            path: PathKind::Through,
            frames: 48,
            width: 640,
            fps: 24,
            ibr: IbrOptions::default(),
        }
    }
}

impl FlightOptions {
    pub fn validate(&self) -> Result<(), SceneError> {
        if self.frames < 2 {
            return Err(SceneError::option(
                "--frames",
                format!("must be at least 2, got {}", self.frames),
            ));
        }
        if self.width < 16 || self.width > 8192 {
            return Err(SceneError::option(
                "--width",
                format!("must be between 16 and 8192, got {}", self.width),
            ));
        }
        if self.fps == 0 {
            return Err(SceneError::option("--fps", "must be at least 1"));
        }
        self.ibr
            .validate()
            .map_err(|e| SceneError::option("--method", e.to_string()))
    }
}

/// The recorded views of a reconstruction, ready for rendering.
pub struct RenderScene {
    pub scene: IbrScene,
    /// Every recorded view: name and camera (at the rendering resolution) in its pose, in name
    /// order.
    pub views: Vec<(String, PosedCamera)>,
    /// The sparse points (paths look at their median).
    pub points: Vec<Point3<f64>>,
    /// The textured mesh, when there is one.
    pub mesh: Option<(TriMesh, Option<RgbImage>)>,
    pub warnings: Vec<String>,
}

impl RenderScene {
    /// A scene from the recorded views (with depth maps, or without for the fixed plane only),
    /// the sparse points and the textured mesh.
    pub fn new(
        views: &[PosedView],
        points: Vec<Point3<f64>>,
        mesh: Option<(TriMesh, Option<RgbImage>)>,
        warnings: Vec<String>,
    ) -> Result<Self, SceneError> {
        if views.is_empty() {
            return Err(SceneError::Scene(
                "no recorded view to render from (is every view held out?)".into(),
            ));
        }
        let scene = IbrScene::new(views, &points).map_err(|e| SceneError::Scene(e.to_string()))?;
        let mut all: Vec<(String, PosedCamera)> = views
            .iter()
            .map(|v| (v.name.clone(), v.posed.clone()))
            .collect();
        all.sort_by(|a, b| a.0.cmp(&b.0));
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

    /// Renders the view from `view` with `method` into `out`.
    pub fn render(
        &self,
        renderer: &mut Renderer,
        view: &PosedCamera,
        method: RenderMethod,
        opts: &IbrOptions,
        out: &mut Rendered,
    ) -> Result<Option<FrameStats>, SceneError> {
        let method = self.effective(method);
        match method.ibr() {
            Some(m) => {
                let proxy = match (&self.mesh, method) {
                    (Some((mesh, _)), RenderMethod::UlrMesh) => {
                        Some(render_mesh(mesh, None, view).depth)
                    }
                    _ => None,
                };
                let stats = renderer
                    .render_with_proxy(&self.scene, view, m, opts, proxy.as_ref(), out)
                    .map_err(|e| SceneError::option("--method", e.to_string()))?;
                Ok(Some(stats))
            }
            None => {
                let (mesh, tex) = self.mesh.as_ref().ok_or_else(|| {
                    SceneError::option(
                        "--method",
                        "mesh: the workspace has no textured mesh (run the mesh stage first)",
                    )
                })?;
                *out = render_mesh(mesh, tex.as_ref(), view);
                Ok(None)
            }
        }
    }

    /// The virtual camera and the poses of a fly-through.
    pub fn flight_poses(&self, opts: &FlightOptions) -> (Camera, Vec<Rigid3>) {
        let camera = virtual_camera(&self.views[0].1.camera, opts.width);
        let keys: Vec<Rigid3> = self.views.iter().map(|v| v.1.cam_from_world).collect();
        let poses = match opts.path {
            PathKind::Through => path::through(&keys, opts.frames),
            PathKind::Orbit => {
                let focus = self.scene.focus(&self.points);
                path::orbit(&keys, &focus, opts.frames)
            }
        };
        (camera, poses)
    }
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
