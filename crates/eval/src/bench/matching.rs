//! Feature extraction and pair matching on a folder of images, with accuracy against ground-truth
//! cameras and, optionally, COLMAP's `feature_extractor` + `exhaustive_matcher` on the same images
//! in the same run (CPU, same thread count), reporting the speed ratios of issue #3.

use std::path::PathBuf;
use std::time::Instant;

use handheld_core::Progress;
use handheld_features::extract::{extract_features, ExtractionOptions};
use handheld_features::matching::{exhaustive_pairs, sequential_pairs};
use handheld_features::verify::{verify_pairs, PairVerificationOptions, VerifiedPair};
use handheld_features::Features;
use handheld_geometry::{epipolar_residuals, fundamental_from_cameras};
use handheld_io::images::{list_image_folder, load_image, ImageIngestOptions};
use handheld_robust::verify::TwoViewConfiguration;
use nalgebra::{Matrix3, Vector2, Vector3};
use serde::{Deserialize, Serialize};

use super::colmap::{run_colmap, ColmapReport};
use crate::error::{EvalError, Result};
use handheld_pipeline::Context;

/// Options of the matching benchmark.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct MatchingBenchOptions {
    /// Folder of images.
    pub images: PathBuf,
    /// Data set folder with ground-truth cameras in `gt/` (Strecha `.camera` or Middlebury
    /// `*_par.txt`). Default none.
    pub gt_cameras: Option<PathBuf>,
    /// Match every pair (as COLMAP's exhaustive_matcher) instead of only adjacent ones.
    pub exhaustive: bool,
    /// Also run COLMAP (feature_extractor + exhaustive_matcher, CPU) on the same images.
    pub colmap: bool,
    /// Threads for Handheld and COLMAP (default: all cores).
    pub threads: Option<usize>,
    /// Downscale images whose longer side exceeds this (pixels).
    pub max_image_size: Option<u32>,
    /// SIFT contrast threshold (OpenCV convention; default: the library default).
    pub contrast_threshold: Option<f32>,
    /// SIFT: at most this many features per image. Default 13 312, COLMAP's budget here (its
    /// extractor gives 10.5–13.2 k per fountain-P11 image).
    pub max_features: usize,
    /// SIFT: upsample the image first (octave −1), as COLMAP does by default.
    pub upsample: bool,
    /// Brute force only over this many strongest keypoints per image, then guided matching over
    /// all (0: brute force over all; default: the library default).
    pub seed_features: Option<usize>,
}

impl Default for MatchingBenchOptions {
    fn default() -> Self {
        Self {
            images: PathBuf::new(),
            gt_cameras: None,
            exhaustive: false,
            colmap: false,
            threads: None,
            max_image_size: None,
            contrast_threshold: None,
            max_features: 13312,
            upsample: false,
            seed_features: None,
        }
    }
}

impl MatchingBenchOptions {
    /// The extraction options these ask for.
    pub fn extraction(&self) -> ExtractionOptions {
        let mut opts = ExtractionOptions {
            max_image_size: self.max_image_size,
            ..Default::default()
        };
        if let Some(c) = self.contrast_threshold {
            opts.sift.contrast_threshold = c;
        }
        opts.sift.max_features = Some(self.max_features);
        opts.sift.upsample_first_octave = self.upsample;
        opts
    }

    /// The pair verification options these ask for.
    pub fn verification(&self) -> PairVerificationOptions {
        let mut v = PairVerificationOptions::default();
        if let Some(k) = self.seed_features {
            v.seed_features = (k > 0).then_some(k);
        }
        v
    }

    /// Checks the options through the libraries' own checks.
    pub fn validate(&self) -> Result<()> {
        self.extraction()
            .validate()
            .map_err(|e| EvalError::option("feature extraction", e.to_string()))?;
        self.verification()
            .validate()
            .map_err(|e| EvalError::option("pair verification", e.to_string()))
    }
}

/// Accuracy of the adjacent pairs against ground-truth cameras.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct GtMatchingAccuracy {
    /// Fraction of inliers within 1 px of the ground-truth epipolar lines in both images.
    pub gt_inliers_within_1px_fraction: f64,
    /// The estimated F's epipolar error on ground-truth-consistent correspondences: median over
    /// all pairs, and per pair.
    pub gt_epipolar_error_median_px: Option<f64>,
    pub gt_epipolar_error_median_px_per_pair: Vec<f64>,
}

