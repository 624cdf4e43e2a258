//! Projective structure and motion (§3.1–3.3, Table 2, steps 2–4), in the image coordinates
//! normalised by `K_N` of eq. 24 so that every linear system is well conditioned and the cameras come
//! out ready for self-calibration.
//!
//! - Initial frame (§3.1, `init.rs`): the pair that maximises matches × image-based distance (eq. 14); the camera
//!   pair of eq. 16 with the reference plane `a` chosen to make the frame quasi-Euclidean (see
//!   `initial_cameras`); points by the optimal method of Hartley & Sturm (eqs. 17–18).
//! - Adding views (§3.2): 2D–3D candidates from every registered view matched to the new one (the
//!   predecessor and all close views), projective resection by the 6-point DLT inside the shared
//!   RANSAC with T(1,1); structure refinement by eq. 20; new points from all registered partners.
//! - Projective bundle adjustment (§3.3, eq. 21) after the model grows by a fixed factor and at the end,
//!   each followed by removal of observations that no longer reproject within the threshold.
//!
//! Layout: `model.rs` (the growing [`model::ProjectiveModel`] and its bookkeeping, which every
//! other file shares), `init.rs` (§3.1), `resection.rs` (§3.2) and `planar.rs` (its degenerate case:
//! inliers on one plane, Pollefeys et al. 2002), `ba.rs` (§3.3), `tracks.rs`
//! (track completion and merging after the last view), `grow.rs` (the loop of Table 2 steps 2–4,
//! [`grow::reconstruct_projective`]). The read-only data of a reconstruction (the input, the
//! correspondence graph, the `K_N`-normalised keypoints) are in `crate::context`.

pub(crate) mod ba;
pub(crate) mod grow;
pub(crate) mod init;
pub(crate) mod model;
pub(crate) mod planar;
pub(crate) mod resection;
pub(crate) mod tracks;
