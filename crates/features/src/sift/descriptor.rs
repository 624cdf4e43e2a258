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
    let mut hist = [0f32; ORI_BINS];
    let bins_per_rad = ORI_BINS as f32 / (2.0 * PI);
    let ri = r as isize;
    let (y0, y1) = ((yi - ri).max(1), (yi + ri).min(g.h as isize - 2));
    let (x0, x1) = ((xi - ri).max(1), (xi + ri).min(g.w as isize - 2));
    if x0 <= x1 {
        let n = (x1 - x0 + 1) as usize;
        let wx = &wts[(x0 - xi + ri) as usize..(x0 - xi + ri) as usize + n];
        let (mut wgt, mut bins) = ([0f32; ROW_PIXELS], [0u32; ROW_PIXELS]);
        let (mut mag, mut ori) = ([0f32; ROW_PIXELS], [0f32; ROW_PIXELS]);
        for y in y0..=y1 {
            let wy = wts[(y - yi + ri) as usize];
            g.span(
                c.layer,
                y as usize,
                x0 as usize,
                &mut mag[..n],
                &mut ori[..n],
            );
            let (m, a) = (&mag[..n], &ori[..n]);
            // Weights and bins in lanes, then the votes in pixel order (the same sums).
            for k in 0..n {
                wgt[k] = wy * wx[k] * m[k];
                bins[k] = truncate(a[k] * bins_per_rad + 0.5).max(0) as u32 % ORI_BINS as u32;
            }
            for k in 0..n {
                hist[bins[k] as usize] += wgt[k];
            }
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
    let mut hist = [0f32; (D + 2) * (D + 2) * (N + 2)];
    let (mut mag, mut ori) = ([0f32; ROW_PIXELS], [0f32; ROW_PIXELS]);
    let ri = r as isize;
    let (y0, y1) = ((yi - ri).max(1), (yi + ri).min(g.h as isize - 2));
    let (x0, x1) = ((xi - ri).max(1), (xi + ri).min(g.w as isize - 2));
    let half = D as f32 / 2.0 - 0.5;
    let mut row_buf = Row::default();
    for y in y0..=y1 {
        let dy = y as f32 - c.y;
        let wrow = wy[(y - yi + ri) as usize];
        // The x range where both bin coordinates lie in (−1, D): skips the window's corners.
        let (a0, a1) = slab(dy * sin_t + half, cos_t, D as f32);
        let (b0, b1) = slab(dy * cos_t + half, -sin_t, D as f32);
        let (xa, xb) = (
            (c.x + a0.max(b0)).floor() as isize,
            (c.x + a1.min(b1)).ceil() as isize,
        );
        let (xs, xe) = (xa.max(x0), xb.min(x1));
        if xs > xe {
            continue;
        }
        let n = (xe - xs + 1) as usize;
        // Two passes over the row's span: the bins, fractions and weights of every pixel in
        // lanes (`Row::fill`: the same arithmetic as one pixel at a time, so the same numbers),
        // then the trilinear votes in pixel order, which keeps every bin's sum in the same order.
        g.span(
            c.layer,
            y as usize,
            xs as usize,
            &mut mag[..n],
            &mut ori[..n],
        );
        row_buf.fill(
            RowInput {
                x0: xs as i32,
                cx: c.x,
                dy,
                cos_t,
                sin_t,
                half,
                wrow,
                angle,
                bins_per_rad,
            },
            &wx[(xs - xi + ri) as usize..(xs - xi + ri) as usize + n],
            &mag[..n],
            &ori[..n],
        );
        for k in 0..n {
            if !row_buf.inside[k] {
                continue;
            }
            let (wgt, fr, fc, fo) = (row_buf.wgt[k], row_buf.fr[k], row_buf.fc[k], row_buf.fo[k]);
            let base = row_buf.base[k] as usize;
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

/// Pixels in one row of a descriptor window, at most.
const ROW_PIXELS: usize = 2 * MAX_RADIUS + 1;

/// What [`Row::fill`] needs besides the row's pixels.
struct RowInput {
    /// The span's first column and the keypoint's `x`; `y − c.y` of the row.
    x0: i32,
    cx: f32,
    dy: f32,
    cos_t: f32,
    sin_t: f32,
    half: f32,
    wrow: f32,
    angle: f32,
    bins_per_rad: f32,
}

/// One window row's votes before they are cast: each pixel's first histogram cell (`base`), its
/// weight, the fractions toward the next row, column and orientation bin, and whether it lies
/// in the window.
struct Row {
    base: [u32; ROW_PIXELS],
    wgt: [f32; ROW_PIXELS],
    fr: [f32; ROW_PIXELS],
    fc: [f32; ROW_PIXELS],
    fo: [f32; ROW_PIXELS],
    inside: [bool; ROW_PIXELS],
}

impl Default for Row {
    fn default() -> Self {
        Row {
            base: [0; ROW_PIXELS],
            wgt: [0.0; ROW_PIXELS],
            fr: [0.0; ROW_PIXELS],
            fc: [0.0; ROW_PIXELS],
            fo: [0.0; ROW_PIXELS],
            inside: [false; ROW_PIXELS],
        }
    }
}

impl Row {
    /// The votes of the pixels whose Gaussian factors, magnitudes and orientations are `wx`, `mag`
    /// and `ori` (equal lengths, at most [`ROW_PIXELS`]). Branch-free, so that it vectorises; a
    /// pixel outside the window gets `inside = false` and numbers that are not used.
    #[inline]
    fn fill(&mut self, p: RowInput, wx: &[f32], mag: &[f32], ori: &[f32]) {
        const D: usize = DESC_WIDTH;
        const N: usize = DESC_BINS;
        let n = wx.len().min(ROW_PIXELS);
        let (mag, ori) = (&mag[..n], &ori[..n]);
        for k in 0..n {
            let dx = (p.x0 + k as i32) as f32 - p.cx;
            let cbin = dx * p.cos_t + p.dy * p.sin_t + p.half;
            let rbin = -dx * p.sin_t + p.dy * p.cos_t + p.half;
            self.inside[k] = rbin > -1.0 && rbin < D as f32 && cbin > -1.0 && cbin < D as f32;
            self.wgt[k] = p.wrow * wx[k] * mag[k];
            let rel = ori[k] - p.angle;
            let obin = if rel < 0.0 { rel + 2.0 * PI } else { rel } * p.bins_per_rad;
            // Truncation is the floor for the pixels used (rbin, cbin > −1, obin ≥ 0); `min`
            // guards `3.99999 + 1 == 5`; outside the window the value is not used.
            let r1 = truncate(rbin + 1.0).clamp(0, D as i32);
            let c1 = truncate(cbin + 1.0).clamp(0, D as i32);
            let o0 = truncate(obin).max(0);
            self.fr[k] = rbin + 1.0 - r1 as f32;
            self.fc[k] = cbin + 1.0 - c1 as f32;
            self.fo[k] = obin - o0 as f32;
            self.base[k] = ((r1 as u32 * (D as u32 + 2) + c1 as u32) * (N as u32 + 2))
                + (o0 as u32 % N as u32);
        }
    }
}

/// `v` truncated toward zero, for `v` in `[−1, 64]`; others (NaN included) give a value in that
/// range. Unlike `as`, it compiles to one vector conversion (`as` saturates, which the compiler
/// does lane by lane).
#[inline(always)]
// Not `clamp`: it passes NaN through, and NaN would make the conversion undefined.
#[allow(clippy::manual_clamp)]
fn truncate(v: f32) -> i32 {
    // `max` and `min` return the other operand when one is NaN, so the value is finite and within
    // i32's range.
    let v = v.max(-1.0).min(64.0);
    // SAFETY: `v` is finite and in [−1, 64], which i32 represents.
    unsafe { v.to_int_unchecked::<i32>() }
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn truncation_floors_the_window_range_and_tames_the_rest() {
        assert_eq!(truncate(0.0), 0);
        assert_eq!(truncate(3.999), 3);
        assert_eq!(truncate(4.0), 4);
        assert_eq!(truncate(-0.5), 0);
        for v in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, 1e30, -1e30] {
            assert!((-1..=64).contains(&truncate(v)), "{v}");
        }
    }
}
