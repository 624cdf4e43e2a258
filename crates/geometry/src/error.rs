//! One error enum for every solver: the inputs were too few, inconsistent or degenerate. Kept apart
//! so that each solver file holds only its algorithm.

/// Why a solver could not produce an estimate.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum GeometryError {
    /// Fewer correspondences (or views) than the method needs.
    #[error("need at least {required} correspondences, got {actual}")]
    InsufficientCorrespondences { required: usize, actual: usize },
    /// The two point lists (or the camera and point lists) differ in length.
    #[error("input lengths differ: {left} vs {right}")]
    LengthMismatch { left: usize, right: usize },
    /// An input coordinate is NaN or infinite.
    #[error("input contains a non-finite value")]
    NonFinite,
    /// The configuration does not determine a unique solution (coincident or collinear points,
    /// a rank-deficient design matrix, a point on the baseline, ...).
    #[error("degenerate configuration: {reason}")]
    Degenerate { reason: &'static str },
}

/// Result alias of this crate.
pub type Result<T> = std::result::Result<T, GeometryError>;

pub(crate) fn check_pair_lengths<A, B>(x1: &[A], x2: &[B], required: usize) -> Result<()> {
    if x1.len() != x2.len() {
        return Err(GeometryError::LengthMismatch {
            left: x1.len(),
            right: x2.len(),
        });
    }
    if x1.len() < required {
        return Err(GeometryError::InsufficientCorrespondences {
            required,
            actual: x1.len(),
        });
    }
    Ok(())
}
