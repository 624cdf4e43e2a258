//! [`match_rectified`]: dense matching of a rectified pair (paper §4.2), by SGM or DP, with the
//! shared post-processing (median, left–right check, speckle removal, hole filling).
//!
//! Memory is bounded by [`StereoOptions::max_volume_bytes`]: the volumes take `width · ndisp · B`
//! bytes per row (`B` = 5 for SGM — `u8` cost plus two `u16` pass sums — and 1 for DP, plus 1 when
//! a census cost is box-averaged). When the whole image does not fit, rows are processed in bands;
//! SGM bands overlap by [`SGM_BAND_OVERLAP`] rows on each side so that the vertical and diagonal
//! paths have run in before the kept rows (the tiling of Hirschmüller 2008, "Processing of Huge
//! Images"). A 3072×2048 pair with 256 disparities would need ~8 GB of SGM volumes in one piece;
//! with the default 1 GiB budget it runs in 12 bands of at most 273 rows (measured: 1.5 GB peak
//! resident memory, ~14 s on 2 shared cores). Besides the volumes, `O(width · height)` maps (census
//! descriptors, disparities, masks) are kept.

use std::time::Instant;

use handheld_core::FloatMap;
use tracing::debug;

use crate::cost::{cost_volume, CostInput, VolumeSpec};
use crate::disparity::{Disparity, Gray};
use crate::dp::dp_band;
use crate::error::{DenseError, Result};
use crate::fill::{fill_directional, fill_scanline, occlusions};
use crate::options::{HoleFill, MatchingCost, StereoMethod, StereoOptions};
use crate::pyramid::{fill_from_coarse, half, half_range, windows_from_coarse};
use crate::refine::{lr_check, median3, remove_speckles};
use crate::sgm::{aggregate, Aggregated, SgmParams};
use crate::wta::{wta, Windows};

/// Rows of context above and below each SGM band when the image is split.
pub const SGM_BAND_OVERLAP: usize = 48;
/// Smallest number of kept rows per band.
const MIN_BAND_CORE: usize = 8;

/// Matches a rectified pair and returns the disparity of the left view (left `(x, y)` ↔ right
/// `(x − d, y)`). Images are 1-channel grey or 3-channel RGB [`FloatMap`]s with intensities in
/// `0..=255`, of equal size. To match many pairs, a [`StereoMatcher`] keeps its volumes'
/// storage between calls.
///
/// Errors: invalid options ([`StereoOptions::validate`]), images of different sizes, malformed
/// images, or a volume budget too small for even one band.
pub fn match_rectified(
    left: &FloatMap,
    right: &FloatMap,
    opts: &StereoOptions,
) -> Result<Disparity> {
    StereoMatcher::new(opts.clone())?.match_pair(left, right)
}

/// A stereo matcher with fixed options that reuses its cost and aggregation volumes from one pair
/// to the next (like OpenCV's `StereoSGBM` object), avoiding fresh page-faulting allocations.
pub struct StereoMatcher {
    opts: StereoOptions,
    cost: Vec<u8>,
    sums: Aggregated,
}

impl StereoMatcher {
    /// Validates the options.
    pub fn new(opts: StereoOptions) -> Result<Self> {
        opts.validate()?;
        Ok(Self {
            opts,
            cost: Vec::new(),
            sums: Aggregated {
                fwd: Vec::new(),
                bwd: Vec::new(),
            },
        })
    }

    /// Changes the disparity range, keeping the volumes' storage (one matcher serves the pairs
    /// of a sequence, each with its own range).
    pub fn set_disparity_range(&mut self, min: i32, max: i32) -> Result<()> {
        let mut o = self.opts.clone();
        o.min_disparity = min;
        o.max_disparity = max;
        o.validate()?;
        self.opts = o;
        Ok(())
    }

    /// The options in use.
    pub fn options(&self) -> &StereoOptions {
        &self.opts
    }

    /// Matches one rectified pair; see [`match_rectified`].
    ///
    /// When the options allow it ([`StereoOptions::pyramid_applies`]) and the range is wider than
    /// [`StereoOptions::pyramid_disparities`], the pair is matched coarse to fine
    /// ([`crate::pyramid`]).
    pub fn match_pair(&mut self, left: &FloatMap, right: &FloatMap) -> Result<Disparity> {
        if (left.width, left.height) != (right.width, right.height) {
            return Err(DenseError::SizeMismatch {
                lw: left.width,
                lh: left.height,
                rw: right.width,
                rh: right.height,
            });
        }
        let gl = Gray::from_map(left, "left")?;
        let gr = Gray::from_map(right, "right")?;
        let range = (self.opts.min_disparity, self.opts.max_disparity);
        self.match_levels(&gl, &gr, range)
    }

