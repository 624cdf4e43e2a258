//! The registered stages as a graph ([`Pipeline`]): each after the stages it reads, run up to a
//! stage, unit by unit, or in full. Split from `stage.rs`, which holds the [`Stage`] trait and its
//! runner.

use super::*;

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

    fn stage(&self, name: &str) -> Result<&dyn AnyStage> {
        self.get(name).ok_or_else(|| {
            PipelineError::option(
                "stage",
                format!(
                    "no stage `{name}`; the stages are {}",
                    self.names().join(", ")
                ),
            )
        })
    }

    /// How many work units stage `name` splits into in this workspace (0: it does not split, or
    /// it is up to date and `force` is false); the stages it reads must have run.
    pub fn units(&self, ws: &Workspace, name: &str, force: bool) -> Result<usize> {
        let ctx = StageContext {
            ws,
            progress: &handheld_core::NoProgress,
            units: None,
        };
        self.stage(name)?.units(&ctx, force)
    }

    /// Runs unit `k` of stage `name` apart (see the module notes); nothing when it is done.
    pub fn run_unit(
        &self,
        ws: &Workspace,
        name: &str,
        k: usize,
        progress: &dyn Progress,
    ) -> Result<()> {
        let ctx = StageContext {
            ws,
            progress,
            units: None,
        };
        self.stage(name)?.run_unit(&ctx, k)
    }

    /// Runs one stage (taking the files of its units run apart), unless it is up to date; the
    /// stages it reads must have run.
    pub fn run_stage(
        &self,
        ws: &Workspace,
        name: &str,
        force: bool,
        progress: &dyn Progress,
    ) -> Result<StageReport> {
        let ctx = StageContext {
            ws,
            progress,
            units: None,
        };
        self.stage(name)?.run_or_skip(&ctx, force)
    }

    /// The stages `target` cannot do without (what it reads, transitively; not what it only
    /// uses when present), in run order.
    pub fn required(&self, target: &str) -> Result<Vec<&'static str>> {
        let needed = self.closure(target, false)?;
        Ok(self
            .names()
            .into_iter()
            .filter(|n| needed.contains(n))
            .collect())
    }

    /// The stages `name` reads (needs); empty for an unknown stage.
    pub fn reads(&self, name: &str) -> Vec<&'static str> {
        self.get(name)
            .map(|s| s.reads().to_vec())
            .unwrap_or_default()
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
        let ctx = StageContext {
            ws,
            progress,
            units: None,
        };
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
