//! Coarse-to-fine disparity windows (tSGM, Rothermel et al., "SURE: Photogrammetric Surface
//! Reconstruction from Imagery", LC3D 2012): a pair matched at half size tells each full-size
//! pixel which disparities are worth searching, so the search per pixel stays small however wide
//! the pair's whole range is.
//!
//! Each full-size pixel takes the measured coarse disparities in a 5×5 neighbourhood of its coarse
//! pixel (tSGM's window, which reaches across depth edges to both sides), doubles their minimum
//! and maximum, and widens them by [`WINDOW_MARGIN`]. Its window of `n` disparities is centred
//! on that span when it fits; when the span is wider (a large depth edge), it is centred on the
//! pixel's own coarse disparity, or the nearest measured one (the left–right check leaves edges
//! unmeasured at the coarse level), and where the 5×5 neighbourhood has none, on the median of a
//! wider one. Windows stay inside the pair's range.

use crate::disparity::{Disparity, Gray};

/// Radius (coarse pixels) of the neighbourhood whose disparities set a pixel's window.
const NEAR: usize = 2;
/// Radius of the wider neighbourhood used where the near one measured nothing.
const FAR: usize = 8;
/// Full-size pixels added on both sides of the doubled coarse span: one for the coarse level's
/// whole-pixel error, one for the sampling of the half-size grid.
pub const WINDOW_MARGIN: i32 = 2;
/// Largest step (coarse pixels per pixel of distance) between a coarse disparity and a
/// neighbour's for the coarse value to stand in for a missing full-size one.
const MAX_STEP: f32 = 2.0;
/// Radius (coarse pixels) searched for a depth edge around a coarse disparity that would stand in.
const EDGE_RADIUS: usize = 2;
/// Fewest measured neighbours (of 8) a coarse disparity needs to stand in.
const MIN_NEIGHBOURS: usize = 3;

/// The image at half size (2×2 means; an odd last row or column is averaged with itself).
pub(crate) fn half(g: &Gray) -> Gray {
    let (w, h) = (g.width.div_ceil(2), g.height.div_ceil(2));
    let at = |x: usize, y: usize| g.data[y.min(g.height - 1) * g.width + x.min(g.width - 1)];
    let data = (0..h)
        .flat_map(|y| {
            (0..w).map(move |x| {
                let (x0, y0) = (2 * x, 2 * y);
                0.25 * (at(x0, y0) + at(x0 + 1, y0) + at(x0, y0 + 1) + at(x0 + 1, y0 + 1))
            })
        })
        .collect();
    Gray {
        width: w,
        height: h,
        data,
    }
}

/// The coarse level's range for a full-size range `min..=max` (a whole-pixel margin each side).
pub(crate) fn half_range(min: i32, max: i32) -> (i32, i32) {
    (min.div_euclid(2) - 1, (max + 1).div_euclid(2) + 1)
}