    /// Matches at this size, after the half-size level when the pyramid applies.
    fn match_levels(&mut self, gl: &Gray, gr: &Gray, (min, max): (i32, i32)) -> Result<Disparity> {
        let n = self.opts.pyramid_disparities;
        let nd = (max - min + 1) as usize;
        let coarser = gl.width.max(gl.height).div_ceil(2);
        if !self.opts.pyramid_applies() || nd <= n || coarser < self.opts.pyramid_min_size {
            return self.match_gray(gl, gr, (min, max), None);
        }
        let t = Instant::now();
        let (cl, cr) = rayon::join(|| half(gl), || half(gr));
        let coarse = self.match_levels(&cl, &cr, half_range(min, max))?;
        let bases = windows_from_coarse(&coarse, gl.width, gl.height, (min, max), n);
        debug!(
            ms = t.elapsed().as_secs_f64() * 1e3,
            width = gl.width,
            "coarse level and windows"
        );
        let mut fine = self.match_gray(gl, gr, (min, max), Some(&bases))?;
        fill_from_coarse(&mut fine, &coarse);
        Ok(fine)
    }

    /// Matches grey images over `min..=max`, or over each pixel's window of
    /// `pyramid_disparities` starting at `bases`.
    fn match_gray(
        &mut self,
        gl: &Gray,
        gr: &Gray,
        (min, max): (i32, i32),
        bases: Option<&[i32]>,
    ) -> Result<Disparity> {
        let opts = &self.opts;
        let nd = match bases {
            Some(_) => opts.pyramid_disparities,
            None => (max - min + 1) as usize,
        };
        let (w, h) = (gl.width, gl.height);
        let t0 = Instant::now();
        let input = CostInput::new(gl, gr, opts.cost, opts.window);
        debug!(ms = t0.elapsed().as_secs_f64() * 1e3, "cost input");

        let boxed = matches!(opts.cost, MatchingCost::Census { .. }) && opts.window > 1;
        let per_entry = match opts.method {
            StereoMethod::Sgm => 5,
            StereoMethod::Dp => 1,
        } + usize::from(boxed);
        let overlap = match opts.method {
            StereoMethod::Sgm => SGM_BAND_OVERLAP,
            StereoMethod::Dp => 0,
        };
        let bands = plan_bands(h, w * nd * per_entry, opts.max_volume_bytes, overlap)?;
        let spec = VolumeSpec {
            width: w,
            height: h,
            min_disparity: min,
            ndisp: nd,
            window: opts.window,
        };

        let mut dl = vec![f32::NAN; w * h];
        let mut dr = vec![f32::NAN; w * h];
        let grey: Vec<u8> = gl
            .data
            .iter()
            .map(|v| v.round().clamp(0.0, 255.0) as u8)
            .collect();
        let params = SgmParams::new(
            opts.p1,
            opts.p2,
            opts.adaptive_p2_scale,
            opts.sgm_paths.count() == 8,
        );
        for b in &bands {
            let t = Instant::now();
            let cv = cost_volume(
                &input,
                &spec,
                bases,
                b.ext.0,
                b.ext.1,
                std::mem::take(&mut self.cost),
            );
            debug!(
                ms = t.elapsed().as_secs_f64() * 1e3,
                rows = b.ext.1 - b.ext.0,
                "cost volume"
            );
            let core = b.core.0 * w..b.core.1 * w;
            let t = Instant::now();
            match opts.method {
                StereoMethod::Sgm => {
                    let reuse = std::mem::replace(
                        &mut self.sums,
                        Aggregated {
                            fwd: Vec::new(),
                            bwd: Vec::new(),
                        },
                    );
                    let s = aggregate(&cv, &grey[b.ext.0 * w..b.ext.1 * w], &params, reuse);
                    debug!(ms = t.elapsed().as_secs_f64() * 1e3, "sgm aggregation");
                    let t = Instant::now();
                    let rows = (b.core.0 - b.ext.0, b.core.1 - b.ext.0);
                    let (l, r) = (&mut dl[core.clone()], &mut dr[core]);
                    let windows = Windows {
                        min_disparity: min,
                        base: &cv.base,
                        max_disparity: max,
                    };
                    wta(&s, w, nd, rows, windows, opts.subpixel, l, r);
                    debug!(ms = t.elapsed().as_secs_f64() * 1e3, "winner take all");
                    self.sums = s;
                }
                StereoMethod::Dp => {
                    let (l, r) = (&mut dl[core.clone()], &mut dr[core]);
                    dp_band(&cv, opts.occlusion_cost, opts.subpixel, l, r);
                    debug!(ms = t.elapsed().as_secs_f64() * 1e3, "dynamic programming");
                }
            }
            self.cost = cv.data;
        }

        let t = Instant::now();
        let d = post_process(opts, dl, dr, w, h, (min, max));
        debug!(ms = t.elapsed().as_secs_f64() * 1e3, "post-processing");
        Ok(d)
    }
}

