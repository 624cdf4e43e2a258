//! Dense surface estimation (paper §4): rectified-pair stereo matching.
//!
//! [`match_rectified`] matches a rectified pair (left `(x, y)` ↔ right `(x − d, y)`) by
//! Semi-Global Matching ([`StereoMethod::Sgm`], Hirschmüller 2008) or by the scanline dynamic
//! programming of the paper (§4.2, [`StereoMethod::Dp`]), then applies a median filter, the
//! left–right consistency check, speckle removal and background hole filling.
//!
//! # Measured on Middlebury (issue #6)
//!
//! teddy and cones (450×375, 64 disparities 0..=63), scored by `../shared/tools/eval_stereo.py`
//! (bad1/bad2 = % of GT-valid pixels off by > 1 / > 2 px, a missing estimate counting as bad),
//! default options, dense (hole-filled) output:
//!
//! | method | teddy bad1 / bad2 | cones bad1 / bad2 |
//! |---|---|---|
//! | SGM (census 9×7, 8 paths) | 11.1 / 6.2 | 9.5 / 7.5 |
//! | SGM, 4 paths | 10.8 / 6.0 | 9.5 / 7.4 |
//! | DP (ZNCC 3×3, κ_occ = 45) | 14.2 / 9.9 | 11.4 / 9.2 |
//! | DP, census 9×7 + 3×3 window, κ_occ = 20 | 13.3 / 8.9 | 11.6 / 9.8 |
//! | OpenCV StereoSGBM (same session) | 27.5 / 24.7 | 22.4 / 21.3 |
//!
//! Measured pixels alone (no filling; 87% / 77% density for SGM / DP) score 18.1 / 27.6 (teddy)
//! and 16.2 / 23.7 (cones) with missing pixels counted as bad. Timing (median of 5 runs with a
//! reused [`StereoMatcher`], 2 cores shared with other jobs, interleaved with OpenCV's SGBM in
//! the same session): SGM 45–90 ms, DP 50–110 ms, OpenCV 37–75 ms; the SGM/OpenCV ratio ranged
//! 0.7–1.6 and DP/OpenCV 0.9–2.1 over four sessions, the high end when another process held one
//! core (OpenCV's SGBM barely slows down then; our two passes run on two threads). Reproduce with
//! `examples/middlebury.sh`.
//!
//! Split by concept:
//! - [`options`] holds [`StereoOptions`] and its validation;
//! - [`disparity`] holds the [`Disparity`] output (values plus a measured/filled mask);
//! - [`error`] holds [`DenseError`];
//! - `cost`, `zncc` (private): census and ZNCC cost volumes;
//! - `sgm`, `dp` (private): the two optimisers;
//! - `wta`, `refine`, `fill` (private): winner-take-all with sub-pixel fits, median / consistency
//!   / speckle filtering, and hole filling;
//! - `stereo` (private): [`match_rectified`] and the reusable [`StereoMatcher`], band tiling for
//!   bounded memory;
//! - `pyramid` (private): coarse-to-fine per-pixel disparity windows (tSGM), so that wide ranges
//!   at full resolution search a fixed number of disparities per pixel.
//!
//! Beyond the pair matcher, the crate holds the whole §4 stage:
//! - [`rectify`]: rectification of calibrated pairs: polar around the oriented epipoles with the minimal-size angle step
//!   (`polar.rs`; any motion, the epipole inside the image included), planar homographies as the fast path
//!   (`planar.rs`), both on ideal (undistorted) coordinates (`ideal.rs`) with exact `R(·)`/`R⁻¹(·)` and one-step
//!   resampling that removes distortion;
//! - `stereo` also keeps the left and right disparities of the left–right check, and bounds memory by bands;
//! - [`pair`]: one pair end to end, with the disparity range from the sparse points;
//! - [`order`]: the sequence a set of photos is densified in (a path through the shared-point graph);
//! - [`link`]: multi-view linking, eq. 28 chains with Kalman fusion, gate and visibility; `LinkedDepth::confidence`;
//! - [`stage`]: the sequence stage with a sliding pair window and the fused cloud, handing out each view as a
//!   `PosedView` with its depth, variance, confidence and visibility.
//!
//! Options and summaries are serialisable; the pipeline's dense stage and `handheld dense` only call [`stage`].

mod cost;
pub mod disparity;
mod dp;
pub mod error;
mod fill;
pub mod link;
pub mod options;
pub mod order;
pub mod pair;
mod pyramid;
pub mod rectify;
mod refine;
mod sgm;
pub mod sparse_points;
pub mod stage;
mod stereo;
#[cfg(test)]
mod synthetic;
mod wta;
mod zncc;

pub use disparity::Disparity;
pub use error::DenseError;
pub use link::{link_depth, LinkOptions, LinkedDepth, CONFIDENCE_RELATIVE_SIGMA};
pub use options::{
    HoleFill, MatchingCost, ParseStereoMethodError, SgmPaths, StereoMethod, StereoOptions,
    MAX_DISPARITIES,
};
pub use order::{densify_order, SequenceOrder};
pub use pair::{
    grey_image, match_pair, match_pair_with, match_sequence_pairs, PairDisparity, PairOptions,
};
pub use rectify::{rectify_pair, Rectification, RectifyMethod, RectifyOptions};
pub use sparse_points::{SparsePoints, MIN_RANGE_POINTS};
pub use stage::{
    dense_reconstruct, dense_reconstruct_with, DenseOptions, DenseSummary, DenseViewResult,
    FailedPair,
};
pub use stereo::{match_rectified, StereoMatcher, SGM_BAND_OVERLAP};
