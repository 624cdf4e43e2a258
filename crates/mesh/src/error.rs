//! Errors of the surface stage. Each message names the offending option, view or input.

use thiserror::Error;

/// Everything that can go wrong while meshing, fusing, simplifying or texturing.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum MeshError {
    /// An options field is out of its valid range.
    #[error("invalid mesh option `{option}`: {reason}")]
    InvalidOption {
        option: &'static str,
        reason: String,
    },
    /// A stage was given no views at all.
    #[error("no {what} were given")]
    NoViews { what: &'static str },
    /// A map (depth, confidence) or image does not have the size of its view's camera.
    #[error("view {view}: the {what} is {got_w}x{got_h} but its camera is {cam_w}x{cam_h}; depth maps, confidence maps and images must be at the camera's resolution")]
    SizeMismatch {
        view: usize,
        what: &'static str,
        got_w: usize,
        got_h: usize,
        cam_w: usize,
        cam_h: usize,
    },
    /// A view lacks a map the stage needs (e.g. fusion needs every view's depth map).
    #[error(
        "view {view} has no {what}; this stage needs one per view (run the dense stage first)"
    )]
    MissingMap { view: usize, what: &'static str },
    /// A map has the wrong channel count or a data length that does not match its size.
    #[error("view {view}: malformed {what}: {reason}")]
    MalformedMap {
        view: usize,
        what: &'static str,
        reason: String,
    },
    /// A camera or pose is unusable (non-finite values, non-positive focal length).
    #[error("view {view}: unusable camera: {reason}")]
    BadCamera { view: usize, reason: String },
    /// A depth map has no valid (finite, positive, confident) pixel.
    #[error("view {view}: the depth map has no valid pixel (all missing, non-positive or below the confidence threshold)")]
    EmptyDepth { view: usize },
    /// The depth maps never agree on a surface: nothing was observed by enough views.
    #[error("no voxel near a surface was observed by at least {min_observations} of the {views} depth maps: the depth maps do not overlap (check that poses, scale and depth units match)")]
    NoOverlap {
        views: usize,
        min_observations: usize,
    },
    /// The TSDF would need more blocks than allowed.
    #[error("the TSDF needs more than {limit} voxel blocks ({bytes_mib} MiB) at voxel size {voxel_size}: raise the voxel size or `max_blocks`")]
    TooManyBlocks {
        limit: usize,
        bytes_mib: usize,
        voxel_size: f64,
    },
    /// A stage produced no triangle.
    #[error("the {stage} produced an empty mesh: {reason}")]
    EmptyResult { stage: &'static str, reason: String },
    /// An input mesh is malformed (face index past the vertices, attribute counts).
    #[error("invalid input mesh: {0}")]
    BadMesh(String),
}

/// Shorthand for results of this crate.
pub type Result<T> = std::result::Result<T, MeshError>;

/// Checks that `value` is finite and strictly positive.
pub(crate) fn positive(option: &'static str, value: f64) -> Result<()> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(MeshError::InvalidOption {
            option,
            reason: format!("must be finite and positive, got {value}"),
        })
    }
}

/// Checks that `value` lies in `[lo, hi]`.
pub(crate) fn in_range(option: &'static str, value: f64, lo: f64, hi: f64) -> Result<()> {
    if value.is_finite() && (lo..=hi).contains(&value) {
        Ok(())
    } else {
        Err(MeshError::InvalidOption {
            option,
            reason: format!("must lie in [{lo}, {hi}], got {value}"),
        })
    }
}
