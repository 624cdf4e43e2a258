//! Dense per-pixel float maps: depth (z in the camera frame), its variance, visibility counts,
//! disparities. Row-major, `channels` interleaved values per pixel, top row first.

use serde::{Deserialize, Serialize};

/// A row-major float image with one or three channels (the two layouts PFM stores).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FloatMap {
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    pub data: Vec<f32>,
}

impl FloatMap {
    /// A map from interleaved 8-bit samples (e.g. an RGB image's raw buffer), values 0..=255.
    pub fn from_u8(width: usize, height: usize, channels: usize, samples: &[u8]) -> Self {
        Self {
            width,
            height,
            channels,
            data: samples.iter().map(|&v| f32::from(v)).collect(),
        }
    }

    /// A map filled with `value`.
    pub fn filled(width: usize, height: usize, channels: usize, value: f32) -> Self {
        Self {
            width,
            height,
            channels,
            data: vec![value; width * height * channels],
        }
    }

    /// Value of channel `c` at pixel `(x, y)`.
    pub fn get(&self, x: usize, y: usize, c: usize) -> f32 {
        self.data[(y * self.width + x) * self.channels + c]
    }

    pub fn set(&mut self, x: usize, y: usize, c: usize, v: f32) {
        self.data[(y * self.width + x) * self.channels + c] = v;
    }

    /// Fraction of finite, positive values (the fill of a depth map).
    pub fn fill_ratio(&self) -> f64 {
        if self.data.is_empty() {
            return 0.0;
        }
        self.data
            .iter()
            .filter(|v| v.is_finite() && **v > 0.0)
            .count() as f64
            / self.data.len() as f64
    }
}
