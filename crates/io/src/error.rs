//! One error type for every file the io crate touches. Each variant names the path and says what to do.

use std::path::PathBuf;

/// Errors from reading or writing files and running external tools.
#[derive(Debug, thiserror::Error)]
pub enum IoError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: does not exist")]
    NotFound { path: PathBuf },
    #[error("{path}: {reason}")]
    Format { path: PathBuf, reason: String },
    #[error("{path}: cannot decode image ({reason}); check that the file is a complete JPEG, PNG or TIFF")]
    Decode { path: PathBuf, reason: String },
    #[error("{path}: {reason}")]
    Input { path: PathBuf, reason: String },
    #[error("ffmpeg was not found (tried `{program}`): install it, e.g. `sudo apt-get install ffmpeg` on Debian/Ubuntu, `brew install ffmpeg` on macOS, or set HANDHELD_FFMPEG to its path")]
    FfmpegMissing { program: String },
    #[error("{path}: ffmpeg cannot read this video: {reason}")]
    Video { path: PathBuf, reason: String },
    /// `ffmpeg` ran but could not write the video `path`.
    #[error("{path}: ffmpeg could not encode the video: {reason}; check that this ffmpeg has the libx264 encoder (`ffmpeg -encoders`) and that the folder is writable")]
    Encode { path: PathBuf, reason: String },
    /// An option of an io function is out of its valid range; `option` is the field's name.
    #[error("invalid option `{option}`: {reason}")]
    InvalidOption {
        option: &'static str,
        reason: String,
    },
}

impl IoError {
    /// Wraps a `std::io::Error` with the path it concerns (a missing file becomes [`IoError::NotFound`]).
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        let path = path.into();
        if source.kind() == std::io::ErrorKind::NotFound {
            IoError::NotFound { path }
        } else {
            IoError::Io { path, source }
        }
    }

    pub fn format(path: impl Into<PathBuf>, reason: impl Into<String>) -> Self {
        IoError::Format {
            path: path.into(),
            reason: reason.into(),
        }
    }
}

pub type Result<T, E = IoError> = std::result::Result<T, E>;
