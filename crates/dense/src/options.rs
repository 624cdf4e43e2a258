//! Options of rectified-pair stereo matching ([`crate::match_rectified`]).
//!
//! Defaults were chosen by measurement on the Middlebury teddy and cones pairs (450×375, 64
//! disparities); see the crate documentation for the numbers.

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

use crate::error::{DenseError, Result};

/// Which optimiser turns the matching cost into a disparity map. Parsed from and displayed as
/// `sgm` / `dp` (also its serde names).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StereoMethod {
    /// Semi-Global Matching (Hirschmüller, PAMI 2008) over 8 or 4 paths.
    Sgm,
    /// Scanline dynamic programming with ordering, uniqueness and occlusion costs (paper §4.2;
    /// Cox et al. 1996, Van Meerbergen et al. 2002).
    Dp,
}

impl StereoMethod {
    /// Every method, in the order of [`Self::name`]s a command line lists.
    pub const ALL: [StereoMethod; 2] = [StereoMethod::Sgm, StereoMethod::Dp];

    /// The method's name: `sgm` or `dp`.
    pub fn name(self) -> &'static str {
        match self {
            StereoMethod::Sgm => "sgm",
            StereoMethod::Dp => "dp",
        }
    }
}

impl fmt::Display for StereoMethod {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A name that is not a [`StereoMethod`].
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("unknown stereo method `{0}`: expected `sgm` or `dp`")]
pub struct ParseStereoMethodError(pub String);

impl FromStr for StereoMethod {
    type Err = ParseStereoMethodError;

    /// `sgm` or `dp`, case-insensitive.
    fn from_str(s: &str) -> std::result::Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|m| m.name().eq_ignore_ascii_case(s.trim()))
            .ok_or_else(|| ParseStereoMethodError(s.to_string()))
    }
}

/// The pixel-wise (or window) matching cost that fills the cost volume.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MatchingCost {
    /// Hamming distance of census transforms (Zabih & Woodfill 1994) over a `width`×`height`
    /// window (both odd, at most 64 pixels in all); cost unit = one differing bit.
    Census { width: usize, height: usize },
    /// `(1 − ZNCC) · 100` over a square window of [`StereoOptions::window`] pixels (the window
    /// correlation of paper §2.1, eq. 9 of the feature matcher); range 0..=200.
    Zncc,
}

/// How the pixels rejected by the checks are filled (they stay marked invalid).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum HoleFill {
    /// Leave them `NaN`.
    None,
    /// The lower (background) of the nearest valid disparities left and right on the row.
    Scanline,
    /// Nearest valid disparities along 8 directions: second lowest for occlusions, median for
    /// mismatches (Hirschmüller 2008, "Disparity Refinement").
    Directional,
}

/// Number of SGM aggregation directions.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SgmPaths {
    /// Horizontal and vertical only (faster, more streaking).
    Four,
    /// Horizontal, vertical and both diagonals (Hirschmüller's recommendation).
    Eight,
}

impl SgmPaths {
    /// The number of directions.
    pub fn count(self) -> usize {
        match self {
            SgmPaths::Four => 4,
            SgmPaths::Eight => 8,
        }
    }
}

