//! The shared read-only data of one reconstruction: the input, its correspondence graph and
//! options, and the keypoints in the units normalised by `K_N` of eq. 24, in which every linear
//! system of the projective stage (§3.1–3.3) is well conditioned.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use handheld_core::ImageId;
use handheld_robust::RansacOptions;
use nalgebra::{Matrix3, Vector2};

use crate::graph::CorrespondenceGraph;
use crate::input::SfmInput;
use crate::options::SfmOptions;

/// Shared read-only data of a reconstruction.
pub(crate) struct Context<'a> {
    pub input: &'a SfmInput,
    pub graph: &'a CorrespondenceGraph,
    pub opts: &'a SfmOptions,
    /// Keypoints normalised by `K_N⁻¹` (eq. 24).
    pub kps: Vec<Vec<Vector2<f64>>>,
    /// `K_N` per image.
    pub kn: Vec<Matrix3<f64>>,
    /// Pixels → normalised units (`1 / (w + h)`).
    pub scale: Vec<f64>,
    /// Localisation σ (pixels) of every keypoint, per image id, for metric BA; empty when the
    /// observations are not weighted (see [`keypoint_sigmas`]).
    pub keypoint_sigma: BTreeMap<ImageId, Arc<[f64]>>,
    /// The view each view is an identical copy of (`duplicates.rs`), else the view itself: a new
    /// point needs two views of different twins (the same keypoints twice fix no depth).
    pub twin: Vec<usize>,
    /// The duplicate shots found in the input.
    pub duplicates: Vec<crate::duplicates::Duplicate>,
    /// Images with keypoints and at least one verified pair: the ones a projective model can hold
    /// (a video's in-between frames have none; they are registered from their tracks).
    pub linked: Vec<bool>,
    /// Set when the model being built was found not to determine its principal point
    /// (`frame::principal_point_test`): every later adjustment holds it at the image centre.
    principal_point_held: AtomicBool,
}

/// σ = √(s / median s), clamped to [0.5, 4], of every keypoint with a detection scale `s`
/// (`SfmOptions::scale_weighted_observations`). The median is over all keypoints of all images,
/// so the median keypoint keeps σ = 1 px and thresholds stay in pixels.
fn keypoint_sigmas(input: &SfmInput, opts: &SfmOptions) -> BTreeMap<ImageId, Arc<[f64]>> {
    if !opts.scale_weighted_observations {
        return BTreeMap::new();
    }
    let mut all: Vec<f32> = input
        .images
        .iter()
        .flat_map(|im| im.keypoint_scales.iter().copied())
        .collect();
    if all.is_empty() {
        return BTreeMap::new();
    }
    let mid = all.len() / 2;
    let median = f64::from(*all.select_nth_unstable_by(mid, f32::total_cmp).1);
    input
        .images
        .iter()
        .filter(|im| !im.keypoint_scales.is_empty())
        .map(|im| {
            let s: Arc<[f64]> = im
                .keypoint_scales
                .iter()
                .map(|&s| (f64::from(s) / median).sqrt().clamp(0.5, 4.0))
                .collect();
            (im.id, s)
        })
        .collect()
}

impl<'a> Context<'a> {
    pub fn new(input: &'a SfmInput, graph: &'a CorrespondenceGraph, opts: &'a SfmOptions) -> Self {
        let kn: Vec<Matrix3<f64>> = input
            .images
            .iter()
            .map(|im| crate::upgrade::selfcal::normalization_matrix(im.width, im.height))
            .collect();
        let kps = input
            .images
            .iter()
            .zip(&kn)
            .map(|(im, k)| {
                let s = k[(0, 0)];
                let (cx, cy) = (k[(0, 2)], k[(1, 2)]);
                im.keypoints
                    .iter()
                    .map(|p| Vector2::new((p.x - cx) / s, (p.y - cy) / s))
                    .collect()
            })
            .collect();
        let scale = kn.iter().map(|k| 1.0 / k[(0, 0)]).collect();
        let linked: Vec<bool> = input
            .images
            .iter()
            .enumerate()
            .map(|(i, im)| !im.keypoints.is_empty() && !graph.neighbours(i).is_empty())
            .collect();
        let duplicates = crate::duplicates::find_duplicates(input, &linked);
        let mut twin: Vec<usize> = (0..input.images.len()).collect();
        for d in &duplicates {
            let names = &input.images;
            if d.identical() {
                twin[d.image] = d.of;
                tracing::info!(
                    "{} and {} are the same photo (the same keypoints): no point is made from the two alone",
                    names[d.image].name,
                    names[d.of].name
                );
            } else {
                tracing::info!(
                    "{} nearly repeats {} (their matches moved {:.1} px, and one homography explains them)",
                    names[d.image].name,
                    names[d.of].name,
                    d.shift_px
                );
            }
        }
        Self {
            twin,
            duplicates,
            linked,
            input,
            graph,
            opts,
            kps,
            kn,
            scale,
            keypoint_sigma: keypoint_sigmas(input, opts),
            principal_point_held: AtomicBool::new(false),
        }
    }

    /// Whether metric adjustments refine the principal point: the options ask for it and the
    /// model being built has not been found to leave it undetermined.
    pub fn refines_principal_point(&self) -> bool {
        self.opts.refine_principal_point && !self.principal_point_held.load(Ordering::Relaxed)
    }

    /// Holds (or frees again) the principal point of the model being built.
    pub fn hold_principal_point(&self, held: bool) {
        self.principal_point_held.store(held, Ordering::Relaxed);
    }

    /// RANSAC options of a resection (projective or calibrated) of `image`: T(1,1), a seed per
    /// image derived from the options' seed (same seed, same model), at most 5000 trials.
    pub fn resection_ransac(&self, image: usize, max_error: f64) -> RansacOptions {
        RansacOptions {
            max_error,
            tdd: Some(1),
            seed: self.opts.seed ^ (image as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15),
            min_inlier_ratio: 0.02,
            max_iterations: 5000,
            ..Default::default()
        }
    }

    /// The projective inlier threshold of an image in normalised units.
    pub fn threshold(&self, image: usize) -> f64 {
        self.opts.projective_max_error_px * self.scale[image]
    }

    pub(crate) fn median_scale(&self) -> f64 {
        let mut s = self.scale.clone();
        s.sort_by(f64::total_cmp);
        s[s.len() / 2]
    }
}
