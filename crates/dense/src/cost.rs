//! Matching-cost volumes `C(x, y, d)` for a band of rows of a rectified pair.
//!
//! Layout: `data[((y − y0) · width + x) · ndisp + k]` with `d = min_disparity + k`, disparities
//! innermost and contiguous so that the SGM and DP inner loops run over contiguous `u8` slices.
//! A pixel whose match `x − d` falls outside the right image gets a neutral cost (half the census
//! bits, or `ρ = 0` for ZNCC: that of a random mismatch), so that aggregation decides it from its
//! neighbours.
//!
//! Coarse-to-fine matching ([`crate::stereo`]) gives every pixel its own window of `ndisp`
//! disparities starting at `base(p)`, so that `k` indexes `d = base(p) + k` (the per-pixel search
//! ranges of tSGM, Rothermel et al. 2012, here of one width).

use rayon::prelude::*;

use crate::disparity::Gray;
use crate::options::MatchingCost;
use crate::zncc;

/// A `u8` cost volume over `rows` consecutive rows of the image.
pub(crate) struct CostVolume {
    pub width: usize,
    pub rows: usize,
    pub ndisp: usize,
    pub min_disparity: i32,
    /// Upper bound of every cost in `data`.
    pub max_cost: u8,
    pub data: Vec<u8>,
    /// Per-pixel first disparity `base(x, y0 + r)` at `r · width + x`; empty when every pixel
    /// starts at `min_disparity`.
    pub base: Vec<i32>,
}

impl CostVolume {
    /// Costs of pixel `(x, y0 + r)` for all disparities.
    #[inline]
    pub fn pixel(&self, x: usize, r: usize) -> &[u8] {
        let i = (r * self.width + x) * self.ndisp;
        &self.data[i..i + self.ndisp]
    }

    /// The disparity of index 0 at pixel `(x, y0 + r)`.
    #[inline]
    pub fn base(&self, x: usize, r: usize) -> i32 {
        if self.base.is_empty() {
            self.min_disparity
        } else {
            self.base[r * self.width + x]
        }
    }
}

/// Per-image precomputation shared by all bands (census descriptors or window statistics).
pub(crate) enum CostInput {
    Census {
        left: Vec<u64>,
        right: Vec<u64>,
        bits: u32,
    },
    Zncc(zncc::ZnccInput),
}

impl CostInput {
    pub fn new(left: &Gray, right: &Gray, cost: MatchingCost, window: usize) -> Self {
        match cost {
            MatchingCost::Census { width, height } => {
                let (l, r) = rayon::join(
                    || census(left, width, height),
                    || census(right, width, height),
                );
                CostInput::Census {
                    left: l,
                    right: r,
                    bits: (width * height - 1) as u32,
                }
            }
            MatchingCost::Zncc => CostInput::Zncc(zncc::ZnccInput::new(left, right, window)),
        }
    }
}

/// Census transform (Zabih & Woodfill 1994) with a `cw`×`ch` window: bit `i` is set when the
/// `i`-th neighbour (row-major, centre skipped) is darker than the centre. Borders replicate.
/// The loops run along the row for one neighbour offset at a time, so they vectorise.
pub(crate) fn census(img: &Gray, cw: usize, ch: usize) -> Vec<u64> {
    let (w, h) = (img.width, img.height);
    let (rx, ry) = (cw / 2, ch / 2);
    let pw = w + 2 * rx;
    let mut out = vec![0u64; w * h];
    out.par_chunks_mut(w).enumerate().for_each_init(
        || vec![0f32; ch * pw],
        |rows, (y, row)| {
            // The window's rows, replicated at the borders and padded by rx on both sides.
            for (j, dst) in rows.chunks_exact_mut(pw).enumerate() {
                let yy = (y + j).saturating_sub(ry).min(h - 1);
                let src = &img.data[yy * w..(yy + 1) * w];
                dst[rx..rx + w].copy_from_slice(src);
                dst[..rx].fill(src[0]);
                dst[rx + w..].fill(src[w - 1]);
            }
            let centre = &rows[ry * pw + rx..ry * pw + rx + w];
            for j in 0..ch {
                for i in 0..cw {
                    if (i, j) == (rx, ry) {
                        continue;
                    }
                    let nb = &rows[j * pw + i..j * pw + i + w];
                    for ((o, n), c) in row.iter_mut().zip(nb).zip(centre) {
                        *o = (*o << 1) | u64::from(*n < *c);
                    }
                }
            }
        },
    );
    out
}

