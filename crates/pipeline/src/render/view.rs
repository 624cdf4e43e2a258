//! One view: a recorded image's camera or a pose file's, rendered to a PNG.

use std::path::{Path, PathBuf};

use handheld_core::{Camera, PosedCamera, Rigid3};
use handheld_render::scene::{virtual_camera, RenderMethod};
use handheld_render::{IbrOptions, Rendered, Renderer};
use image::RgbImage;
use nalgebra::{Quaternion, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use super::load::{load_scene, scene_error, write_png};
use crate::error::{PipelineError, Result};
use crate::files::stage;
use crate::manifest::Workspace;

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
    let scene = load_scene(ws, &exclude, 1600)?;
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
                .unwrap_or_else(|| virtual_camera(&scene.views[0].1.camera, 0));
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
        camera.scaled(s, s)
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
    scene
        .render(
            &mut renderer,
            &PosedCamera::new(camera.clone(), pose),
            method,
            ibr,
            &mut out,
        )
        .map_err(scene_error)?;
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
