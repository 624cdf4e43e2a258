//! What the SfM stage consumes: images with their keypoints, and verified image pairs with inlier
//! matches (Table 1's output). Plain data, so that the CLI can fill it from COLMAP's `database.db`,
//! tests from testkit, and the video mode from KLT tracks.

use handheld_core::{FrameInfo, ImageId};
use handheld_robust::TwoViewConfiguration;
use nalgebra::{Matrix3, Vector2};

/// One input image.
#[derive(Clone, Debug)]
pub struct SfmImage {
    pub id: ImageId,
    pub name: String,
    pub width: u32,
    pub height: u32,
    /// Keypoint positions in pixels (top-left pixel centre at (0, 0)); matches index into this list.
    pub keypoints: Vec<Vector2<f64>>,
    /// Detection scale of each keypoint (the SIFT σ, pixels), same length as `keypoints`; empty when
    /// unknown. Metric BA weights observations by it (a coarser keypoint is located less precisely).
    pub keypoint_scales: Vec<f32>,
    /// Images with the same key share one intrinsics group (camera body + zoom from EXIF; one key for
    /// a whole video).
    pub camera_key: String,
    /// An EXIF focal length in pixels: only a prior, never required.
    pub focal_prior_px: Option<f64>,
    /// Frame index and time for video input.
    pub frame: Option<FrameInfo>,
    /// Video input: the stable KLT track id of every keypoint (same length as `keypoints`); empty
    /// for photos. In-between frames, which have no verified pairs, are linked to the 3D points
    /// through these ids.
    pub track_ids: Vec<u64>,
    /// Descriptors quantised to bytes, row-major `keypoints.len() × descriptor_dim` (RootSIFT times
    /// 512, as in COLMAP's database); empty with `descriptor_dim == 0` when there are none (video
    /// tracks). Used to match predicted projections (§3.2).
    pub descriptors: Vec<u8>,
    pub descriptor_dim: usize,
}

/// One verified image pair (indices into [`SfmInput::images`]).
#[derive(Clone, Debug)]
pub struct SfmPair {
    pub a: usize,
    pub b: usize,
    /// Inlier matches `(keypoint in a, keypoint in b)`.
    pub matches: Vec<(u32, u32)>,
    /// `x_bᵀ F x_a = 0` in pixels, when estimated.
    pub f: Option<Matrix3<f64>>,
    pub configuration: TwoViewConfiguration,
    /// The image-based distance of eq. 14 in pixels (median residual of the best planar homography).
    pub view_distance_px: Option<f64>,
}

/// The whole input of [`crate::reconstruct`].
#[derive(Clone, Debug, Default)]
pub struct SfmInput {
    pub images: Vec<SfmImage>,
    pub pairs: Vec<SfmPair>,
    /// Video input: one camera, aspect ratio estimated (§3.4), per-frame poses.
    pub video: bool,
}

impl SfmInput {
    /// Checks indices and sizes; the error names the offending image or pair.
    pub fn validate(&self) -> Result<(), String> {
        for im in &self.images {
            if im.width == 0 || im.height == 0 {
                return Err(format!("image {} ({}) has zero size", im.id, im.name));
            }
            if im
                .keypoints
                .iter()
                .any(|k| !k.x.is_finite() || !k.y.is_finite())
            {
                return Err(format!(
                    "image {} ({}) has a non-finite keypoint",
                    im.id, im.name
                ));
            }
        }
        for im in &self.images {
            if im.descriptors.len() != im.keypoints.len() * im.descriptor_dim {
                return Err(format!(
                    "image {} ({}) has {} descriptor bytes for {} keypoints of dimension {}",
                    im.id,
                    im.name,
                    im.descriptors.len(),
                    im.keypoints.len(),
                    im.descriptor_dim
                ));
            }
            if !im.keypoint_scales.is_empty() && im.keypoint_scales.len() != im.keypoints.len() {
                return Err(format!(
                    "image {} ({}) has {} keypoint scales for {} keypoints",
                    im.id,
                    im.name,
                    im.keypoint_scales.len(),
                    im.keypoints.len()
                ));
            }
            if im
                .keypoint_scales
                .iter()
                .any(|s| !(s.is_finite() && *s > 0.0))
            {
                return Err(format!(
                    "image {} ({}) has a non-positive or non-finite keypoint scale",
                    im.id, im.name
                ));
            }
            if !im.track_ids.is_empty() && im.track_ids.len() != im.keypoints.len() {
                return Err(format!(
                    "image {} ({}) has {} track ids for {} keypoints",
                    im.id,
                    im.name,
                    im.track_ids.len(),
                    im.keypoints.len()
                ));
            }
        }
        for p in &self.pairs {
            let (Some(a), Some(b)) = (self.images.get(p.a), self.images.get(p.b)) else {
                return Err(format!("pair ({}, {}) refers to a missing image", p.a, p.b));
            };
            if p.a == p.b {
                return Err(format!(
                    "pair ({}, {}) matches an image with itself",
                    p.a, p.b
                ));
            }
            for &(i, j) in &p.matches {
                if i as usize >= a.keypoints.len() || j as usize >= b.keypoints.len() {
                    return Err(format!(
                        "pair {} – {}: match ({i}, {j}) refers to a missing keypoint",
                        a.name, b.name
                    ));
                }
            }
        }
        Ok(())
    }
}
