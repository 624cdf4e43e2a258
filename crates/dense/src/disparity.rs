//! The disparity map of the left view of a rectified pair, and the grey input images.

use handheld_core::FloatMap;

use crate::error::{DenseError, Result};

/// Disparity of the left view: the left pixel `(x, y)` matches the right pixel `(x − d, y)`.
///
/// `data` is row-major, top row first; `NaN` means "no estimate". `valid` marks the pixels whose
/// value was measured and passed every check (left–right consistency, speckle filter); pixels
/// whose value came from hole filling have a finite `data` but `valid == false`, so multi-view
/// linking can ignore them.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Disparity {
    pub width: usize,
    pub height: usize,
    pub data: Vec<f32>,
    pub valid: Vec<bool>,
    /// The right view's disparities that passed the left–right check (right `(x, y)` ↔ left
    /// `(x + d, y)`), `NaN` elsewhere; empty when the producer did not keep them.
    pub right: Vec<f32>,
    /// The size, in pixels of this map, of the pixel each left value was measured at: 1 at full
    /// size, 2 where coarse-to-fine matching kept a half-size value, and so on (its matching
    /// uncertainty scales with it). Empty: 1 everywhere.
    #[serde(default)]
    pub scale: Vec<u8>,
    /// [`Disparity::scale`] of the right map.
    #[serde(default)]
    pub right_scale: Vec<u8>,
}

impl Disparity {
    /// A map with no estimates.
    pub fn missing(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            data: vec![f32::NAN; width * height],
            valid: vec![false; width * height],
            right: vec![f32::NAN; width * height],
            scale: Vec::new(),
            right_scale: Vec::new(),
        }
    }

    /// The measurement's pixel size at index `i` of the left (`side` 0) or right map.
    pub fn scale_at(&self, side: usize, i: usize) -> f64 {
        let s = if side == 0 {
            &self.scale
        } else {
            &self.right_scale
        };
        s.get(i).map_or(1.0, |v| f64::from(*v))
    }

    /// Disparity at `(x, y)` (`NaN` when missing).
    pub fn get(&self, x: usize, y: usize) -> f32 {
        self.data[y * self.width + x]
    }

    /// Whether `(x, y)` holds a measured (not filled) disparity.
    pub fn is_valid(&self, x: usize, y: usize) -> bool {
        self.valid[y * self.width + x]
    }

    /// Fraction of pixels with a finite value (measured or filled).
    pub fn density(&self) -> f64 {
        frac(
            self.data.iter().filter(|v| v.is_finite()).count(),
            self.data.len(),
        )
    }

    /// Fraction of pixels with a measured value.
    pub fn valid_fraction(&self) -> f64 {
        frac(self.valid.iter().filter(|v| **v).count(), self.valid.len())
    }

    /// The map as a one-channel [`FloatMap`] (all finite values, filled ones included).
    pub fn to_float_map(&self) -> FloatMap {
        FloatMap {
            width: self.width,
            height: self.height,
            channels: 1,
            data: self.data.clone(),
        }
    }

    /// The measured values only, as a [`FloatMap`] with `NaN` where nothing was measured.
    pub fn valid_float_map(&self) -> FloatMap {
        let data = self
            .data
            .iter()
            .zip(&self.valid)
            .map(|(d, ok)| if *ok { *d } else { f32::NAN })
            .collect();
        FloatMap {
            width: self.width,
            height: self.height,
            channels: 1,
            data,
        }
    }
}

fn frac(n: usize, total: usize) -> f64 {
    if total == 0 {
        0.0
    } else {
        n as f64 / total as f64
    }
}

/// A grey image in `f32`, intensities nominally in `0..=255`.
#[derive(Clone, Debug)]
pub(crate) struct Gray {
    pub width: usize,
    pub height: usize,
    pub data: Vec<f32>,
}

impl Gray {
    /// Converts a 1-channel map as is, or a 3-channel RGB map by the Rec. 601 luma weights.
    pub fn from_map(map: &FloatMap, which: &'static str) -> Result<Self> {
        let bad = |reason: String| Err(DenseError::InvalidImage { which, reason });
        if map.width == 0 || map.height == 0 {
            return bad(format!("empty image {}x{}", map.width, map.height));
        }
        let expected = map
            .width
            .checked_mul(map.height)
            .and_then(|n| n.checked_mul(map.channels));
        if expected != Some(map.data.len()) {
            return bad(format!(
                "{} values for {}x{}x{}",
                map.data.len(),
                map.width,
                map.height,
                map.channels
            ));
        }
        let data = match map.channels {
            1 => map.data.clone(),
            3 => map
                .data
                .chunks_exact(3)
                .map(|c| 0.299 * c[0] + 0.587 * c[1] + 0.114 * c[2])
                .collect(),
            c => return bad(format!("1 or 3 channels expected, got {c}")),
        };
        if data.iter().any(|v| !v.is_finite()) {
            return bad("non-finite intensity".into());
        }
        Ok(Self {
            width: map.width,
            height: map.height,
            data,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gray_conversion_checks_input() {
        let m = FloatMap::filled(4, 3, 3, 100.0);
        let g = Gray::from_map(&m, "left").unwrap();
        assert_eq!(g.data.len(), 12);
        assert!((g.data[0] - 100.0).abs() < 1e-3);
        let mut bad = FloatMap::filled(4, 3, 1, 1.0);
        bad.data.pop();
        let e = Gray::from_map(&bad, "right").unwrap_err();
        assert!(e.to_string().contains("right"), "{e}");
        let two = FloatMap::filled(4, 3, 2, 1.0);
        assert!(Gray::from_map(&two, "left").is_err());
    }

    #[test]
    fn density_and_valid_maps() {
        let mut d = Disparity::missing(2, 2);
        d.data[0] = 3.0;
        d.valid[0] = true;
        d.data[1] = 4.0;
        assert_eq!(d.density(), 0.5);
        assert_eq!(d.valid_fraction(), 0.25);
        let v = d.valid_float_map();
        assert_eq!(v.data[0], 3.0);
        assert!(v.data[1].is_nan());
    }
}