/// COLMAP on the same images, and its speed relative to ours (> 1: we are faster).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ColmapComparison {
    pub colmap_extraction_speed_ratio: f64,
    pub colmap_matching_speed_ratio_per_pair: f64,
    pub colmap: ColmapReport,
}

/// What the matching benchmark measured.
#[derive(Debug, Clone, Serialize)]
pub struct MatchingBenchReport {
    pub images: usize,
    pub threads: usize,
    /// Extraction: per-image latency (one at a time, all threads inside SIFT) and the total.
    pub extraction_seconds_per_image_median: Option<f64>,
    pub extraction_seconds_total: f64,
    pub features_per_image: Vec<usize>,
    pub pairs: usize,
    pub matching_seconds_total: f64,
    pub matching_seconds_per_pair: f64,
    pub seed_features: Option<usize>,
    /// Pairs with at least 15 inliers.
    pub verified_pairs: usize,
    /// Pairs matched from seed features (fewer putative matches than inliers).
    pub seeded_pairs: usize,
    pub adjacent_guided_added: Vec<usize>,
    pub adjacent_inliers: Vec<usize>,
    pub adjacent_inliers_median: Option<f64>,
    pub adjacent_configurations: Vec<TwoViewConfiguration>,
    /// With ground-truth cameras.
    #[serde(flatten)]
    pub gt: Option<GtMatchingAccuracy>,
    /// With COLMAP.
    #[serde(flatten)]
    pub colmap: Option<ColmapComparison>,
}

fn median(v: &mut [f64]) -> Option<f64> {
    v.sort_by(|a, b| a.total_cmp(b));
    v.get(v.len() / 2).copied()
}

/// GT accuracy of one verified pair: inliers within 1 px of the GT epipolar lines, and the
/// estimated F's epipolar error on GT-consistent correspondences (each x2 moved onto its GT line).
fn gt_pair_stats(f_gt: &Matrix3<f64>, v: &VerifiedPair, feats: &[Features]) -> (usize, Vec<f64>) {
    let (f1, f2) = (&feats[v.i], &feats[v.j]);
    let mut within = 0;
    let mut errs = Vec::new();
    for &(a, b) in &v.inliers {
        let (Some(k1), Some(k2)) = (f1.keypoints.get(a as usize), f2.keypoints.get(b as usize))
        else {
            continue;
        };
        let (x1, x2) = (
            Vector2::new(k1.x as f64, k1.y as f64),
            Vector2::new(k2.x as f64, k2.y as f64),
        );
        let [d2, d1] = epipolar_residuals(f_gt, &x1, &x2);
        if d2.abs() <= 1.0 && d1.abs() <= 1.0 {
            within += 1;
        }
        if let Some(f_est) = v.geometry.f {
            let l = f_gt * Vector3::new(x1.x, x1.y, 1.0);
            let n2 = l.x * l.x + l.y * l.y;
            let s = (l.x * x2.x + l.y * x2.y + l.z) / n2;
            let x2_gt = Vector2::new(x2.x - s * l.x, x2.y - s * l.y);
            errs.push(epipolar_residuals(&f_est, &x1, &x2_gt)[0].abs());
        }
    }
    (within, errs)
}

/// Scores the adjacent pairs against the ground-truth cameras of data set `ds`.
fn gt_accuracy(
    ds: &std::path::Path,
    names: &[String],
    adjacent: &[&VerifiedPair],
    feats: &[Features],
) -> Result<GtMatchingAccuracy> {
    let gt = handheld_io::gt::read_gt_cameras(ds)?;
    let stem = |n: &str| n.split('.').next().unwrap_or_default().to_string();
    let (mut within, mut total, mut errs, mut per_pair) = (0usize, 0usize, Vec::new(), Vec::new());
    for v in adjacent {
        let (Some(ni), Some(nj)) = (names.get(v.i), names.get(v.j)) else {
            continue;
        };
        let (Some(ci), Some(cj)) = (gt.get(&stem(ni)), gt.get(&stem(nj))) else {
            continue;
        };
        let f_gt = fundamental_from_cameras(
            &handheld_core::ProjectiveCamera { P: ci.projection() },
            &handheld_core::ProjectiveCamera { P: cj.projection() },
        )
        .context("the ground-truth fundamental matrix")?;
        let (w, mut e) = gt_pair_stats(&f_gt, v, feats);
        within += w;
        total += v.inliers.len();
        per_pair.push(median(&mut e.clone()).unwrap_or(f64::NAN));
        errs.append(&mut e);
    }
    Ok(GtMatchingAccuracy {
        gt_inliers_within_1px_fraction: within as f64 / total.max(1) as f64,
        gt_epipolar_error_median_px: median(&mut errs),
        gt_epipolar_error_median_px_per_pair: per_pair,
    })
}

