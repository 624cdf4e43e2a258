//! Texture enhancement of a single-depth-map model through the linked views (paper §5.1; Ofek,
//! Shilat, Rappoport and Werman, *Multiresolution textures from image sequences*, IEEE CG&A 1997).
//!
//! Every texel of the reference image with a depth is lifted to 3D and projected into each linked
//! view. A linked view contributes its (bilinear) colour when the point is inside its image and —
//! when the view has a depth map — not occluded there: the point's depth in that view agrees with
//! the view's own depth within [`EnhanceOptions::depth_tolerance`]. The texel becomes the
//! per-channel median of the reference colour and the contributions, which discards sensor noise,
//! specular reflections and highlights that move with the viewpoint. Texels with fewer than
//! [`EnhanceOptions::min_samples`] samples keep their colour.

use handheld_core::{PosedView, Progress};
use image::RgbImage;
use rayon::prelude::*;

use crate::error::{in_range, MeshError, Result};
use crate::view::{check_image_view, sample_depth, Depth, Projector};

/// Options of [`enhance_texture`].
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct EnhanceOptions {
    /// Relative depth agreement required for a linked view to see the texel's point:
    /// `|z_projected − z_view| ≤ depth_tolerance · z_view`. Default 0.02.
    pub depth_tolerance: f64,
    /// Fewest samples (reference included) for the median to replace a texel. Default 3.
    pub min_samples: usize,
}

impl Default for EnhanceOptions {
    fn default() -> Self {
        Self {
            depth_tolerance: 0.02,
            min_samples: 3,
        }
    }
}

impl EnhanceOptions {
    pub fn validate(&self) -> Result<()> {
        in_range("depth_tolerance", self.depth_tolerance, 0.0, 1.0)?;
        if !(1..=1024).contains(&self.min_samples) {
            return Err(MeshError::InvalidOption {
                option: "min_samples",
                reason: format!("must lie in 1..=1024, got {}", self.min_samples),
            });
        }
        Ok(())
    }
}

/// What [`enhance_texture`] did.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct EnhanceSummary {
    /// Texels replaced by a median.
    pub texels_replaced: usize,
    /// Mean number of samples per replaced texel (reference included).
    pub mean_samples: f64,
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// The reference view's image with each texel replaced by the robust median over the linked
/// views (the reference needs a depth map; a linked view's depth map, where present, rejects
/// occluded samples). Errors number the reference 0 and the linked views from 1.
pub fn enhance_texture(
    reference: &PosedView,
    linked: &[PosedView],
    opts: &EnhanceOptions,
    progress: &dyn Progress,
) -> Result<(RgbImage, EnhanceSummary)> {
    opts.validate()?;
    let depth = Depth::of(reference, 0)?;
    check_image_view(0, reference)?;
    let image = &reference.image;
    let reference = depth;
    for (i, v) in linked.iter().enumerate() {
        check_image_view(i + 1, v)?;
    }
    let (w, h) = (image.width() as usize, image.height() as usize);
    let rp = Projector::new(reference.posed);
    let others: Vec<(Projector, &PosedView)> = linked
        .iter()
        .map(|v| (Projector::new(&v.posed), v))
        .collect();
    progress.start("texture enhancement", h as u64);
    let src = image.as_raw();
    let rows: Vec<(Vec<u8>, usize, usize)> = (0..h)
        .into_par_iter()
        .map(|y| {
            let mut row = src[y * w * 3..(y + 1) * w * 3].to_vec();
            let (mut replaced, mut samples) = (0, 0);
            let mut chans: [Vec<f64>; 3] = Default::default();
            for x in 0..w {
                let d = reference.depth.data[y * w + x];
                if !(d.is_finite() && d > 0.0) {
                    continue;
                }
                let p = rp.lift(x as f64, y as f64, d as f64);
                for (c, ch) in chans.iter_mut().enumerate() {
                    ch.clear();
                    ch.push(row[x * 3 + c] as f64);
                }
                for (proj, v) in &others {
                    let pc = proj.to_cam(&p);
                    let Some(px) = proj.cam_to_pixel(&pc) else {
                        continue;
                    };
                    if !proj.posed.camera.contains(&px) {
                        continue;
                    }
                    if let Some(dm) = &v.depth {
                        match sample_depth(dm, &px, opts.depth_tolerance) {
                            Some(z) if (pc.z - z).abs() <= opts.depth_tolerance * z => {}
                            _ => continue,
                        }
                    }
                    let col = crate::view::sample_rgb(&v.image, &px);
                    for (ch, value) in chans.iter_mut().zip(col) {
                        ch.push(value);
                    }
                }
                if chans[0].len() >= opts.min_samples {
                    samples += chans[0].len();
                    replaced += 1;
                    for (c, ch) in chans.iter_mut().enumerate() {
                        row[x * 3 + c] = median(ch).round().clamp(0.0, 255.0) as u8;
                    }
                }
            }
            progress.inc(1);
            (row, replaced, samples)
        })
        .collect();
    progress.finish();
    let replaced: usize = rows.iter().map(|r| r.1).sum();
    let samples: usize = rows.iter().map(|r| r.2).sum();
    let data: Vec<u8> = rows.into_iter().flat_map(|r| r.0).collect();
    let out = RgbImage::from_raw(w as u32, h as u32, data)
        .ok_or_else(|| MeshError::BadMesh("internal: enhanced image has the wrong size".into()))?;
    Ok((
        out,
        EnhanceSummary {
            texels_replaced: replaced,
            mean_samples: if replaced > 0 {
                samples as f64 / replaced as f64
            } else {
                0.0
            },
        },
    ))
}
