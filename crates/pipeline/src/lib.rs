//! The pipeline as a library (COLMAP's `controllers` layer): the workspace and every file in it
//! ([`files`]), the stage graph and its resumption ([`stage`], [`manifest`]), the standard stages
//! ([`stages`]) with their typed options and summaries, and the policies between them ([`policy`]).
//!
//! ```no_run
//! use handheld_pipeline::{Pipeline, PipelineOptions, Workspace};
//! # fn main() -> Result<(), handheld_pipeline::PipelineError> {
//! let options = PipelineOptions::default();
//! let pipeline = Pipeline::standard("photos/".as_ref(), &options)?;
//! let ws = Workspace::open("ws".as_ref())?;
//! let reports = pipeline.run(&ws, Some("sparse"), false, &handheld_core::NoProgress)?;
//! # Ok(()) }
//! ```

pub mod error;
pub mod files;
pub mod manifest;
pub mod options;
pub mod policy;
pub mod preview;
pub mod render;
pub mod report;
pub mod stage;
pub mod stages;
pub mod warning;

pub use error::{Context, PipelineError, Result};
pub use manifest::{Fingerprint, StageManifest, Workspace, HANDHELD_VERSION, WORKSPACE_FORMAT};
pub use options::PipelineOptions;
pub use stage::{
    AnyStage, Pipeline, Produced, Stage, StageContext, StageReport, StageStatus, SummaryFile,
};
/// The augment stage and its options (`stages::augment`).
pub use stages::augment;
pub use warning::Warning;

/// Runs the standard graph on `input` (a photo folder or a video) into the workspace `ws`, up to
/// `until` (everything with `None`). At the end, also when a stage failed, `ws/report.html` is
/// written from whatever exists ([`report::write_workspace_report`]; a failure to write it is a
/// warning, not an error).
pub fn reconstruct(
    input: &std::path::Path,
    ws: &std::path::Path,
    options: &PipelineOptions,
    until: Option<&str>,
    force: bool,
    progress: &dyn handheld_core::Progress,
) -> Result<Vec<StageReport>> {
    let pipeline = Pipeline::standard(input, options)?;
    if let Some(t) = until {
        pipeline.plan(t)?;
    }
    let ws = Workspace::open(ws)?;
    let result = pipeline.run(&ws, until, force, progress);
    if ws.manifest(files::stage::INGEST).is_some() {
        let t = std::time::Instant::now();
        match report::write_workspace_report(&ws, &pipeline.names()) {
            Ok(r) => tracing::info!(
                "report: {} ({:.1} MB) in {:.2} s",
                r.html.display(),
                r.bytes as f64 / 1e6,
                t.elapsed().as_secs_f64()
            ),
            Err(e) => tracing::warn!("the report was not written: {e}"),
        }
    }
    result
}

/// Rebuilds the report of a workspace (`handheld report`): the standard graph's stages, and the
/// augment stage when the workspace has one.
pub fn write_report(ws: &Workspace) -> Result<handheld_report::ReportSummary> {
    let options = PipelineOptions {
        augment: ws
            .manifest(files::stage::AUGMENT)
            .map(|_| augment::AugmentOptions::default()),
        ..Default::default()
    };
    let pipeline = Pipeline::standard(std::path::Path::new(""), &options)?;
    report::write_workspace_report(ws, &pipeline.names())
}
