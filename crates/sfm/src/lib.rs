//! Uncalibrated structure and motion (§3 of Pollefeys et al. 2004, Table 2): from images with
//! keypoints and verified pairs to one or more metric models. One call, [`reconstruct`], takes an
//! [`SfmInput`] and returns [`SfmResult`]: a broken sequence gives several models with the reason,
//! never a silent partial result; the images left out each get theirs.
//!
//! The folders follow the phases of §3:
//!
//! | phase | where | what |
//! |---|---|---|
//! | input | `input.rs`, `canonical.rs`, `graph.rs`, `context.rs` | images, verified pairs; photos put in content order (ids renumbered and restored, so file names and order change nothing); the correspondence graph (Table 2 step 1); the read-only `Context` with the keypoints normalised by `K_N` (eq. 24) |
//! | §3.1–3.3 projective | `projective/` | initial pair (eqs. 14, 16–18), resection and structure extension (eq. 20) with its planar case (Pollefeys et al. 2002, `planar.rs`), projective BA (eq. 21), track completion |
//! | §3.4 upgrade | `upgrade/` | linear self-calibration with the dual absolute quadric (eqs. 22–27, `selfcal/`), the upgrade applied (eq. 27), focal hypotheses under critical motion, the candidate frames and their judge (`guard/`) |
//! | §3.4 metric | `metric/` | metric BA with radial distortion (eq. 3) and its noise-scaled loss, calibrated registration, predicted matches (§3.2), view consistency, the principal point's test, uncertainty |
//! | safety net | `calibrated.rs`, `duplicates.rs` | the calibrated incremental candidate (a focal length assumed from the start, E from F, P3P growth, f and k1 adjusted as the model grows; COLMAP's way) when the first stratified start fails, when none is sound or the one kept is a fall-back; duplicate shots (an identical copy makes no point with its original alone) |
//! | pieces | `merge/` | models of a broken sequence merged where they share points (3D–3D or 2D–3D) |
//! | scale | `split/` | split-and-merge for large sets: the view graph cut by normalised cuts into overlapping clusters, each reconstructed on its own, merged through their shared views, one global adjustment |
//! | video | `video.rs` | in-between frames posed from their KLT tracks (Table 2's "for every frame") |
//! | steps | `pipeline/` | [`reconstruct`]: the models one after the other, each by named steps that fail with a [`StepError`] |
//!
//! Shared leaves that import no phase: `error.rs` ([`SfmError`], [`StepError`]), `options.rs`
//! ([`SfmOptions`]), `common.rs` (the median, the image centre), `summary.rs` (what a model
//! reports, [`ModelSummary`]). No file imports one that imports it back: `projective/` knows
//! nothing of the later phases; `upgrade/` and `metric/` share the adjustment machinery
//! (`metric/ba.rs`, `noise.rs`, `profile.rs`) and the judge of adjustments (`upgrade/guard/`); the
//! pipeline, the merge and the summary sit on top.
//!
//! Deterministic for a given input and seed, and for photos independent of their order.

mod calibrated;
mod canonical;
mod common;
mod context;
mod duplicates;
mod error;
pub mod graph;
pub mod input;
pub mod merge;
pub mod metric;
pub mod options;
mod pipeline;
pub(crate) mod projective;
pub mod split;
mod summary;
#[cfg(test)]
mod test_scene;
pub mod upgrade;
mod video;

pub use error::{SfmError, StepError};
pub use input::{SfmImage, SfmInput, SfmPair};
pub use merge::MergeRecord;
pub use metric::ba::MetricBaRecord;
pub use metric::consistency::{ConsistencyReport, ViewDisagreement};
pub use metric::profile::PrincipalPointSpread;
pub use metric::uncertainty::{IntrinsicsSigma, UncertaintyReport};
pub use options::{Distortion, KnownIntrinsics, SfmOptions};
pub use pipeline::reconstruct;
pub use projective::model::ProjectiveBaRecord;
pub use split::{SplitOptions, SplitReport};
pub use summary::{DuplicateShot, GroupSummary, ModelSummary, SfmModel, SfmResult};
pub use upgrade::guard::CandidateRecord;
pub use upgrade::transform::{RejectedStart, SelfCalibrationReport};
