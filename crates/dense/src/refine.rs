//! Disparity post-processing shared by SGM and DP (Hirschmüller 2008, "Disparity Computation"
//! and "Disparity Refinement"): median filtering, the left–right consistency check and peak
//! (speckle) removal. Maps are row-major `f32` with `NaN` = no value.

use rayon::prelude::*;

/// 3×3 median over the finite values of each window; `NaN` pixels stay `NaN`. Interior pixels
/// run the 19-exchange median network of Paeth (Graphics Gems, 1990) on whole rows at once (so
/// it vectorises); border pixels and windows holding a `NaN` sort their finite values instead.
pub(crate) fn median3(data: &[f32], w: usize, h: usize) -> Vec<f32> {
    const NET: [(usize, usize); 19] = [
        (1, 2),
        (4, 5),
        (7, 8),
        (0, 1),
        (3, 4),
        (6, 7),
        (1, 2),
        (4, 5),
        (7, 8),
        (0, 3),
        (5, 8),
        (4, 7),
        (3, 6),
        (1, 4),
        (2, 5),
        (4, 7),
        (4, 2),
        (6, 4),
        (4, 2),
    ];
    let mut out = vec![f32::NAN; w * h];
    out.par_chunks_mut(w).enumerate().for_each_init(
        || vec![0f32; 9 * w],
        |lanes, (y, orow)| {
            let n = w.saturating_sub(2);
            let network = y > 0 && y + 1 < h && n > 0;
            if network {
                // Lane j holds neighbour j of the pixels x = 1..w−1.
                for (j, lane) in lanes.chunks_exact_mut(w).enumerate() {
                    let (dy, dx) = (j / 3, j % 3);
                    let start = (y + dy - 1) * w + dx;
                    lane[..n].copy_from_slice(&data[start..start + n]);
                }
                for (a, b) in NET {
                    let (la, lb) = lanes.split_at_mut(a.max(b) * w);
                    let (pa, pb) = if a < b {
                        (&mut la[a * w..a * w + n], &mut lb[..n])
                    } else {
                        (&mut lb[..n], &mut la[b * w..b * w + n])
                    };
                    for (u, v) in pa.iter_mut().zip(pb.iter_mut()) {
                        let (lo, hi) =
                            (if *u < *v { *u } else { *v }, if *u < *v { *v } else { *u });
                        *u = lo;
                        *v = hi;
                    }
                }
                orow[1..1 + n].copy_from_slice(&lanes[4 * w..4 * w + n]);
            }
            let all_finite = network
                && data[(y - 1) * w..(y + 2) * w]
                    .iter()
                    .fold(true, |a, v| a & v.is_finite());
            for (x, o) in orow.iter_mut().enumerate() {
                let c = data[y * w + x];
                let border = !network || x == 0 || x + 1 == w;
                if !c.is_finite() {
                    *o = f32::NAN;
                } else if border || (!all_finite && window_has_nan(data, w, x, y)) {
                    *o = median_slow(data, w, h, x, y);
                }
            }
        },
    );
    out
}

fn window_has_nan(data: &[f32], w: usize, x: usize, y: usize) -> bool {
    (y - 1..y + 2).any(|yy| {
        data[yy * w + x - 1..yy * w + x + 2]
            .iter()
            .any(|v| !v.is_finite())
    })
}

fn median_slow(data: &[f32], w: usize, h: usize, x: usize, y: usize) -> f32 {
    let mut buf = [0f32; 9];
    let mut n = 0;
    for yy in y.saturating_sub(1)..(y + 2).min(h) {
        for xx in x.saturating_sub(1)..(x + 2).min(w) {
            let v = data[yy * w + xx];
            if v.is_finite() {
                buf[n] = v;
                n += 1;
            }
        }
    }
    let s = &mut buf[..n];
    s.sort_unstable_by(f32::total_cmp);
    if n % 2 == 1 {
        s[n / 2]
    } else {
        0.5 * (s[n / 2 - 1] + s[n / 2])
    }
}

