//! Hole filling of the pixels rejected by the consistency checks, so that the map is dense
//! (Hirschmüller 2008, "Disparity Refinement": discontinuity preserving interpolation). Filled
//! pixels keep `valid == false` in the output so that multi-view linking can ignore them.

use rayon::prelude::*;

/// Valid pixels next to a hole from which the slope of the background surface is fitted.
const SLOPE_WINDOW: usize = 16;
/// Largest disparity step between neighbours inside that window (pixels).
const SLOPE_STEP: f32 = 1.0;
/// Largest fitted slope (disparity per pixel) that is extrapolated.
const MAX_SLOPE: f32 = 1.0;

/// Fills every run of invalid pixels on a row from its lower (background) side: the nearest valid
/// disparity on that side, extended along the row with the slope fitted to the valid pixels behind
/// it (so slanted surfaces, e.g. at the left image border where no match exists, continue instead
/// of flattening). Only one side exists at the image border; with two sides the fill never
/// exceeds the higher (foreground) one. Rows without any valid pixel stay `NaN`.
pub(crate) fn fill_scanline(disp: &[f32], valid: &[bool], w: usize) -> Vec<f32> {
    let mut out = vec![f32::NAN; disp.len()];
    out.par_chunks_mut(w)
        .zip(disp.par_chunks(w))
        .zip(valid.par_chunks(w))
        .for_each(|((orow, drow), vrow)| {
            for ((o, d), v) in orow.iter_mut().zip(drow).zip(vrow) {
                if *v {
                    *o = *d;
                }
            }
            let mut a = 0;
            while a < w {
                if vrow[a] {
                    a += 1;
                    continue;
                }
                let mut b = a;
                while b < w && !vrow[b] {
                    b += 1;
                }
                // Hole [a, b): sides a − 1 and b when inside the image.
                let left = (a > 0).then(|| a - 1);
                let right = (b < w).then_some(b);
                let (side, cap) = match (left, right) {
                    (Some(l), Some(r)) if drow[l] <= drow[r] => (l, drow[r]),
                    (Some(l), Some(r)) => (r, drow[l]),
                    (Some(l), None) => (l, f32::INFINITY),
                    (None, Some(r)) => (r, f32::INFINITY),
                    (None, None) => break,
                };
                let slope = side_slope(drow, vrow, side, side + 1 == a);
                for (x, o) in orow.iter_mut().enumerate().take(b).skip(a) {
                    let v = drow[side] + slope * (x as f32 - side as f32);
                    *o = v.min(cap);
                }
                a = b;
            }
        });
    out
}

/// Least-squares slope of the valid pixels from `side` away from the hole (leftwards when the hole
/// is to its right), stopping at a gap or a step above [`SLOPE_STEP`]; 0 unless all
/// [`SLOPE_WINDOW`] pixels qualify (a smooth, well-measured surface).
fn side_slope(d: &[f32], valid: &[bool], side: usize, hole_right: bool) -> f32 {
    let (mut n, mut sx, mut sy, mut sxx, mut sxy) = (0f32, 0f32, 0f32, 0f32, 0f32);
    let mut x = side;
    let mut prev = d[side];
    for i in 0..SLOPE_WINDOW {
        if !valid[x] || (d[x] - prev).abs() > SLOPE_STEP {
            break;
        }
        prev = d[x];
        let t = i as f32;
        n += 1.0;
        sx += t;
        sy += d[x];
        sxx += t * t;
        sxy += t * d[x];
        match (hole_right, x) {
            (true, 0) => break,
            (true, _) => x -= 1,
            (false, _) if x + 1 == d.len() => break,
            (false, _) => x += 1,
        }
    }
    if n < SLOPE_WINDOW as f32 {
        return 0.0;
    }
    let den = n * sxx - sx * sx;
    if den <= 0.0 {
        return 0.0;
    }
    // Slope per step away from the hole; per pixel towards the hole's side of x it flips sign.
    let per_step = (n * sxy - sx * sy) / den;
    let per_px = if hole_right { -per_step } else { per_step };
    per_px.clamp(-MAX_SLOPE, MAX_SLOPE)
}

