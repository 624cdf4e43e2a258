//! Multi-view geometry solvers of paper §1.1–§3: plain functions, each citing the equation of
//! Pollefeys et al. (IJCV 2004) or the algorithm of Hartley & Zisserman (*Multiple View Geometry*,
//! 2nd ed., "H&Z") that it implements. Nothing here is robust to outliers: `handheld-robust` wraps
//! these solvers in RANSAC (§2.2, Table 1).
//!
//! Split by concept, one file per estimated object:
//! - [`normalize`]: Hartley's isotropic normalisation, used by every linear solver;
//! - [`fundamental`]: the 7- and 8-point F, Sampson and symmetric epipolar distances, epipoles,
//!   F from two cameras (§2.2, eqs. 11–13);
//! - [`homography`]: the normalised DLT for H and its transfer errors (§3.1, eq. 15);
//! - [`triangulation`]: linear n-view DLT, eq. 20 iterated, and the Hartley–Sturm optimal two-view method (eqs. 17–18);
//! - [`skew`](mod@skew): the cross-product matrix `[e]×` and the canonical camera pair of eq. 16;
//! - [`refine_f`]: LM on eq. 12 over the orthonormal representation of F;
//! - [`gold_standard`]: the sparse ML estimate of eq. 13 (points eliminated by Schur complement);
//! - [`view_distance`](mod@view_distance): the image-based view distance of eqs. 14–15;
//! - [`pnp`]: calibrated resection: Grunert's P3P, absolute orientation, pose refinement;
//! - [`resection`]: 6-point projective resection (DLT) for the projective stage of §3.2;
//! - [`epipolar_uncertainty`]: how well an estimated F fixes each epipolar line: F's covariance from its inliers'
//!   Sampson residuals on the 7-dimensional tangent space, propagated to a line's position at any point of image 2
//!   (H&Z §5.2); guided matching uses it to size its bands;
//! - [`poly`]: small real polynomial root finders (the cubic of the 7-point method, the sextic of
//!   Hartley–Sturm).
//!
//! Conventions: image points are pixels (top-left pixel centre at `(0, 0)`, see
//! [`handheld_core::PIXEL_CENTER_OFFSET_COLMAP`]); a correspondence `x1 ↔ x2` satisfies
//! `x2ᵀ F x1 = 0` and `x2 ~ H x1`. Degenerate or too-small inputs return a [`GeometryError`],
//! never panic.

pub mod epipolar_uncertainty;
pub mod error;
pub mod fundamental;
pub mod gold_standard;
pub mod homography;
mod linalg;
pub mod normalize;
pub mod pnp;
pub mod poly;
pub mod refine_f;
pub mod resection;
pub mod skew;
pub mod triangulation;
pub mod view_distance;

#[cfg(test)]
pub(crate) mod test_util;

pub use epipolar_uncertainty::{EpipolarUncertainty, LineUncertainty};
pub use error::{GeometryError, Result};
pub use fundamental::{
    enforce_rank2, epipoles, fundamental_7point, fundamental_8point, fundamental_from_cameras,
    sampson_distance, sampson_distance_sq, symmetric_epipolar_distance_sq,
};
pub use gold_standard::{gold_standard_fundamental, GoldStandardOptions, GoldStandardReport};
pub use homography::{homography_dlt, symmetric_transfer_error_sq, transfer_error_sq};
pub use normalize::{hartley_normalization, Normalization};
pub use pnp::{absolute_orientation, p3p, refine_pose, Pose};
pub use refine_f::{epipolar_residuals, refine_fundamental, RefineFOptions, RefineFReport};
pub use resection::{reprojection_distance, resection_dlt, resection_iterative};
pub use skew::{canonical_cameras, skew};
pub use triangulation::{
    optimal_correction, triangulate_iterative, triangulate_linear, triangulate_optimal,
};
pub use view_distance::{view_distance, ViewDistance};