/// Size and disparity range of the cost volumes of one matching run.
#[derive(Clone, Copy, Debug)]
pub(crate) struct VolumeSpec {
    pub width: usize,
    pub height: usize,
    pub min_disparity: i32,
    pub ndisp: usize,
    /// Cost aggregation window ([`crate::StereoOptions::window`]).
    pub window: usize,
}

/// Builds the cost volume of rows `y0..y1` into `buf` (reused storage: its capacity is kept).
/// `bases` (the whole image's per-pixel first disparities, row-major) replaces the constant
/// `spec.min_disparity`; it needs the census cost without box averaging.
pub(crate) fn cost_volume(
    input: &CostInput,
    spec: &VolumeSpec,
    bases: Option<&[i32]>,
    y0: usize,
    y1: usize,
    mut buf: Vec<u8>,
) -> CostVolume {
    let VolumeSpec {
        width,
        height,
        min_disparity,
        ndisp,
        window,
    } = *spec;
    let rows = y1 - y0;
    buf.clear();
    buf.resize(rows * width * ndisp, 0);
    let base = bases.map_or_else(Vec::new, |b| b[y0 * width..y1 * width].to_vec());
    match input {
        CostInput::Census { left, right, bits } => {
            let border = (*bits / 2) as u8;
            if window <= 1 {
                let starts = Starts {
                    min_disparity,
                    base: &base,
                };
                census_rows(left, right, width, y0, starts, ndisp, border, &mut buf);
            } else {
                let r = window / 2;
                let e0 = y0.saturating_sub(r);
                let e1 = (y1 + r).min(height);
                debug_assert!(base.is_empty(), "per-pixel ranges need window 1");
                let mut raw = vec![0u8; (e1 - e0) * width * ndisp];
                let starts = Starts {
                    min_disparity,
                    base: &[],
                };
                census_rows(left, right, width, e0, starts, ndisp, border, &mut raw);
                box_average(&raw, width, (e0, e1), y0, ndisp, window, &mut buf);
            }
        }
        CostInput::Zncc(z) => {
            debug_assert!(base.is_empty(), "per-pixel ranges need the census cost");
            z.cost_rows(y0, min_disparity, ndisp, &mut buf)
        }
    }
    let max_cost = match input {
        CostInput::Census { bits, .. } => *bits as u8,
        CostInput::Zncc(_) => 200,
    };
    CostVolume {
        width,
        rows,
        ndisp,
        min_disparity,
        max_cost,
        data: buf,
        base,
    }
}

/// Where each pixel's disparities start: `base` (rows from `y0`, row-major) or, when empty,
/// `min_disparity` everywhere.
#[derive(Clone, Copy)]
struct Starts<'a> {
    min_disparity: i32,
    base: &'a [i32],
}

/// Hamming distances of census descriptors for rows starting at `y0` (as many as `out` holds).
#[allow(clippy::too_many_arguments)]
fn census_rows(
    left: &[u64],
    right: &[u64],
    width: usize,
    y0: usize,
    starts: Starts,
    ndisp: usize,
    border: u8,
    out: &mut [u8],
) {
    out.par_chunks_mut(width * ndisp)
        .enumerate()
        .for_each(|(r, row)| {
            let y = y0 + r;
            let brow = (!starts.base.is_empty()).then(|| &starts.base[r * width..(r + 1) * width]);
            let l = &left[y * width..(y + 1) * width];
            // The right row mirrored: x_r = top − k sits at width − 1 − top + k, a forward slice.
            let rr: Vec<u64> = right[y * width..(y + 1) * width]
                .iter()
                .rev()
                .copied()
                .collect();
            for (x, px) in row.chunks_exact_mut(ndisp).enumerate() {
                // Disparities whose match x_r = x − d_min − k lies inside the right image.
                let d0 = brow.map_or(starts.min_disparity, |b| b[x]);
                let top = x as i64 - d0 as i64;
                let k_lo = (top - (width as i64 - 1)).max(0);
                let k_hi = top.min(ndisp as i64 - 1);
                if k_hi < k_lo {
                    px.fill(border);
                    continue;
                }
                let (k_lo, k_hi) = (k_lo as usize, k_hi as usize);
                px[..k_lo].fill(border);
                px[k_hi + 1..].fill(border);
                let base = (width as i64 - 1 - top + k_lo as i64) as usize;
                let n = k_hi + 1 - k_lo;
                let cl = l[x];
                for (c, r) in px[k_lo..=k_hi].iter_mut().zip(&rr[base..base + n]) {
                    *c = (cl ^ r).count_ones() as u8;
                }
            }
        });
}