/// Median filter, left–right check, speckle removal and hole filling (Hirschmüller 2008,
/// "Disparity Computation" and "Disparity Refinement").
fn post_process(
    opts: &StereoOptions,
    mut dl: Vec<f32>,
    mut dr: Vec<f32>,
    w: usize,
    h: usize,
    (min, max): (i32, i32),
) -> Disparity {
    if opts.median {
        let (l, r) = rayon::join(|| median3(&dl, w, h), || median3(&dr, w, h));
        dl = l;
        dr = r;
    }
    let mut valid = lr_check(&dl, &dr, w, opts.lr_tolerance);
    remove_speckles(&dl, &mut valid, w, h, opts.speckle_size, opts.speckle_range);
    let right = consistent_right(&dl, &dr, &valid, w, opts.lr_tolerance.unwrap_or(1.0));
    let data = match opts.hole_fill {
        HoleFill::None => dl
            .iter()
            .zip(&valid)
            .map(|(d, v)| if *v { *d } else { f32::NAN })
            .collect(),
        HoleFill::Scanline => fill_scanline(&dl, &valid, w),
        HoleFill::Directional => {
            let occ = occlusions(&dr, &valid, w, min, (max - min + 1) as usize);
            fill_directional(&dl, &valid, &occ, w, h)
        }
    };
    Disparity {
        width: w,
        height: h,
        data,
        valid,
        right,
        scale: Vec::new(),
        right_scale: Vec::new(),
    }
}

/// The right view's disparities that agree with a kept left disparity (right `(x, y)` ↔ left
/// `(x + d, y)`); `NaN` elsewhere. Multi-view linking walks a pair from right to left with it.
fn consistent_right(dl: &[f32], dr: &[f32], valid: &[bool], w: usize, tol: f32) -> Vec<f32> {
    dr.iter()
        .enumerate()
        .map(|(i, &d)| {
            if !d.is_finite() {
                return f32::NAN;
            }
            let xl = (i % w) as f32 + d;
            if xl < 0.0 || xl.round() as usize >= w {
                return f32::NAN;
            }
            let j = i - i % w + xl.round() as usize;
            if valid[j] && (dl[j] - d).abs() <= tol.max(0.5) {
                d
            } else {
                f32::NAN
            }
        })
        .collect()
}

/// Rows `core` are kept from a band computed over rows `ext ⊇ core`.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Band {
    core: (usize, usize),
    ext: (usize, usize),
}

fn plan_bands(h: usize, row_bytes: usize, budget: usize, overlap: usize) -> Result<Vec<Band>> {
    let max_rows = budget / row_bytes.max(1);
    if max_rows >= h {
        return Ok(vec![Band {
            core: (0, h),
            ext: (0, h),
        }]);
    }
    let core = max_rows.saturating_sub(2 * overlap);
    if core < MIN_BAND_CORE {
        return Err(DenseError::InvalidOption {
            option: "max_volume_bytes",
            reason: format!(
                "{budget} bytes hold {max_rows} rows of {row_bytes} bytes; need at least {}",
                MIN_BAND_CORE + 2 * overlap
            ),
        });
    }
    let mut bands = Vec::new();
    let mut y = 0;
    while y < h {
        let y1 = (y + core).min(h);
        bands.push(Band {
            core: (y, y1),
            ext: (y.saturating_sub(overlap), (y1 + overlap).min(h)),
        });
        y = y1;
    }
    Ok(bands)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bands_cover_every_row_once_within_budget() {
        assert_eq!(plan_bands(100, 10, 5000, 4).unwrap().len(), 1);
        let bands = plan_bands(100, 10, 300, 4).unwrap();
        let mut next = 0;
        for b in &bands {
            assert_eq!(b.core.0, next);
            assert!((b.ext.1 - b.ext.0) * 10 <= 300);
            assert!(b.ext.0 <= b.core.0 && b.core.1 <= b.ext.1);
            next = b.core.1;
        }
        assert_eq!(next, 100);
        assert!(plan_bands(100, 10, 100, 4).is_err());
    }

    #[test]
    fn size_mismatch_is_reported_with_both_sizes() {
        let a = FloatMap::filled(450, 375, 1, 0.0);
        let b = FloatMap::filled(449, 375, 1, 0.0);
        let e = match_rectified(&a, &b, &StereoOptions::default()).unwrap_err();
        assert_eq!(
            e.to_string(),
            "left and right images differ in size: 450x375 vs 449x375"
        );
    }
}

#[cfg(test)]
#[path = "stereo_tests.rs"]
mod end_to_end;
