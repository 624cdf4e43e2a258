//! The SIFT orientation histogram and descriptor (Lowe 2004, §5–6), split from the detector in
//! `sift.rs`: 36-bin orientation histograms with peak interpolation, the 4×4×8 descriptor with
//! trilinear interpolation over the rotated window, normalise–clip(0.2)–renormalise, and RootSIFT
//! (Arandjelović & Zisserman 2012).

use std::f32::consts::{PI, SQRT_2};

use super::{
    Candidate, OctaveGrad, DESC_BINS, DESC_MAG_THRESHOLD, DESC_SCALE_FACTOR, DESC_WIDTH,
    MAX_RADIUS, ORI_BINS, ORI_SIG_FACTOR,
};

/// Fills `out[0..=2r]` with `exp(-(i − r − frac)² · k)`, the separable factor of a Gaussian window.
#[inline]
pub(super) fn gauss_weights(out: &mut [f32], r: usize, frac: f32, k: f32) {
    for (i, v) in out[..=2 * r].iter_mut().enumerate() {
        let d = i as f32 - r as f32 - frac;
        *v = (-d * d * k).exp();
    }
}

/// Dominant orientations (Lowe §5): 36-bin histogram of gradient orientations weighted by magnitude
/// and a Gaussian of σ = 1.5·scale, smoothed, with every local peak ≥ `peak_ratio`·max kept and its
/// position interpolated by a parabola. Returns up to 18 angles in [0, 2π).
pub(super) fn orientations(
    g: &OctaveGrad,
    c: &Candidate,
    peak_ratio: f32,
) -> ([f32; ORI_BINS / 2], usize) {
    let sigma = ORI_SIG_FACTOR * c.scale;
    let r = ((3.0 * sigma).round() as usize).min(MAX_RADIUS);
    let (xi, yi) = (c.x.round() as isize, c.y.round() as isize);
    let mut wts = [0f32; 2 * MAX_RADIUS + 1];
    gauss_weights(&mut wts, r, 0.0, 0.5 / (sigma * sigma));
    let (mag, ori) = (&g.mag[c.layer - 1], &g.ori[c.layer - 1]);
    let mut hist = [0f32; ORI_BINS];
    let bins_per_rad = ORI_BINS as f32 / (2.0 * PI);
    let ri = r as isize;
    let (y0, y1) = ((yi - ri).max(1), (yi + ri).min(g.h as isize - 2));
    let (x0, x1) = ((xi - ri).max(1), (xi + ri).min(g.w as isize - 2));
    for y in y0..=y1 {
        let wy = wts[(y - yi + ri) as usize];
        let row = y as usize * g.w;
        for x in x0..=x1 {
            let wgt = wy * wts[(x - xi + ri) as usize] * mag[row + x as usize];
            let bin = (ori[row + x as usize] * bins_per_rad + 0.5) as usize % ORI_BINS;
            hist[bin] += wgt;
        }
    }
    let n = ORI_BINS;
    let smooth: [f32; ORI_BINS] = std::array::from_fn(|i| {
        let at = |d: isize| hist[(i as isize + d).rem_euclid(n as isize) as usize];
        (at(-2) + at(2)) / 16.0 + (at(-1) + at(1)) * (4.0 / 16.0) + at(0) * (6.0 / 16.0)
    });
    let max = smooth.iter().copied().fold(0.0, f32::max);
    let mut out = [0f32; ORI_BINS / 2];
    let mut count = 0;
    if max <= 0.0 {
        return (out, 0);
    }
    for i in 0..n {
        let (l, v, rr) = (smooth[(i + n - 1) % n], smooth[i], smooth[(i + 1) % n]);
        if v > l && v > rr && v >= peak_ratio * max && count < out.len() {
            let bin = i as f32 + 0.5 * (l - rr) / (l - 2.0 * v + rr);
            out[count] = (bin / bins_per_rad).rem_euclid(2.0 * PI);
            count += 1;
        }
    }
    (out, count)
}