/// Rounded mean of `raw` (rows `e0..e1`) over a `window`×`window` box, for the rows from `y0`
/// on (as many as `out` holds); the box is clipped at the image border.
fn box_average(
    raw: &[u8],
    width: usize,
    (e0, e1): (usize, usize),
    y0: usize,
    ndisp: usize,
    window: usize,
    out: &mut [u8],
) {
    let r = window / 2;
    let row_len = width * ndisp;
    out.par_chunks_mut(row_len)
        .enumerate()
        .for_each(|(i, orow)| {
            let y = y0 + i;
            let ya = y.saturating_sub(r).max(e0);
            let yb = (y + r + 1).min(e1);
            // Vertical sums.
            let mut vs = vec![0u16; row_len];
            for yy in ya..yb {
                let src = &raw[(yy - e0) * row_len..(yy - e0 + 1) * row_len];
                vs.iter_mut()
                    .zip(src)
                    .for_each(|(s, v)| *s += u16::from(*v));
            }
            let nrows = (yb - ya) as u32;
            // Horizontal running sums over the clipped box.
            let mut acc = vec![0u32; ndisp];
            for x in 0..r.min(width) {
                add_px(&mut acc, &vs[x * ndisp..(x + 1) * ndisp]);
            }
            for x in 0..width {
                if x + r < width {
                    add_px(&mut acc, &vs[(x + r) * ndisp..(x + r + 1) * ndisp]);
                }
                if x > r {
                    let o = x - r - 1;
                    acc.iter_mut()
                        .zip(&vs[o * ndisp..(o + 1) * ndisp])
                        .for_each(|(a, v)| *a -= u32::from(*v));
                }
                let ncols = ((x + r + 1).min(width) - x.saturating_sub(r)) as u32;
                let n = nrows * ncols;
                let (half, inv) = (n / 2, (1u32 << 16).div_ceil(n));
                orow[x * ndisp..(x + 1) * ndisp]
                    .iter_mut()
                    .zip(&acc)
                    .for_each(|(o, a)| *o = (((a + half) * inv) >> 16).min(255) as u8);
            }
        });
}

fn add_px(acc: &mut [u32], v: &[u16]) {
    acc.iter_mut().zip(v).for_each(|(a, v)| *a += u32::from(*v));
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Pseudo-random texture shifted left by `shift` pixels.
    fn ramp(w: usize, h: usize, shift: usize) -> Gray {
        let f = |x: usize, y: usize| ((x * x * 7919 + y * 104_729 + x * y * 31) % 251) as f32;
        let data = (0..h)
            .flat_map(|y| (0..w).map(move |x| f(x + shift, y)))
            .collect();
        Gray {
            width: w,
            height: h,
            data,
        }
    }

    #[test]
    fn census_cost_is_zero_at_the_true_shift() {
        let (w, h, d) = (40, 12, 3);
        let left = ramp(w, h, 0);
        let right = ramp(w, h, d);
        let input = CostInput::new(
            &left,
            &right,
            MatchingCost::Census {
                width: 5,
                height: 5,
            },
            1,
        );
        for window in [1, 3] {
            let spec = VolumeSpec {
                width: w,
                height: h,
                min_disparity: 0,
                ndisp: 8,
                window,
            };
            let v = cost_volume(&input, &spec, None, 2, 10, Vec::new());
            let px = v.pixel(20, 3);
            assert_eq!(px[d], 0, "window {window}: {px:?}");
            assert!(
                px.iter().enumerate().all(|(k, c)| k == d || *c > 0),
                "{px:?}"
            );
            // Out-of-image matches get the neutral border cost.
            assert_eq!(v.pixel(1, 0)[7], 12);
        }
    }
}
