//! Zero-mean normalised cross-correlation (paper eq. 9) on small patches, and a matcher for the patch
//! descriptors of [`crate::harris::HarrisZncc`].
//!
//! A patch is bilinearly sampled around a sub-pixel position, its mean is subtracted and it is scaled to
//! unit L2 norm; the dot product of two such vectors is exactly the ZNCC of eq. 9 with `w(x, y) = 1`.
//! ZNCC is invariant to affine intensity changes but only to image translation (§2.1), so it suits
//! small baselines: [`match_zncc`] takes an optional search radius for video and mutual-best checks.
//! The windowed bilinear sampler [`sample_patch`] is shared with the KLT tracker.

use rayon::prelude::*;

use crate::detector::Features;
use crate::error::{check, FeatureError};
use crate::gray::GrayImage;

/// Patches whose intensity standard deviation (values in [0, 1]) is below this are too uniform to be
/// matched and are dropped (about 1.3 grey levels).
pub const MIN_PATCH_STD: f32 = 0.005;

/// Samples the `(2r+1)²` window centred on the sub-pixel position `(x, y)` bilinearly into `out`
/// (row-major, top row first). All samples share one fractional offset, so the four weights are
/// computed once; windows touching the border fall back to clamped sampling.
pub fn sample_patch(img: &GrayImage, x: f32, y: f32, radius: usize, out: &mut [f32]) {
    let side = 2 * radius + 1;
    let out = &mut out[..side * side];
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let r = radius as isize;
    let (xs, ys) = (x0 as isize - r, y0 as isize - r);
    let (w, h) = (img.width as isize, img.height as isize);
    if xs >= 0
        && ys >= 0
        && xs + (side as isize) < w
        && ys + (side as isize) < h
        && x.is_finite()
        && y.is_finite()
    {
        let (w00, w10, w01, w11) = (
            (1.0 - fx) * (1.0 - fy),
            fx * (1.0 - fy),
            (1.0 - fx) * fy,
            fx * fy,
        );
        let (xs, ys, w) = (xs as usize, ys as usize, img.width);
        for (j, row) in out.chunks_exact_mut(side).enumerate() {
            let top = &img.data[(ys + j) * w + xs..(ys + j) * w + xs + side + 1];
            let bot = &img.data[(ys + j + 1) * w + xs..(ys + j + 1) * w + xs + side + 1];
            for (i, o) in row.iter_mut().enumerate() {
                *o = w00 * top[i] + w10 * top[i + 1] + w01 * bot[i] + w11 * bot[i + 1];
            }
        }
    } else {
        for (j, row) in out.chunks_exact_mut(side).enumerate() {
            for (i, o) in row.iter_mut().enumerate() {
                *o = img.sample(x + (i as isize - r) as f32, y + (j as isize - r) as f32);
            }
        }
    }
}

/// Subtracts the mean and scales to unit L2 norm in place; false (and `v` unspecified) when the
/// standard deviation is below `min_std`.
pub fn normalize_zero_mean(v: &mut [f32], min_std: f32) -> bool {
    if v.is_empty() {
        return false;
    }
    let n = v.len() as f32;
    let mean = v.iter().sum::<f32>() / n;
    let mut ss = 0.0;
    for x in v.iter_mut() {
        *x -= mean;
        ss += *x * *x;
    }
    if ss.is_nan() || ss / n < min_std * min_std || ss <= 0.0 {
        return false;
    }
    let inv = ss.sqrt().recip();
    v.iter_mut().for_each(|x| *x *= inv);
    true
}

/// Writes the normalised `(2r+1)²` patch at `(x, y)` into `out`; false when the window leaves the image
/// or the patch is nearly uniform ([`MIN_PATCH_STD`]).
pub fn zncc_patch_into(img: &GrayImage, x: f32, y: f32, radius: usize, out: &mut [f32]) -> bool {
    let side = 2 * radius + 1;
    if out.len() < side * side || !img.inside(x, y, radius as f32) {
        return false;
    }
    sample_patch(img, x, y, radius, out);
    normalize_zero_mean(&mut out[..side * side], MIN_PATCH_STD)
}

/// The zero-mean, unit-norm `(2r+1)²` patch around `(x, y)`, or `None` when the window leaves the image
/// or the patch is nearly uniform.
pub fn zncc_patch(img: &GrayImage, x: f32, y: f32, radius: usize) -> Option<Vec<f32>> {
    let side = 2 * radius + 1;
    let mut out = vec![0f32; side * side];
    zncc_patch_into(img, x, y, radius, &mut out).then_some(out)
}

