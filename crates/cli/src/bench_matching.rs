//! `handheld bench matching`: feature extraction and pair matching on a folder of images, with
//! accuracy against ground-truth cameras and, with `--colmap`, COLMAP's `feature_extractor` +
//! `exhaustive_matcher` on the same images in the same run (CPU, same thread count), reporting the
//! speed ratios of issue #3.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::Args;
use handheld_features::extract::{extract_features, ExtractionOptions};
use handheld_features::matching::{exhaustive_pairs, sequential_pairs};
use handheld_features::verify::{verify_pairs, PairVerificationOptions, VerifiedPair};
use handheld_features::Features;
use handheld_geometry::{epipolar_residuals, fundamental_from_cameras};
use handheld_io::images::{list_image_folder, load_image, ImageIngestOptions};
use nalgebra::{Matrix3, Vector2, Vector3};
use serde_json::json;

use crate::args::GlobalArgs;
use crate::ui::{print_result, Bars};

#[derive(Debug, Args)]
pub struct BenchMatchingArgs {
    /// Folder of images.
    #[arg(long)]
    pub images: PathBuf,
    /// Data set folder with ground-truth cameras in `gt/` (Strecha `.camera` or Middlebury `*_par.txt`).
    #[arg(long)]
    pub gt_cameras: Option<PathBuf>,
    /// Match every pair (as COLMAP's exhaustive_matcher) instead of only adjacent ones.
    #[arg(long)]
    pub exhaustive: bool,
    /// Also run COLMAP (feature_extractor + exhaustive_matcher, CPU) on the same images.
    #[arg(long)]
    pub colmap: bool,
    /// Threads for Handheld and COLMAP (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Downscale images whose longer side exceeds this (pixels).
    #[arg(long)]
    pub max_image_size: Option<u32>,
    /// SIFT contrast threshold (OpenCV convention; default: the library default).
    #[arg(long)]
    pub contrast_threshold: Option<f32>,
    /// SIFT: keep at most this many features per image. Default 13 312, COLMAP's budget here (its
    /// extractor gives 10.5–13.2 k per fountain-P11 image); `reconstruct` keeps 8192.
    #[arg(long, default_value_t = 13312)]
    pub max_features: usize,
    /// SIFT: upsample the image first (octave −1), as COLMAP does by default.
    #[arg(long)]
    pub upsample: bool,
    /// Brute force only over this many strongest keypoints per image, then guided matching over
    /// all (0: brute force over all; default: the library default).
    #[arg(long)]
    pub seed_features: Option<usize>,
}

fn median(v: &mut [f64]) -> Option<f64> {
    v.sort_by(|a, b| a.total_cmp(b));
    v.get(v.len() / 2).copied()
}

