//! The float grey image every detector works on (values in [0, 1], row-major), with the few
//! operations they share: conversion, separable Gaussian blur, 2× downsampling, bilinear sampling and
//! central-difference gradients.

use image::DynamicImage;

/// A row-major `f32` grey image.
#[derive(Clone, Debug, PartialEq)]
pub struct GrayImage {
    pub width: usize,
    pub height: usize,
    pub data: Vec<f32>,
}

impl GrayImage {
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            data: vec![0.0; width * height],
        }
    }

    /// Luma of any decoded image (8 or 16 bit, grey or colour) scaled to [0, 1].
    pub fn from_dynamic(img: &DynamicImage) -> Self {
        let l = img.to_luma32f();
        Self {
            width: l.width() as usize,
            height: l.height() as usize,
            data: l.into_raw(),
        }
    }

    /// From an 8-bit RGB image (Rec. 601 luma).
    pub fn from_rgb8(img: &image::RgbImage) -> Self {
        let data = img
            .pixels()
            .map(|p| (0.299 * p[0] as f32 + 0.587 * p[1] as f32 + 0.114 * p[2] as f32) / 255.0)
            .collect();
        Self {
            width: img.width() as usize,
            height: img.height() as usize,
            data,
        }
    }

    #[inline]
    pub fn get(&self, x: usize, y: usize) -> f32 {
        self.data[y * self.width + x]
    }

    /// Value at integer coordinates clamped to the border.
    #[inline]
    pub fn get_clamped(&self, x: isize, y: isize) -> f32 {
        let xc = x.clamp(0, self.width as isize - 1) as usize;
        let yc = y.clamp(0, self.height as isize - 1) as usize;
        self.data[yc * self.width + xc]
    }

    /// Bilinear interpolation at a sub-pixel position (clamped at the border).
    #[inline]
    pub fn sample(&self, x: f32, y: f32) -> f32 {
        let x0 = x.floor();
        let y0 = y.floor();
        let (fx, fy) = (x - x0, y - y0);
        let (xi, yi) = (x0 as isize, y0 as isize);
        let a = self.get_clamped(xi, yi);
        let b = self.get_clamped(xi + 1, yi);
        let c = self.get_clamped(xi, yi + 1);
        let d = self.get_clamped(xi + 1, yi + 1);
        (a * (1.0 - fx) + b * fx) * (1.0 - fy) + (c * (1.0 - fx) + d * fx) * fy
    }

    /// True when `(x, y)` is at least `margin` pixels inside the image.
    #[inline]
    pub fn inside(&self, x: f32, y: f32, margin: f32) -> bool {
        x >= margin
            && y >= margin
            && x <= self.width as f32 - 1.0 - margin
            && y <= self.height as f32 - 1.0 - margin
    }

    /// Separable Gaussian blur with standard deviation `sigma` (kernel radius ⌈3σ⌉, border clamped).
    pub fn gaussian_blur(&self, sigma: f32) -> Self {
        if sigma <= 0.0 {
            return self.clone();
        }
        let k = gaussian_kernel(sigma);
        let r = (k.len() / 2) as isize;
        let (w, h) = (self.width, self.height);
        let mut tmp = vec![0f32; w * h];
        for y in 0..h {
            let row = &self.data[y * w..(y + 1) * w];
            for x in 0..w {
                let mut s = 0.0;
                for (i, kv) in k.iter().enumerate() {
                    let xx = (x as isize + i as isize - r).clamp(0, w as isize - 1) as usize;
                    s += kv * row[xx];
                }
                tmp[y * w + x] = s;
            }
        }
        let mut out = vec![0f32; w * h];
        for y in 0..h {
            for (i, kv) in k.iter().enumerate() {
                let yy = (y as isize + i as isize - r).clamp(0, h as isize - 1) as usize;
                let src = &tmp[yy * w..(yy + 1) * w];
                let dst = &mut out[y * w..(y + 1) * w];
                for x in 0..w {
                    dst[x] += kv * src[x];
                }
            }
        }
        Self {
            width: w,
            height: h,
            data: out,
        }
    }

    /// Halves the resolution by averaging 2×2 blocks (pixel (i, j) covers (2i, 2j)…(2i+1, 2j+1), so a
    /// position `p` at this level is `(p − 0.5) / 2` at the next).
    pub fn downsample2(&self) -> Self {
        let (w, h) = (self.width / 2, self.height / 2);
        let mut out = vec![0f32; w * h];
        for y in 0..h {
            for x in 0..w {
                let s = self.get(2 * x, 2 * y)
                    + self.get(2 * x + 1, 2 * y)
                    + self.get(2 * x, 2 * y + 1)
                    + self.get(2 * x + 1, 2 * y + 1);
                out[y * w + x] = 0.25 * s;
            }
        }
        Self {
            width: w,
            height: h,
            data: out,
        }
    }

    /// Central-difference gradients `(∂I/∂x, ∂I/∂y)` (one-sided at the border).
    pub fn gradients(&self) -> (Self, Self) {
        let (w, h) = (self.width, self.height);
        let mut gx = Self::new(w, h);
        let mut gy = Self::new(w, h);
        for y in 0..h {
            for x in 0..w {
                let xm = x.saturating_sub(1);
                let xp = (x + 1).min(w - 1);
                let ym = y.saturating_sub(1);
                let yp = (y + 1).min(h - 1);
                gx.data[y * w + x] = (self.get(xp, y) - self.get(xm, y)) / (xp - xm).max(1) as f32;
                gy.data[y * w + x] = (self.get(x, yp) - self.get(x, ym)) / (yp - ym).max(1) as f32;
            }
        }
        (gx, gy)
    }
}

/// Normalised Gaussian kernel of radius ⌈3σ⌉.
pub fn gaussian_kernel(sigma: f32) -> Vec<f32> {
    let r = (3.0 * sigma).ceil().max(1.0) as isize;
    let mut k: Vec<f32> = (-r..=r)
        .map(|i| (-(i * i) as f32 / (2.0 * sigma * sigma)).exp())
        .collect();
    let s: f32 = k.iter().sum();
    k.iter_mut().for_each(|v| *v /= s);
    k
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blur_keeps_mean_and_sample_interpolates() {
        let mut img = GrayImage::new(32, 24);
        for (i, v) in img.data.iter_mut().enumerate() {
            *v = ((i * 37) % 11) as f32 / 10.0;
        }
        let b = img.gaussian_blur(1.5);
        let m0: f32 = img.data.iter().sum::<f32>() / img.data.len() as f32;
        let m1: f32 = b.data.iter().sum::<f32>() / b.data.len() as f32;
        assert!((m0 - m1).abs() < 0.02);
        let ramp = GrayImage {
            width: 4,
            height: 1,
            data: vec![0.0, 1.0, 2.0, 3.0],
        };
        assert!((ramp.sample(1.25, 0.0) - 1.25).abs() < 1e-6);
        let (gx, _) = ramp.gradients();
        assert!((gx.get(1, 0) - 1.0).abs() < 1e-6);
        assert_eq!(img.downsample2().width, 16);
    }
}
