//! COLMAP 4.2's whole sparse run through pycolmap in a `python3` child process, timed stage by
//! stage, as `bench sparse`'s reference (`pip install pycolmap` gives COLMAP 4.2's CPU code without
//! the `colmap` program that [`super::colmap`] runs). The script lives beside this file
//! (`pycolmap_sparse.py`) and is embedded in the binary.

use std::path::{Path, PathBuf};
use std::process::Command;

use serde::{Deserialize, Serialize};

use crate::error::{EvalError, Result};

/// The script run with `python3 -c SCRIPT IMAGES WORK THREADS`.
pub const PYCOLMAP_SPARSE_SCRIPT: &str = include_str!("pycolmap_sparse.py");

/// The script's exit status when `pycolmap` (4.x) cannot be imported.
const MISSING_PYCOLMAP: i32 = 3;

/// What COLMAP did: each stage's wall time inside the child (the interpreter's start and the
/// import of pycolmap not counted) and the largest model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PycolmapSparseRun {
    /// `pycolmap.__version__`.
    pub version: String,
    /// `extract_features`: one shared SIMPLE_RADIAL camera, CPU.
    pub extraction_seconds: f64,
    /// `match_exhaustive`, with geometric verification, CPU.
    pub matching_seconds: f64,
    /// `incremental_mapping`.
    pub mapping_seconds: f64,
    /// Models the mapper built.
    pub models: usize,
    /// Images registered in the largest model.
    pub registered: usize,
    /// Images in COLMAP's database.
    pub total_images: usize,
    /// 3D points of the largest model.
    pub points: usize,
    /// The largest model's mean reprojection error (none without a model).
    pub mean_reprojection_error_px: Option<f64>,
    /// The largest model as COLMAP text (`cameras.txt`, `images.txt`, …); none without a model.
    pub model: Option<PathBuf>,
}

impl PycolmapSparseRun {
    /// Extraction + matching + mapping.
    pub fn total_seconds(&self) -> f64 {
        self.extraction_seconds + self.matching_seconds + self.mapping_seconds
    }
}

/// Prints pycolmap's version; exits with [`MISSING_PYCOLMAP`] when it is missing or older than 4.
const VERSION_CHECK: &str = r#"
import sys
try:
    import pycolmap
except ImportError as e:
    print(e)
    sys.exit(3)
v = pycolmap.__version__
ok = int(v.split(".")[0]) >= 4
print(v if ok else f"pycolmap {v} is older than 4.2")
sys.exit(0 if ok else 3)
"#;

/// The installed pycolmap's version, or one clear error saying how to install COLMAP 4.2; run
/// before anything is timed, so that a missing pycolmap stops the benchmark at once.
pub fn pycolmap_version() -> Result<String> {
    let out = Command::new("python3")
        .args(["-c", VERSION_CHECK])
        .output()
        .map_err(|e| EvalError::tool("python3", format!("cannot run it for COLMAP 4.2 ({e})")))?;
    let stdout = String::from_utf8_lossy(&out.stdout).trim().to_string();
    match out.status.code() {
        Some(0) => Ok(stdout),
        Some(MISSING_PYCOLMAP) => Err(missing(&stdout)),
        _ => Err(EvalError::tool(
            "pycolmap",
            format!("cannot import it: {}", tail(&out.stderr, 2)),
        )),
    }
}

/// The error of a missing (or pre-4) pycolmap.
fn missing(why: &str) -> EvalError {
    EvalError::tool(
        "pycolmap",
        format!("COLMAP 4.2 is needed: pip install pycolmap ({why})"),
    )
}

/// The last `n` lines of a child's stderr, on one line.
fn tail(stderr: &[u8], n: usize) -> String {
    let text = String::from_utf8_lossy(stderr);
    let lines: Vec<&str> = text.lines().filter(|l| !l.trim().is_empty()).collect();
    lines[lines.len().saturating_sub(n)..].join(" | ")
}

/// Runs COLMAP's extraction, exhaustive matching and incremental mapping on `images` with
/// `threads` threads; its database and models go into `work` (which must exist).
pub fn run_pycolmap_sparse(
    images: &Path,
    work: &Path,
    threads: usize,
) -> Result<PycolmapSparseRun> {
    let out = Command::new("python3")
        .arg("-c")
        .arg(PYCOLMAP_SPARSE_SCRIPT)
        .arg(images)
        .arg(work)
        .arg(threads.to_string())
        .output()
        .map_err(|e| EvalError::tool("python3", format!("cannot run it for COLMAP 4.2 ({e})")))?;
    if out.status.code() == Some(MISSING_PYCOLMAP) {
        return Err(missing(String::from_utf8_lossy(&out.stdout).trim()));
    }
    if !out.status.success() {
        return Err(EvalError::tool(
            "pycolmap",
            format!("the sparse run failed: {}", tail(&out.stderr, 3)),
        ));
    }
    let stdout = String::from_utf8_lossy(&out.stdout);
    let last = stdout.lines().last().unwrap_or_default();
    serde_json::from_str(last)
        .map_err(|e| EvalError::tool("pycolmap", format!("unreadable report ({e}): {last:?}")))
}

/// Scores a COLMAP text model against a data set's ground-truth cameras with the shared
/// `eval_sfm.py` (its last line of output is JSON).
pub fn eval_sfm(script: &Path, model: &Path, dataset: &Path) -> Result<serde_json::Value> {
    let out = Command::new("python3")
        .arg(script)
        .arg(model)
        .arg(dataset)
        .output()
        .map_err(|e| {
            EvalError::tool("python3", format!("cannot run {} ({e})", script.display()))
        })?;
    if !out.status.success() {
        return Err(EvalError::tool(
            "python3",
            format!(
                "{} {} failed (it needs `pip install numpy`): {}",
                script.display(),
                model.display(),
                tail(&out.stderr, 2)
            ),
        ));
    }
    let stdout = String::from_utf8_lossy(&out.stdout);
    let last = stdout.lines().last().unwrap_or_default();
    serde_json::from_str(last).map_err(|e| {
        EvalError::tool(
            "python3",
            format!("{}: unreadable JSON ({e}): {last:?}", script.display()),
        )
    })
}
