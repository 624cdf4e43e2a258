//! Scanline stereo by dynamic programming (paper §4.2 and Fig. 4; Cox, Hingorani, Rao & Maggs,
//! "A maximum likelihood stereo algorithm", CVIU 1996; Van Meerbergen, Vergauwen, Pollefeys &
//! Van Gool, IJCV 2002).
//!
//! Matching a pair of scanlines is a shortest path through the grid of (left pixel `i`, right
//! pixel `j`) inside the disparity band `d = i − j ∈ [d_min, d_max]`. With `M(i, j)` the cost of
//! aligning `left[..=i]` with `right[..=j]`:
//!
//! `M(i, j) = min( M(i−1, j−1) + C(i, i − j),   // i and j match
//!                 M(i−1, j)   + κ_occ,         // left pixel i is occluded in the right view
//!                 M(i, j−1)   + κ_occ )        // right pixel j is occluded in the left view`
//!
//! A monotone path enforces the ordering constraint, each pixel is matched at most once in either
//! direction (bidirectional uniqueness), and every disparity step of one pixel pays the explicit
//! occlusion cost `κ_occ` once. In band coordinates `k = d − d_min` the three moves are
//! `(i−1, k)`, `(i−1, k−1)` and `(i, k+1)`. The path may start and end at any disparity.
//!
//! Rows are independent and solved in parallel (rayon); each needs `width · ndisp` bytes of
//! back-pointers and two `ndisp` columns of costs.

use rayon::prelude::*;

use crate::cost::CostVolume;
use crate::wta::parabola;

const DIAG: u8 = 0;
const HORIZ: u8 = 1;
const VERT: u8 = 2;

/// Solves every row of `cost`. Writes the left disparities (`NaN` = occluded or matched outside
/// the right image) and the right disparities of the matched right pixels (`NaN` otherwise),
/// `cost.rows · cost.width` values each.
pub(crate) fn dp_band(
    cost: &CostVolume,
    occlusion: u16,
    subpixel: bool,
    left: &mut [f32],
    right: &mut [f32],
) {
    let (w, nd) = (cost.width, cost.ndisp);
    left.par_chunks_mut(w)
        .zip(right.par_chunks_mut(w))
        .enumerate()
        .for_each_init(
            || vec![0u8; w * nd],
            |moves, (r, (lrow, rrow))| {
                solve_row(cost, r, u32::from(occlusion), subpixel, moves, lrow, rrow);
            },
        );
}

fn solve_row(
    cost: &CostVolume,
    r: usize,
    occ: u32,
    subpixel: bool,
    moves: &mut [u8],
    lrow: &mut [f32],
    rrow: &mut [f32],
) {
    let (w, nd, dmin) = (cost.width, cost.ndisp, i64::from(cost.min_disparity));
    // prev[k + 1] = M(i − 1, k); prev[0] is a sentinel so that k − 1 needs no branch.
    let mut prev = vec![0u32; nd + 1];
    prev[0] = u32::MAX / 2;
    let mut cur = vec![0u32; nd];
    for i in 0..w {
        let c = cost.pixel(i, r);
        let mv = &mut moves[i * nd..(i + 1) * nd];
        // Match and left-occlusion moves from column i − 1 (vectorised).
        let (pk, pk1) = (&prev[1..nd + 1], &prev[0..nd]);
        for k in 0..nd {
            let diag = pk[k] + u32::from(c[k]);
            let horiz = pk1[k] + occ;
            cur[k] = diag.min(horiz);
            mv[k] = u8::from(horiz < diag) * HORIZ;
        }
        // Right-occlusion moves inside column i, from larger to smaller disparities (branch-free:
        // the choice is data dependent and would mispredict).
        let mut run = u32::MAX / 2;
        for (c, m) in cur.iter_mut().zip(mv.iter_mut()).rev() {
            let vert = run + occ;
            let better = vert < *c;
            *c = if better { vert } else { *c };
            *m = if better { VERT } else { *m };
            run = *c;
        }
        // Keep the numbers small: only differences matter.
        let m = cur.iter().copied().min().unwrap_or(0);
        for (p, c) in prev[1..].iter_mut().zip(&cur) {
            *p = c - m;
        }
    }
    let prev = &prev[1..];
    lrow.iter_mut().for_each(|v| *v = f32::NAN);
    rrow.iter_mut().for_each(|v| *v = f32::NAN);
    // Backtrack from the best final disparity.
    let mut k = (0..nd).min_by_key(|k| prev[*k]).unwrap_or(0);
    let mut i = w as i64 - 1;
    while i >= 0 {
        let iu = i as usize;
        match moves[iu * nd + k] {
            DIAG => {
                let d = dmin + k as i64;
                let j = i - d;
                if j >= 0 && j < w as i64 {
                    let mut df = d as f32;
                    if subpixel && k > 0 && k + 1 < nd {
                        let c = cost.pixel(iu, r);
                        df += parabola(f32::from(c[k - 1]), f32::from(c[k]), f32::from(c[k + 1]));
                    }
                    lrow[iu] = df;
                    rrow[j as usize] = d as f32;
                }
                i -= 1;
            }
            HORIZ => {
                i -= 1;
                k -= 1;
            }
            _ => k += 1,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A one-row cost volume whose cheapest disparity is `truth[x]`.
    fn row_volume(truth: &[usize], nd: usize) -> CostVolume {
        let data = truth
            .iter()
            .flat_map(|t| (0..nd).map(move |k| if k == *t { 0 } else { 50 }))
            .collect();
        CostVolume {
            width: truth.len(),
            rows: 1,
            ndisp: nd,
            min_disparity: 0,
            base: Vec::new(),
            max_cost: 255,
            data,
        }
    }

    #[test]
    fn recovers_a_step_with_an_occlusion() {
        // Background at 2, foreground at 6 from x = 20 to 29: left pixels 16..20 are occluded.
        let truth: Vec<usize> = (0..40)
            .map(|x| if (20..30).contains(&x) { 6 } else { 2 })
            .collect();
        let v = row_volume(&truth, 8);
        let (mut l, mut r) = (vec![0f32; 40], vec![0f32; 40]);
        dp_band(&v, 10, false, &mut l, &mut r);
        for x in 2..40 {
            if (16..20).contains(&x) {
                assert!(l[x].is_nan(), "x = {x}: {}", l[x]);
            } else {
                assert_eq!(l[x], truth[x] as f32, "x = {x}");
            }
        }
        // Every matched right pixel points back to a left pixel with the same disparity.
        for (j, d) in r.iter().enumerate() {
            if d.is_finite() {
                assert_eq!(l[j + *d as usize], *d);
            }
        }
    }

    #[test]
    fn high_occlusion_cost_smooths_over_a_blip() {
        let mut truth = vec![3usize; 30];
        truth[15] = 7;
        let v = row_volume(&truth, 8);
        let (mut l, mut r) = (vec![0f32; 30], vec![0f32; 30]);
        dp_band(&v, 100, false, &mut l, &mut r);
        assert_eq!(l[15], 3.0);
    }
}