/// The 4×4×8 descriptor (Lowe §6.1) with trilinear interpolation and a Gaussian window of σ = half the
/// descriptor width, normalised, clipped at 0.2, renormalised; then optionally RootSIFT.
pub(super) fn describe(
    g: &OctaveGrad,
    c: &Candidate,
    angle: f32,
    root_sift: bool,
    out: &mut [f32],
) {
    const D: usize = DESC_WIDTH;
    const N: usize = DESC_BINS;
    let hist_width = DESC_SCALE_FACTOR * c.scale;
    let r = ((hist_width * SQRT_2 * (D as f32 + 1.0) * 0.5).round() as usize).min(MAX_RADIUS);
    let (sin_a, cos_a) = angle.sin_cos();
    let (cos_t, sin_t) = (cos_a / hist_width, sin_a / hist_width);
    let bins_per_rad = N as f32 / (2.0 * PI);
    let (xi, yi) = (c.x.round() as isize, c.y.round() as isize);
    // exp(−(c_rot² + r_rot²)/(D²/2)) with rotated offsets in cell units is separable in the pixel offsets.
    let k = 2.0 / ((D * D) as f32 * hist_width * hist_width);
    let mut wx = [0f32; 2 * MAX_RADIUS + 1];
    let mut wy = [0f32; 2 * MAX_RADIUS + 1];
    gauss_weights(&mut wx, r, c.x - xi as f32, k);
    gauss_weights(&mut wy, r, c.y - yi as f32, k);
    let (mag, ori) = (&g.mag[c.layer - 1], &g.ori[c.layer - 1]);
    let mut hist = [0f32; (D + 2) * (D + 2) * (N + 2)];
    let ri = r as isize;
    let (y0, y1) = ((yi - ri).max(1), (yi + ri).min(g.h as isize - 2));
    let (x0, x1) = ((xi - ri).max(1), (xi + ri).min(g.w as isize - 2));
    let half = D as f32 / 2.0 - 0.5;
    for y in y0..=y1 {
        let dy = y as f32 - c.y;
        let wrow = wy[(y - yi + ri) as usize];
        let row = y as usize * g.w;
        // The x range where both bin coordinates lie in (−1, D): skips the window's corners.
        let (a0, a1) = slab(dy * sin_t + half, cos_t, D as f32);
        let (b0, b1) = slab(dy * cos_t + half, -sin_t, D as f32);
        let (xa, xb) = (
            (c.x + a0.max(b0)).floor() as isize,
            (c.x + a1.min(b1)).ceil() as isize,
        );
        for x in xa.max(x0)..=xb.min(x1) {
            let dx = x as f32 - c.x;
            let cbin = dx * cos_t + dy * sin_t + half;
            let rbin = -dx * sin_t + dy * cos_t + half;
            if !(rbin > -1.0 && rbin < D as f32 && cbin > -1.0 && cbin < D as f32) {
                continue;
            }
            let idx = row + x as usize;
            let wgt = wrow * wx[(x - xi + ri) as usize] * mag[idx];
            let rel = ori[idx] - angle;
            let obin = if rel < 0.0 { rel + 2.0 * PI } else { rel } * bins_per_rad;
            // Truncation is the floor here (rbin, cbin > −1, obin ≥ 0); `min` guards `3.99999 + 1 == 5`.
            let (r1, c1, o0) = (
                ((rbin + 1.0) as usize).min(D),
                ((cbin + 1.0) as usize).min(D),
                obin as usize,
            );
            let (fr, fc, fo) = (
                rbin + 1.0 - r1 as f32,
                cbin + 1.0 - c1 as f32,
                obin - o0 as f32,
            );
            let base = (r1 * (D + 2) + c1) * (N + 2) + o0 % N;
            let v_r1 = wgt * fr;
            let v_r0 = wgt - v_r1;
            let (v_rc11, v_rc01) = (v_r1 * fc, v_r0 * fc);
            let (v_rc10, v_rc00) = (v_r1 - v_rc11, v_r0 - v_rc01);
            let cells = [
                (0, v_rc00),
                (N + 2, v_rc01),
                ((D + 2) * (N + 2), v_rc10),
                ((D + 3) * (N + 2), v_rc11),
            ];
            for (off, v) in cells {
                let v1 = v * fo;
                hist[base + off] += v - v1;
                hist[base + off + 1] += v1;
            }
        }
    }
    for i in 0..D {
        for j in 0..D {
            let src = ((i + 1) * (D + 2) + j + 1) * (N + 2);
            let dst = &mut out[(i * D + j) * N..(i * D + j + 1) * N];
            dst.copy_from_slice(&hist[src..src + N]);
            dst[0] += hist[src + N];
            dst[1] += hist[src + N + 1];
        }
    }
    normalize_descriptor(out, root_sift);
}

/// The interval of `t` where `−1 < offset + slope·t < upper` (unbounded when `slope` is 0 and the
/// offset is inside).
#[inline(always)]
pub(super) fn slab(offset: f32, slope: f32, upper: f32) -> (f32, f32) {
    if slope.abs() < 1e-12 {
        return if offset > -1.0 && offset < upper {
            (-1e6, 1e6)
        } else {
            (1.0, -1.0)
        };
    }
    let (t0, t1) = ((-1.0 - offset) / slope, (upper - offset) / slope);
    (t0.min(t1), t0.max(t1))
}

/// Normalise, clip at 0.2, renormalise (Lowe §6.1); then RootSIFT (L1-normalise, square root).
pub(super) fn normalize_descriptor(v: &mut [f32], root_sift: bool) {
    let norm = v.iter().map(|x| x * x).sum::<f32>().sqrt();
    if norm <= 0.0 {
        return;
    }
    let clip = DESC_MAG_THRESHOLD * norm;
    v.iter_mut().for_each(|x| *x = x.min(clip));
    if root_sift {
        let l1 = v.iter().sum::<f32>().max(f32::MIN_POSITIVE);
        v.iter_mut().for_each(|x| *x = (*x / l1).sqrt());
    } else {
        let n2 = v
            .iter()
            .map(|x| x * x)
            .sum::<f32>()
            .sqrt()
            .max(f32::MIN_POSITIVE);
        v.iter_mut().for_each(|x| *x /= n2);
    }
}
