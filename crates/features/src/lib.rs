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

pub mod close_views;
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
pub mod quantized;
pub mod refine;
pub mod retrieval;
pub mod sift;
pub mod verify;
pub mod video;
pub mod zncc;

pub use detector::{Descriptors, FeatureDetector, Features, Keypoint};
pub use error::FeatureError;
pub use gray::GrayImage;