/// ZNCC of eq. 9 between two raw windows of equal length, in [−1, 1]; 0 when either is constant or the
/// lengths differ. For patches from [`zncc_patch`] it equals their dot product.
pub fn zncc(a: &[f32], b: &[f32]) -> f32 {
    if a.len() != b.len() || a.is_empty() {
        return 0.0;
    }
    let n = a.len() as f64;
    let ma = a.iter().map(|&v| v as f64).sum::<f64>() / n;
    let mb = b.iter().map(|&v| v as f64).sum::<f64>() / n;
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (&x, &y) in a.iter().zip(b) {
        let (x, y) = (x as f64 - ma, y as f64 - mb);
        sab += x * y;
        saa += x * x;
        sbb += y * y;
    }
    let d = (saa * sbb).sqrt();
    if d > 0.0 {
        (sab / d) as f32
    } else {
        0.0
    }
}

/// Options of [`match_zncc`].
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ZnccMatchOptions {
    /// Minimum ZNCC of an accepted match. Default 0.8.
    pub min_score: f32,
    /// Search radius in pixels around the keypoint's own position (video, small baselines); `None`
    /// compares every pair. Default `None`.
    pub max_disparity: Option<f32>,
    /// Keep only pairs that are each other's best match. Default true.
    pub mutual: bool,
}

impl Default for ZnccMatchOptions {
    fn default() -> Self {
        Self {
            min_score: 0.8,
            max_disparity: None,
            mutual: true,
        }
    }
}

impl ZnccMatchOptions {
    /// Checks the score range and the search radius; the error names the offending option.
    pub fn validate(&self) -> Result<(), FeatureError> {
        check((-1.0..=1.0).contains(&self.min_score), "min_score", || {
            format!("must be in [-1, 1], got {}", self.min_score)
        })?;
        if let Some(r) = self.max_disparity {
            check(r > 0.0 && r.is_finite(), "max_disparity", || {
                format!("must be finite and positive, got {r}")
            })?;
        }
        Ok(())
    }
}

/// A uniform-grid index of keypoint positions (cells of the search radius), stored CSR-style.
struct Grid {
    cell: f32,
    x0: f32,
    y0: f32,
    cols: usize,
    rows: usize,
    start: Vec<u32>,
    items: Vec<u32>,
}

impl Grid {
    fn new(pts: &[(f32, f32)], cell: f32) -> Self {
        let finite = || pts.iter().filter(|p| p.0.is_finite() && p.1.is_finite());
        let x0 = finite().map(|p| p.0).fold(f32::INFINITY, f32::min);
        let y0 = finite().map(|p| p.1).fold(f32::INFINITY, f32::min);
        let x1 = finite().map(|p| p.0).fold(f32::NEG_INFINITY, f32::max);
        let y1 = finite().map(|p| p.1).fold(f32::NEG_INFINITY, f32::max);
        let (x0, y0) = if x0.is_finite() { (x0, y0) } else { (0.0, 0.0) };
        let span = |a: f32, b: f32| {
            if b >= a {
                ((b - a) / cell) as usize + 1
            } else {
                1
            }
        };
        let (cols, rows) = (span(x0, x1).min(4096), span(y0, y1).min(4096));
        let mut g = Self {
            cell,
            x0,
            y0,
            cols,
            rows,
            start: vec![0; cols * rows + 1],
            items: Vec::new(),
        };
        let cells: Vec<Option<usize>> = pts.iter().map(|&(x, y)| g.cell_of(x, y)).collect();
        for c in cells.iter().flatten() {
            g.start[c + 1] += 1;
        }
        for i in 0..cols * rows {
            g.start[i + 1] += g.start[i];
        }
        let mut fill = g.start.clone();
        g.items = vec![0; g.start[cols * rows] as usize];
        for (i, c) in cells.iter().enumerate() {
            if let Some(c) = c {
                g.items[fill[*c] as usize] = i as u32;
                fill[*c] += 1;
            }
        }
        g
    }

    fn coords(&self, x: f32, y: f32) -> (isize, isize) {
        (
            ((x - self.x0) / self.cell).floor() as isize,
            ((y - self.y0) / self.cell).floor() as isize,
        )
    }

    fn cell_of(&self, x: f32, y: f32) -> Option<usize> {
        if !(x.is_finite() && y.is_finite()) {
            return None;
        }
        let (cx, cy) = self.coords(x, y);
        let (cx, cy) = (
            cx.clamp(0, self.cols as isize - 1) as usize,
            cy.clamp(0, self.rows as isize - 1) as usize,
        );
        Some(cy * self.cols + cx)
    }

    /// Calls `f` with every indexed item in the cells overlapping the square of half-side `r` at `(x, y)`.
    fn for_near(&self, x: f32, y: f32, r: f32, mut f: impl FnMut(usize)) {
        let (ax, ay) = self.coords(x - r, y - r);
        let (bx, by) = self.coords(x + r, y + r);
        let (ax, bx) = (ax.max(0), bx.min(self.cols as isize - 1));
        let (ay, by) = (ay.max(0), by.min(self.rows as isize - 1));
        for cy in ay..=by {
            for cx in ax..=bx {
                let c = cy as usize * self.cols + cx as usize;
                for &i in &self.items[self.start[c] as usize..self.start[c + 1] as usize] {
                    f(i as usize);
                }
            }
        }
    }
}

