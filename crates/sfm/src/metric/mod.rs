//! The metric model (§3.4's metric bundle adjustment, and §3.2's extension of the structure once
//! the cameras are calibrated): adjusting it, growing it and judging it.
//!
//! - `ba.rs`: the metric bundle adjustment schedule (eq. 21 with the calibration of eq. 3: focal
//!   length and k1 first with the principal point at the centre, then every intrinsic the options
//!   allow, then a final pass and the survivors), each followed by outlier removal; the paper's
//!   constraints (photos: one camera per group, constant f, principal point and k1, aspect 1, skew
//!   0; video: a constant aspect ratio too), the soft priors (principal point near the centre,
//!   EXIF focal lengths, a known calibration) and the scale gauge kept in range.
//! - `noise.rs`: the observations' noise σ̂ measured on the residuals, which sets the later
//!   adjustments' Huber scale and their priors' weight (Huber's proposal 2).
//! - `profile.rs`: probes that adjust the model again on a sample of its points: the fit along the
//!   focal length held ±20 % (`focal_profile`, `held_adjustment`) and the principal point's
//!   jackknife over the views (`principal_point_spread`).
//! - `principal_point.rs`: whether the images determine the principal point (its offset against
//!   that spread, Σ offset² < 2 Σ σ², and whether the views rotate at all: Sturm 1997), holding it
//!   at the image centre when they do not.
//! - `resect.rs`, `register.rs`, `register_pair.rs`, `planes.rs`: calibrated registration of the
//!   views the projective stage could not add (P3P in the shared RANSAC, then new points with every
//!   registered partner), and of views that share no 3D point, from a registered partner's
//!   plane-segmented depths.
//! - `predict.rs`: more observations at the points' predicted projections (§3.2's guided matching).
//! - `consistency.rs`: every registered view against its verified pairs (the rotation of
//!   `E = K_bᵀ F K_a` against the model's, H&Z §9.6.2); the pipeline takes out a view that
//!   disagrees, builds the model again without it and registers it again; `pair_rotation.rs`: each
//!   pair's rotation refined on its inliers and its uncertainty, which widens what the pair allows.
//! - `depthless.rs`: points whose rays are parallel within their noise (no measured depth), taken
//!   out of the finished model.
//! - `rolling.rs`: a video's rolling shutter, its read-out adjusted with the model, each frame's
//!   velocity from its registered neighbours.
//! - `uncertainty.rs`: per-point and intrinsics uncertainty from the adjustment's covariance.

pub mod ba;
pub mod consistency;
pub(crate) mod depthless;
pub(crate) mod noise;
pub(crate) mod pair_rotation;
pub(crate) mod planes;
pub(crate) mod predict;
pub(crate) mod principal_point;
pub mod profile;
pub(crate) mod register;
pub(crate) mod register_pair;
pub(crate) mod resect;
pub mod rolling;
pub mod uncertainty;
