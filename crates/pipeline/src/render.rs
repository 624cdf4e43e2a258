//! Rendering a workspace's new views (§5.2): the recorded views and their depth maps loaded as an
//! [`IbrScene`], one view rendered to a PNG, a camera path rendered to an H.264 video, and the
//! textured mesh through the rasteriser as the geometry-based alternative.
//!
//! A workspace without dense depth maps falls back to the fixed plane, with a warning.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use handheld_core::{Camera, PosedView, Progress, Rigid3, TriMesh};
use handheld_dense::scale_camera;
use handheld_io::dense_folder::{read_views, MapKind};
use handheld_render::path;
use handheld_render::{IbrMethod, IbrOptions, IbrScene, Rendered, Renderer};
use image::RgbImage;
use nalgebra::{Point3, Quaternion, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use crate::error::{PipelineError, Result};
use crate::files::{stage, MODEL_GLB};
use crate::manifest::Workspace;

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
        match self {
            Self::Plane => "plane",
            Self::Planes => "planes",
            Self::Subdivided => "subdivided",
            Self::Ulr => "ulr",
            Self::UlrMesh => "ulr_mesh",
            Self::Mesh => "mesh",
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
            .map(|v| (v.name.clone(), v.camera.clone(), v.cam_from_world))
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
        match method.ibr() {
            Some(m) => {
                let proxy = match (&self.mesh, method) {
                    (Some((mesh, _)), RenderMethod::UlrMesh) => {
                        Some(handheld_render::render_mesh(mesh, None, camera, pose).depth)
                    }
                    _ => None,
                };
                let stats = renderer
                    .render_with_proxy(&self.scene, camera, pose, m, opts, proxy.as_ref(), out)
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
                *out = handheld_render::render_mesh(mesh, tex.as_ref(), camera, pose);
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
                (small, scale_camera(cam, sx, sy))
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
    scale_camera(
        &c,
        f64::from(w) / f64::from(c.width),
        f64::from(h) / f64::from(c.height),
    )
}

/// A pose file: the virtual camera's pose (world → camera, COLMAP's convention) and optionally
/// its intrinsics.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct PoseFile {
    /// Unit quaternion (w, x, y, z) of the world → camera rotation.
    pub rotation: [f64; 4],
    /// World → camera translation.
    pub translation: [f64; 3],
    /// The camera; the first recorded view's (without distortion) when absent.
    #[serde(default)]
    pub camera: Option<Camera>,
}

impl PoseFile {
    /// Reads and checks a pose file; the error names the file and says what a pose file holds.
    pub fn read(path: &Path) -> Result<Self> {
        let bad = |reason: String| PipelineError::Input {
            path: path.to_path_buf(),
            reason,
        };
        let bytes = std::fs::read(path).map_err(|e| bad(format!("cannot read ({e})")))?;
        let p: PoseFile = serde_json::from_slice(&bytes).map_err(|e| {
            bad(format!(
                "not a pose file ({e}); expected JSON {{\"rotation\": [w, x, y, z], \"translation\": [x, y, z]}} \
                 (world → camera, as in COLMAP's images.txt)"
            ))
        })?;
        let q = Vector3::new(p.rotation[1], p.rotation[2], p.rotation[3]);
        let norm = (p.rotation[0].powi(2) + q.norm_squared()).sqrt();
        if !(norm.is_finite() && (norm - 1.0).abs() < 1e-3)
            || p.translation.iter().any(|v| !v.is_finite())
        {
            return Err(bad(format!(
                "rotation must be a unit quaternion and translation finite; got |q| = {norm}"
            )));
        }
        if let Some(c) = &p.camera {
            c.intrinsics
                .validate()
                .map_err(|e| bad(format!("camera: {e}")))?;
            if c.width < 2 || c.height < 2 {
                return Err(bad("camera: width and height must be at least 2".into()));
            }
        }
        Ok(p)
    }

    pub fn pose(&self) -> Rigid3 {
        let [w, x, y, z] = self.rotation;
        let [tx, ty, tz] = self.translation;
        Rigid3::from_parts(
            Translation3::new(tx, ty, tz),
            UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z)),
        )
    }

    pub fn from_pose(pose: &Rigid3, camera: Option<Camera>) -> Self {
        let q = pose.rotation.into_inner();
        let t = pose.translation.vector;
        Self {
            rotation: [q.w, q.i, q.j, q.k],
            translation: [t.x, t.y, t.z],
            camera,
        }
    }
}

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
    pub fn parse(s: &str) -> Result<Self> {
        match s {
            "through" => Ok(Self::Through),
            "orbit" => Ok(Self::Orbit),
            _ => Err(PipelineError::option(
                "--path",
                format!("unknown path `{s}`; use orbit or through"),
            )),
        }
    }
}