/// Extracts and matches the images, scores them and optionally runs COLMAP on them.
pub fn bench_matching(
    o: &MatchingBenchOptions,
    progress: &dyn Progress,
) -> Result<MatchingBenchReport> {
    o.validate()?;
    let threads = o.threads.unwrap_or_else(rayon::current_num_threads);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .context("starting the thread pool")?;
    let listing = list_image_folder(&o.images, &ImageIngestOptions::default())?;
    let names: Vec<String> = listing
        .images
        .iter()
        .map(|p| {
            p.file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default()
        })
        .collect();
    let opts = o.extraction();
    let images: Vec<_> = listing
        .images
        .iter()
        .map(|p| load_image(p, &ImageIngestOptions::default()).map(|l| l.image))
        .collect::<std::result::Result<_, _>>()?;
    // Extraction: per-image latency (one at a time, all threads inside SIFT) and throughput.
    progress.start("extracting", images.len() as u64);
    let t0 = Instant::now();
    let timed: Vec<(Features, f64)> = pool.install(|| {
        images
            .iter()
            .map(|img| {
                let t = Instant::now();
                let f = extract_features(img, &opts);
                progress.inc(1);
                (f, t.elapsed().as_secs_f64())
            })
            .collect()
    });
    let extract_total = t0.elapsed().as_secs_f64();
    progress.finish();
    let mut per_image: Vec<f64> = timed.iter().map(|t| t.1).collect();
    let feats: Vec<Features> = timed.into_iter().map(|t| t.0).collect();
    let pairs = if o.exhaustive {
        exhaustive_pairs(feats.len())
    } else {
        sequential_pairs(feats.len(), 1)
    };
    let t1 = Instant::now();
    let vopts = o.verification();
    let verified = pool.install(|| verify_pairs(&feats, &pairs, &vopts, progress));
    let match_total = t1.elapsed().as_secs_f64();
    let adjacent: Vec<&VerifiedPair> = verified.iter().filter(|v| v.j == v.i + 1).collect();
    let mut inl: Vec<f64> = adjacent.iter().map(|v| v.inliers.len() as f64).collect();
    let gt = match &o.gt_cameras {
        Some(ds) => Some(gt_accuracy(ds, &names, &adjacent, &feats)?),
        None => None,
    };
    let colmap = if o.colmap {
        let c = run_colmap(&o.images, threads)?;
        let n = feats.len().max(1) as f64;
        let colmap_pairs = (feats.len() * feats.len().saturating_sub(1) / 2).max(1) as f64;
        let ours_extract = extract_total / n;
        let ours_match = match_total / pairs.len().max(1) as f64;
        Some(ColmapComparison {
            colmap_extraction_speed_ratio: c.extraction_seconds_total / n / ours_extract,
            colmap_matching_speed_ratio_per_pair: c.matching_seconds_total
                / colmap_pairs
                / ours_match,
            colmap: c,
        })
    } else {
        None
    };
    Ok(MatchingBenchReport {
        images: feats.len(),
        threads,
        extraction_seconds_per_image_median: median(&mut per_image),
        extraction_seconds_total: extract_total,
        features_per_image: feats.iter().map(|f| f.keypoints.len()).collect(),
        pairs: pairs.len(),
        matching_seconds_total: match_total,
        matching_seconds_per_pair: match_total / pairs.len().max(1) as f64,
        seed_features: vopts.seed_features,
        verified_pairs: verified.iter().filter(|v| v.inliers.len() >= 15).count(),
        seeded_pairs: verified
            .iter()
            .filter(|v| v.putative.len() < v.inliers.len())
            .count(),
        adjacent_guided_added: adjacent.iter().map(|v| v.guided_added).collect(),
        adjacent_inliers: adjacent.iter().map(|v| v.inliers.len()).collect(),
        adjacent_inliers_median: median(&mut inl),
        adjacent_configurations: adjacent.iter().map(|v| v.geometry.configuration).collect(),
        gt,
        colmap,
    })
}
