//! Window ZNCC matching cost, the similarity the paper uses for correspondences (§2.1, eq. 9):
//! `ρ = (Σ l·r / n − μ_l μ_r) / (σ_l σ_r)` over a square window, stored as `(1 − ρ) · 100`.
//!
//! The cross term is a separable box sum (vertical, then horizontal) computed for all disparities
//! of a pixel at once, so a row costs `O(width · ndisp · window)` in vectorised loops.

use rayon::prelude::*;

use crate::disparity::Gray;

/// Variance floor (grey levels²) so that flat windows give `ρ ≈ 0` instead of a division by zero.
const VAR_EPS: f32 = 4.0;
/// Cost of a match outside the right image (`ρ = 0`).
pub(crate) const ZNCC_BORDER: u8 = 100;

/// Images with replicated borders plus per-pixel window means and inverse deviations.
pub(crate) struct ZnccInput {
    width: usize,
    height: usize,
    window: usize,
    left: Vec<f32>,
    right: Vec<f32>,
    mean_l: Vec<f32>,
    mean_r: Vec<f32>,
    inv_std_l: Vec<f32>,
    inv_std_r: Vec<f32>,
}

impl ZnccInput {
    pub fn new(left: &Gray, right: &Gray, window: usize) -> Self {
        let ((mean_l, inv_std_l), (mean_r, inv_std_r)) =
            rayon::join(|| moments(left, window), || moments(right, window));
        Self {
            width: left.width,
            height: left.height,
            window,
            left: left.data.clone(),
            right: right.data.clone(),
            mean_l,
            mean_r,
            inv_std_l,
            inv_std_r,
        }
    }

    /// `u8` costs of the rows from `y0` on (as many as `out` holds), layout `[(row, x, k)]`.
    ///
    /// Disparities are innermost everywhere: the right rows and statistics are stored mirrored,
    /// `M[u] = R(w − 1 + r − d_min − u)` (clamped), so that `R(x − d_min − k)` is
    /// `M[w − 1 + r − x + k]`, a forward slice in `k`, and every loop vectorises.
    pub fn cost_rows(&self, y0: usize, min_disparity: i32, ndisp: usize, out: &mut [u8]) {
        let (w, h, win) = (self.width, self.height, self.window);
        let r = win / 2;
        let inv_n = 1.0 / (win * win) as f32;
        let a = (w + r) as i64 - 1 - min_disparity as i64;
        let mlen = w + 2 * r + ndisp - 1;
        let mirror = |src: &[f32]| -> Vec<f32> {
            (0..mlen)
                .map(|u| src[(a - u as i64).clamp(0, w as i64 - 1) as usize])
                .collect()
        };
        let row_len = w * ndisp;
        out.par_chunks_mut(row_len)
            .enumerate()
            .for_each(|(i, orow)| {
                let y = y0 + i;
                let rows: Vec<usize> = (0..win)
                    .map(|j| (y + j).saturating_sub(r).min(h - 1))
                    .collect();
                let lpad: Vec<Vec<f32>> = rows
                    .iter()
                    .map(|&yy| pad(&self.left[yy * w..(yy + 1) * w], r))
                    .collect();
                let rmir: Vec<Vec<f32>> = rows
                    .iter()
                    .map(|&yy| mirror(&self.right[yy * w..(yy + 1) * w]))
                    .collect();
                let mr = mirror(&self.mean_r[y * w..(y + 1) * w]);
                let sr = mirror(&self.inv_std_r[y * w..(y + 1) * w]);
                // V[x'][k] = Σ_j l_j(x') · r_j(x' − r − d): vertical sums at padded abscissae x'.
                let nw = w + 2 * r;
                let mut v = vec![0f32; nw * ndisp];
                for (lrow, rrow) in lpad.iter().zip(&rmir) {
                    for (xp, vx) in v.chunks_exact_mut(ndisp).enumerate() {
                        let l = lrow[xp];
                        let base = w - 1 + 2 * r - xp;
                        for (o, rv) in vx.iter_mut().zip(&rrow[base..base + ndisp]) {
                            *o += l * rv;
                        }
                    }
                }
                let mut hs = vec![0f32; ndisp];
                for (x, px) in orow.chunks_exact_mut(ndisp).enumerate() {
                    hs.copy_from_slice(&v[x * ndisp..(x + 1) * ndisp]);
                    for o in 1..win {
                        let src = &v[(x + o) * ndisp..(x + o + 1) * ndisp];
                        hs.iter_mut().zip(src).for_each(|(a, b)| *a += b);
                    }
                    let (ml, sl) = (self.mean_l[y * w + x], self.inv_std_l[y * w + x]);
                    let base = w - 1 + r - x;
                    let (mrx, srx) = (&mr[base..base + ndisp], &sr[base..base + ndisp]);
                    for k in 0..ndisp {
                        let cov = hs[k] * inv_n - ml * mrx[k];
                        let rho = cov * sl * srx[k];
                        // Round to the nearest integer by the 2^23 trick (vectorises, unlike `as`).
                        let c = ((1.0 - rho) * 100.0).clamp(0.0, 200.0);
                        px[k] = (c + 8_388_608.0).to_bits() as u8;
                    }
                    // Matches outside the right image: x − d_min − k ∉ [0, w).
                    let top = x as i64 - min_disparity as i64;
                    let k_lo = (top - (w as i64 - 1)).clamp(0, ndisp as i64) as usize;
                    let k_hi = (top + 1).clamp(0, ndisp as i64) as usize;
                    px[..k_lo].fill(ZNCC_BORDER);
                    px[k_hi.max(k_lo)..].fill(ZNCC_BORDER);
                }
            });
    }
}

