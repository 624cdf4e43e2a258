//! Robust estimation of §2.2 (Table 1): one generic RANSAC loop, [`run`], parametrised by three small
//! traits, plus the estimators that wrap `handheld-geometry`'s minimal solvers.
//!
//! Split by concept:
//! - [`estimator`]: the [`Estimator`] trait (minimal fit, residual, non-minimal refit);
//! - [`sampler`]: the [`Sampler`] trait and [`UniformSampler`], which owns a seeded `ChaCha8Rng`
//!   (no hidden thread-local generator anywhere, so every run is reproducible from its seed);
//! - [`consensus`]: the [`Consensus`] trait, [`InlierCount`] (plain RANSAC) and [`Msac`]
//!   (truncated quadratic, Torr & Zisserman 2000);
//! - [`options`]: [`RansacOptions`] with documented defaults and `validate()`;
//! - [`ransac`]: the loop itself with adaptive stopping (paper: `Γ = 1 − (1 − γᵖ)ᵐ`), LO-RANSAC
//!   (Chum, Matas & Kittler 2003) with an inner RANSAC, and the preemptive T(d,d) test (Chum & Matas 2002), returning a
//!   [`RansacReport`]: finding no model is a normal outcome, not an error;
//! - [`two_view`]: [`Match2d2d`], [`FundamentalEstimator`] (7-point minimal, 8-point refit, Sampson
//!   residual) and [`HomographyEstimator`] (4-point DLT, symmetric transfer residual);
//! - [`resection`]: the projective resection (6-point) and calibrated P3P estimators of §3.2;
//! - [`gric`]: Torr's GRIC for choosing between F and H;
//! - [`verify`]: the Table 1 facade [`estimate_two_view_geometry`] (RANSAC, eq. 12/13 refinement,
//!   GRIC, configuration: general, planar, pure rotation, too few inliers).
//!
//! Other crates reuse [`run`] for their own models: the sfm crate's plane estimator for plane-segmented depths, and the
//! render crate's dominant-plane search for the augmented video's object.

pub mod consensus;
pub mod estimator;
pub mod gric;
pub mod options;
pub mod ransac;
pub mod resection;
pub mod sampler;
pub mod two_view;
pub mod verify;

pub use consensus::{Consensus, InlierCount, Msac};
pub use estimator::Estimator;
pub use options::{RansacError, RansacOptions};
pub use ransac::{required_iterations, run, RansacReport};
pub use resection::{CalibratedMatch, Match2d3d, P3pEstimator, ResectionEstimator};
pub use sampler::{Sampler, UniformSampler};
pub use two_view::{FundamentalEstimator, HomographyEstimator, Match2d2d};
pub use verify::{
    estimate_two_view_geometry, refine_two_view, TwoViewConfiguration, TwoViewGeometry,
    TwoViewOptions,
};
