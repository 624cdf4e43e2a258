//! Progress reporting without a UI dependency: stages report through this trait and the CLI draws
//! bars (indicatif). Libraries and tests pass [`NoProgress`].

/// A sink for the progress of one long-running step.
pub trait Progress: Sync {
    /// Starts a step of `len` units of work (`0` when unknown).
    fn start(&self, label: &str, len: u64);
    /// `n` more units are done.
    fn inc(&self, n: u64);
    /// The step is over.
    fn finish(&self);
}

/// Progress that goes nowhere.
#[derive(Clone, Copy, Debug, Default)]
pub struct NoProgress;

impl Progress for NoProgress {
    fn start(&self, _label: &str, _len: u64) {}
    fn inc(&self, _n: u64) {}
    fn finish(&self) {}
}