/// The first disparity of each full-size pixel's window of `n` (row-major, `width × height`),
/// from the half-size map `coarse`, inside `min..=max` (which must hold at least `n`).
pub(crate) fn windows_from_coarse(
    coarse: &Disparity,
    width: usize,
    height: usize,
    (min, max): (i32, i32),
    n: usize,
) -> Vec<i32> {
    let (cw, ch) = (coarse.width, coarse.height);
    let measured = |i: usize| coarse.valid[i] && coarse.data[i].is_finite();
    // Per coarse pixel: the span of its near neighbourhood, or a wide fallback centre.
    let n_i = n as i32;
    let mut start = vec![0i32; cw * ch];
    let mut vals = Vec::new();
    for cy in 0..ch {
        for cx in 0..cw {
            let mut lo = f32::INFINITY;
            let mut hi = f32::NEG_INFINITY;
            // The measured neighbour nearest to this pixel (itself when measured).
            let mut nearest = (usize::MAX, f32::NAN);
            for y in cy.saturating_sub(NEAR)..(cy + NEAR + 1).min(ch) {
                for x in cx.saturating_sub(NEAR)..(cx + NEAR + 1).min(cw) {
                    let i = y * cw + x;
                    if measured(i) {
                        let v = coarse.data[i];
                        lo = lo.min(v);
                        hi = hi.max(v);
                        let d2 = (x.abs_diff(cx)).pow(2) + (y.abs_diff(cy)).pow(2);
                        if d2 < nearest.0 {
                            nearest = (d2, v);
                        }
                    }
                }
            }
            let own = cy * cw + cx;
            let centre = if lo.is_finite() {
                let (a, b) = (
                    (2.0 * lo).floor() as i32 - WINDOW_MARGIN,
                    (2.0 * hi).ceil() as i32 + WINDOW_MARGIN,
                );
                if b - a < n_i {
                    (a + b) / 2
                } else {
                    (2.0 * nearest.1).round() as i32
                }
            } else {
                vals.clear();
                for y in cy.saturating_sub(FAR)..(cy + FAR + 1).min(ch) {
                    for x in cx.saturating_sub(FAR)..(cx + FAR + 1).min(cw) {
                        let i = y * cw + x;
                        if measured(i) {
                            vals.push(coarse.data[i]);
                        }
                    }
                }
                if vals.is_empty() {
                    (min + max) / 2
                } else {
                    let m = vals.len() / 2;
                    let (_, v, _) = vals.select_nth_unstable_by(m, f32::total_cmp);
                    (2.0 * *v).round() as i32
                }
            };
            start[own] = (centre - n_i / 2).clamp(min, max - n_i + 1);
        }
    }
    let mut out = Vec::with_capacity(width * height);
    for y in 0..height {
        let cy = (y / 2).min(ch - 1);
        for x in 0..width {
            out.push(start[cy * cw + (x / 2).min(cw - 1)]);
        }
    }
    out
}

