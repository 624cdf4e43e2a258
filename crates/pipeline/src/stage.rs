//! The stage graph. A stage is a type implementing [`Stage`]: its name (its workspace folder), the
//! stages whose outputs it reads, its typed options and its typed summary. A [`Pipeline`] holds the
//! registered stages in an order where every stage comes after those it reads; running up to a
//! stage runs exactly the stages it needs, each skipped when its manifest is up to date.
//!
//! The fingerprint of a stage is its serialised options, whatever inputs it adds itself (the
//! photos' identities for ingest), and the input hashes of the stages it reads, which carry their
//! own upstream hashes: a change anywhere upstream reaches every stage below it, and nothing else.
//!
//! Work units: a stage may split its work into units that run apart, on other machines, before it
//! (the per-image work of the features stage). [`Pipeline::run_unit`] runs one into
//! `WS/.units/<stage>/<input hash>/`, each file written under a temporary name and renamed, and
//! its marker (`unit-<k>.json`, with the unit's result) last, so a unit a scheduler retries after
//! a worker died is either done or redone whole. The stage's `run` then takes each finished unit's
//! files ([`StageContext::take_unit`]) instead of computing them, and computes the rest itself:
//! the files are the same bytes either way, written by the same code.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::time::Instant;

use handheld_core::Progress;
use serde::{Deserialize, Serialize};

use handheld_io::atomic::write_bytes_atomic;
use handheld_io::IoError;

use crate::error::{PipelineError, Result};
use crate::manifest::{
    now_unix_s, Fingerprint, StageManifest, Workspace, HANDHELD_VERSION, WORKSPACE_FORMAT,
};
use crate::warning::Warning;

/// Every stage folder's `summary.json` (written by the runner, see [`SummaryFile`]).
pub const SUMMARY_FILE: &str = "summary.json";

/// `WS/.units/`: the files of work units run apart, by stage and input hash (see the module notes).
pub const UNITS_DIR: &str = ".units";

/// What a stage body runs with.
pub struct StageContext<'a> {
    pub ws: &'a Workspace,
    pub progress: &'a dyn Progress,
    /// Where this stage's units run apart left their files (`WS/.units/<stage>/<input hash>/`),
    /// set by the runner; `None` for a stage body called outside the graph.
    pub units: Option<PathBuf>,
}

impl StageContext<'_> {
    /// Whether the stage `name` (one of the stage's optional inputs) is finished in the workspace.
    pub fn has(&self, name: &str) -> bool {
        self.ws.manifest(name).is_some()
    }

    /// The result of unit `k` when it ran apart, after moving its `files` (relative paths) into
    /// the stage folder `dir`; `None` when it did not run (or left a file missing), and the stage
    /// computes it itself.
    pub fn take_unit(
        &self,
        k: usize,
        files: &[String],
        dir: &Path,
    ) -> Result<Option<serde_json::Value>> {
        let Some(units) = &self.units else {
            return Ok(None);
        };
        let marker = units.join(unit_marker(k));
        let Ok(text) = std::fs::read(&marker) else {
            return Ok(None);
        };
        let Ok(result) = serde_json::from_slice(&text) else {
            return Ok(None);
        };
        if !files.iter().all(|f| units.join(f).is_file()) {
            return Ok(None);
        }
        for f in files {
            let to = dir.join(f);
            if let Some(parent) = to.parent() {
                std::fs::create_dir_all(parent).map_err(|e| IoError::io(parent, e))?;
            }
            std::fs::rename(units.join(f), &to).map_err(|e| IoError::io(&to, e))?;
        }
        Ok(Some(result))
    }
}

/// A unit's outcome file taken into the stage folder (postcard), read and removed. `None` when
/// it cannot be read or decoded, with a warning naming it: the stage then computes that unit
/// itself. An outcome written by another version of Handheld (a worker not upgraded with the
/// others) does not decode, and would otherwise be redone without a word.
pub(crate) fn read_unit_outcome<T: serde::de::DeserializeOwned>(path: &Path) -> Option<T> {
    let outcome = match std::fs::read(path) {
        Ok(bytes) => match postcard::from_bytes(&bytes) {
            Ok(o) => Some(o),
            Err(e) => {
                tracing::warn!(
                    "{}: a unit's outcome that does not decode ({e}; written by another version of Handheld?): it is computed again here",
                    path.display()
                );
                None
            }
        },
        Err(e) => {
            tracing::warn!(
                "{}: a unit's outcome that cannot be read ({e}): it is computed again here",
                path.display()
            );
            None
        }
    };
    let _ = std::fs::remove_file(path);
    outcome
}

