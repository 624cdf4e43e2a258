//! The stage sequence of `handheld reconstruct`: each stage is fingerprinted (inputs, options,
//! upstream manifests), skipped when its manifest is up to date, and otherwise run through its library
//! call, with its outputs written atomically and its manifest last.

use std::path::Path;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::ValueEnum;
use handheld_io::images::{list_image_folder, ImageIngestOptions};
use handheld_io::ingest::{ingest, IngestOptions, IngestResult};
use handheld_io::video::VideoOptions;
use handheld_io::workspace::{now_unix_s, Fingerprint, StageManifest, Workspace, HANDHELD_VERSION};
use serde::Serialize;

use crate::args::InputArgs;
use crate::ui::Bars;

/// Pipeline stages, in order. Later stages (features, sparse, dense, mesh) join as they land.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, ValueEnum, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Stage {
    /// Validate photos / decode video frames.
    Ingest,
}

impl Stage {
    /// The last implemented stage: what `reconstruct` runs up to by default.
    pub const LAST: Stage = Stage::Ingest;
    pub const ALL: [Stage; 1] = [Stage::Ingest];

    /// The stage's folder name in the workspace.
    pub fn dir_name(self) -> &'static str {
        match self {
            Stage::Ingest => "ingest",
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

/// Builds the ingest options from the command line, naming the option that is out of range.
pub fn ingest_options(a: &InputArgs) -> Result<IngestOptions> {
    let opts = IngestOptions {
        images: ImageIngestOptions { skip_unreadable: a.skip_bad_images, ..Default::default() },
        video: VideoOptions { stride: a.stride, start_s: a.start, end_s: a.end, max_frames: a.max_frames },
    };
    opts.validate().map_err(anyhow::Error::msg)?;
    Ok(opts)
}

/// Runs the stages up to `until` on the workspace.
pub fn run(a: &InputArgs, until: Stage, bars: &Bars) -> Result<Vec<StageReport>> {
    let opts = ingest_options(a)?;
    if !a.input.exists() {
        anyhow::bail!("{}: does not exist", a.input.display());
    }
    let ws = Workspace::open(&a.output)?;
    let mut reports = Vec::new();
    for stage in Stage::ALL.into_iter().filter(|s| *s <= until) {
        let report = match stage {
            Stage::Ingest => run_ingest(&ws, &a.input, &opts, a.force, bars)?,
        };
        match report.status {
            "ran" => tracing::info!("{}: done in {:.2} s", stage.dir_name(), report.seconds),
            _ => tracing::info!("{}: up to date, skipped (use --force to redo)", stage.dir_name()),
        }
        reports.push(report);
    }
    Ok(reports)
}

fn ingest_fingerprint(input: &Path, opts: &IngestOptions) -> Result<String> {
    let mut fp = Fingerprint::new();
    fp.add_str("stage", "ingest").add_json("options", opts);
    if input.is_dir() {
        // Only the listing and file identities: cheap, and any change to the photos invalidates it.
        let listing = list_image_folder(input, &ImageIngestOptions { min_images: 0, ..opts.images.clone() })?;
        for p in &listing.images {
            fp.add_file(p)?;
        }
    } else {
        fp.add_file(input)?;
    }
    Ok(fp.hex())
}

fn run_ingest(ws: &Workspace, input: &Path, opts: &IngestOptions, force: bool, bars: &Bars) -> Result<StageReport> {
    let stage = Stage::Ingest;
    let hash = ingest_fingerprint(input, opts)?;
    if !force && ws.is_up_to_date(stage.dir_name(), &hash) {
        let m = ws.manifest(stage.dir_name()).context("manifest vanished")?;
        return Ok(StageReport { stage, status: "up_to_date", seconds: m.seconds, summary: m.summary });
    }
    let started = now_unix_s();
    let t0 = Instant::now();
    let dir = ws.begin(stage.dir_name())?;
    let result: IngestResult = ingest(input, &dir.join("frames"), opts, bars)?;
    let json = serde_json::to_vec_pretty(&result)?;
    handheld_io::atomic::write_bytes_atomic(&dir.join("images.json"), &json)?;
    for (p, why) in &result.skipped {
        tracing::warn!("{}: skipped ({why})", p.display());
    }
    let summary = serde_json::json!({
        "kind": result.kind,
        "images": result.images.len(),
        "skipped": result.skipped.len(),
        "width": result.images.first().map(|i| i.info.width),
        "height": result.images.first().map(|i| i.info.height),
        "exif_focal_priors": result.images.iter().filter(|i| i.info.focal_prior_px.is_some()).count(),
    });
    let seconds = t0.elapsed().as_secs_f64();
    ws.finish(&StageManifest {
        stage: stage.dir_name().into(),
        handheld_version: HANDHELD_VERSION.into(),
        input_hash: hash,
        options: serde_json::to_value(opts)?,
        started_unix_s: started,
        seconds,
        outputs: vec!["images.json".into()],
        summary: summary.clone(),
    })?;
    Ok(StageReport { stage, status: "ran", seconds, summary })
}
