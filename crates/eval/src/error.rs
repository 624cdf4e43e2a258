//! The crate's one error type. Every message names the option, file or tool it concerns.

use thiserror::Error;

/// Everything that can stop a demo or a benchmark.
#[derive(Debug, Error)]
pub enum EvalError {
    /// An option is out of its range (named as the command line spells it).
    #[error("{option}: {reason}")]
    InvalidOption { option: String, reason: String },
    /// An external program (ffmpeg, COLMAP, python3 with OpenCV) is missing or failed.
    #[error("{program}: {reason}")]
    Tool { program: String, reason: String },
    /// The data cannot be evaluated (too little was reconstructed, a file is missing).
    #[error("{0}")]
    Data(String),
    /// Reading or writing a file.
    #[error(transparent)]
    Io(#[from] handheld_io::IoError),
    /// The pipeline stopped.
    #[error(transparent)]
    Pipeline(#[from] handheld_pipeline::PipelineError),
    /// Stereo, rectification or linking failed.
    #[error(transparent)]
    Dense(#[from] handheld_dense::DenseError),
    /// Mesh evaluation failed.
    #[error(transparent)]
    Mesh(#[from] handheld_mesh::MeshError),
}

/// Shorthand for results of this crate.
pub type Result<T, E = EvalError> = std::result::Result<T, E>;

impl EvalError {
    /// An out-of-range option.
    pub fn option(option: impl Into<String>, reason: impl Into<String>) -> Self {
        Self::InvalidOption {
            option: option.into(),
            reason: reason.into(),
        }
    }

    /// An external program that failed.
    pub fn tool(program: impl Into<String>, reason: impl Into<String>) -> Self {
        Self::Tool {
            program: program.into(),
            reason: reason.into(),
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