/// The marker of unit `k`: its result, written after its files.
fn unit_marker(k: usize) -> String {
    format!("unit-{k}.json")
}

/// What the runner writes as the stage's `summary.json`.
pub enum SummaryFile {
    /// The typed summary (the same as the manifest's).
    Summary,
    /// A fuller record than the manifest's summary (per-view or per-frame figures), serialised.
    Full(Vec<u8>),
    /// Nothing: the stage writes its own (the sparse stage's per-model reports).
    Own,
}

impl SummaryFile {
    /// A fuller record than the manifest's summary.
    pub fn full<T: Serialize>(record: &T) -> Result<Self> {
        serde_json::to_vec_pretty(record)
            .map(Self::Full)
            .map_err(|e| PipelineError::Graph(format!("a summary does not serialise: {e}")))
    }
}

/// What a stage body returns. The runner writes `summary.json` (see [`SummaryFile`]), logs the
/// warnings and records outputs, summary and warnings in the manifest.
pub struct Produced<S> {
    /// Output files and folders, relative to the stage folder (all must exist for the stage to be
    /// up to date); the runner adds `summary.json`.
    pub outputs: Vec<String>,
    pub summary: S,
    /// Warnings for the user: a code, the message, what to do.
    pub warnings: Vec<Warning>,
    pub summary_file: SummaryFile,
}

impl<S> Produced<S> {
    pub fn new(outputs: Vec<String>, summary: S) -> Self {
        Self {
            outputs,
            summary,
            warnings: Vec::new(),
            summary_file: SummaryFile::Summary,
        }
    }

    /// With these warnings.
    pub fn warn(mut self, warnings: Vec<Warning>) -> Self {
        self.warnings = warnings;
        self
    }

    /// With this `summary.json`.
    pub fn summary_file(mut self, file: SummaryFile) -> Self {
        self.summary_file = file;
        self
    }
}

impl<S: Serialize> Produced<S> {
    /// Writes `dir/summary.json` as [`Self::summary_file`] says (the runner does this; a stage
    /// body called outside the graph can too).
    pub fn write_summary_file(&self, dir: &Path) -> Result<()> {
        let bytes = match &self.summary_file {
            SummaryFile::Summary => serde_json::to_vec_pretty(&self.summary)
                .map_err(|e| PipelineError::Graph(format!("a summary does not serialise: {e}")))?,
            SummaryFile::Full(bytes) => bytes.clone(),
            SummaryFile::Own => return Ok(()),
        };
        write_bytes_atomic(&dir.join(SUMMARY_FILE), &bytes)?;
        Ok(())
    }
}

/// One pipeline stage. A stage is one file: its name, what it reads, its options and their check,
/// its summary and its body; adding it to the standard graph is one line in
/// [`crate::stages::STANDARD`] (see `tests/add_stage.rs` for a stage added from outside).
pub trait Stage: Send + Sync {
    /// Typed options; serialised into the fingerprint and the manifest.
    type Options: Serialize;
    /// Typed summary; serialised into the manifest (read it back with
    /// [`crate::Workspace::summary`]).
    type Summary: Serialize;

    /// The stage's name and workspace folder.
    const NAME: &'static str;
    /// The stages whose outputs this one needs.
    const READS: &'static [&'static str];
    /// The stages whose outputs this one uses when they are there (the mesh for occlusion): they
    /// run first when planned, their failure does not stop this stage, and the fingerprint covers
    /// them when present (and their absence when not).
    const READS_IF_PRESENT: &'static [&'static str] = &[];
    /// One line for `--help` and reports.
    const ABOUT: &'static str;

    fn options(&self) -> &Self::Options;
    /// Checks the options; the error names the first option out of range.
    fn validate(&self) -> Result<()> {
        Ok(())
    }
    /// The optional inputs these options use (default [`Self::READS_IF_PRESENT`]).
    fn reads_if_present(&self) -> &'static [&'static str] {
        Self::READS_IF_PRESENT
    }
    /// Adds inputs other than the upstream stages (files outside the workspace) to the fingerprint.
    fn fingerprint_inputs(&self, _fp: &mut Fingerprint) -> Result<()> {
        Ok(())
    }
    /// Runs the stage, writing into `dir` (its folder, emptied of its manifest).
    fn run(&self, ctx: &StageContext, dir: &Path) -> Result<Produced<Self::Summary>>;
    /// How many work units this run splits into, to run apart before `run` (see the module
    /// notes); 0, the default, for a stage that does not split.
    fn units(&self, _ctx: &StageContext) -> Result<usize> {
        Ok(0)
    }
    /// Runs unit `k` of [`Stage::units`], writing its files into `dir` (a fresh folder) under
    /// the names they have in the stage folder; returns those names and the unit's result, which
    /// `run` gets back from [`StageContext::take_unit`].
    fn run_unit(
        &self,
        _ctx: &StageContext,
        _dir: &Path,
        k: usize,
    ) -> Result<(Vec<String>, serde_json::Value)> {
        Err(PipelineError::Graph(format!(
            "stage `{}` has no work units (unit {k} asked for)",
            Self::NAME
        )))
    }
}

