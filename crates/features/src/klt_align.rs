//! The alignment kernels of [`crate::klt`]: the image pyramid with its gradients, Bouguet's
//! pyramidal Lucas–Kanade for the frame-to-frame translation (eq. 8), and the Shi–Tomasi affine
//! registration against a track's first appearance. Split from the tracker, which owns the tracks.

use rayon::prelude::*;

use crate::gray::GrayImage;
use crate::klt::KltOptions;
use crate::zncc::sample_patch;

/// Blur (σ, pixels) applied before each 2× pyramid reduction, on top of the 2×2 averaging.
const PYRAMID_SIGMA: f32 = 0.8;
/// Weight of the prior that keeps the affine deformation near its previous value, relative to the
/// data term's scale for those parameters.
const AFFINE_PRIOR: f64 = 0.05;
/// Bounds of the determinant of the fitted affine map (area change since the first appearance).
const AFFINE_DET_RANGE: (f32, f32) = (0.25, 4.0);

/// One pyramid level with its central-difference gradients.
pub(crate) struct Level {
    pub(crate) img: GrayImage,
    pub(crate) gx: GrayImage,
    pub(crate) gy: GrayImage,
}

pub(crate) fn build_pyramid(
    img: &GrayImage,
    sigma: f32,
    levels: usize,
    min_size: usize,
) -> Vec<Level> {
    let mut imgs = vec![img.gaussian_blur(sigma)];
    while imgs.len() < levels {
        let Some(last) = imgs.last() else { break };
        if last.width / 2 < min_size || last.height / 2 < min_size {
            break;
        }
        let next = last.gaussian_blur(PYRAMID_SIGMA).downsample2();
        imgs.push(next);
    }
    imgs.into_par_iter()
        .map(|img| {
            let (gx, gy) = img.gradients();
            Level { img, gx, gy }
        })
        .collect()
}

/// Bouguet's pyramidal Lucas–Kanade: the position in `next` of the feature at `(x, y)` in `prev`, or
/// `None` when the gradient matrix is too weak or the iteration diverges.
pub(crate) fn lk_translation(
    opts: &KltOptions,
    prev: &[Level],
    next: &[Level],
    x: f32,
    y: f32,
) -> Option<(f32, f32)> {
    let r = opts.window_radius;
    let n = (2 * r + 1) * (2 * r + 1);
    let mut buf = vec![0f32; 4 * n];
    let (t, rest) = buf.split_at_mut(n);
    let (tx, rest) = rest.split_at_mut(n);
    let (ty, c) = rest.split_at_mut(n);
    let levels = prev.len().min(next.len());
    let (mut gx, mut gy) = (0f32, 0f32);
    for lvl in (0..levels).rev() {
        let s = 0.5f32.powi(lvl as i32);
        let (ux, uy) = ((x + 0.5) * s - 0.5, (y + 0.5) * s - 0.5);
        let (p, q) = (&prev[lvl], &next[lvl]);
        sample_patch(&p.img, ux, uy, r, t);
        sample_patch(&p.gx, ux, uy, r, tx);
        sample_patch(&p.gy, ux, uy, r, ty);
        let (mut gxx, mut gxy, mut gyy) = (0f32, 0f32, 0f32);
        for (a, b) in tx.iter().zip(ty.iter()) {
            gxx += a * a;
            gxy += a * b;
            gyy += b * b;
        }
        let det = gxx * gyy - gxy * gxy;
        let min_eig =
            0.5 * ((gxx + gyy) - ((gxx - gyy).powi(2) + 4.0 * gxy * gxy).sqrt()) / n as f32;
        let singular = det.is_nan() || det <= f32::EPSILON * (gxx + gyy).powi(2);
        if singular || (lvl == 0 && min_eig < opts.min_eigenvalue) {
            return None;
        }
        let (mut vx, mut vy) = (0f32, 0f32);
        let limit = (q.img.width + q.img.height) as f32;
        for _ in 0..opts.max_iterations {
            sample_patch(&q.img, ux + gx + vx, uy + gy + vy, r, c);
            let (mut bx, mut by) = (0f32, 0f32);
            for i in 0..n {
                let di = t[i] - c[i];
                bx += di * tx[i];
                by += di * ty[i];
            }
            let (ex, ey) = ((gyy * bx - gxy * by) / det, (gxx * by - gxy * bx) / det);
            vx += ex;
            vy += ey;
            if !(vx.is_finite() && vy.is_finite())
                || (gx + vx).abs() > limit
                || (gy + vy).abs() > limit
            {
                return None;
            }
            if ex * ex + ey * ey < opts.epsilon * opts.epsilon {
                break;
            }
        }
        if lvl > 0 {
            (gx, gy) = (2.0 * (gx + vx), 2.0 * (gy + vy));
        } else {
            (gx, gy) = (gx + vx, gy + vy);
        }
    }
    Some((x + gx, y + gy))
}

