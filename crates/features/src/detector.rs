//! The detector trait: every detector (Harris + ZNCC patches, SIFT) produces keypoints and, for each,
//! a fixed-length float descriptor, so one matcher serves all of them.

use serde::{Deserialize, Serialize};

use crate::gray::GrayImage;

/// An interest point. Pixel convention: the centre of the top-left pixel is (0, 0).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Keypoint {
    pub x: f32,
    pub y: f32,
    /// Scale (σ of the detection scale, pixels); 1 for single-scale corners.
    pub scale: f32,
    /// Orientation in radians (0 when the detector has none).
    pub orientation: f32,
    /// Detector response (larger is stronger).
    pub response: f32,
}

/// Row-major `n × dim` descriptors, one row per keypoint.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Descriptors {
    pub dim: usize,
    pub data: Vec<f32>,
}

impl Descriptors {
    pub fn len(&self) -> usize {
        self.data.len().checked_div(self.dim).unwrap_or(0)
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Descriptor of keypoint `i`.
    pub fn row(&self, i: usize) -> &[f32] {
        &self.data[i * self.dim..(i + 1) * self.dim]
    }
}

/// The features of one image.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Features {
    pub keypoints: Vec<Keypoint>,
    pub descriptors: Descriptors,
}

/// A feature detector and descriptor. Implementations are deterministic.
pub trait FeatureDetector: Sync {
    /// A short name stored with the features (e.g. `"harris-zncc7"`, `"rootsift"`).
    fn name(&self) -> &'static str;
    /// Detects and describes features in a grey image with values in [0, 1].
    fn detect(&self, image: &GrayImage) -> Features;
}
