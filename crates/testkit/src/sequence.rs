//! The options of a synthetic hand-held sequence (size, frames, path, intrinsics with radial
//! distortion and aspect ratio, anti-aliasing, noise) and their validation.

use handheld_core::Intrinsics;
use nalgebra::Vector2;

use crate::path::PathOptions;
use crate::shutter::Shutter;
use crate::util::hash_words;

/// Options of [`crate::render::render_sequence`].
#[derive(Clone, Debug, PartialEq)]
pub struct SequenceOptions {
    /// Seeds the scene, the path jitter (mixed with `path.seed`) and the image noise.
    pub seed: u64,
    pub width: u32,
    pub height: u32,
    /// Number of frames; overrides `path.num_frames`.
    pub num_frames: usize,
    pub path: PathOptions,
    /// Base focal length in pixels; `None` means `0.9 · width`.
    pub focal_px: Option<f64>,
    pub k1: f64,
    pub k2: f64,
    /// Pixel aspect ratio `f_y / f_x` (eq. 2's r); 1 for square pixels, e.g. 1.09 for the paper's
    /// Medusa camcorder (§3.4).
    pub aspect: f64,
    /// Anti-aliasing: `samples_per_axis²` rays per pixel area on a regular sub-pixel grid, tent-filtered.
    pub samples_per_axis: u32,
    /// Standard deviation of the additive Gaussian image noise, in grey levels.
    pub image_noise_sigma: f64,
    /// Latitude rings per sphere in the ground-truth mesh.
    pub mesh_resolution: usize,
    /// Rolling read-out and exposure time ([`crate::shutter`]); the default is a global shutter.
    pub shutter: Shutter,
}

impl Default for SequenceOptions {
    fn default() -> Self {
        Self {
            seed: 0,
            width: 640,
            height: 480,
            num_frames: 20,
            path: PathOptions::default(),
            focal_px: None,
            k1: -0.08,
            k2: 0.01,
            aspect: 1.0,
            samples_per_axis: 3,
            image_noise_sigma: 1.0,
            mesh_resolution: 32,
            shutter: Shutter::default(),
        }
    }
}

impl SequenceOptions {
    /// The base focal length in pixels.
    pub fn focal(&self) -> f64 {
        self.focal_px.unwrap_or(0.9 * self.width as f64)
    }

    /// The intrinsics of a frame with focal factor `factor`: aspect [`Self::aspect`], no skew,
    /// principal point at the image centre.
    pub fn intrinsics(&self, factor: f64) -> Intrinsics {
        Intrinsics {
            f: self.focal() * factor,
            aspect: self.aspect,
            skew: 0.0,
            pp: Vector2::new(
                (self.width as f64 - 1.0) / 2.0,
                (self.height as f64 - 1.0) / 2.0,
            ),
            k1: self.k1,
            k2: self.k2,
        }
    }

    /// The path actually used: `path` with this sequence's frame count and a seed mixed with `seed`.
    pub fn effective_path(&self) -> PathOptions {
        PathOptions {
            num_frames: self.num_frames,
            seed: hash_words(&[self.seed, self.path.seed]),
            ..self.path.clone()
        }
    }

    pub fn validate(&self) -> Result<(), String> {
        if self.width < 8 || self.height < 8 || self.width > 16384 || self.height > 16384 {
            return Err(format!(
                "image size {}x{} out of range",
                self.width, self.height
            ));
        }
        if self.num_frames == 0 {
            return Err("num_frames must be at least 1".into());
        }
        if !(1..=16).contains(&self.samples_per_axis) {
            return Err(format!(
                "samples_per_axis must be in 1..=16, got {}",
                self.samples_per_axis
            ));
        }
        if !(0.5..=2.0).contains(&self.aspect) {
            return Err(format!("aspect must be in [0.5, 2], got {}", self.aspect));
        }
        if !(self.image_noise_sigma >= 0.0 && self.image_noise_sigma.is_finite()) {
            return Err("image_noise_sigma must be finite and non-negative".into());
        }
        self.shutter.validate()?;
        let path = self.effective_path();
        path.validate()?;
        let (a, b) = path.zoom.unwrap_or((1.0, 1.0));
        for factor in [a, b] {
            let k = self.intrinsics(factor);
            k.validate()?;
            // The distortion must be monotonic over the image (plus margin) to be invertible.
            let corner = Vector2::new(k.pp.x + 0.5, k.pp.y + 0.5) / k.f;
            let r_max = 1.5 * corner.norm();
            for i in 0..=100 {
                let r2 = (r_max * i as f64 / 100.0).powi(2);
                if 1.0 + 3.0 * k.k1 * r2 + 5.0 * k.k2 * r2 * r2 <= 0.0 {
                    return Err(format!(
                        "radial distortion (k1 {}, k2 {}) folds over inside the image",
                        k.k1, k.k2
                    ));
                }
            }
        }
        Ok(())
    }
}