/// What a path rendering did.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct FlightSummary {
    pub output: PathBuf,
    pub method: RenderMethod,
    pub path: PathKind,
    pub frames: usize,
    pub width: u32,
    pub height: u32,
    /// Median and maximum seconds per frame (rendering only).
    pub median_frame_seconds: f64,
    pub max_frame_seconds: f64,
    pub mean_covered_fraction: f64,
    pub warnings: Vec<String>,
}

/// Options of a path rendering.
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
    pub fn validate(&self) -> Result<()> {
        if self.frames < 2 {
            return Err(PipelineError::option(
                "--frames",
                format!("must be at least 2, got {}", self.frames),
            ));
        }
        if self.width < 16 || self.width > 8192 {
            return Err(PipelineError::option(
                "--width",
                format!("must be between 16 and 8192, got {}", self.width),
            ));
        }
        if self.fps == 0 {
            return Err(PipelineError::option("--fps", "must be at least 1"));
        }
        self.ibr
            .validate()
            .map_err(|e| PipelineError::option("--method", e.to_string()))
    }
}

/// The poses and virtual camera of a path.
pub fn flight_poses(scene: &RenderScene, opts: &FlightOptions) -> (Camera, Vec<Rigid3>) {
    let camera = virtual_camera(&scene.views[0].1, opts.width);
    let keys: Vec<Rigid3> = scene.views.iter().map(|v| v.2).collect();
    let poses = match opts.path {
        PathKind::Through => path::through(&keys, opts.frames),
        PathKind::Orbit => {
            let focus = scene.scene.focus(&scene.points);
            path::orbit(&keys, &focus, opts.frames)
        }
    };
    (camera, poses)
}

/// Renders a camera path and encodes it as H.264 at `output` (written under a temporary name and
/// renamed when complete).
/// Returns the summary and the middle frame. When the `ffmpeg` program cannot be run, the video
/// is skipped with a warning (the frames were rendered; `output` does not exist).
pub fn render_flight(
    scene: &RenderScene,
    opts: &FlightOptions,
    output: &Path,
    progress: &dyn Progress,
) -> Result<(FlightSummary, Option<RgbImage>)> {
    opts.validate()?;
    let (camera, poses) = flight_poses(scene, opts);
    let mut renderer = Renderer::new();
    let mut times = Vec::with_capacity(poses.len());
    let mut covered = 0.0;
    let mut out = Rendered {
        image: RgbImage::new(0, 0),
        covered: Vec::new(),
        depth: handheld_core::FloatMap::filled(0, 0, 1, 0.0),
    };
    let mut warnings = scene.warnings.clone();
    // Frames are streamed to ffmpeg as they are rendered (none kept but the middle one).
    let mut writer = match handheld_io::video::encode::VideoWriter::create(
        output,
        camera.width,
        camera.height,
        f64::from(opts.fps),
        18,
        None,
    ) {
        Ok(w) => Some(w),
        Err(e @ handheld_io::IoError::FfmpegMissing { .. }) => {
            warnings.push(format!("the fly-through video was not written: {e}"));
            None
        }
        Err(e) => return Err(e.into()),
    };
    let mut middle = None;
    progress.start("rendering the fly-through", poses.len() as u64);
    for (k, pose) in poses.iter().enumerate() {
        let t = std::time::Instant::now();
        scene.render(
            &mut renderer,
            &camera,
            pose,
            opts.method,
            &opts.ibr,
            &mut out,
        )?;
        times.push(t.elapsed().as_secs_f64());
        covered += out.covered.iter().filter(|c| **c).count() as f64 / out.covered.len() as f64;
        if let Some(w) = writer.as_mut() {
            w.push(&out.image)?;
        }
        if k == poses.len() / 2 {
            middle = Some(out.image.clone());
        }
        progress.inc(1);
    }
    progress.finish();
    if let Some(w) = writer {
        w.finish()?;
    }
    let frames = poses.len();
    times.sort_by(f64::total_cmp);
    if scene.effective(opts.method) != opts.method {
        warnings.push(format!(
            "method {} fell back to the fixed plane (no depth maps)",
            opts.method.name()
        ));
    }
    let summary = FlightSummary {
        output: output.to_path_buf(),
        method: scene.effective(opts.method),
        path: opts.path,
        frames,
        width: camera.width,
        height: camera.height,
        median_frame_seconds: times[times.len() / 2],
        max_frame_seconds: times[times.len() - 1],
        mean_covered_fraction: covered / frames.max(1) as f64,
        warnings,
    };
    Ok((summary, middle))
}

