//! The stage sequence of `handheld reconstruct`: each stage is fingerprinted (inputs, options,
//! upstream manifests), skipped when its manifest is up to date, and otherwise run through its library
//! call by [`run_stage`], which times it and writes its manifest last.

use std::path::Path;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::ValueEnum;
use handheld_io::images::ImageIngestOptions;
use handheld_io::ingest::IngestOptions;
use handheld_io::video::VideoOptions;
use handheld_io::workspace::{now_unix_s, Fingerprint, StageManifest, Workspace, HANDHELD_VERSION};
use serde::Serialize;

use crate::args::InputArgs;
use crate::stages;
use crate::ui::Bars;

/// Pipeline stages, in order. Later stages (sparse, dense, mesh) join as they land.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, ValueEnum, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Stage {
    /// Validate photos / decode video frames.
    Ingest,
    /// Detect and describe features (RootSIFT).
    Features,
    /// Match image pairs and verify them (Table 1); writes COLMAP's database.db.
    Matches,
    /// Uncalibrated structure and motion with self-calibration (§3); writes the COLMAP model.
    Sparse,
    /// Rectification, stereo and multi-view linking (§4); writes depth maps and fused.ply.
    Dense,
    /// Surface models (§5.1): fused textured mesh (OBJ, glTF, PLY) and per-view meshes.
    Mesh,
}

impl Stage {
    /// The last implemented stage: what `reconstruct` runs up to by default.
    pub const LAST: Stage = Stage::Mesh;
    pub const ALL: [Stage; 6] = [
        Stage::Ingest,
        Stage::Features,
        Stage::Matches,
        Stage::Sparse,
        Stage::Dense,
        Stage::Mesh,
    ];

    /// The stage's folder name in the workspace.
    pub fn dir_name(self) -> &'static str {
        match self {
            Stage::Ingest => "ingest",
            Stage::Features => "features",
            Stage::Matches => "matches",
            Stage::Sparse => "sparse",
            Stage::Dense => "dense",
            Stage::Mesh => "mesh",
        }
    }
}

/// What happened to one stage in this run.
#[derive(Debug, Clone, Serialize)]
pub struct StageReport {
    pub stage: Stage,
    /// `ran` or `up_to_date`.
    pub status: &'static str,
    pub seconds: f64,
    pub summary: serde_json::Value,
}

/// What a stage body returns: its output files (relative to the stage folder) and a summary.
pub struct StageOutput {
    pub outputs: Vec<String>,
    pub summary: serde_json::Value,
}

/// Builds the ingest options from the command line, naming the option that is out of range.
pub fn ingest_options(a: &InputArgs) -> Result<IngestOptions> {
    let opts = IngestOptions {
        images: ImageIngestOptions {
            skip_unreadable: a.skip_bad_images,
            ..Default::default()
        },
        video: VideoOptions {
            stride: a.stride,
            start_s: a.start,
            end_s: a.end,
            max_frames: a.max_frames,
        },
    };
    opts.validate().map_err(anyhow::Error::msg)?;
    Ok(opts)
}

/// Runs one stage unless its manifest is up to date. `fingerprint` already holds the stage's inputs
/// and options; the upstream manifests' hashes are added here.
pub fn run_stage(
    ws: &Workspace,
    stage: Stage,
    mut fingerprint: Fingerprint,
    options: serde_json::Value,
    force: bool,
    body: impl FnOnce(&Path) -> Result<StageOutput>,
) -> Result<StageReport> {
    fingerprint
        .add_str("stage", stage.dir_name())
        .add_json("options", &options);
    for up in Stage::ALL.into_iter().filter(|s| *s < stage) {
        let m = ws
            .manifest(up.dir_name())
            .with_context(|| format!("stage {} has not run", up.dir_name()))?;
        fingerprint.add_str(up.dir_name(), &m.input_hash);
    }
    let hash = fingerprint.hex();
    if !force && ws.is_up_to_date(stage.dir_name(), &hash) {
        let m = ws.manifest(stage.dir_name()).context("manifest vanished")?;
        return Ok(StageReport {
            stage,
            status: "up_to_date",
            seconds: m.seconds,
            summary: m.summary,
        });
    }
    let started = now_unix_s();
    let t0 = Instant::now();
    let dir = ws.begin(stage.dir_name())?;
    let out = body(&dir)?;
    let seconds = t0.elapsed().as_secs_f64();
    ws.finish(&StageManifest {
        stage: stage.dir_name().into(),
        handheld_version: HANDHELD_VERSION.into(),
        input_hash: hash,
        options,
        started_unix_s: started,
        seconds,
        outputs: out.outputs,
        summary: out.summary.clone(),
    })?;
    Ok(StageReport {
        stage,
        status: "ran",
        seconds,
        summary: out.summary,
    })
}

/// Runs the stages up to `until` on the workspace.
pub fn run(a: &InputArgs, until: Stage, bars: &Bars) -> Result<Vec<StageReport>> {
    let ingest_opts = ingest_options(a)?;
    let feature_opts = stages::features::options(a)?;
    let match_opts = stages::matches::options(a)?;
    let sparse_opts = stages::sparse::options(a)?;
    let dense_opts = stages::dense::options(&a.dense)?;
    let mesh_opts = stages::mesh::options(&a.mesh)?;
    if !a.input.exists() {
        anyhow::bail!("{}: does not exist", a.input.display());
    }
    let ws = Workspace::open(&a.output)?;
    let mut reports = Vec::new();
    for stage in Stage::ALL.into_iter().filter(|s| *s <= until) {
        let report = match stage {
            Stage::Ingest => stages::ingest::run(&ws, &a.input, &ingest_opts, a.force, bars)?,
            Stage::Features => stages::features::run(&ws, &feature_opts, a.force, bars)?,
            Stage::Matches => stages::matches::run(&ws, &match_opts, a.force, bars)?,
            Stage::Sparse => stages::sparse::run(&ws, &sparse_opts, a.force, bars)?,
            Stage::Dense => stages::dense::run(&ws, &dense_opts, a.force, bars)?,
            Stage::Mesh => stages::mesh::run(&ws, &mesh_opts, a.force, bars)?,
        };
        match report.status {
            "ran" => tracing::info!("{}: done in {:.2} s", stage.dir_name(), report.seconds),
            _ => tracing::info!(
                "{}: up to date, skipped (use --force to redo)",
                stage.dir_name()
            ),
        }
        reports.push(report);
    }
    Ok(reports)
}
