//! Image quality against a photo, over a mask: PSNR and SSIM (Wang, Bovik, Sheikh & Simoncelli,
//! IEEE TIP 2004: 11×11 Gaussian window, σ = 1.5, K1 = 0.01, K2 = 0.03, L = 255), the measures
//! of the novel-view evaluations (Mip-NeRF 360, 3D Gaussian Splatting).

use image::RgbImage;
use serde::{Deserialize, Serialize};

/// PSNR, SSIM and coverage of one rendering.
#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize)]
pub struct Quality {
    /// dB over the masked pixels, the three channels together.
    pub psnr: f64,
    /// Mean SSIM (over the three channels) of the windows centred on masked pixels.
    pub ssim: f64,
    /// Masked pixels / all pixels.
    pub coverage: f64,
    pub pixels: usize,
}

/// PSNR and SSIM of `rendered` against `photo` over the pixels where `mask` is true.
pub fn quality(rendered: &RgbImage, photo: &RgbImage, mask: &[bool]) -> Quality {
    let (w, h) = (photo.width() as usize, photo.height() as usize);
    assert_eq!(
        (rendered.width(), rendered.height()),
        (photo.width(), photo.height())
    );
    assert_eq!(mask.len(), w * h);
    let pixels = mask.iter().filter(|m| **m).count();
    if pixels == 0 {
        return Quality::default();
    }
    let (r, p) = (rendered.as_raw(), photo.as_raw());
    let mut se = 0.0f64;
    for (k, _) in mask.iter().enumerate().filter(|(_, m)| **m) {
        for c in 0..3 {
            let d = f64::from(r[3 * k + c]) - f64::from(p[3 * k + c]);
            se += d * d;
        }
    }
    let mse = se / (3 * pixels) as f64;
    let psnr = if mse > 0.0 {
        10.0 * (255.0f64 * 255.0 / mse).log10()
    } else {
        f64::INFINITY
    };
    let mut ssim_sum = 0.0;
    for c in 0..3 {
        let a: Vec<f32> = (0..w * h).map(|k| f32::from(r[3 * k + c])).collect();
        let b: Vec<f32> = (0..w * h).map(|k| f32::from(p[3 * k + c])).collect();
        let map = ssim_map(&a, &b, w, h);
        let s: f64 = map
            .iter()
            .zip(mask)
            .filter(|(_, m)| **m)
            .map(|(v, _)| f64::from(*v))
            .sum();
        ssim_sum += s / pixels as f64;
    }
    Quality {
        psnr,
        ssim: ssim_sum / 3.0,
        coverage: pixels as f64 / (w * h) as f64,
        pixels,
    }
}

/// The SSIM index at every pixel (the window is cut at the image border and renormalised).
pub fn ssim_map(a: &[f32], b: &[f32], w: usize, h: usize) -> Vec<f32> {
    let kernel: Vec<f32> = {
        let k: Vec<f32> = (-5..=5)
            .map(|i: i32| (-(i * i) as f32 / (2.0 * 1.5 * 1.5)).exp())
            .collect();
        let s: f32 = k.iter().sum();
        k.into_iter().map(|v| v / s).collect()
    };
    // One pass of the separable window along x (`dx = 1`) or y, cut at the border.
    let pass = |src: &[f32], along_x: bool| -> Vec<f32> {
        let mut out = vec![0.0f32; w * h];
        for y in 0..h {
            for x in 0..w {
                let (mut acc, mut ws) = (0.0, 0.0);
                for (j, kv) in kernel.iter().enumerate() {
                    let (xx, yy) = if along_x {
                        (x as i64 + j as i64 - 5, y as i64)
                    } else {
                        (x as i64, y as i64 + j as i64 - 5)
                    };
                    if xx >= 0 && (xx as usize) < w && yy >= 0 && (yy as usize) < h {
                        acc += kv * src[yy as usize * w + xx as usize];
                        ws += kv;
                    }
                }
                out[y * w + x] = acc / ws;
            }
        }
        out
    };
    let blur = |src: &[f32]| pass(&pass(src, true), false);
    let ma = blur(a);
    let mb = blur(b);
    let aa: Vec<f32> = a.iter().map(|v| v * v).collect();
    let bb: Vec<f32> = b.iter().map(|v| v * v).collect();
    let ab: Vec<f32> = a.iter().zip(b).map(|(u, v)| u * v).collect();
    let (saa, sbb, sab) = (blur(&aa), blur(&bb), blur(&ab));
    let c1 = (0.01f32 * 255.0).powi(2);
    let c2 = (0.03f32 * 255.0).powi(2);
    (0..w * h)
        .map(|k| {
            let (mu_a, mu_b) = (ma[k], mb[k]);
            let va = (saa[k] - mu_a * mu_a).max(0.0);
            let vb = (sbb[k] - mu_b * mu_b).max(0.0);
            let cov = sab[k] - mu_a * mu_b;
            ((2.0 * mu_a * mu_b + c1) * (2.0 * cov + c2))
                / ((mu_a * mu_a + mu_b * mu_b + c1) * (va + vb + c2))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Identical images: infinite PSNR, SSIM 1. A constant offset of 10 grey levels:
    /// PSNR = 20 log10(255/10) = 28.13 dB. Only masked pixels count.
    #[test]
    fn psnr_and_ssim_of_known_differences() {
        let (w, h) = (32u32, 24u32);
        let a = RgbImage::from_fn(w, h, |x, y| image::Rgb([(x * 7) as u8, (y * 9) as u8, 100]));
        let mask = vec![true; (w * h) as usize];
        let q = quality(&a, &a, &mask);
        assert!(q.psnr.is_infinite());
        assert!((q.ssim - 1.0).abs() < 1e-5);
        let b = RgbImage::from_fn(w, h, |x, y| {
            image::Rgb(a.get_pixel(x, y).0.map(|v| v.saturating_add(10)))
        });
        let q = quality(&a, &b, &mask);
        assert!((q.psnr - 28.1308).abs() < 1e-3, "{}", q.psnr);
        assert!(q.ssim < 1.0 && q.ssim > 0.9);
        let mut half = vec![false; (w * h) as usize];
        half[..(w * h / 2) as usize].fill(true);
        let q = quality(&a, &b, &half);
        assert_eq!(q.pixels, (w * h / 2) as usize);
        assert!((q.coverage - 0.5).abs() < 1e-12);
    }
}