/// Writes a rendering as PNG, atomically.
pub fn write_png(path: &Path, image: &RgbImage) -> Result<()> {
    let bytes = handheld_io::obj::encode_png(path, image)?;
    handheld_io::atomic::write_bytes_atomic(path, &bytes)?;
    Ok(())
}

/// Which view to render.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ViewSpec {
    /// A recorded image's camera (by name).
    Image(String),
    /// A pose file ([`PoseFile`]).
    PoseFile(PathBuf),
}

/// What a one-view rendering did.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ViewSummary {
    pub output: PathBuf,
    pub method: RenderMethod,
    pub width: u32,
    pub height: u32,
    pub covered_fraction: f64,
    pub seconds: f64,
    pub warnings: Vec<String>,
}

/// Renders one view of the workspace `ws` with `method` to the PNG `output`. With
/// [`ViewSpec::Image`] that image is left out of the recorded views, so the rendering can be
/// compared with its photo (its depth map still shaped the dense stage). `width` 0 keeps the
/// camera's size.
pub fn render_view(
    ws: &Workspace,
    spec: &ViewSpec,
    method: RenderMethod,
    width: u32,
    ibr: &IbrOptions,
    output: &Path,
) -> Result<ViewSummary> {
    ibr.validate()
        .map_err(|e| PipelineError::option("--method", e.to_string()))?;
    let (exclude, pose_file) = match spec {
        ViewSpec::Image(name) => (vec![name.clone()], None),
        ViewSpec::PoseFile(p) => (Vec::new(), Some(PoseFile::read(p)?)),
    };
    let scene = RenderScene::load(ws, &exclude, 1600)?;
    let (camera, pose) = match (spec, pose_file) {
        (ViewSpec::Image(name), _) => {
            let dense = ws.root.join(stage::DENSE);
            let cams = if dense.join(handheld_io::dense_folder::CAMERAS_FILE).exists() {
                handheld_io::dense_folder::read_cameras(&dense)?
            } else {
                Vec::new()
            };
            match cams.into_iter().find(|e| &e.image == name) {
                Some(e) => (e.camera, e.cam_from_world),
                None => {
                    let rec = ws.read_sparse_model()?;
                    let v = rec
                        .views
                        .values()
                        .find(|v| &v.name == name)
                        .ok_or_else(|| {
                            PipelineError::option(
                                "--view",
                                format!("{name}: not a registered image of the workspace"),
                            )
                        })?;
                    let cam = rec.cameras.get(&v.camera_id).ok_or_else(|| {
                        PipelineError::workspace(&v.name, "camera missing from the sparse model")
                    })?;
                    (cam.clone(), v.cam_from_world)
                }
            }
        }
        (_, Some(p)) => {
            let cam = p
                .camera
                .clone()
                .unwrap_or_else(|| virtual_camera(&scene.views[0].1, 0));
            (cam, p.pose())
        }
        (ViewSpec::PoseFile(p), None) => {
            return Err(PipelineError::Input {
                path: p.clone(),
                reason: "not read".into(),
            })
        }
    };
    let camera = if width > 0 && width != camera.width {
        let s = f64::from(width) / f64::from(camera.width);
        scale_camera(&camera, s, s)
    } else {
        camera
    };
    let mut renderer = Renderer::new();
    let mut out = Rendered {
        image: RgbImage::new(0, 0),
        covered: Vec::new(),
        depth: handheld_core::FloatMap::filled(0, 0, 1, 0.0),
    };
    let t = std::time::Instant::now();
    scene.render(&mut renderer, &camera, &pose, method, ibr, &mut out)?;
    let seconds = t.elapsed().as_secs_f64();
    write_png(output, &out.image)?;
    let mut warnings = scene.warnings.clone();
    if scene.effective(method) != method {
        warnings.push(format!(
            "method {} fell back to the fixed plane (no depth maps)",
            method.name()
        ));
    }
    Ok(ViewSummary {
        output: output.to_path_buf(),
        method: scene.effective(method),
        width: camera.width,
        height: camera.height,
        covered_fraction: out.covered.iter().filter(|c| **c).count() as f64
            / out.covered.len().max(1) as f64,
        seconds,
        warnings,
    })
}