/// Whether a stage ran or was skipped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StageStatus {
    Ran,
    UpToDate,
}

impl std::fmt::Display for StageStatus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            StageStatus::Ran => "ran",
            StageStatus::UpToDate => "up_to_date",
        })
    }
}

/// What happened to one stage in this run.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct StageReport {
    pub stage: String,
    pub status: StageStatus,
    pub seconds: f64,
    pub summary: serde_json::Value,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub warnings: Vec<Warning>,
}

/// The object-safe face of a [`Stage`], with its summary serialised.
pub trait AnyStage: Send + Sync {
    fn name(&self) -> &'static str;
    fn reads(&self) -> &'static [&'static str];
    fn reads_if_present(&self) -> &'static [&'static str];
    fn about(&self) -> &'static str;
    fn validate(&self) -> Result<()>;
    /// Runs the stage unless its manifest is up to date.
    fn run_or_skip(&self, ctx: &StageContext, force: bool) -> Result<StageReport>;
    /// The fingerprint of the stage's inputs and options (fails when a stage it reads has not run).
    fn input_hash(&self, ws: &Workspace) -> Result<String>;
    /// The number of work units the stage splits into (0: none, or up to date unless `force`).
    fn units(&self, ctx: &StageContext, force: bool) -> Result<usize>;
    /// Runs unit `k` apart (nothing when it is done already).
    fn run_unit(&self, ctx: &StageContext, k: usize) -> Result<()>;
}