/// Bilinear samples of the image and both gradients at one position (one set of weights; clamped
/// sampling near the border).
#[inline]
pub(crate) fn sample3(level: &Level, x: f32, y: f32) -> (f32, f32, f32) {
    let (x0, y0) = (x.floor(), y.floor());
    let (xi, yi) = (x0 as isize, y0 as isize);
    let w = level.img.width;
    if xi >= 0 && yi >= 0 && ((xi + 1) as usize) < w && ((yi + 1) as usize) < level.img.height {
        let (fx, fy) = (x - x0, y - y0);
        let (w00, w10, w01, w11) = (
            (1.0 - fx) * (1.0 - fy),
            fx * (1.0 - fy),
            (1.0 - fx) * fy,
            fx * fy,
        );
        let i = yi as usize * w + xi as usize;
        let s = |d: &[f32]| w00 * d[i] + w10 * d[i + 1] + w01 * d[i + w] + w11 * d[i + w + 1];
        (s(&level.img.data), s(&level.gx.data), s(&level.gy.data))
    } else {
        (
            level.img.sample(x, y),
            level.gx.sample(x, y),
            level.gy.sample(x, y),
        )
    }
}

/// Registers the first-appearance window `template` to `level` (full resolution) by Gauss–Newton over
/// `I(p + A w) − β ≈ T(w)`: affine `A`, centre `p` and intensity offset `β` (Shi & Tomasi 1994), with a
/// weak prior keeping `A` near `a0`. Returns the centre, `A` and the mean absolute residual, or `None`
/// when the fit is singular or degenerate.
pub(crate) fn affine_register(
    level: &Level,
    template: &[f32],
    r: usize,
    x: f32,
    y: f32,
    a0: [f32; 4],
    opts: &KltOptions,
) -> Option<(f32, f32, [f32; 4], f32)> {
    use nalgebra::{SMatrix, SVector};
    let ri = r as isize;
    let side = 2 * r + 1;
    let template = template.get(..side * side)?;
    let mut p = [
        a0[0] as f64,
        a0[1] as f64,
        a0[2] as f64,
        a0[3] as f64,
        x as f64,
        y as f64,
        0.0,
    ];
    let warp = |p: &[f64; 7], k: usize| {
        let (u, v) = (
            ((k % side) as isize - ri) as f64,
            ((k / side) as isize - ri) as f64,
        );
        (
            u,
            v,
            (p[4] + p[0] * u + p[1] * v) as f32,
            (p[5] + p[2] * u + p[3] * v) as f32,
        )
    };
    for _ in 0..opts.affine_max_iterations {
        // Upper triangle of JᵀJ (row-major over the 7 parameters) and Jᵀr.
        let mut hh = [0f64; 28];
        let mut g = [0f64; 7];
        for (k, &tv) in template.iter().enumerate() {
            let (u, v, wx, wy) = warp(&p, k);
            let (iv, ix, iy) = sample3(level, wx, wy);
            let res = iv as f64 - p[6] - tv as f64;
            let (ix, iy) = (ix as f64, iy as f64);
            let jac = [ix * u, ix * v, iy * u, iy * v, ix, iy, -1.0];
            let mut n = 0;
            for a in 0..7 {
                g[a] += jac[a] * res;
                for b in a..7 {
                    hh[n] += jac[a] * jac[b];
                    n += 1;
                }
            }
        }
        let mut h = SMatrix::<f64, 7, 7>::zeros();
        let mut n = 0;
        for a in 0..7 {
            for b in a..7 {
                h[(a, b)] = hh[n];
                h[(b, a)] = hh[n];
                n += 1;
            }
        }
        // Weak prior towards the previous frame's affine map: the four deformation parameters are poorly
        // constrained by one window (a shear along an edge costs almost nothing), and are otherwise free
        // to wander off and drag the centre along.
        let mu = AFFINE_PRIOR * 0.5 * (h[(4, 4)] + h[(5, 5)]) * (r * r) as f64 / 3.0;
        for k in 0..4 {
            h[(k, k)] += mu;
            g[k] += mu * (p[k] - a0[k] as f64);
        }
        let step = h.cholesky()?.solve(&(-SVector::<f64, 7>::from(g)));
        if !step.iter().all(|s| s.is_finite()) {
            return None;
        }
        for (pk, sk) in p.iter_mut().zip(step.iter()) {
            *pk += sk;
        }
        let da = step[0]
            .abs()
            .max(step[1].abs())
            .max(step[2].abs())
            .max(step[3].abs())
            * r as f64;
        if step[4].hypot(step[5]) < opts.epsilon as f64 && da < opts.epsilon as f64 {
            break;
        }
    }
    let a = [p[0] as f32, p[1] as f32, p[2] as f32, p[3] as f32];
    let det = a[0] * a[3] - a[1] * a[2];
    if !(AFFINE_DET_RANGE.0..=AFFINE_DET_RANGE.1).contains(&det) {
        return None;
    }
    let mut sum = 0f64;
    for (k, &tv) in template.iter().enumerate() {
        let (_, _, wx, wy) = warp(&p, k);
        sum += (level.img.sample(wx, wy) as f64 - p[6] - tv as f64).abs();
    }
    Some((
        p[4] as f32,
        p[5] as f32,
        a,
        (sum / (side * side) as f64) as f32,
    ))
}
