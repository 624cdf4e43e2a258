//! SIFT's scale space (Lowe 2004, §3), split from the detector in `sift.rs`: the first octave's
//! 2× upsampling, the incremental Gaussian blurs, the 2×2 downsampling between octaves, and the
//! blurred levels whose gradients the orientation and descriptor windows read.

use std::f32::consts::PI;

use rayon::prelude::*;

use crate::gray::{gaussian_kernel, GrayImage};

/// The blurred levels 1..=s of one octave, whose gradients the orientation and descriptor windows
/// read ([`OctaveGrad::span`]). Computing them only there, instead of over every level (two
/// arrays of the octave's size per level: 150 MB for the first octave of a 6 MP image), does a
/// fraction of the work for 8 192 keypoints and halves what the windows read (fountain-P11's
/// features stage: peak memory 864 → 684 MB).
pub(super) struct OctaveGrad {
    pub octave: i32,
    pub w: usize,
    pub h: usize,
    pub levels: Vec<Vec<f32>>,
}

impl OctaveGrad {
    /// Central-difference gradient magnitude and orientation ([0, 2π), image y axis down) of
    /// `layer` (1..=s) at the pixels `x0..x0 + mag.len()` of row `y`, all within the border
    /// (1 ≤ x, y and x < w − 1, y < h − 1).
    #[inline]
    pub(super) fn span(&self, layer: usize, y: usize, x0: usize, mag: &mut [f32], ori: &mut [f32]) {
        let (w, n) = (self.w, mag.len());
        let src = &self.levels[layer - 1];
        let at = y * w + x0;
        let mid = &src[at - 1..at + n + 1];
        let (up, down) = (&src[at - w..at - w + n], &src[at + w..at + w + n]);
        gradient_row(up, mid, down, mag, &mut ori[..n]);
    }
}

/// Bilinear 2× upsampling: output pixel `i` samples input position `(i + 0.5)/2 − 0.5`, border
/// clamped ([`GrayImage::sample`]). Along a row that position is `k − ¼` for output `2k` and `k + ¼`
/// for `2k + 1`, so the weights are the constants ¼ and ¾ and the loop needs neither `floor` nor
/// clamping but at the ends: the same products and sums as `sample`, bit for bit, without its
/// per-pixel index arithmetic (8.6 % of templeSparseRing's features stage).
pub(super) fn upsample2(img: &GrayImage) -> GrayImage {
    let (w, h) = (img.width * 2, img.height * 2);
    let (iw, ih) = (img.width, img.height);
    let mut data = vec![0f32; w * h];
    if iw == 0 || ih == 0 {
        return GrayImage {
            width: w,
            height: h,
            data,
        };
    }
    data.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        let sy = (y as f32 + 0.5) * 0.5 - 0.5;
        let y0 = sy.floor();
        let fy = sy - y0;
        let clamp = |v: isize| v.clamp(0, ih as isize - 1) as usize;
        let (ya, yb) = (clamp(y0 as isize), clamp(y0 as isize + 1));
        let (ra, rb) = (
            &img.data[ya * iw..ya * iw + iw],
            &img.data[yb * iw..yb * iw + iw],
        );
        let (wa, wb) = (1.0 - fy, fy);
        for (k, out) in row.chunks_exact_mut(2).enumerate() {
            let (km, kp) = (k.saturating_sub(1), (k + 1).min(iw - 1));
            out[0] = (ra[km] * 0.25 + ra[k] * 0.75) * wa + (rb[km] * 0.25 + rb[k] * 0.75) * wb;
            out[1] = (ra[k] * 0.75 + ra[kp] * 0.25) * wa + (rb[k] * 0.75 + rb[kp] * 0.25) * wb;
        }
    });
    GrayImage {
        width: w,
        height: h,
        data,
    }
}

/// 2×2 block average (the relation of [`GrayImage::downsample2`]), in parallel over rows.
pub(super) fn downsample(src: &[f32], w: usize, h: usize) -> GrayImage {
    let (w2, h2) = (w / 2, h / 2);
    let mut data = vec![0f32; w2 * h2];
    data.par_chunks_mut(w2.max(1))
        .enumerate()
        .for_each(|(y, row)| {
            let (r0, r1) = (
                &src[2 * y * w..2 * y * w + w],
                &src[(2 * y + 1) * w..(2 * y + 1) * w + w],
            );
            for (x, v) in row.iter_mut().enumerate() {
                *v = 0.25 * (r0[2 * x] + r0[2 * x + 1] + r1[2 * x] + r1[2 * x + 1]);
            }
        });
    GrayImage {
        width: w2,
        height: h2,
        data,
    }
}

