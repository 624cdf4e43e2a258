//! Feature extraction for one decoded image: optional downscaling to a maximum size (keypoints are
//! mapped back to full-resolution pixels), then the detector.

use image::DynamicImage;
use serde::{Deserialize, Serialize};

use crate::detector::{FeatureDetector, Features};
use crate::error::{check, FeatureError};
use crate::gray::GrayImage;
use crate::sift::{Sift, SiftOptions};

/// Options of [`extract_features`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ExtractionOptions {
    pub sift: SiftOptions,
    /// Downscale images whose longer side exceeds this many pixels before detection (default
    /// `None`: full resolution).
    pub max_image_size: Option<u32>,
    /// Detect from a 2× upsampled first octave (Lowe's "−1 octave", COLMAP's default) when the
    /// image's longer side is at most this many pixels (default 1280). Small images (640×480
    /// turntable or video frames) otherwise give too few features for tracks of 3+ views: on
    /// templeSparseRing the median went from 437 to ~1.7 k per image. `None` never upsamples.
    #[serde(default)]
    pub upsample_below: Option<u32>,
    /// Adaptive contrast threshold: while an image gives fewer than this many features, detect
    /// again with a third of the threshold, down to [`MIN_CONTRAST_THRESHOLD`] (default 2000).
    /// Weakly textured scenes (plastered walls, a plaster dinosaur) otherwise give a few dozen
    /// features: on iclnuim-5 the median verified inliers between consecutive frames went from 0
    /// at 0.02 to 280 at 0.005 and 950 at 0.002. `None` keeps the threshold fixed.
    #[serde(default)]
    pub min_features: Option<usize>,
}

/// The lowest contrast threshold the adaptive detection goes down to (see
/// [`ExtractionOptions::min_features`]); below it, mostly noise and compression artefacts respond.
pub const MIN_CONTRAST_THRESHOLD: f32 = 0.002;

impl Default for ExtractionOptions {
    /// RootSIFT with COLMAP's contrast threshold (its `peak_threshold` 0.02/3 is 0.02 in the
    /// OpenCV convention used here), at most 8192 features, full resolution. `handheld bench
    /// matching` raises the budget to 13 312 to compare with COLMAP, which extracts 10.5–13.2 k
    /// per fountain-P11 image (see README).
    fn default() -> Self {
        Self {
            sift: SiftOptions {
                contrast_threshold: 0.02,
                ..SiftOptions::default()
            },
            max_image_size: None,
            upsample_below: Some(1280),
            min_features: Some(2000),
        }
    }
}

impl ExtractionOptions {
    /// Checks the SIFT options and the image size limit; the error names the offending option.
    pub fn validate(&self) -> Result<(), FeatureError> {
        self.sift.validate()?;
        check(
            self.max_image_size.is_none_or(|m| m >= 64),
            "max_image_size",
            || "must be at least 64 pixels (--max-image-size)".into(),
        )
    }
}

/// Detects and describes features of an image (any depth, grey or colour), lowering the contrast
/// threshold while too few are found (see [`ExtractionOptions::min_features`]).
pub fn extract_features(image: &DynamicImage, opts: &ExtractionOptions) -> Features {
    let mut sift_opts = opts.sift.clone();
    let mut best = extract_once(image, opts, &sift_opts);
    while let Some(min) = opts.min_features {
        let max = sift_opts.max_features.unwrap_or(usize::MAX);
        if best.keypoints.len() >= min.min(max)
            || sift_opts.contrast_threshold <= MIN_CONTRAST_THRESHOLD
        {
            break;
        }
        sift_opts.contrast_threshold =
            (sift_opts.contrast_threshold / 3.0).max(MIN_CONTRAST_THRESHOLD);
        let f = extract_once(image, opts, &sift_opts);
        if f.keypoints.len() > best.keypoints.len() {
            best = f;
        }
    }
    best
}

fn extract_once(
    image: &DynamicImage,
    opts: &ExtractionOptions,
    sift_opts: &SiftOptions,
) -> Features {
    let (w, h) = (image.width(), image.height());
    let longest = w.max(h);
    let mut sift_opts = sift_opts.clone();
    let detected_longest = opts.max_image_size.map_or(longest, |m| longest.min(m));
    if opts.upsample_below.is_some_and(|u| detected_longest <= u) {
        sift_opts.upsample_first_octave = true;
    }
    let sift = Sift::new(sift_opts);
    match opts.max_image_size {
        Some(m) if longest > m => {
            let s = longest as f32 / m as f32;
            let (nw, nh) = (
                ((w as f32 / s).round() as u32).max(1),
                ((h as f32 / s).round() as u32).max(1),
            );
            let small = image.resize_exact(nw, nh, image::imageops::FilterType::Triangle);
            let mut f = sift.detect(&GrayImage::from_dynamic(&small));
            let (sx, sy) = (w as f32 / nw as f32, h as f32 / nh as f32);
            for k in &mut f.keypoints {
                k.x = (k.x + 0.5) * sx - 0.5;
                k.y = (k.y + 0.5) * sy - 0.5;
                k.scale *= 0.5 * (sx + sy);
            }
            f
        }
        _ => sift.detect(&GrayImage::from_dynamic(image)),
    }
}
