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

use crate::error::{PipelineError, Result};
use crate::manifest::{
    now_unix_s, Fingerprint, StageManifest, Workspace, HANDHELD_VERSION, WORKSPACE_FORMAT,
};

/// What a stage body runs with.
pub struct StageContext<'a> {
    pub ws: &'a Workspace,
    pub progress: &'a dyn Progress,
}

/// What a stage body returns.
pub struct Produced<S> {
    /// Output files and folders, relative to the stage folder (all must exist for the stage to be
    /// up to date).
    pub outputs: Vec<String>,
    pub summary: S,
    /// Warnings for the user, in words, with what to do (also logged).
    pub warnings: Vec<String>,
}

impl<S> Produced<S> {
    pub fn new(outputs: Vec<String>, summary: S) -> Self {
        Self {
            outputs,
            summary,
            warnings: Vec::new(),
        }
    }
}

/// One pipeline stage. Adding a stage to the standard graph is one file implementing this trait and
/// one line in [`crate::Pipeline::standard`].
pub trait Stage: Send + Sync {
    /// Typed options; serialised into the fingerprint and the manifest.
    type Options: Serialize;
    /// Typed summary; serialised into the manifest (read it back with
    /// [`crate::Workspace::summary`]).
    type Summary: Serialize;

    /// The stage's name and workspace folder.
    const NAME: &'static str;
    /// The stages whose outputs this one reads.
    const READS: &'static [&'static str];
    /// One line for `--help` and reports.
    const ABOUT: &'static str;

    fn options(&self) -> &Self::Options;
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
    pub warnings: Vec<String>,
}

/// The object-safe face of a [`Stage`], with its summary serialised.
pub trait AnyStage: Send + Sync {
    fn name(&self) -> &'static str;
    fn reads(&self) -> &'static [&'static str];
    fn about(&self) -> &'static str;
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

    fn about(&self) -> &'static str {
        T::ABOUT
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
        let out = self.run(ctx, &dir)?;
        let seconds = t0.elapsed().as_secs_f64();
        let summary = serde_json::to_value(&out.summary).map_err(|e| {
            PipelineError::Graph(format!("{name}: summary does not serialise: {e}"))
        })?;
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

    /// Adds a stage. It must read only stages registered before it, and its name must be new.
    pub fn register(&mut self, stage: impl AnyStage + 'static) -> Result<&mut Self> {
        let name = stage.name();
        if self.get(name).is_some() {
            return Err(PipelineError::Graph(format!(
                "stage `{name}` is registered twice"
            )));
        }
        if let Some(up) = stage.reads().iter().find(|r| self.get(r).is_none()) {
            return Err(PipelineError::Graph(format!(
                "stage `{name}` reads `{up}`, which is not registered before it"
            )));
        }
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

    /// `(name, reads, about)` of every stage, in run order.
    pub fn describe(&self) -> Vec<(&'static str, &'static [&'static str], &'static str)> {
        self.stages
            .iter()
            .map(|s| (s.name(), s.reads(), s.about()))
            .collect()
    }

    /// The stages `target` needs (itself included), in run order.
    pub fn plan(&self, target: &str) -> Result<Vec<&'static str>> {
        if self.get(target).is_none() {
            return Err(PipelineError::option(
                "--until",
                format!(
                    "no stage `{target}`; the stages are {}",
                    self.names().join(", ")
                ),
            ));
        }
        let mut needed = BTreeSet::from([target]);
        // Registration order is topological: one backward sweep closes the set.
        for s in self.stages.iter().rev() {
            if needed.contains(s.name()) {
                needed.extend(s.reads().iter().copied());
            }
        }
        Ok(self
            .names()
            .into_iter()
            .filter(|n| needed.contains(n))
            .collect())
    }

    /// Runs the stages `target` needs (all of them with `None`), skipping those up to date.
    pub fn run(
        &self,
        ws: &Workspace,
        target: Option<&str>,
        force: bool,
        progress: &dyn Progress,
    ) -> Result<Vec<StageReport>> {
        let plan = match target {
            Some(t) => self.plan(t)?,
            None => self.names(),
        };
        let ctx = StageContext { ws, progress };
        plan.into_iter()
            .filter_map(|n| self.get(n))
            .map(|s| s.run_or_skip(&ctx, force))
            .collect()
    }
}
