//! The workspace report: `report.html`, a quality report a person opens by double-click. It works
//! from `file://` with no server and no network: the page, its inline SVG plots and its viewer
//! are in the HTML; the 3D data (points, cameras, the decimated mesh with its JPEG atlas as a
//! data URI) are in `report/scene.js` beside it, loaded by a `<script>` tag (browsers block
//! `fetch` of local files, not scripts); thumbnails are `report/thumbs/*.jpg`. Nothing comes from
//! elsewhere, so the workspace folder can be zipped and mailed.
//!
//! The report is safe to open and to share: names, warnings and paths are data, escaped for
//! where they land ([`html`]); the viewer writes them with `textContent`; and the page's
//! Content-Security-Policy allows no network and no script but its own.
//!
//! This crate only formats: the pipeline gathers what the stages left into a [`ReportInput`].

pub mod html;
mod page;
mod scene;
pub mod svg;
#[cfg(test)]
mod tests;

use std::path::{Path, PathBuf};

use base64::Engine;
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
    pub observations: Option<usize>,
    /// Relative to the workspace: the dense stage's depth preview, and its fill.
    pub depth_preview: Option<String>,
    pub fill: Option<f64>,
}

/// One recorded camera for the viewer.
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

/// Everything the report shows.
#[derive(Clone, Debug, Default)]
pub struct ReportInput {
    pub title: String,
    pub verdict: Verdict,
    /// Warnings in words a user understands, with what to do.
    pub warnings: Vec<String>,
    /// Stages that have not run (the report says what is missing).
    pub missing: Vec<String>,
    pub images: Vec<ImageEntry>,
    pub reprojection_errors: Vec<f64>,
    pub track_lengths: Vec<usize>,
    /// Image count and (i, j, inliers) of the verified pairs.
    pub pairs: Option<(usize, Vec<(usize, usize, f64)>)>,
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

pub(crate) fn jpeg(img: &RgbImage, quality: u8, path: &Path) -> Result<Vec<u8>> {
    let mut out = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, quality)
        .encode_image(img)
        .map_err(|e| ReportError::Encode {
            path: path.to_path_buf(),
            reason: e.to_string(),
        })?;
    Ok(out)
}

pub(crate) fn b64(bytes: &[u8]) -> String {
    base64::engine::general_purpose::STANDARD.encode(bytes)
}

/// The report's files, relative to the workspace, and what they hold. The caller writes them
/// (this crate touches no file).
pub struct ReportFiles {
    pub files: Vec<(PathBuf, Vec<u8>)>,
    pub summary: ReportSummary,
}

/// Formats the report: `report.html`, `report/scene.js` and `report/thumbs/*.jpg`.
pub fn render_report(input: &ReportInput) -> Result<ReportFiles> {
    let mut files = Vec::new();
    let mut thumb_paths = Vec::new();
    for (k, im) in input.images.iter().enumerate() {
        match &im.thumb {
            Some(t) => {
                let rel = format!("{REPORT_DIR}/thumbs/{k:05}.jpg");
                files.push((PathBuf::from(&rel), jpeg(t, 80, Path::new(&rel))?));
                thumb_paths.push(Some(rel));
            }
            None => thumb_paths.push(None),
        }
    }
    let scene_rel = PathBuf::from(format!("{REPORT_DIR}/scene.js"));
    let scene = scene::scene_js(input, &thumb_paths, &scene_rel)?;
    files.push((scene_rel, scene.into_bytes()));
    // The page last: it is what a person opens, so it appears only once the rest is there.
    files.push((
        PathBuf::from(REPORT_HTML),
        page::page(input, &thumb_paths).into_bytes(),
    ));
    let bytes = files.iter().map(|f| f.1.len() as u64).sum();
    Ok(ReportFiles {
        files,
        summary: ReportSummary {
            html: PathBuf::from(REPORT_HTML),
            bytes,
            points: input.points.len(),
            mesh_faces: input.mesh.as_ref().map_or(0, |m| m.0.faces.len()),
            cameras: input.cameras.len(),
            images: input.images.len(),
            missing: input.missing.clone(),
        },
    })
}