/// Separable Gaussian blur (border replicated), parallel over output rows: for each row the vertical
/// pass accumulates into a padded scratch row, then the horizontal pass uses the kernel's symmetry.
/// Both inner loops are contiguous multiply-adds that vectorise.
pub(super) fn blur(src: &[f32], w: usize, h: usize, sigma: f32) -> Vec<f32> {
    let kern = gaussian_kernel(sigma);
    let r = kern.len() / 2;
    let half = &kern[r..];
    let mut out = vec![0f32; w * h];
    out.par_chunks_mut(w).enumerate().for_each_init(
        || vec![0f32; w + 2 * r],
        |buf, (y, dst)| blur_row(src, (w, h), y, half, buf, dst),
    );
    out
}

/// One output row of [`blur`]; `buf` is scratch of `w + 2r` floats.
fn blur_row(
    src: &[f32],
    (w, h): (usize, usize),
    y: usize,
    half: &[f32],
    buf: &mut [f32],
    dst: &mut [f32],
) {
    let r = half.len() - 1;
    let acc = &mut buf[r..r + w];
    let row = |yy: isize| {
        let yy = yy.clamp(0, h as isize - 1) as usize;
        &src[yy * w..yy * w + w]
    };
    for (a, &s) in acc.iter_mut().zip(row(y as isize)) {
        *a = half[0] * s;
    }
    for (i, &kv) in half.iter().enumerate().skip(1) {
        let (up, down) = (row(y as isize - i as isize), row(y as isize + i as isize));
        for ((a, &u), &d) in acc.iter_mut().zip(up).zip(down) {
            *a += kv * (u + d);
        }
    }
    let (first, last) = (buf[r], buf[r + w - 1]);
    buf[..r].fill(first);
    buf[r + w..].fill(last);
    for (d, &s) in dst.iter_mut().zip(&buf[r..r + w]) {
        *d = half[0] * s;
    }
    for (i, &kv) in half.iter().enumerate().skip(1) {
        let (left, right) = (&buf[r - i..r - i + w], &buf[r + i..r + i + w]);
        for ((d, &l), &rr) in dst.iter_mut().zip(left).zip(right) {
            *d += kv * (l + rr);
        }
    }
}

/// Central-difference gradient magnitude and orientation of the pixels of a row: `mid` holds
/// the row from one pixel before the first to one after the last, `up` and `down` the rows above
/// and below at the pixels themselves. Branch-free, so that it vectorises.
#[inline]
fn gradient_row(up: &[f32], mid: &[f32], down: &[f32], m: &mut [f32], a: &mut [f32]) {
    let it = m
        .iter_mut()
        .zip(a.iter_mut())
        .zip(mid.windows(3))
        .zip(up)
        .zip(down);
    for ((((mv, av), win), &u), &d) in it {
        let dx = win[2] - win[0];
        let dy = d - u;
        *mv = (dx * dx + dy * dy).sqrt();
        *av = fast_atan2(dy, dx);
    }
}

/// `atan2(y, x)` in [0, 2π) by a 7th-order minimax polynomial (max error about 1e-4 rad), branch-free.
#[inline(always)]
pub(crate) fn fast_atan2(y: f32, x: f32) -> f32 {
    let (ax, ay) = (x.abs(), y.abs());
    let (num, den) = if ax >= ay { (ay, ax) } else { (ax, ay) };
    let t = num / (den + f32::MIN_POSITIVE);
    let t2 = t * t;
    let mut a = (((-0.044_326_556 * t2 + 0.155_578_65) * t2 - 0.325_808_4) * t2 + 0.999_787_84) * t;
    a = if ax >= ay { a } else { 0.5 * PI - a };
    a = if x < 0.0 { PI - a } else { a };
    if y < 0.0 {
        2.0 * PI - a
    } else {
        a
    }
}
