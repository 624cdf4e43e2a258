//! COLMAP's `feature_extractor` + `exhaustive_matcher` (CPU) on a folder of images, timed, as the
//! matching benchmark's reference.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use serde::{Deserialize, Serialize};

use crate::error::{EvalError, Result};

/// What COLMAP did on the same images.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ColmapReport {
    pub extraction_seconds_total: f64,
    pub matching_seconds_total: f64,
    /// Inliers of each pair of consecutive images (0: not verified).
    pub adjacent_inliers: Vec<usize>,
    pub features_per_image: Vec<usize>,
}

/// Runs one COLMAP command; a failure carries the last line COLMAP wrote on stderr.
fn colmap(what: &str, args: &mut Command, hint: &str) -> Result<()> {
    let out = args.output().map_err(|e| {
        EvalError::tool("colmap", format!("cannot run `colmap {what}` ({e}){hint}"))
    })?;
    if !out.status.success() {
        let stderr = String::from_utf8_lossy(&out.stderr);
        let last = stderr.lines().last().unwrap_or("");
        return Err(EvalError::tool("colmap", format!("{what} failed: {last}")));
    }
    Ok(())
}

/// A fresh scratch folder for COLMAP's database, removed when dropped.
struct Scratch(PathBuf);

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Runs COLMAP's extraction and exhaustive matching on `images` with `threads` threads.
pub fn run_colmap(images: &Path, threads: usize) -> Result<ColmapReport> {
    let dir = std::env::temp_dir().join(format!("handheld-bench-colmap-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).map_err(|e| handheld_io::IoError::io(&dir, e))?;
    let scratch = Scratch(dir);
    let db = scratch.0.join("database.db");
    let threads = threads.to_string();
    let t0 = Instant::now();
    colmap(
        "feature_extractor",
        Command::new("colmap")
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
                &threads,
            ]),
        "; install it with `apt-get install colmap`",
    )?;
    let extraction_seconds_total = t0.elapsed().as_secs_f64();
    let t1 = Instant::now();
    colmap(
        "exhaustive_matcher",
        Command::new("colmap")
            .args(["exhaustive_matcher", "--database_path"])
            .arg(&db)
            .args([
                "--SiftMatching.use_gpu",
                "0",
                "--SiftMatching.num_threads",
                &threads,
            ]),
        "",
    )?;
    let matching_seconds_total = t1.elapsed().as_secs_f64();
    let database = handheld_io::database::Database::open(&db)?;
    let imgs = database.images()?;
    let mut adjacent_inliers = Vec::new();
    for w in imgs.windows(2) {
        let g = database.read_two_view_geometry(w[0].0, w[1].0)?;
        adjacent_inliers.push(g.map(|g| g.inliers.len()).unwrap_or(0));
    }
    let mut features_per_image = Vec::new();
    for (id, _, _) in &imgs {
        features_per_image.push(database.read_keypoints(*id)?.len());
    }
    drop(database);
    drop(scratch);
    Ok(ColmapReport {
        extraction_seconds_total,
        matching_seconds_total,
        adjacent_inliers,
        features_per_image,
    })
}
