//! What the report shows ([`ReportInput`], gathered by the pipeline), what it wrote
//! ([`ReportSummary`]), its error and its file names.

use std::path::PathBuf;

use handheld_core::TriMesh;
use image::RgbImage;
use serde::{Deserialize, Serialize};
use thiserror::Error;

#[derive(Debug, Error)]
pub enum ReportError {
    #[error("{path}: cannot encode ({reason})")]
    Encode { path: PathBuf, reason: String },
}

pub type Result<T> = std::result::Result<T, ReportError>;

/// The verdict at the top.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct Verdict {
    pub images_in: usize,
    pub registered: Option<usize>,
    /// e.g. "pinhole + radial k1, one camera".
    pub camera_model: Option<String>,
    /// Focal length and its standard deviation (pixels).
    pub focal_px: Option<f64>,
    pub focal_sigma_px: Option<f64>,
    pub reprojection_px: Option<f64>,
    /// How the metric frame was found (e.g. "self-calibration", "calibrated incremental
    /// (two-view focal length)").
    #[serde(default)]
    pub metric_frame: Option<String>,
    pub total_seconds: f64,
}

/// One input image.
#[derive(Clone, Debug, Default)]
pub struct ImageEntry {
    pub name: String,
    pub thumb: Option<RgbImage>,
    pub registered: Option<bool>,
    /// Why it was not registered.
    pub reason: Option<String>,
    /// What else to know about it (e.g. "a copy of a.jpg").
    pub note: Option<String>,
    pub observations: Option<usize>,
    /// Relative to the workspace: the dense stage's depth preview, and its fill.
    pub depth_preview: Option<String>,
    pub fill: Option<f64>,
}

/// One recorded camera for the viewer.
///
/// Not a `PosedCamera`: this is the viewer's wire format (`report/scene.js`, read by `viewer.js`),
/// flat numbers in the frame the viewer draws in (centre and world ← camera rotation rather than
/// `cam_from_world`). Build it with [`ViewerCamera::from_posed`].
#[derive(Clone, Debug, Serialize)]
pub struct ViewerCamera {
    pub name: String,
    /// Centre, and world ← camera rotation (row-major).
    pub c: [f64; 3],
    pub r: [f64; 9],
    pub f: f64,
    pub aspect: f64,
    pub cx: f64,
    pub cy: f64,
    pub w: u32,
    pub h: u32,
    pub registered: bool,
    /// The thumbnail, relative to the page.
    pub thumb: String,
}

impl ViewerCamera {
    /// The viewer's camera of a registered view.
    pub fn from_posed(name: &str, view: &handheld_core::PosedCamera) -> Self {
        let r = view.cam_from_world.rotation.inverse().to_rotation_matrix();
        let m = r.matrix();
        let c = view.center();
        let i = &view.camera.intrinsics;
        Self {
            name: name.to_string(),
            c: [c.x, c.y, c.z],
            r: [
                m[(0, 0)],
                m[(0, 1)],
                m[(0, 2)],
                m[(1, 0)],
                m[(1, 1)],
                m[(1, 2)],
                m[(2, 0)],
                m[(2, 1)],
                m[(2, 2)],
            ],
            f: i.f,
            aspect: i.aspect,
            cx: i.pp.x,
            cy: i.pp.y,
            w: view.camera.width,
            h: view.camera.height,
            registered: true,
            thumb: String::new(),
        }
    }
}

/// A stage's warning: what happened in plain language, what to do, and the figures behind it
/// (folded away on the page). `code` is the stable kind (`focal_undetermined`, ...).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct ReportWarning {
    pub code: String,
    pub text: String,
    pub advice: Option<String>,
    pub details: Option<String>,
}

impl From<&str> for ReportWarning {
    fn from(text: &str) -> Self {
        Self {
            code: "note".into(),
            text: text.into(),
            ..Default::default()
        }
    }
}

impl From<String> for ReportWarning {
    fn from(text: String) -> Self {
        Self::from(text.as_str())
    }
}

/// Everything the report shows.
/// The verified pairs as the report draws them: the image count and `(i, j, inliers)` per pair.
pub type PairGraph = (usize, Vec<(usize, usize, f64)>);

#[derive(Clone, Debug, Default)]
pub struct ReportInput {
    pub title: String,
    pub verdict: Verdict,
    /// Warnings in words a user understands, with what to do.
    pub warnings: Vec<ReportWarning>,
    /// Stages that have not run (the report says what is missing).
    pub missing: Vec<String>,
    pub images: Vec<ImageEntry>,
    pub reprojection_errors: Vec<f64>,
    pub track_lengths: Vec<usize>,
    /// Image count and (i, j, inliers) of the verified pairs.
    pub pairs: Option<PairGraph>,
    /// Index into `images` of each camera.
    pub cameras: Vec<(usize, ViewerCamera)>,
    pub up: [f64; 3],
    pub stage_times: Vec<(String, f64)>,
    pub points: Vec<([f32; 3], [u8; 3])>,
    pub mesh: Option<(TriMesh, Option<RgbImage>)>,
    /// (label, path relative to the workspace) of renders: PNG images and MP4 videos.
    pub renders: Vec<(String, String)>,
}

/// What was written.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ReportSummary {
    pub html: PathBuf,
    pub bytes: u64,
    pub points: usize,
    pub mesh_faces: usize,
    pub cameras: usize,
    pub images: usize,
    pub missing: Vec<String>,
}

/// `report/` beside `report.html`.
pub const REPORT_DIR: &str = "report";
pub const REPORT_HTML: &str = "report.html";
