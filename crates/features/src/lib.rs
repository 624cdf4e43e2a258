//! Correspondences (paper §2): interest points, descriptors, matching and tracking.
//!
//! Split by concept: [`close_views`] (extra pairs for cameras that return, §3.2), [`extract`] (one image in, features out), [`gray`] (the float grey image, blur, pyramid, sampling), [`detector`] (the
//! swappable detector trait and feature types), [`error`] (the typed option errors), [`harris`] (Harris corners, §2.1), [`zncc`] (normalised
//! patches whose dot product is the ZNCC of eq. 9), [`klt`] (pyramidal Lucas–Kanade tracking, eq. 8),
//! [`keyframes`] (video key-frames by GRIC, §3.1 footnote 1), [`sift`] (SIFT-class wide-baseline features, RootSIFT), [`matching`] (brute-force descriptor matching
//! by matrix product, ratio and mutual tests), [`quantized`] (the product in 8-bit integers), [`verify`] (Table 1 over image pairs: RANSAC, model
//! selection, guided matching, refinement; the keypoint grid of its epipolar-band queries is in
//! `epipolar_grid`), [`video`] (KLT tracks over a whole video, key-frames and
//! key-frame pairs).
//!
//! Where each piece lives:
//! - `sift.rs`, `sift/descriptor.rs`: RootSIFT (own implementation); `extract.rs` upsamples the first octave for small
//!   images and lowers the contrast threshold adaptively while an image gives too few features;
//! - `harris.rs`, `zncc.rs`: Harris corners and ZNCC patches;
//! - `klt.rs` (the tracker) and `klt_align.rs` (the pyramid, the Lucas–Kanade and affine kernels): pyramidal KLT with
//!   the affine consistency check;
//! - `matching.rs`: GEMM descriptor matching, ratio and mutual tests; `quantized.rs`: descriptors quantised to bytes, an
//!   AVX-512 VNNI kernel where the CPU has one, else the f32 GEMM on the same integers, with the same matches;
//! - `verify.rs`: pair verification (Table 1), seeded matching (brute force over the strongest keypoints, then guided
//!   matching over all), pairs verified in the order of their images' content keys;
//! - `guided.rs`: guided matching: the ratio test sees every keypoint that may lie on the true line, the band widened
//!   by 3σ of the seeds' line there, and no match is made where the line is too uncertain; `epipolar_grid.rs`: the
//!   epipolar-band keypoint grid;
//! - `video.rs`: video tracks, GRIC key-frames and key-frame pairs, and the verdict on whether KLT held over a video
//!   (track survival from frame to frame, key-frames to the end; the features stage falls back to SIFT when it did not);
//! - `refine.rs`: multi-view keypoint refinement by affine registration to each track's reference keypoint (opt-in);
//! - `retrieval.rs`: VLAD image retrieval for pair selection, with a vocabulary trained in content order, and the
//!   spectral seriation that recovers a capture order from the images (`--pairs retrieval`, and the default pairs of
//!   photo sets over 40 images);
//! - `close_views.rs`: extra pairs for cameras that return (§3.2);
//! - `second_round.rs`: the second round of pairs for selectively matched photo sets (every pair of an image
//!   whose first round verified few).

pub mod close_views;
pub mod copies;
pub mod detector;
mod epipolar_grid;
pub mod error;
pub mod extract;
pub mod gray;
mod guided;
pub mod harris;
pub mod keyframes;
pub mod klt;
mod klt_align;
pub mod matching;
mod nearest;
pub mod quantized;
pub mod refine;
pub mod retrieval;
pub mod second_round;
pub mod sift;
pub mod verify;
pub mod video;
pub mod zncc;

pub use detector::{Descriptors, FeatureDetector, Features, Keypoint};
pub use error::FeatureError;
pub use gray::GrayImage;