impl<T: Stage> AnyStage for T {
    fn name(&self) -> &'static str {
        T::NAME
    }

    fn reads(&self) -> &'static [&'static str] {
        T::READS
    }

    fn reads_if_present(&self) -> &'static [&'static str] {
        Stage::reads_if_present(self)
    }

    fn about(&self) -> &'static str {
        T::ABOUT
    }

    fn validate(&self) -> Result<()> {
        Stage::validate(self)
    }

    fn input_hash(&self, ws: &Workspace) -> Result<String> {
        let name = T::NAME;
        let options = serde_json::to_value(self.options())
            .map_err(|e| PipelineError::Graph(format!("{name}: options do not serialise: {e}")))?;
        let mut fp = Fingerprint::new();
        fp.add_str("stage", name).add_json("options", &options);
        self.fingerprint_inputs(&mut fp)?;
        for up in T::READS {
            let m = ws.manifest(up).ok_or_else(|| PipelineError::NotRun {
                needed: (*up).into(),
                by: name.into(),
            })?;
            fp.add_str(up, &m.input_hash);
        }
        for up in Stage::reads_if_present(self) {
            let hash = ws.manifest(up).map(|m| m.input_hash);
            fp.add_str(up, hash.as_deref().unwrap_or("absent"));
        }
        Ok(fp.hex())
    }

    fn units(&self, ctx: &StageContext, force: bool) -> Result<usize> {
        let hash = self.input_hash(ctx.ws)?;
        if !force && ctx.ws.is_up_to_date(T::NAME, &hash) {
            return Ok(0);
        }
        let units = ctx.ws.root.join(UNITS_DIR).join(T::NAME).join(&hash);
        std::fs::create_dir_all(&units).map_err(|e| IoError::io(&units, e))?;
        let ctx = StageContext {
            ws: ctx.ws,
            progress: ctx.progress,
            units: Some(units),
        };
        Stage::units(self, &ctx)
    }

    fn run_unit(&self, ctx: &StageContext, k: usize) -> Result<()> {
        let hash = self.input_hash(ctx.ws)?;
        let units = ctx.ws.root.join(UNITS_DIR).join(T::NAME).join(&hash);
        let marker = units.join(unit_marker(k));
        if marker.is_file() {
            return Ok(());
        }
        // A fresh folder per attempt: two workers on the same unit never share a file.
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_nanos())
            .unwrap_or(0);
        let tmp = units.join(format!("tmp-{k}-{}-{nanos}", std::process::id()));
        std::fs::create_dir_all(&tmp).map_err(|e| IoError::io(&tmp, e))?;
        let ctx = StageContext {
            ws: ctx.ws,
            progress: ctx.progress,
            units: Some(units.clone()),
        };
        let done = Stage::run_unit(self, &ctx, &tmp, k).and_then(|(files, result)| {
            for f in &files {
                let to = units.join(f);
                if let Some(parent) = to.parent() {
                    std::fs::create_dir_all(parent).map_err(|e| IoError::io(parent, e))?;
                }
                std::fs::rename(tmp.join(f), &to).map_err(|e| IoError::io(&to, e))?;
            }
            let bytes = serde_json::to_vec(&result).map_err(|e| {
                PipelineError::Graph(format!(
                    "{}: unit {k}'s result does not serialise: {e}",
                    T::NAME
                ))
            })?;
            write_bytes_atomic(&marker, &bytes)?;
            Ok(())
        });
        let _ = std::fs::remove_dir_all(&tmp);
        done
    }

    fn run_or_skip(&self, ctx: &StageContext, force: bool) -> Result<StageReport> {
        let name = T::NAME;
        let ws = ctx.ws;
        let options = serde_json::to_value(self.options())
            .map_err(|e| PipelineError::Graph(format!("{name}: options do not serialise: {e}")))?;
        let hash = self.input_hash(ws)?;
        if !force && ws.is_up_to_date(name, &hash) {
            if let Some(m) = ws.manifest(name) {
                tracing::info!("{name}: up to date, skipped (use --force to redo)");
                return Ok(StageReport {
                    stage: name.into(),
                    status: StageStatus::UpToDate,
                    seconds: m.seconds,
                    summary: m.summary,
                    warnings: m.warnings,
                });
            }
        }
        if let Some(old) = ws.manifest(name) {
            if old.workspace_format != WORKSPACE_FORMAT {
                tracing::warn!(
                    "{name}: written by an older Handheld ({}, workspace format {}); it is redone in format {WORKSPACE_FORMAT}",
                    old.handheld_version,
                    old.workspace_format
                );
            }
        }
        let started = now_unix_s();
        let t0 = Instant::now();
        let dir = ws.begin(name)?;
        let units_root = ws.root.join(UNITS_DIR).join(name);
        let ctx = StageContext {
            ws,
            progress: ctx.progress,
            units: Some(units_root.join(&hash)),
        };
        let mut out = self.run(&ctx, &dir)?;
        let summary = serde_json::to_value(&out.summary).map_err(|e| {
            PipelineError::Graph(format!("{name}: summary does not serialise: {e}"))
        })?;
        out.write_summary_file(&dir)?;
        if !out.outputs.iter().any(|o| o == SUMMARY_FILE) {
            out.outputs.push(SUMMARY_FILE.into());
        }
        let seconds = t0.elapsed().as_secs_f64();
        for w in &out.warnings {
            tracing::warn!("{w}");
        }
        ws.finish(&StageManifest {
            stage: name.into(),
            handheld_version: HANDHELD_VERSION.into(),
            workspace_format: WORKSPACE_FORMAT,
            input_hash: hash,
            options,
            started_unix_s: started,
            seconds,
            outputs: out.outputs,
            summary: summary.clone(),
            warnings: out.warnings.clone(),
        })?;
        // The units' files have moved into the stage folder; what is left is stale.
        if units_root.exists() {
            let _ = std::fs::remove_dir_all(&units_root);
            let _ = std::fs::remove_dir(ws.root.join(UNITS_DIR)); // when no other stage's are left
        }
        tracing::info!("{name}: done in {seconds:.2} s");
        Ok(StageReport {
            stage: name.into(),
            status: StageStatus::Ran,
            seconds,
            summary,
            warnings: out.warnings,
        })
    }
}

mod graph;
pub use graph::Pipeline;

#[cfg(test)]
mod tests {
    use super::read_unit_outcome;

    #[test]
    fn a_unit_outcome_is_read_once_and_one_that_does_not_decode_is_none() {
        let dir = tempfile::tempdir().expect("a temporary folder");
        let path = dir.path().join("unit.bin");
        let value = (3u32, vec![1.5f64, 2.5], Some("k".to_string()));
        std::fs::write(&path, postcard::to_stdvec(&value).expect("encodes")).expect("written");
        assert_eq!(read_unit_outcome(&path), Some(value));
        assert!(!path.exists(), "taken");
        // Cut short, as a format another version wrote would read.
        std::fs::write(&path, [7u8]).expect("written");
        assert_eq!(
            read_unit_outcome::<(u32, Vec<f64>, Option<String>)>(&path),
            None
        );
        assert!(!path.exists());
        assert_eq!(read_unit_outcome::<u32>(&path), None);
    }
}