/// Options of [`crate::match_rectified`]. Disparity convention: the left pixel `(x, y)` matches
/// the right pixel `(x − d, y)`; `min_disparity..=max_disparity` is searched (both inclusive).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct StereoOptions {
    /// Optimiser. Default [`StereoMethod::Sgm`].
    pub method: StereoMethod,
    /// Smallest disparity searched (may be negative). Default 0.
    pub min_disparity: i32,
    /// Largest disparity searched, inclusive. Default 63 (64 disparities).
    pub max_disparity: i32,
    /// Matching cost. Default census 9×7 for SGM, ZNCC for DP.
    pub cost: MatchingCost,
    /// Side of the square window over which the pixel-wise cost is averaged (census) or correlated
    /// (ZNCC); odd, 1 = no aggregation. Default 1 for SGM, 3 for DP.
    pub window: usize,
    /// SGM penalty for a disparity change of one pixel between neighbours (the energy `E(D)` of
    /// Hirschmüller 2008), in cost units. Default 10.
    pub p1: u16,
    /// SGM penalty for larger disparity jumps (same energy), in cost units; must exceed `p1`.
    /// Default 60.
    pub p2: u16,
    /// Make P2 adapt to the intensity step along the path: `P2' = max(P1 + 1, P2 / (1 + |ΔI| /
    /// adaptive_p2_scale))` with `ΔI` in grey levels (Hirschmüller 2008, "Cost Aggregation":
    /// `P2 = P2' / |I_bp − I_bq|`). `None` keeps P2 constant. Default `Some(16.0)`.
    pub adaptive_p2_scale: Option<f32>,
    /// SGM directions. Default [`SgmPaths::Eight`].
    pub sgm_paths: SgmPaths,
    /// DP cost of one occluded pixel (in cost units); every disparity step of one pixel along a
    /// scanline pays it once (Cox et al. 1996). Default 45 (with the ZNCC cost's 0..=200 scale).
    pub occlusion_cost: u16,
    /// Left–right consistency: a left disparity `d` at `x` is kept when the right map at `x − d`
    /// agrees within this many pixels (the right map is whole pixels, so keep it ≥ 0.5 with
    /// sub-pixel refinement). `None` disables the check. Default `Some(1.0)`.
    pub lr_tolerance: Option<f32>,
    /// Sub-pixel refinement by a parabola through the costs at `d − 1, d, d + 1`. Default on.
    pub subpixel: bool,
    /// 3×3 median filter on both disparity maps before the consistency check. Default on.
    pub median: bool,
    /// Connected regions (4-neighbours, steps ≤ `speckle_range`) smaller than this many pixels are
    /// invalidated (Hirschmüller 2008, removal of peaks); 0 disables. Default 100.
    pub speckle_size: usize,
    /// Largest disparity step inside one speckle region, in pixels. Default 1.0.
    pub speckle_range: f32,
    /// Hole filling of the rejected pixels; filled pixels stay marked invalid in
    /// [`crate::Disparity::valid`]. Default [`HoleFill::Scanline`].
    pub hole_fill: HoleFill,
    /// Upper bound on the bytes of cost/aggregation volumes alive at once. Larger images are
    /// processed in horizontal bands with overlap (Hirschmüller 2008, "Processing of Huge
    /// Images"). Default 1 GiB.
    pub max_volume_bytes: usize,
    /// Coarse-to-fine matching (tSGM, Rothermel et al. 2012): when more disparities than this
    /// are to be searched (SGM with the census cost and `window` 1), the pair is first matched at
    /// half size, recursively, and each pixel then searches only this many disparities around
    /// what the coarser level found near it. 0 searches the whole range at every pixel.
    /// Default 64.
    pub pyramid_disparities: usize,
    /// The coarsest pyramid level keeps its longer side at least this many pixels, and is matched
    /// over the whole range. Default 640.
    pub pyramid_min_size: usize,
}

/// The widest disparity range one matching run accepts (the winner-take-all keys hold 16 bits).
pub const MAX_DISPARITIES: usize = 65_535;

impl Default for StereoOptions {
    fn default() -> Self {
        Self::sgm()
    }
}

impl StereoOptions {
    /// Defaults of Semi-Global Matching (the better method on Middlebury).
    pub fn sgm() -> Self {
        Self {
            method: StereoMethod::Sgm,
            min_disparity: 0,
            max_disparity: 63,
            cost: MatchingCost::Census {
                width: 9,
                height: 7,
            },
            window: 1,
            p1: 10,
            p2: 60,
            adaptive_p2_scale: Some(16.0),
            sgm_paths: SgmPaths::Eight,
            occlusion_cost: 45,
            lr_tolerance: Some(1.0),
            subpixel: true,
            median: true,
            speckle_size: 100,
            speckle_range: 1.0,
            hole_fill: HoleFill::Scanline,
            max_volume_bytes: 1 << 30,
            pyramid_disparities: 64,
            pyramid_min_size: 640,
        }
    }

    /// Defaults of scanline dynamic programming (paper §4.2).
    pub fn dp() -> Self {
        Self {
            method: StereoMethod::Dp,
            cost: MatchingCost::Zncc,
            window: 3,
            occlusion_cost: 45,
            ..Self::sgm()
        }
    }

    /// The defaults of `method`.
    pub fn for_method(method: StereoMethod) -> Self {
        match method {
            StereoMethod::Sgm => Self::sgm(),
            StereoMethod::Dp => Self::dp(),
        }
    }

    /// Whether the pair may be matched coarse to fine (SGM on the pixel-wise census cost).
    pub fn pyramid_applies(&self) -> bool {
        self.pyramid_disparities > 0
            && self.method == StereoMethod::Sgm
            && matches!(self.cost, MatchingCost::Census { .. })
            && self.window == 1
    }

    /// Number of disparities searched.
    pub fn num_disparities(&self) -> usize {
        (i64::from(self.max_disparity) - i64::from(self.min_disparity) + 1).max(0) as usize
    }