/// Left–right consistency (Hirschmüller 2008, "Disparity Computation"): the left disparity `d`
/// at `x` is valid when `x − round(d)` is inside the image and the right map there is within `tol`
/// of `d`. The right map holds whole disparities while `d` may be sub-pixel, so useful tolerances
/// are ≥ 0.5. With
/// `tol = None` only the inside-the-image test is made.
pub(crate) fn lr_check(left: &[f32], right: &[f32], w: usize, tol: Option<f32>) -> Vec<bool> {
    let mut valid = vec![false; left.len()];
    valid
        .par_chunks_mut(w)
        .zip(left.par_chunks(w))
        .zip(right.par_chunks(w))
        .for_each(|((vrow, lrow), rrow)| {
            for (x, (v, d)) in vrow.iter_mut().zip(lrow).enumerate() {
                if !d.is_finite() {
                    continue;
                }
                let dr = d.round();
                let xr = x as i64 - dr as i64;
                if xr < 0 || xr >= w as i64 {
                    continue;
                }
                *v = match tol {
                    Some(t) => (rrow[xr as usize] - d).abs() <= t,
                    None => true,
                };
            }
        });
    valid
}

/// Invalidates 4-connected regions of valid pixels (neighbour steps ≤ `range`) smaller than
/// `min_size` pixels — the removal of peaks of Hirschmüller 2008 / OpenCV's speckle filter.
pub(crate) fn remove_speckles(
    disp: &[f32],
    valid: &mut [bool],
    w: usize,
    h: usize,
    min_size: usize,
    range: f32,
) {
    if min_size == 0 {
        return;
    }
    const UNSEEN: u32 = u32::MAX;
    let mut label = vec![UNSEEN; w * h];
    let mut stack = Vec::new();
    let mut region = Vec::new();
    let mut next = 0u32;
    for start in 0..w * h {
        if !valid[start] || label[start] != UNSEEN {
            continue;
        }
        region.clear();
        stack.push(start);
        label[start] = next;
        while let Some(p) = stack.pop() {
            region.push(p);
            let (x, y) = (p % w, p / w);
            let d = disp[p];
            let mut visit = |q: usize| {
                if valid[q] && label[q] == UNSEEN && (disp[q] - d).abs() <= range {
                    label[q] = next;
                    stack.push(q);
                }
            };
            if x > 0 {
                visit(p - 1);
            }
            if x + 1 < w {
                visit(p + 1);
            }
            if y > 0 {
                visit(p - w);
            }
            if y + 1 < h {
                visit(p + w);
            }
        }
        if region.len() < min_size {
            for &p in &region {
                valid[p] = false;
            }
        }
        next += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_removes_an_outlier_and_keeps_nan() {
        let mut d = vec![5.0f32; 25];
        d[12] = 40.0;
        d[0] = f32::NAN;
        let m = median3(&d, 5, 5);
        assert_eq!(m[12], 5.0);
        assert!(m[0].is_nan());
    }

    #[test]
    fn median_network_agrees_with_sorting() {
        let mut seed = 12345u32;
        for _ in 0..200 {
            let mut p = [0f32; 9];
            for v in p.iter_mut() {
                seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                *v = (seed >> 24) as f32;
            }
            let mut s = p;
            s.sort_by(f32::total_cmp);
            let m = median3(&p, 3, 3);
            assert_eq!(m[4], s[4]);
        }
    }

    #[test]
    fn lr_check_flags_inconsistent_pixels() {
        let left = [0.0, 1.0, 4.0, 2.0, 5.0];
        let right = [3.0, 1.0, 2.0, 2.0, 2.0];
        // x=0,1: the right map at x − d says 3; x=2,4: x − d is outside; x=3: right[1] = 1 is
        // within 1 px of 2.
        let v = lr_check(&left, &right, 5, Some(1.0));
        assert_eq!(v, vec![false, false, false, true, false]);
        let v = lr_check(&left, &right, 5, None);
        assert_eq!(v, vec![true, true, false, true, false]);
    }

    #[test]
    fn speckles_are_removed_and_large_regions_kept() {
        let (w, h) = (10, 4);
        let mut d = vec![3.0f32; w * h];
        d[15] = 20.0;
        d[16] = 20.5;
        let mut valid = vec![true; w * h];
        remove_speckles(&d, &mut valid, w, h, 3, 1.0);
        assert!(!valid[15] && !valid[16]);
        assert_eq!(valid.iter().filter(|v| **v).count(), w * h - 2);
    }
}