fn pad(row: &[f32], r: usize) -> Vec<f32> {
    let w = row.len();
    (0..w + 2 * r)
        .map(|i| row[(i as isize - r as isize).clamp(0, w as isize - 1) as usize])
        .collect()
}

/// Window means and `1 / sqrt(var + VAR_EPS)` with replicated borders, by separable sums
/// (vertical over the window's rows, then horizontal over the padded row).
fn moments(img: &Gray, window: usize) -> (Vec<f32>, Vec<f32>) {
    let (w, h) = (img.width, img.height);
    let r = window / 2;
    let inv_n = 1.0 / (window * window) as f32;
    let mut mean = vec![0f32; w * h];
    let mut inv = vec![0f32; w * h];
    mean.par_chunks_mut(w)
        .zip(inv.par_chunks_mut(w))
        .enumerate()
        .for_each(|(y, (mrow, irow))| {
            let (mut s, mut s2) = (vec![0f32; w], vec![0f32; w]);
            for j in 0..window {
                let yy = (y + j).saturating_sub(r).min(h - 1);
                for ((a, b), v) in s
                    .iter_mut()
                    .zip(s2.iter_mut())
                    .zip(&img.data[yy * w..(yy + 1) * w])
                {
                    *a += v;
                    *b += v * v;
                }
            }
            let (ps, ps2) = (pad(&s, r), pad(&s2, r));
            for x in 0..w {
                let a: f32 = ps[x..x + window].iter().sum();
                let b: f32 = ps2[x..x + window].iter().sum();
                let m = a * inv_n;
                mrow[x] = m;
                irow[x] = 1.0 / ((b * inv_n - m * m).max(0.0) + VAR_EPS).sqrt();
            }
        });
    (mean, inv)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn textured(w: usize, h: usize, shift: usize) -> Gray {
        let f = |x: usize, y: usize| ((x * x * 7919 + y * 104_729 + x * y * 31) % 251) as f32;
        Gray {
            width: w,
            height: h,
            data: (0..h)
                .flat_map(|y| (0..w).map(move |x| f(x + shift, y)))
                .collect(),
        }
    }

    /// ZNCC of the 3×3 windows at left (x, y) and right (x − d, y), computed directly.
    fn naive(l: &Gray, r: &Gray, x: usize, y: usize, d: usize) -> f32 {
        let (mut a, mut b) = (Vec::new(), Vec::new());
        for dy in 0..3 {
            for dx in 0..3 {
                a.push(l.data[(y + dy - 1) * l.width + x + dx - 1]);
                b.push(r.data[(y + dy - 1) * r.width + x - d + dx - 1]);
            }
        }
        let mean = |v: &[f32]| v.iter().sum::<f32>() / 9.0;
        let (ma, mb) = (mean(&a), mean(&b));
        let cov: f32 = a
            .iter()
            .zip(&b)
            .map(|(p, q)| (p - ma) * (q - mb))
            .sum::<f32>()
            / 9.0;
        let var =
            |v: &[f32], m: f32| v.iter().map(|p| (p - m) * (p - m)).sum::<f32>() / 9.0 + VAR_EPS;
        cov / (var(&a, ma) * var(&b, mb)).sqrt()
    }

    #[test]
    fn costs_agree_with_direct_zncc() {
        let (w, h, nd) = (30, 8, 6);
        let (l, r) = (textured(w, h, 0), textured(w, h, 2));
        let z = ZnccInput::new(&l, &r, 3);
        let mut out = vec![0u8; 3 * w * nd];
        z.cost_rows(2, 0, nd, &mut out);
        for row in 0..3 {
            for x in (nd + 1)..(w - 1) {
                for d in 0..nd {
                    let want = ((1.0 - naive(&l, &r, x, 2 + row, d)) * 100.0).clamp(0.0, 200.0);
                    let got = f32::from(out[(row * w + x) * nd + d]);
                    assert!((got - want).abs() <= 1.0, "x {x} d {d}: {got} vs {want}");
                }
                assert!(
                    out[(row * w + x) * nd + 2] <= 1,
                    "true shift is a near-perfect match"
                );
            }
            // Left of d: the match falls outside the right image.
            assert_eq!(out[(row * w + 1) * nd + 4], ZNCC_BORDER);
        }
    }
}
