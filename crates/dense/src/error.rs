//! Errors of the dense stage.

use thiserror::Error;

/// Everything that can go wrong in dense matching. Messages name the offending option or input.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum DenseError {
    /// A [`crate::StereoOptions`] field is out of its valid range.
    #[error("invalid stereo option `{option}`: {reason}")]
    InvalidOption {
        option: &'static str,
        reason: String,
    },
    /// The two images of a rectified pair do not have the same size.
    #[error("left and right images differ in size: {lw}x{lh} vs {rw}x{rh}")]
    SizeMismatch {
        lw: usize,
        lh: usize,
        rw: usize,
        rh: usize,
    },
    /// An input image is malformed (empty, wrong channel count, data length).
    #[error("invalid {which} image: {reason}")]
    InvalidImage { which: &'static str, reason: String },
    /// A pair cannot be rectified (degenerate geometry); the reason says which and what to do.
    #[error("cannot rectify the pair: {reason}")]
    Rectification { reason: String },
    /// Inputs of multi-view linking do not fit together.
    #[error("invalid linking input: {reason}")]
    Linking { reason: String },
}

/// Shorthand for results of this crate.
pub type Result<T> = std::result::Result<T, DenseError>;