/// GT accuracy of one verified pair: fraction of inliers within 1 px of the GT epipolar lines, and the
/// estimated F's epipolar error on GT-consistent correspondences (each x2 moved onto its GT line).
fn gt_pair_stats(f_gt: &Matrix3<f64>, v: &VerifiedPair, feats: &[Features]) -> (usize, Vec<f64>) {
    let (f1, f2) = (&feats[v.i], &feats[v.j]);
    let mut within = 0;
    let mut errs = Vec::new();
    for &(a, b) in &v.inliers {
        let k1 = f1.keypoints[a as usize];
        let k2 = f2.keypoints[b as usize];
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

fn run_colmap(images: &Path, threads: usize) -> Result<serde_json::Value> {
    let dir = tempfile_dir()?;
    let db = dir.join("database.db");
    let t0 = Instant::now();
    let st = Command::new("colmap")
        .args(["feature_extractor", "--database_path"])
        .arg(&db)
        .arg("--image_path")
        .arg(images)
        .args([
            "--ImageReader.single_camera",
            "1",
            "--SiftExtraction.use_gpu",
            "0",
            "--SiftExtraction.num_threads",
            &threads.to_string(),
        ])
        .output()
        .context("cannot run `colmap` (install it with `apt-get install colmap`)")?;
    if !st.status.success() {
        anyhow::bail!(
            "colmap feature_extractor failed: {}",
            String::from_utf8_lossy(&st.stderr)
                .lines()
                .last()
                .unwrap_or("")
        );
    }
    let extract_s = t0.elapsed().as_secs_f64();
    let t1 = Instant::now();
    let st = Command::new("colmap")
        .args(["exhaustive_matcher", "--database_path"])
        .arg(&db)
        .args([
            "--SiftMatching.use_gpu",
            "0",
            "--SiftMatching.num_threads",
            &threads.to_string(),
        ])
        .output()
        .context("cannot run `colmap exhaustive_matcher`")?;
    if !st.status.success() {
        anyhow::bail!(
            "colmap exhaustive_matcher failed: {}",
            String::from_utf8_lossy(&st.stderr)
                .lines()
                .last()
                .unwrap_or("")
        );
    }
    let match_s = t1.elapsed().as_secs_f64();
    let database = handheld_io::database::Database::open(&db)?;
    let imgs = database.images()?;
    let mut adjacent = Vec::new();
    let mut features = Vec::new();
    for w in imgs.windows(2) {
        let g = database.read_two_view_geometry(w[0].0, w[1].0)?;
        adjacent.push(g.map(|g| g.inliers.len()).unwrap_or(0));
    }
    for (id, _, _) in &imgs {
        features.push(database.read_keypoints(*id)?.len());
    }
    let _ = std::fs::remove_dir_all(&dir);
    Ok(
        json!({ "extraction_seconds_total": extract_s, "matching_seconds_total": match_s, "adjacent_inliers": adjacent, "features_per_image": features }),
    )
}

fn tempfile_dir() -> Result<PathBuf> {
    let dir = std::env::temp_dir().join(format!("handheld-bench-colmap-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir)?;
    Ok(dir)
}

pub fn run(a: &BenchMatchingArgs, g: &GlobalArgs, bars: &Bars) -> Result<()> {
    let threads = a.threads.unwrap_or_else(rayon::current_num_threads);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()?;
    let listing = list_image_folder(&a.images, &ImageIngestOptions::default())?;
    let names: Vec<String> = listing
        .images
        .iter()
        .map(|p| {
            p.file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default()
        })
        .collect();
    let mut opts = ExtractionOptions {
        max_image_size: a.max_image_size,
        ..Default::default()
    };
    if let Some(c) = a.contrast_threshold {
        opts.sift.contrast_threshold = c;
    }
    opts.sift.max_features = Some(a.max_features);
    opts.sift.upsample_first_octave = a.upsample;
    opts.validate().map_err(anyhow::Error::msg)?;
    let images: Vec<_> = listing
        .images
        .iter()
        .map(|p| load_image(p, &ImageIngestOptions::default()).map(|l| l.image))
        .collect::<std::result::Result<_, _>>()?;
    // Extraction: per-image latency (one at a time, all threads inside SIFT) and throughput.
    use handheld_core::Progress;
    bars.start("extracting", images.len() as u64);
    let t0 = Instant::now();
    let timed: Vec<(Features, f64)> = pool.install(|| {
        images
            .iter()
            .map(|img| {
                let t = Instant::now();
                let f = extract_features(img, &opts);
                bars.inc(1);
                (f, t.elapsed().as_secs_f64())
            })
            .collect()
    });
    let extract_total = t0.elapsed().as_secs_f64();
    bars.finish();
    let mut per_image: Vec<f64> = timed.iter().map(|t| t.1).collect();
    let feats: Vec<Features> = timed.into_iter().map(|t| t.0).collect();
    let pairs = if a.exhaustive {
        exhaustive_pairs(feats.len())
    } else {
        sequential_pairs(feats.len(), 1)
    };
    let t1 = Instant::now();
    let mut vopts = PairVerificationOptions::default();
    if let Some(k) = a.seed_features {
        vopts.seed_features = (k > 0).then_some(k);
    }
    vopts.validate().map_err(anyhow::Error::msg)?;
    let verified = pool.install(|| verify_pairs(&feats, &pairs, &vopts, bars));
    let match_total = t1.elapsed().as_secs_f64();
    let adjacent: Vec<&VerifiedPair> = verified.iter().filter(|v| v.j == v.i + 1).collect();
    let mut inl: Vec<f64> = adjacent.iter().map(|v| v.inliers.len() as f64).collect();
    let mut result = json!({
        "images": feats.len(),
        "threads": threads,
        "extraction_seconds_per_image_median": median(&mut per_image),
        "extraction_seconds_total": extract_total,
        "features_per_image": feats.iter().map(|f| f.keypoints.len()).collect::<Vec<_>>(),
        "pairs": pairs.len(),
        "matching_seconds_total": match_total,
        "matching_seconds_per_pair": match_total / pairs.len().max(1) as f64,
        "seed_features": vopts.seed_features,
        "verified_pairs": verified.iter().filter(|v| v.inliers.len() >= 15).count(),
        "seeded_pairs": verified.iter().filter(|v| v.putative.len() < v.inliers.len()).count(),
        "adjacent_guided_added": adjacent.iter().map(|v| v.guided_added).collect::<Vec<_>>(),
        "adjacent_inliers": adjacent.iter().map(|v| v.inliers.len()).collect::<Vec<_>>(),
        "adjacent_inliers_median": median(&mut inl),
        "adjacent_configurations": adjacent.iter().map(|v| v.geometry.configuration).collect::<Vec<_>>(),
    });
    if let Some(ds) = &a.gt_cameras {
        let gt = handheld_io::gt::read_gt_cameras(ds)?;
        let stem = |n: &str| n.split('.').next().unwrap_or_default().to_string();
        let (mut within, mut total, mut errs, mut per_pair_median) =
            (0usize, 0usize, Vec::new(), Vec::new());
        for v in &adjacent {
            let (Some(ci), Some(cj)) = (gt.get(&stem(&names[v.i])), gt.get(&stem(&names[v.j])))
            else {
                continue;
            };
            let f_gt = fundamental_from_cameras(
                &handheld_core::ProjectiveCamera { P: ci.projection() },
                &handheld_core::ProjectiveCamera { P: cj.projection() },
            )?;
            let (w, mut e) = gt_pair_stats(&f_gt, v, &feats);
            within += w;
            total += v.inliers.len();
            per_pair_median.push(median(&mut e.clone()).unwrap_or(f64::NAN));
            errs.append(&mut e);
        }
        result["gt_inliers_within_1px_fraction"] = json!(within as f64 / total.max(1) as f64);
        result["gt_epipolar_error_median_px"] = json!(median(&mut errs));
        result["gt_epipolar_error_median_px_per_pair"] = json!(per_pair_median);
    }
    if a.colmap {
        let c = run_colmap(&a.images, threads)?;
        let n = feats.len().max(1) as f64;
        let colmap_pairs = (feats.len() * feats.len().saturating_sub(1) / 2).max(1) as f64;
        let ours_extract = extract_total / n;
        let ours_match = match_total / pairs.len().max(1) as f64;
        result["colmap_extraction_speed_ratio"] =
            json!(c["extraction_seconds_total"].as_f64().unwrap_or(0.0) / n / ours_extract);
        result["colmap_matching_speed_ratio_per_pair"] =
            json!(c["matching_seconds_total"].as_f64().unwrap_or(0.0) / colmap_pairs / ours_match);
        result["colmap"] = c;
    }
    let human = serde_json::to_string_pretty(&result)?;
    print_result(g, &result, &human);
    Ok(())
}