/// Where the full-size level kept no disparity but the half-size level measured a surface with no
/// depth edge around the pixel (see `smooth` below), the
/// half-size disparities, interpolated and doubled, stand; for the left map and the right map
/// alike. Full-size matching leaves isolated holes on fine texture (sensor noise at the pixel
/// scale) that the half-size level measured; depth edges, where the half-size level is coarse,
/// are left alone.
pub(crate) fn fill_from_coarse(fine: &mut Disparity, coarse: &Disparity) {
    let (cw, ch) = (coarse.width, coarse.height);
    // A surface without a depth edge: the coarse pixel measured, at least 3 of its 8 neighbours
    // measured, and every measured pixel of its 5×5 neighbourhood within 2 coarse pixels per
    // pixel of distance of it. A slanted surface, such as the ground seen at a grazing angle,
    // passes; an edge does not, even when the left–right check left its near side unmeasured.
    let smooth = |map: &[f32], valid: Option<&[bool]>, cx: usize, cy: usize| -> bool {
        if cx < EDGE_RADIUS || cy < EDGE_RADIUS || cx + EDGE_RADIUS >= cw || cy + EDGE_RADIUS >= ch
        {
            return false;
        }
        let ok = |k: usize| map[k].is_finite() && valid.is_none_or(|m| m[k]);
        let own = cy * cw + cx;
        if !ok(own) {
            return false;
        }
        let mut n = 0;
        for y in cy - EDGE_RADIUS..=cy + EDGE_RADIUS {
            for x in cx - EDGE_RADIUS..=cx + EDGE_RADIUS {
                let k = y * cw + x;
                if k == own || !ok(k) {
                    continue;
                }
                let dist = x.abs_diff(cx).max(y.abs_diff(cy));
                if (map[k] - map[own]).abs() > MAX_STEP * dist as f32 {
                    return false;
                }
                n += usize::from(dist == 1);
            }
        }
        n >= MIN_NEIGHBOURS
    };
    // Bilinear value of the coarse map at full-size pixel (x, y), doubled.
    let at = |map: &[f32], x: usize, y: usize| -> f32 {
        let u = ((x as f32 + 0.5) / 2.0 - 0.5).clamp(0.0, (cw - 1) as f32);
        let v = ((y as f32 + 0.5) / 2.0 - 0.5).clamp(0.0, (ch - 1) as f32);
        let (x0, y0) = (u.floor() as usize, v.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(cw - 1), (y0 + 1).min(ch - 1));
        let (fx, fy) = (u - x0 as f32, v - y0 as f32);
        let g = |x: usize, y: usize| map[y * cw + x];
        let top = g(x0, y0) * (1.0 - fx) + g(x1, y0) * fx;
        let bot = g(x0, y1) * (1.0 - fx) + g(x1, y1) * fx;
        2.0 * (top * (1.0 - fy) + bot * fy)
    };
    let w = fine.width;
    let n = fine.data.len();
    let has_right = fine.right.len() == n && coarse.right.len() == cw * ch;
    // A value kept from the coarse level was measured on pixels twice the size (or more, when
    // that level kept its own coarser values).
    let coarse_scale = |side: usize, cx: usize, cy: usize| {
        (2.0 * coarse.scale_at(side, cy * cw + cx)).min(f64::from(u8::MAX)) as u8
    };
    if fine.scale.len() != n {
        fine.scale = vec![1; n];
    }
    if has_right && fine.right_scale.len() != n {
        fine.right_scale = vec![1; n];
    }
    for i in 0..fine.data.len() {
        let (x, y) = (i % w, i / w);
        let (cx, cy) = ((x / 2).min(cw - 1), (y / 2).min(ch - 1));
        if !fine.valid[i] && smooth(&coarse.data, Some(&coarse.valid), cx, cy) {
            // Bilinear where the four coarse neighbours are measured, the coarse pixel's own
            // value otherwise.
            let mut d = at(&coarse.data, x, y);
            if !d.is_finite() {
                d = 2.0 * coarse.data[cy * cw + cx];
            }
            if d.is_finite() {
                fine.data[i] = d;
                fine.valid[i] = true;
                fine.scale[i] = coarse_scale(0, cx, cy);
            }
        }
        if has_right && !fine.right[i].is_finite() && smooth(&coarse.right, None, cx, cy) {
            let mut d = at(&coarse.right, x, y);
            if !d.is_finite() {
                d = 2.0 * coarse.right[cy * cw + cx];
            }
            fine.right[i] = d.round();
            fine.right_scale[i] = coarse_scale(1, cx, cy);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn halving_averages_blocks() {
        let g = Gray {
            width: 3,
            height: 2,
            data: vec![0.0, 2.0, 4.0, 2.0, 4.0, 8.0],
        };
        let h = half(&g);
        assert_eq!((h.width, h.height), (2, 1));
        assert_eq!(h.data, vec![2.0, 6.0]);
        assert_eq!(half_range(-7, 9), (-5, 6));
    }

    #[test]
    fn windows_cover_both_sides_of_a_small_edge_and_follow_a_large_one() {
        // Coarse map: 10 on the left half, 14 (small edge) or 100 (large edge) on the right.
        for (right, n) in [(14.0f32, 32usize), (100.0, 32)] {
            let (cw, ch) = (12, 6);
            let mut c = Disparity::missing(cw, ch);
            for i in 0..cw * ch {
                c.data[i] = if i % cw < 6 { 10.0 } else { right };
                c.valid[i] = true;
            }
            // A hole the far neighbourhood fills.
            for y in 0..ch {
                for x in 0..3 {
                    c.valid[y * cw + x] = false;
                }
            }
            let b = windows_from_coarse(&c, 2 * cw, 2 * ch, (0, 300), n);
            let covers = |x: usize, d: i32| {
                let s = b[4 * 2 * cw + x];
                (s..s + n as i32).contains(&d)
            };
            // Far from the edge, the pixel's own disparity (doubled) is inside its window.
            assert!(covers(8, 20), "{:?}", &b[4 * 2 * cw..5 * 2 * cw]);
            assert!(covers(2 * cw - 1, 2 * right as i32));
            // In the hole, the wider neighbourhood's median (the near side's, when the step is
            // small enough for the median to be on the near side).
            if right == 14.0 {
                assert!(covers(1, 20));
            }
            // At the edge, both sides fit the window when the step is small; with a large
            // step each pixel keeps its own side.
            assert!(covers(11, 20));
            assert!(covers(12, 2 * right as i32));
            if right == 14.0 {
                assert!(covers(11, 28) && covers(12, 20));
            }
        }
    }
}
