//! The pipeline's one error type. Every message names the option, file or stage it concerns and
//! says what to do.

use std::path::PathBuf;

use thiserror::Error;

/// Everything that can stop a pipeline run.
#[derive(Debug, Error)]
pub enum PipelineError {
    /// A stage option is out of its range (the option is named as the user gives it).
    #[error("{option}: {reason}")]
    InvalidOption { option: String, reason: String },
    /// The user's input cannot be used.
    #[error("{path}: {reason}")]
    Input { path: PathBuf, reason: String },
    /// A workspace file is missing, unreadable or inconsistent with the others.
    #[error("{path}: {reason}")]
    Workspace { path: PathBuf, reason: String },
    /// A stage needs another one that is not in the graph, or the graph is malformed.
    #[error("stage graph: {0}")]
    Graph(String),
    /// A stage needs the output of one that has not run.
    #[error("stage `{needed}` has not run (stage `{by}` reads it): run `handheld reconstruct` with `--until {by}`")]
    NotRun { needed: String, by: String },
    /// A library step failed; `context` says which.
    #[error("{context}: {cause}")]
    Step {
        context: String,
        cause: Box<dyn std::error::Error + Send + Sync>,
    },
    #[error(transparent)]
    Io(#[from] handheld_io::IoError),
}

/// Shorthand for results of this crate.
pub type Result<T, E = PipelineError> = std::result::Result<T, E>;

impl PipelineError {
    /// An out-of-range option.
    pub fn option(option: impl Into<String>, reason: impl Into<String>) -> Self {
        Self::InvalidOption {
            option: option.into(),
            reason: reason.into(),
        }
    }

    /// A workspace file that cannot be used.
    pub fn workspace(path: impl Into<PathBuf>, reason: impl Into<String>) -> Self {
        Self::Workspace {
            path: path.into(),
            reason: reason.into(),
        }
    }

    /// A library's range check failed on a stage's options.
    pub fn invalid(stage: &str, e: impl Into<Box<dyn std::error::Error + Send + Sync>>) -> Self {
        Self::Step {
            context: format!("invalid {stage} options"),
            cause: e.into(),
        }
    }

    /// The name of the invalid option, when this is one.
    pub fn invalid_option(&self) -> Option<&str> {
        match self {
            Self::InvalidOption { option, .. } => Some(option),
            _ => None,
        }
    }
}

/// Adds what was being done to a library error (or a library's `String` error); `?` turns the
/// result into any error type that wraps [`PipelineError`] (the eval crate's does).
pub trait Context<T> {
    fn context(self, what: impl Into<String>) -> Result<T>;
    fn with_context<S: Into<String>>(self, what: impl FnOnce() -> S) -> Result<T>;
}

impl<T, E: Into<Box<dyn std::error::Error + Send + Sync>>> Context<T>
    for std::result::Result<T, E>
{
    fn context(self, what: impl Into<String>) -> Result<T> {
        self.map_err(|e| PipelineError::Step {
            context: what.into(),
            cause: e.into(),
        })
    }

    fn with_context<S: Into<String>>(self, what: impl FnOnce() -> S) -> Result<T> {
        self.map_err(|e| PipelineError::Step {
            context: what().into(),
            cause: e.into(),
        })
    }
}

/// A rendering option or scene error: an option names its flag.
impl From<handheld_render::scene::SceneError> for PipelineError {
    fn from(e: handheld_render::scene::SceneError) -> Self {
        match e {
            handheld_render::scene::SceneError::Option { option, reason } => {
                PipelineError::option(option, reason)
            }
            handheld_render::scene::SceneError::Scene(reason) => PipelineError::Graph(reason),
        }
    }
}