/// For every feature of `a`, the index and score of its best partner in `b` (dot product of the
/// normalised patches), restricted to `radius` pixels when given.
fn best_partners(
    a: &Features,
    b: &Features,
    radius: Option<f32>,
    grid: Option<&Grid>,
) -> Vec<Option<(u32, f32)>> {
    let na = a.keypoints.len().min(a.descriptors.len());
    let nb = b.keypoints.len().min(b.descriptors.len());
    (0..na)
        .into_par_iter()
        .map(|i| {
            let da = a.descriptors.row(i);
            let (x, y) = (a.keypoints[i].x, a.keypoints[i].y);
            let mut best: Option<(u32, f32)> = None;
            let consider = |j: usize| {
                if j >= nb {
                    return;
                }
                if let Some(r) = radius {
                    let kp = &b.keypoints[j];
                    if (kp.x - x).powi(2) + (kp.y - y).powi(2) > r * r {
                        return;
                    }
                }
                let s: f32 = da
                    .iter()
                    .zip(b.descriptors.row(j))
                    .map(|(p, q)| p * q)
                    .sum();
                // Ties go to the lower index so the result does not depend on the scan order.
                let better = match best {
                    None => true,
                    Some((bj, bs)) => s > bs || (s == bs && (j as u32) < bj),
                };
                if better {
                    best = Some((j as u32, s));
                }
            };
            match (radius, grid) {
                (Some(r), Some(g)) => g.for_near(x, y, r, consider),
                _ => (0..nb).for_each(consider),
            }
            best
        })
        .collect()
}

/// Matches two sets of ZNCC patch features: for each feature of `f1` the best-scoring feature of `f2`
/// (within `max_disparity` pixels when set), kept when its score reaches `min_score` and, with
/// `mutual`, when it is also the best partner in the other direction. Returns `(i1, i2, zncc)` sorted by
/// `i1`; empty when the descriptor sizes differ or the options are invalid.
pub fn match_zncc(
    f1: &Features,
    f2: &Features,
    options: &ZnccMatchOptions,
) -> Vec<(u32, u32, f32)> {
    if options.validate().is_err()
        || f1.descriptors.dim != f2.descriptors.dim
        || f1.descriptors.dim == 0
    {
        return Vec::new();
    }
    let radius = options.max_disparity;
    let pos = |f: &Features| f.keypoints.iter().map(|k| (k.x, k.y)).collect::<Vec<_>>();
    let (g2, g1) = match radius {
        Some(r) => (
            Some(Grid::new(&pos(f2), r)),
            options.mutual.then(|| Grid::new(&pos(f1), r)),
        ),
        None => (None, None),
    };
    let forward = best_partners(f1, f2, radius, g2.as_ref());
    let backward = if options.mutual {
        Some(best_partners(f2, f1, radius, g1.as_ref()))
    } else {
        None
    };
    forward
        .iter()
        .enumerate()
        .filter_map(|(i, m)| {
            let (j, s) = (*m)?;
            if s < options.min_score {
                return None;
            }
            if let Some(back) = &backward {
                if back.get(j as usize).copied().flatten().map(|(bi, _)| bi) != Some(i as u32) {
                    return None;
                }
            }
            Some((i as u32, j, s))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn patch_dot_product_is_zncc() {
        let mut img = GrayImage::new(20, 20);
        for (i, v) in img.data.iter_mut().enumerate() {
            *v = (((i * 7919) % 97) as f32) / 97.0;
        }
        let p = zncc_patch(&img, 9.3, 8.6, 3).expect("textured");
        let q = zncc_patch(&img, 10.1, 8.0, 3).expect("textured");
        let mut raw_p = vec![0f32; 49];
        let mut raw_q = vec![0f32; 49];
        sample_patch(&img, 9.3, 8.6, 3, &mut raw_p);
        sample_patch(&img, 10.1, 8.0, 3, &mut raw_q);
        let dot: f32 = p.iter().zip(&q).map(|(a, b)| a * b).sum();
        assert!((dot - zncc(&raw_p, &raw_q)).abs() < 1e-5);
        // Affine intensity changes leave ZNCC unchanged.
        let scaled: Vec<f32> = raw_q.iter().map(|v| 0.3 * v + 0.2).collect();
        assert!((zncc(&raw_p, &scaled) - zncc(&raw_p, &raw_q)).abs() < 1e-5);
        assert!((zncc(&raw_p, &raw_p) - 1.0).abs() < 1e-6);
        // Clamped sampling at the border agrees with GrayImage::sample.
        let mut border = vec![0f32; 9];
        sample_patch(&img, 0.5, 0.25, 1, &mut border);
        assert_eq!(border[4], img.sample(0.5, 0.25));
        assert!(zncc_patch(&GrayImage::new(20, 20), 10.0, 10.0, 3).is_none());
        assert!(zncc_patch(&img, 1.0, 10.0, 3).is_none());
    }
}
