//! Linear self-calibration with the dual absolute quadric (§3.4 "Upgrading to Metric", eqs. 22–27).
//!
//! A projective reconstruction `{Pᵢ, Mⱼ}` is only defined up to a 4×4 homography. In a metric frame
//! the dual absolute quadric is `Ω* = diag(1, 1, 1, 0)` and it projects to the dual image of the
//! absolute conic (eqs. 22–23):
//!
//! ```text
//! ω*ᵢ ∼ Pᵢ Ω* Pᵢᵀ ∼ Kᵢ Kᵢᵀ
//! ```
//!
//! Since the images do not depend on the projective basis, prior knowledge about the intrinsics
//! (`f ≈ 1 ± 3`, `u ≈ v ≈ 0 ± 0.1`, `r ≈ 1 ± 0.1`, `s = 0` after the normalization `K_N` of eq. 24)
//! turns into linear equations on the 10 coefficients of the symmetric `Ω*` (eqs. 25–26). They are
//! solved by weighted linear least squares (smallest right singular vector of the stacked system),
//! re-weighted with `ν = P₃ Ω* P₃ᵀ` of the previous estimate, the rank-3 constraint is enforced and
//! the upgrade `T` with `diag(1, 1, 1, 0) = T Ω* Tᵀ` gives the metric cameras and points
//! `P_M = P T⁻¹`, `M_M = T M` (eq. 27).
//!
//! Two additions to the paper, both documented on [`SelfCalibrationOptions`]:
//! - the means of the priors can be estimated jointly (still one linear system), which removes the
//!   bias of eq. 26 when the intrinsics are far from the prior means (on by default; the verbatim
//!   scheme is `estimate_prior_means: false`);
//! - critical motions are detected from the singular values of the equations that do not involve
//!   the focal prior, and reported in [`SelfCalibration::degenerate`] rather than as an error.
//!
//! Layout: `types.rs` (options, result, errors, the `K_N` of eq. 24), `equations.rs` (the eq. 26
//! system and the guarded linear algebra every solver shares), `linear.rs` ([`self_calibrate`]),
//! `rank3.rs` (the rank-3 upgrade `T` of eq. 27 and the decomposition `K [R | t]`), `known.rs`
//! (eq. 26 for a given focal length, [`upgrade_for_focal`], which the focal hypotheses of
//! `upgrade/hypotheses.rs` search over).

mod equations;
mod known;
mod linear;
mod rank3;
mod types;

pub use known::*;
pub use linear::self_calibrate;
pub use rank3::decompose_camera;
pub use types::*;

#[cfg(test)]
mod test_scenes;
#[cfg(test)]
mod tests;
#[cfg(test)]
mod tests_degenerate;
