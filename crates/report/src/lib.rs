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

mod encode;
pub mod html;
mod input;
mod page;
mod scene;
pub mod svg;
#[cfg(test)]
mod tests;

use std::path::{Path, PathBuf};

pub use input::{
    ImageEntry, ReportError, ReportInput, ReportSummary, ReportWarning, Result, Verdict,
    ViewerCamera, REPORT_DIR, REPORT_HTML,
};

use encode::jpeg;

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