/// Marks the invalid pixels that are occlusions rather than mismatches (Hirschmüller 2008,
/// "Disparity Refinement"): the epipolar line of a mismatch meets the right disparity function —
/// some right pixel `x − d'` has right disparity `d'` and so points back at `x` — while that of an
/// occluded pixel passes behind the occluding foreground and meets none.
pub(crate) fn occlusions(
    right: &[f32],
    valid: &[bool],
    w: usize,
    min_disparity: i32,
    ndisp: usize,
) -> Vec<bool> {
    let mut occ = vec![false; valid.len()];
    occ.par_chunks_mut(w)
        .zip(valid.par_chunks(w))
        .zip(right.par_chunks(w))
        .for_each(|((orow, vrow), rrow)| {
            for (x, (o, v)) in orow.iter_mut().zip(vrow).enumerate() {
                if *v {
                    continue;
                }
                let meets = (0..ndisp).any(|k| {
                    let d = min_disparity as i64 + k as i64;
                    let xr = x as i64 - d;
                    xr >= 0 && xr < w as i64 && (rrow[xr as usize] - d as f32).abs() < 0.5
                });
                *o = !meets;
            }
        });
    occ
}

/// The 8 directions along which valid neighbours are collected.
const DIRS: [(i64, i64); 8] = [
    (1, 0),
    (-1, 0),
    (0, 1),
    (0, -1),
    (1, 1),
    (-1, -1),
    (1, -1),
    (-1, 1),
];

/// Fills every invalid pixel from the nearest valid disparities along 8 directions: an occluded
/// pixel takes the second lowest of them (the background, robust to one outlier), a mismatch their
/// median (Hirschmüller 2008, "Disparity Refinement"). Pixels that see no valid pixel stay `NaN`.
pub(crate) fn fill_directional(
    disp: &[f32],
    valid: &[bool],
    occluded: &[bool],
    w: usize,
    h: usize,
) -> Vec<f32> {
    let mut out = vec![f32::NAN; disp.len()];
    out.par_chunks_mut(w).enumerate().for_each(|(y, orow)| {
        let mut found = [0f32; 8];
        for (x, o) in orow.iter_mut().enumerate() {
            let i = y * w + x;
            if valid[i] {
                *o = disp[i];
                continue;
            }
            let mut n = 0;
            for (dx, dy) in DIRS {
                let (mut xx, mut yy) = (x as i64 + dx, y as i64 + dy);
                while xx >= 0 && yy >= 0 && xx < w as i64 && yy < h as i64 {
                    let j = yy as usize * w + xx as usize;
                    if valid[j] {
                        found[n] = disp[j];
                        n += 1;
                        break;
                    }
                    xx += dx;
                    yy += dy;
                }
            }
            if n == 0 {
                continue;
            }
            let f = &mut found[..n];
            f.sort_unstable_by(f32::total_cmp);
            *o = if occluded[i] {
                f[1.min(n - 1)]
            } else if n % 2 == 1 {
                f[n / 2]
            } else {
                0.5 * (f[n / 2 - 1] + f[n / 2])
            };
        }
    });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scanline_fill_takes_the_background_side() {
        let d = [2.0, 0.0, 0.0, 9.0, 0.0, 4.0, 0.0];
        let v = [true, false, false, true, false, true, false];
        let f = fill_scanline(&d, &v, 7);
        assert_eq!(f, vec![2.0, 2.0, 2.0, 9.0, 4.0, 4.0, 4.0]);
        let none = fill_scanline(&d, &[false; 7], 7);
        assert!(none.iter().all(|v| v.is_nan()));
    }

    #[test]
    fn occlusion_versus_mismatch() {
        // Right map: background 2 everywhere except a foreground 6 at x_r = 4..=6.
        let right = [2.0, 2.0, 2.0, 2.0, 6.0, 6.0, 6.0, 2.0, 2.0, 2.0];
        let mut valid = [true; 10];
        // x = 7: no right pixel 7 − d' has disparity d' (the background match 7 − 2 = 5 is covered
        // by the foreground): an occlusion. x = 3: right[1] = 2 points back at it: a mismatch.
        valid[7] = false;
        valid[3] = false;
        let occ = occlusions(&right, &valid, 10, 0, 8);
        assert!(occ[7] && !occ[3], "{occ:?}");
    }

    #[test]
    fn directional_fill_background_for_occlusions_median_for_mismatches() {
        // 5×5 map: left half 2, right half 8, centre column invalid.
        let (w, h) = (5, 5);
        let disp: Vec<f32> = (0..w * h)
            .map(|i| if i % w < 2 { 2.0 } else { 8.0 })
            .collect();
        let valid: Vec<bool> = (0..w * h).map(|i| i % w != 2).collect();
        let occ_all = vec![true; w * h];
        let f = fill_directional(&disp, &valid, &occ_all, w, h);
        assert_eq!(f[2 * w + 2], 2.0);
        let occ_none = vec![false; w * h];
        let f = fill_directional(&disp, &valid, &occ_none, w, h);
        // Centre pixel sees 2 three times (W, NW, SW), 8 three times and nothing N/S: median 5.
        assert_eq!(f[2 * w + 2], 5.0);
    }
}