    /// Checks every option; the error names the first offending one.
    pub fn validate(&self) -> Result<()> {
        let bad = |option: &'static str, reason: String| {
            Err(DenseError::InvalidOption { option, reason })
        };
        if self.min_disparity >= self.max_disparity {
            return bad(
                "min_disparity",
                format!(
                    "must be below max_disparity ({} >= {})",
                    self.min_disparity, self.max_disparity
                ),
            );
        }
        if self.num_disparities() > MAX_DISPARITIES {
            return bad(
                "max_disparity",
                format!(
                    "at most {MAX_DISPARITIES} disparities, got {}",
                    self.num_disparities()
                ),
            );
        }
        if self.pyramid_disparities != 0 && self.pyramid_disparities < 8 {
            return bad(
                "pyramid_disparities",
                format!(
                    "must be 0 (off) or at least 8, got {}",
                    self.pyramid_disparities
                ),
            );
        }
        if self.pyramid_min_size < 32 {
            return bad(
                "pyramid_min_size",
                format!("must be at least 32 pixels, got {}", self.pyramid_min_size),
            );
        }
        if let MatchingCost::Census { width, height } = self.cost {
            if width % 2 != 1 || height % 2 != 1 || width * height > 65 || width * height < 9 {
                return bad(
                    "cost",
                    format!(
                        "census window must be odd×odd with 9..=65 pixels, got {width}x{height}"
                    ),
                );
            }
        }
        if self.window % 2 != 1 || self.window > 31 {
            return bad(
                "window",
                format!("must be odd and at most 31, got {}", self.window),
            );
        }
        if self.cost == MatchingCost::Zncc && self.window < 3 {
            return bad(
                "window",
                format!("ZNCC needs a window of at least 3, got {}", self.window),
            );
        }
        if self.p1 == 0 || self.p2 <= self.p1 {
            return bad(
                "p2",
                format!(
                    "need 0 < p1 < p2, got p1 = {} and p2 = {}",
                    self.p1, self.p2
                ),
            );
        }
        // Path costs stay below max cost (255) + P2; their sum over all paths must fit in u16.
        let per_path = u16::MAX as usize / self.sgm_paths.count();
        if self.p2 as usize + 256 > per_path {
            return bad(
                "p2",
                format!(
                    "at most {} with {} paths, got {}",
                    per_path - 256,
                    self.sgm_paths.count(),
                    self.p2
                ),
            );
        }
        if let Some(s) = self.adaptive_p2_scale {
            if !(s.is_finite() && s > 0.0) {
                return bad("adaptive_p2_scale", format!("must be positive, got {s}"));
            }
        }
        if self.occlusion_cost == 0 || self.occlusion_cost > 10_000 {
            return bad(
                "occlusion_cost",
                format!("must be in 1..=10000, got {}", self.occlusion_cost),
            );
        }
        if let Some(t) = self.lr_tolerance {
            if !(t.is_finite() && t >= 0.0) {
                return bad("lr_tolerance", format!("must be finite and >= 0, got {t}"));
            }
        }
        if !(self.speckle_range.is_finite() && self.speckle_range >= 0.0) {
            return bad(
                "speckle_range",
                format!("must be finite and >= 0, got {}", self.speckle_range),
            );
        }
        if self.max_volume_bytes < 1 << 20 {
            return bad(
                "max_volume_bytes",
                format!("must be at least 1 MiB, got {}", self.max_volume_bytes),
            );
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn option_of(e: DenseError) -> &'static str {
        match e {
            DenseError::InvalidOption { option, .. } => option,
            other => panic!("expected an option error, got {other}"),
        }
    }

    #[test]
    fn stereo_method_parses_and_displays_its_name() {
        for m in StereoMethod::ALL {
            assert_eq!(m.to_string().parse::<StereoMethod>(), Ok(m));
        }
        assert_eq!("SGM".parse::<StereoMethod>(), Ok(StereoMethod::Sgm));
        let e = "census".parse::<StereoMethod>().unwrap_err();
        assert!(e.to_string().contains("`sgm` or `dp`"), "{e}");
    }

    #[test]
    fn defaults_are_valid() {
        assert!(StereoOptions::sgm().validate().is_ok());
        assert!(StereoOptions::dp().validate().is_ok());
        assert_eq!(StereoOptions::default().num_disparities(), 64);
    }

    #[test]
    fn rejects_bad_options_by_name() {
        let o = StereoOptions {
            min_disparity: 10,
            max_disparity: 10,
            ..Default::default()
        };
        let e = o.validate().unwrap_err();
        assert!(e.to_string().contains("min_disparity"), "{e}");
        let o = StereoOptions {
            min_disparity: 20,
            max_disparity: 5,
            ..Default::default()
        };
        assert_eq!(option_of(o.validate().unwrap_err()), "min_disparity");
        let o = StereoOptions {
            p1: 50,
            p2: 40,
            ..Default::default()
        };
        assert_eq!(option_of(o.validate().unwrap_err()), "p2");
        let o = StereoOptions {
            window: 4,
            ..Default::default()
        };
        assert_eq!(option_of(o.validate().unwrap_err()), "window");
        let o = StereoOptions {
            cost: MatchingCost::Census {
                width: 9,
                height: 9,
            },
            ..Default::default()
        };
        assert_eq!(option_of(o.validate().unwrap_err()), "cost");
        let o = StereoOptions {
            lr_tolerance: Some(f32::NAN),
            ..Default::default()
        };
        assert_eq!(option_of(o.validate().unwrap_err()), "lr_tolerance");
        let o = StereoOptions {
            cost: MatchingCost::Zncc,
            window: 1,
            ..Default::default()
        };
        assert_eq!(option_of(o.validate().unwrap_err()), "window");
        let o = StereoOptions {
            occlusion_cost: 0,
            ..StereoOptions::dp()
        };
        assert_eq!(option_of(o.validate().unwrap_err()), "occlusion_cost");
    }
}
