//! The stage graph. A stage is a type implementing [`Stage`]: its name (its workspace folder), the
//! stages whose outputs it reads, its typed options and its typed summary. A [`Pipeline`] holds the
//! registered stages in an order where every stage comes after those it reads; running up to a
//! stage runs exactly the stages it needs, each skipped when its manifest is up to date.
//!
//! The fingerprint of a stage is its serialised options, whatever inputs it adds itself (the
//! photos' identities for ingest), and the input hashes of the stages it reads, which carry their
//! own upstream hashes: a change anywhere upstream reaches every stage below it, and nothing else.

use std::collections::BTreeSet;
use std::path::Path;
use std::time::Instant;

use handheld_core::Progress;
use serde::{Deserialize, Serialize};

use handheld_io::atomic::write_bytes_atomic;

use crate::error::{PipelineError, Result};
use crate::manifest::{
    now_unix_s, Fingerprint, StageManifest, Workspace, HANDHELD_VERSION, WORKSPACE_FORMAT,
};
use crate::warning::Warning;

/// Every stage folder's `summary.json` (written by the runner, see [`SummaryFile`]).
pub const SUMMARY_FILE: &str = "summary.json";

/// What a stage body runs with.
pub struct StageContext<'a> {
    pub ws: &'a Workspace,
    pub progress: &'a dyn Progress,
}

impl StageContext<'_> {
    /// Whether the stage `name` (one of the stage's optional inputs) is finished in the workspace.
    pub fn has(&self, name: &str) -> bool {
        self.ws.manifest(name).is_some()
    }
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

    fn run_or_skip(&self, ctx: &StageContext, force: bool) -> Result<StageReport> {
        let name = T::NAME;
        let ws = ctx.ws;
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
        let hash = fp.hex();
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
        let mut out = self.run(ctx, &dir)?;
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

/// Registered stages, each after the stages it reads.
#[derive(Default)]
pub struct Pipeline {
    stages: Vec<Box<dyn AnyStage>>,
}

impl Pipeline {
    /// An empty graph.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds a stage after checking its options. It must read (also optionally) only stages
    /// registered before it, and its name must be new.
    pub fn register(&mut self, stage: impl AnyStage + 'static) -> Result<&mut Self> {
        let name = stage.name();
        if self.get(name).is_some() {
            return Err(PipelineError::Graph(format!(
                "stage `{name}` is registered twice"
            )));
        }
        let reads = stage.reads().iter().chain(stage.reads_if_present());
        if let Some(up) = reads.clone().find(|r| self.get(r).is_none()) {
            return Err(PipelineError::Graph(format!(
                "stage `{name}` reads `{up}`, which is not registered before it"
            )));
        }
        stage.validate()?;
        self.stages.push(Box::new(stage));
        Ok(self)
    }

    fn get(&self, name: &str) -> Option<&dyn AnyStage> {
        self.stages
            .iter()
            .find(|s| s.name() == name)
            .map(|s| s.as_ref())
    }

    /// The registered stages' names, in run order.
    pub fn names(&self) -> Vec<&'static str> {
        self.stages.iter().map(|s| s.name()).collect()
    }

    /// The stages `target` needs, itself included, in run order: what it reads, transitively,
    /// and what it reads when present (which is run first, but may fail).
    pub fn plan(&self, target: &str) -> Result<Vec<&'static str>> {
        let needed = self.closure(target, true)?;
        Ok(self
            .names()
            .into_iter()
            .filter(|n| needed.contains(n))
            .collect())
    }

    /// `target` and what it reads, transitively; with `optional`, also what it reads when present.
    fn closure(&self, target: &str, optional: bool) -> Result<BTreeSet<&'static str>> {
        let Some(t) = self.get(target) else {
            return Err(PipelineError::option(
                "--until",
                format!(
                    "no stage `{target}`; the stages are {}",
                    self.names().join(", ")
                ),
            ));
        };
        let mut needed = BTreeSet::from([t.name()]);
        // Registration order is topological: one backward sweep closes the set.
        for s in self.stages.iter().rev() {
            if needed.contains(s.name()) {
                needed.extend(s.reads().iter().copied());
                if optional {
                    needed.extend(s.reads_if_present().iter().copied());
                }
            }
        }
        Ok(needed)
    }

    /// Runs the stages `target` needs (all of them with `None`), skipping those up to date.
    ///
    /// A stage that fails stops the stages that need it; those that only read it when present
    /// run without it. The run fails with the first failure of a stage that the target needs
    /// (every stage with `None`); the failure of a stage that was only an optional input of the
    /// target is logged as a warning, and the run succeeds. An invalid option stops everything.
    pub fn run(
        &self,
        ws: &Workspace,
        target: Option<&str>,
        force: bool,
        progress: &dyn Progress,
    ) -> Result<Vec<StageReport>> {
        let (plan, required) = match target {
            Some(t) => (self.plan(t)?, self.closure(t, false)?),
            None => (self.names(), self.names().into_iter().collect()),
        };
        let ctx = StageContext { ws, progress };
        let mut reports = Vec::new();
        let mut failed: Vec<&'static str> = Vec::new();
        let mut first_error = None;
        for s in plan.into_iter().filter_map(|n| self.get(n)) {
            if let Some(up) = s.reads().iter().find(|r| failed.contains(r)) {
                tracing::warn!("{}: not run, because {up} failed", s.name());
                failed.push(s.name());
                continue;
            }
            match s.run_or_skip(&ctx, force) {
                Ok(r) => reports.push(r),
                Err(e) if e.invalid_option().is_some() => return Err(e),
                Err(e) => {
                    failed.push(s.name());
                    if required.contains(s.name()) && first_error.is_none() {
                        first_error = Some(e);
                    } else if required.contains(s.name()) {
                        tracing::error!("{}: {e}", s.name());
                    } else {
                        tracing::warn!(
                            "{} failed ({e}); the stages that use it when it is there go on without it",
                            s.name()
                        );
                    }
                }
            }
        }
        match first_error {
            Some(e) => Err(e),
            None => Ok(reports),
        }
    }
}
