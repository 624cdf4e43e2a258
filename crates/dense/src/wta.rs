//! Winner-take-all disparity selection with sub-pixel refinement (Hirschmüller 2008, "Disparity
//! Computation").
//!
//! The left map is `D_b(p) = argmin_d S(p, d)`; the right map is `D_m(q) = argmin_d S(q + d, d)`
//! taken from the same volume (the paper's way of getting the match image's disparities), so no
//! second aggregation is needed.

use rayon::prelude::*;

use crate::sgm::Aggregated;

/// Sub-pixel offset of the vertex of the parabola through `(−1, a)`, `(0, b)`, `(1, c)`, in
/// `[−0.5, 0.5]`; 0 when the three costs are not convex.
#[inline]
pub(crate) fn parabola(a: f32, b: f32, c: f32) -> f32 {
    let den = a + c - 2.0 * b;
    if den > 0.0 {
        ((a - c) / (2.0 * den)).clamp(-0.5, 0.5)
    } else {
        0.0
    }
}

/// Bits of a packed `(cost << K_BITS) | k` key holding the disparity index (`S` is `u16`, so the
/// key fits in `u32`).
const K_BITS: u32 = 16;

/// Where each pixel's disparity window starts: `base` (the band's rows, row-major, as in
/// [`crate::cost::CostVolume::base`]) or, when empty, `min_disparity` everywhere.
#[derive(Clone, Copy)]
pub(crate) struct Windows<'a> {
    pub min_disparity: i32,
    pub base: &'a [i32],
    /// The whole range's last disparity: a per-pixel window's minimum on its own edge is no
    /// minimum (the cost may fall further outside) unless that edge is the range's.
    pub max_disparity: i32,
}

/// Left disparities (window start added, sub-pixel when asked) and right disparities
/// `argmin_d S(x_r + d, d)` over the windows of the left pixels `x_r + d` (integers; `NaN` where
/// no window reaches `x_r`) of the rows
/// `core.0..core.1` of a band. `S = fwd + bwd` is summed on the fly ([`Aggregated`] layouts).
/// Ties go to the smaller disparity. `left` and `right` hold the core rows.
///
/// Cost and index are packed into one `u32` key so that both minima are plain vectorisable
/// `min` reductions.
#[allow(clippy::too_many_arguments)]
pub(crate) fn wta(
    agg: &Aggregated,
    width: usize,
    ndisp: usize,
    core: (usize, usize),
    windows: Windows,
    subpixel: bool,
    left: &mut [f32],
    right: &mut [f32],
) {
    let Windows {
        min_disparity,
        base: bases,
        max_disparity,
    } = windows;
    // Right keys hold d − d_lo.
    let d_lo = bases.iter().copied().min().unwrap_or(min_disparity);
    let d_hi = bases.iter().copied().max().unwrap_or(min_disparity) + ndisp as i32 - 1;
    debug_assert!(((d_hi - d_lo) as usize) < 1 << K_BITS);
    debug_assert_eq!(left.len(), (core.1 - core.0) * width);
    let mask = (1u32 << K_BITS) - 1;
    let row_len = width * ndisp;
    let band_rows = agg.fwd.len() / row_len.max(1);
    left.par_chunks_mut(width)
        .zip(right.par_chunks_mut(width))
        .enumerate()
        .for_each_init(
            || (vec![u32::MAX; width], vec![0u16; ndisp]),
            |(best_r, px), (i, (lrow, rrow))| {
                let r = core.0 + i;
                let base_row = (!bases.is_empty()).then(|| &bases[r * width..(r + 1) * width]);
                let frow = &agg.fwd[r * row_len..(r + 1) * row_len];
                let rb = band_rows - 1 - r;
                let brow = &agg.bwd[rb * row_len..(rb + 1) * row_len];
                // best_r[w − 1 − x_r] holds the packed minimum of right pixel x_r, stored
                // mirrored so that the disparities of one left pixel map to a forward slice.
                best_r.fill(u32::MAX);
                for (x, o) in lrow.iter_mut().enumerate() {
                    let f = &frow[x * ndisp..(x + 1) * ndisp];
                    let xb = width - 1 - x;
                    let b = &brow[xb * ndisp..(xb + 1) * ndisp];
                    for ((p, a), b) in px.iter_mut().zip(f).zip(b) {
                        *p = a + b;
                    }
                    let mut key = u32::MAX;
                    for (k, v) in px.iter().enumerate() {
                        key = key.min((u32::from(*v) << K_BITS) | k as u32);
                    }
                    let k = (key & mask) as usize;
                    let d0 = base_row.map_or(min_disparity, |b| b[x]);
                    let mut d = (d0 as i64 + k as i64) as f32;
                    let cut = base_row.is_some()
                        && ((k == 0 && d0 > min_disparity)
                            || (k + 1 == ndisp && d0 + ndisp as i32 - 1 < max_disparity));
                    if cut {
                        d = f32::NAN;
                    } else if subpixel && k > 0 && k + 1 < ndisp {
                        let f = |i: usize| f32::from(px[i]);
                        d += parabola(f(k - 1), f(k), f(k + 1));
                    }
                    *o = d;
                    // Right pixels x_r = top − k inside the image, at mirrored index base + k.
                    let top = x as i64 - d0 as i64;
                    let k_lo = (top - (width as i64 - 1)).max(0);
                    let k_hi = top.min(ndisp as i64 - 1);
                    if k_hi < k_lo {
                        continue;
                    }
                    let (k_lo, k_hi) = (k_lo as usize, k_hi as usize);
                    let base = (width as i64 - 1 - top + k_lo as i64) as usize;
                    let n = k_hi + 1 - k_lo;
                    let dst = &mut best_r[base..base + n];
                    let src = &px[k_lo..k_lo + n];
                    let off = (d0 - d_lo) as usize + k_lo;
                    for i in 0..n {
                        dst[i] = dst[i].min((u32::from(src[i]) << K_BITS) | (off + i) as u32);
                    }
                }
                for (o, b) in rrow.iter_mut().zip(best_r.iter().rev()) {
                    *o = if *b == u32::MAX {
                        f32::NAN
                    } else {
                        (d_lo as i64 + (b & mask) as i64) as f32
                    };
                }
            },
        );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parabola_finds_the_vertex() {
        // y = (x − 0.3)² sampled at −1, 0, 1.
        let f = |x: f32| (x - 0.3) * (x - 0.3);
        assert!((parabola(f(-1.0), f(0.0), f(1.0)) - 0.3).abs() < 1e-6);
        assert_eq!(parabola(1.0, 1.0, 1.0), 0.0);
    }

    #[test]
    fn left_and_right_wta() {
        // Width 6, 4 disparities starting at 1, every pixel's minimum at d = 2 (k = 1).
        let (w, nd) = (6, 4);
        let vol: Vec<u16> = (0..w * nd)
            .map(|i| if i % nd == 1 { 1 } else { 9 })
            .collect();
        let agg = Aggregated {
            fwd: vol,
            bwd: vec![0; w * nd],
        };
        let (mut l, mut r) = (vec![0f32; w], vec![0f32; w]);
        let windows = Windows {
            min_disparity: 1,
            base: &[],
            max_disparity: 4,
        };
        wta(&agg, w, nd, (0, 1), windows, true, &mut l, &mut r);
        assert!(l.iter().all(|d| *d == 2.0), "{l:?}");
        // x_r + 2 is inside for x_r <= 3; x_r = 4 only sees d = 1, x_r = 5 sees nothing.
        assert_eq!(&r[..4], &[2.0; 4]);
        assert_eq!(r[4], 1.0);
        assert!(r[5].is_nan());
    }
}
