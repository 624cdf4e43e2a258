//! SIFT extraction and matching timing on full-size fountain-P11 images (issue #3).
//!
//! `cargo run --release -p handheld-features --example sift_bench -- [DATASETS] [NUM_IMAGES] [--upsample]`
//! prints one JSON object: per-image extraction seconds and feature counts, then the matching time,
//! match count and the fraction of matches within 2 px of the ground-truth epipolar line for the
//! pair (0000, 0001). `DATASETS` defaults to `../shared/datasets`.

use std::path::{Path, PathBuf};
use std::time::Instant;

use handheld_features::matching::{match_descriptors, MatchOptions};
use handheld_features::sift::{Sift, SiftOptions};
use handheld_features::{FeatureDetector, GrayImage};
use nalgebra::{Matrix3, Vector3};

fn camera(path: &Path) -> Option<(Matrix3<f64>, Matrix3<f64>, Vector3<f64>)> {
    let text = std::fs::read_to_string(path).ok()?;
    let v: Vec<f64> = text
        .split_whitespace()
        .map(|t| t.parse().ok())
        .collect::<Option<_>>()?;
    if v.len() < 24 {
        return None;
    }
    Some((
        Matrix3::from_row_slice(&v[0..9]),
        Matrix3::from_row_slice(&v[12..21]),
        Vector3::new(v[21], v[22], v[23]),
    ))
}

/// `x₂ᵀ F x₁ = 0` for Strecha cameras `P = K [Rᵀ | −Rᵀ C]`.
fn fundamental(c1: &Path, c2: &Path) -> Option<Matrix3<f64>> {
    let ((k1, r1, cc1), (k2, r2, cc2)) = (camera(c1)?, camera(c2)?);
    let e = (r2.transpose() * (cc1 - cc2)).cross_matrix() * (r2.transpose() * r1);
    Some(k2.try_inverse()?.transpose() * e * k1.try_inverse()?)
}

/// CPU seconds used by this process so far (user + system, all threads) from `/proc/self/stat`
/// (Linux; `None` elsewhere): wall time on a machine shared with other jobs overstates the cost.
fn cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    let fields: Vec<&str> = stat.rsplit_once(')')?.1.split_whitespace().collect();
    let ticks = fields.get(11)?.parse::<f64>().ok()? + fields.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

fn elapsed_cpu(start: Option<f64>) -> f64 {
    start.zip(cpu_seconds()).map_or(f64::NAN, |(a, b)| b - a)
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let upsample = args.iter().any(|a| a == "--upsample");
    let pos: Vec<&String> = args.iter().filter(|a| !a.starts_with("--")).collect();
    let root = pos
        .first()
        .map_or_else(|| PathBuf::from("../shared/datasets"), PathBuf::from);
    let count: usize = pos.get(1).and_then(|s| s.parse().ok()).unwrap_or(2).max(2);
    let dir = root.join("fountain-P11");
    if !dir.is_dir() {
        eprintln!("skipping: {} not found", dir.display());
        return;
    }
    let sift = Sift::new(SiftOptions {
        upsample_first_octave: upsample,
        ..Default::default()
    });
    let threads = rayon::current_num_threads();
    let mut feats = Vec::new();
    let (mut wall, mut cpu, mut counts, mut size) =
        (Vec::new(), Vec::new(), Vec::new(), String::new());
    for i in 0..count {
        let path = dir.join("images").join(format!("{i:04}.jpg"));
        let img = match image::open(&path) {
            Ok(img) => GrayImage::from_dynamic(&img),
            Err(e) => {
                eprintln!("cannot read {}: {e}", path.display());
                return;
            }
        };
        size = format!("[{}, {}]", img.width, img.height);
        let (t, c) = (Instant::now(), cpu_seconds());
        let f = sift.detect(&img);
        wall.push(t.elapsed().as_secs_f64());
        cpu.push(elapsed_cpu(c));
        counts.push(f.keypoints.len());
        feats.push(f);
    }
    let (t, c) = (Instant::now(), cpu_seconds());
    let matches = match_descriptors(
        &feats[0].descriptors,
        &feats[1].descriptors,
        &MatchOptions::default(),
    );
    let (match_wall, match_cpu) = (t.elapsed().as_secs_f64(), elapsed_cpu(c));
    let epi = fundamental(
        &dir.join("gt/0000.jpg.camera"),
        &dir.join("gt/0001.jpg.camera"),
    )
    .map(|f| {
        let good = matches
            .iter()
            .filter(|m| {
                let (p, q) = (
                    feats[0].keypoints[m.i as usize],
                    feats[1].keypoints[m.j as usize],
                );
                let l = f * Vector3::new(p.x as f64, p.y as f64, 1.0);
                Vector3::new(q.x as f64, q.y as f64, 1.0).dot(&l).abs() / l.xy().norm() < 2.0
            })
            .count();
        good as f64 / matches.len().max(1) as f64
    });
    let list = |v: &[f64], digits: usize| {
        format!(
            "[{}]",
            v.iter()
                .map(|s| format!("{s:.digits$}"))
                .collect::<Vec<_>>()
                .join(", ")
        )
    };
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let counts: Vec<String> = counts.iter().map(|c| c.to_string()).collect();
    println!(
        "{{\"threads\": {threads}, \"upsample_first_octave\": {upsample}, \"image_size\": {size}, \
         \"extract_seconds\": {}, \"mean_extract_seconds\": {:.3}, \"extract_cpu_seconds\": {}, \
         \"mean_extract_cpu_seconds\": {:.2}, \"features\": [{}], \"match_seconds\": {match_wall:.3}, \
         \"match_cpu_seconds\": {match_cpu:.2}, \"matches\": {}, \"epipolar_2px_fraction\": {}}}",
        list(&wall, 3),
        mean(&wall),
        list(&cpu, 2),
        mean(&cpu),
        counts.join(", "),
        matches.len(),
        epi.map_or_else(|| "null".to_string(), |e| format!("{e:.4}")),
    );
}
