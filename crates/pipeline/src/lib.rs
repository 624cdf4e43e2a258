//! The pipeline as a library (COLMAP's `controllers` layer). It only orchestrates; the work of every stage lives in
//! that stage's crate (features, sfm, dense, mesh, render, report) and every format in `handheld-io`.
//!
//! - [`files`]: the workspace's files, each named once with a typed reader or writer;
//! - [`stage`]: the stage graph: the `Stage` trait with typed options and summary (and work units run apart, for
//!   the distributed pipeline), `Pipeline` registration, `plan`,
//!   run-or-skip;
//! - [`manifest`]: resumption: manifests, fingerprints of the serialised options, the skip rule, the workspace format;
//! - [`stages`]: the standard stages (ingest, features + KLT tracks, matches, sparse, dense, mesh, render, and augment
//!   when an object is given), each a thin call into its crate, and [`PipelineOptions`];
//! - [`policy`]: the policies between stages: pair policy, image ids, intrinsics groups, descriptor quantisation,
//!   focal-length warnings; [`preview`]: depth previews;
//! - [`report`]: gathering the report of whatever stages exist (manifests' warnings, summaries, the sparse model, pairs,
//!   dense previews, the mesh decimated for the viewer) into the report crate's input; `reconstruct` writes it at the
//!   end, also after a failure;
//! - rendering and augmenting a workspace: loading what the render crate needs from the workspace's files and writing
//!   what it returns (one view or a pose file to PNG, a path streamed to H.264, the augmented video with the input's
//!   audio, the camera-track exports); the rendering, placement and compositing themselves live in `handheld-render`;
//! - [`error`]: the typed `PipelineError`.
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
