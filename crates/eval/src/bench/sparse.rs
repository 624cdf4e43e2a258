//! The whole sparse run, images → metric model, of Handheld against COLMAP 4.2 in the same run
//! (issue #18: Handheld in at most a fifth of COLMAP's time for feature extraction + exhaustive
//! matching + incremental mapping). Handheld runs through the library
//! ([`handheld_pipeline::reconstruct`] up to `sparse`, into a fresh workspace); COLMAP runs through
//! pycolmap in a child process ([`super::pycolmap`]), after Handheld, with the same thread count.
//! Both models can be scored against ground-truth cameras with the shared `eval_sfm.py`.

use std::path::{Path, PathBuf};
use std::time::Instant;

use handheld_core::Progress;
use handheld_pipeline::files::stage;
use handheld_pipeline::stages::sparse::SparseSummary;
use handheld_pipeline::{PipelineOptions, StageReport};
use serde::{Deserialize, Serialize};

use super::pycolmap::{eval_sfm, pycolmap_version, run_pycolmap_sparse, PycolmapSparseRun};
use crate::error::{EvalError, Result};
use handheld_pipeline::Context;

/// Issue #18's target for the total ratio: Handheld in at most a fifth of COLMAP's time.
pub const TARGET_TOTAL_RATIO: f64 = 5.0;

/// Options of the sparse benchmark.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(default)]
pub struct SparseBenchOptions {
    /// Folder of images.
    pub images: PathBuf,
    /// Data set folder with ground-truth cameras (any format `eval_script` reads); both models
    /// are scored against it. Default none.
    pub gt: Option<PathBuf>,
    /// Threads for Handheld and COLMAP (default: all cores).
    pub threads: Option<usize>,
    /// Also run COLMAP 4.2 (pycolmap, CPU) on the same images. Default false.
    pub colmap: bool,
    /// The scoring script, run with `python3 SCRIPT MODEL DATASET`. Default
    /// `../shared/tools/eval_sfm.py` (from the repository root).
    pub eval_script: PathBuf,
    /// Keep both runs in this folder (`handheld/`, `colmap/`); it must be empty or absent.
    /// Default none: a temporary folder, removed afterwards.
    pub work: Option<PathBuf>,
    /// Handheld's options. Default: the pipeline's defaults, as `handheld reconstruct` runs.
    pub pipeline: PipelineOptions,
    /// Rounds, each Handheld then COLMAP, interleaved so that a slow spell of a shared machine
    /// falls on both runs of a round; the ratios reported are each stage's median over the
    /// rounds' ratios. Default 1.
    pub rounds: usize,
}

impl Default for SparseBenchOptions {
    fn default() -> Self {
        Self {
            images: PathBuf::new(),
            gt: None,
            threads: None,
            colmap: false,
            eval_script: PathBuf::from("../shared/tools/eval_sfm.py"),
            work: None,
            pipeline: PipelineOptions::default(),
            rounds: 1,
        }
    }
}

impl SparseBenchOptions {
    /// Checks the options (the pipeline's through its own checks); the error names the option.
    pub fn validate(&self) -> Result<()> {
        if self.images.as_os_str().is_empty() {
            return Err(EvalError::option(
                "--images",
                "a folder of images is required",
            ));
        }
        if self.threads == Some(0) {
            return Err(EvalError::option("--threads", "must be at least 1"));
        }
        if self.rounds == 0 {
            return Err(EvalError::option("--rounds", "must be at least 1"));
        }
        if self.gt.is_some() && self.eval_script.as_os_str().is_empty() {
            return Err(EvalError::option(
                "--eval-script",
                "is required with --gt (the script that scores a model)",
            ));
        }
        self.pipeline
            .validate()
            .map_err(|e| EvalError::option("pipeline options", e.to_string()))
    }
}

/// Handheld's run: each stage's wall time (as the pipeline reports it), the whole library call,
/// and the largest model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HandheldSparseRun {
    pub ingest_seconds: f64,
    pub features_seconds: f64,
    pub matches_seconds: f64,
    pub sparse_seconds: f64,
    /// The whole `reconstruct` call: the four stages and the workspace's bookkeeping.
    pub total_seconds: f64,
    pub models: usize,
    /// Images registered in the largest model.
    pub registered: usize,
    pub total_images: usize,
    pub points: usize,
    pub mean_reprojection_error_px: f64,
    pub focal_px: Vec<f64>,
    /// `eval_script`'s JSON for the model, with `gt`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub eval: Option<serde_json::Value>,
}

/// COLMAP's run: its three stages, their sum, the largest model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ColmapSparseRun {
    #[serde(flatten)]
    pub run: PycolmapSparseRun,
    /// Extraction + matching + mapping.
    pub total_seconds: f64,
    /// `eval_script`'s JSON for the largest model, with `gt`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub eval: Option<serde_json::Value>,
}

/// COLMAP's time ÷ Handheld's, stage by stage (> 1: Handheld is faster).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SparseRatios {
    /// COLMAP's feature extraction ÷ Handheld's ingest + features.
    pub extraction: f64,
    /// COLMAP's exhaustive matching ÷ Handheld's matches.
    pub matching: f64,
    /// COLMAP's incremental mapping ÷ Handheld's sparse.
    pub mapping: f64,
    /// COLMAP's three stages ÷ Handheld's whole call.
    pub total: f64,
}

impl SparseRatios {
    /// The ratios of two runs.
    pub fn of(handheld: &HandheldSparseRun, colmap: &PycolmapSparseRun) -> Self {
        Self {
            extraction: colmap.extraction_seconds
                / (handheld.ingest_seconds + handheld.features_seconds),
            matching: colmap.matching_seconds / handheld.matches_seconds,
            mapping: colmap.mapping_seconds / handheld.sparse_seconds,
            total: colmap.total_seconds() / handheld.total_seconds,
        }
    }
}

/// What the sparse benchmark measured.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SparseBenchReport {
    pub images: PathBuf,
    pub threads: usize,
    /// The matching kernel that ran: `avx512-vnni` or `avx2` (`HANDHELD_SIMD=avx2` forces the
    /// latter; `handheld_features::quantized::SIMD_ENV`).
    #[serde(default)]
    pub simd: String,
    pub handheld: HandheldSparseRun,
    /// With `colmap`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub colmap: Option<ColmapSparseRun>,
    /// COLMAP ÷ Handheld, with `colmap`: each stage's median over the rounds' ratios.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ratio: Option<SparseRatios>,
    /// Every round's times (seconds) and ratios, in order; `handheld` and `colmap` above are the
    /// first round's runs.
    pub rounds: Vec<SparseRound>,
    /// The target for `ratio.total` ([`TARGET_TOTAL_RATIO`]).
    pub target_total_ratio: f64,
    /// Whether `ratio.total` reaches the target, with `colmap`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub meets_target: Option<bool>,
    /// The folder both runs were kept in (none: a removed temporary folder).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub work: Option<PathBuf>,
}

/// One round of the benchmark: Handheld's stages and whole call, COLMAP's stages, their ratios.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SparseRound {
    /// Ingest + features, matches, sparse, whole call.
    pub handheld_seconds: [f64; 4],
    /// Extraction, matching, mapping, total; none without `colmap`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub colmap_seconds: Option<[f64; 4]>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ratio: Option<SparseRatios>,
}

impl SparseRound {
    /// The times of one round's runs.
    pub fn of(handheld: &HandheldSparseRun, colmap: Option<&PycolmapSparseRun>) -> Self {
        Self {
            handheld_seconds: [
                handheld.ingest_seconds + handheld.features_seconds,
                handheld.matches_seconds,
                handheld.sparse_seconds,
                handheld.total_seconds,
            ],
            colmap_seconds: colmap.map(|c| {
                [
                    c.extraction_seconds,
                    c.matching_seconds,
                    c.mapping_seconds,
                    c.total_seconds(),
                ]
            }),
            ratio: colmap.map(|c| SparseRatios::of(handheld, c)),
        }
    }
}

/// The median of each of the four columns.
fn column_medians(rows: &[[f64; 4]]) -> [f64; 4] {
    let mut out = [0.0; 4];
    for (k, o) in out.iter_mut().enumerate() {
        let mut v: Vec<f64> = rows.iter().map(|r| r[k]).collect();
        v.sort_by(f64::total_cmp);
        let n = v.len();
        *o = if n == 0 {
            f64::NAN
        } else if n % 2 == 1 {
            v[n / 2]
        } else {
            0.5 * (v[n / 2 - 1] + v[n / 2])
        };
    }
    out
}

impl SparseBenchReport {
    /// Puts a report together from the first round's runs and every round's times, with the
    /// median of the rounds' ratios, stage by stage, when COLMAP ran.
    pub fn new(
        images: PathBuf,
        threads: usize,
        handheld: HandheldSparseRun,
        colmap: Option<ColmapSparseRun>,
        rounds: Vec<SparseRound>,
        work: Option<PathBuf>,
    ) -> Self {
        // Each round's runs are next to each other in time, so a round's ratio sees the machine
        // in one state; the medians of the rounds' ratios, stage by stage.
        let per_round: Vec<[f64; 4]> = rounds
            .iter()
            .filter_map(|r| r.ratio.as_ref())
            .map(|q| [q.extraction, q.matching, q.mapping, q.total])
            .collect();
        let ratio = (colmap.is_some() && !per_round.is_empty()).then(|| {
            let m = column_medians(&per_round);
            SparseRatios {
                extraction: m[0],
                matching: m[1],
                mapping: m[2],
                total: m[3],
            }
        });
        Self {
            images,
            threads,
            simd: handheld_features::quantized::simd_path().to_string(),
            meets_target: ratio.as_ref().map(|r| r.total >= TARGET_TOTAL_RATIO),
            handheld,
            colmap,
            ratio,
            rounds,
            target_total_ratio: TARGET_TOTAL_RATIO,
            work,
        }
    }
}

/// The folder both runs go into: the one asked for (empty or absent), or a temporary one.
enum Work {
    Kept(PathBuf),
    Temporary(tempfile::TempDir),
}

impl Work {
    fn open(asked: Option<&Path>) -> Result<Self> {
        let Some(dir) = asked else {
            return tempfile::Builder::new()
                .prefix("handheld-bench-sparse-")
                .tempdir()
                .context("creating a temporary folder")
                .map(Work::Temporary)
                .map_err(EvalError::from);
        };
        if std::fs::read_dir(dir).is_ok_and(|mut d| d.next().is_some()) {
            return Err(EvalError::option(
                "--work",
                format!(
                    "{} is not empty (the runs need a fresh folder)",
                    dir.display()
                ),
            ));
        }
        std::fs::create_dir_all(dir).map_err(|e| handheld_io::IoError::io(dir, e))?;
        Ok(Work::Kept(dir.to_path_buf()))
    }

    fn path(&self) -> &Path {
        match self {
            Work::Kept(p) => p,
            Work::Temporary(t) => t.path(),
        }
    }
}

/// The seconds of stage `name` among the pipeline's reports.
fn stage_seconds(reports: &[StageReport], name: &str) -> Result<f64> {
    reports
        .iter()
        .find(|r| r.stage == name)
        .map(|r| r.seconds)
        .ok_or_else(|| EvalError::Data(format!("the pipeline did not run the {name} stage")))
}

/// Runs Handheld's pipeline up to `sparse` into the fresh workspace `ws`, every stage forced.
fn run_handheld(
    o: &SparseBenchOptions,
    ws: &Path,
    pool: &rayon::ThreadPool,
    progress: &dyn Progress,
) -> Result<HandheldSparseRun> {
    let t0 = Instant::now();
    let reports = pool.install(|| {
        handheld_pipeline::reconstruct(
            &o.images,
            ws,
            &o.pipeline,
            Some(stage::SPARSE),
            true,
            progress,
        )
    })?;
    let total_seconds = t0.elapsed().as_secs_f64();
    let sparse = reports
        .iter()
        .find(|r| r.stage == stage::SPARSE)
        .ok_or_else(|| EvalError::Data("the pipeline did not run the sparse stage".into()))?;
    let summary: SparseSummary = serde_json::from_value(sparse.summary.clone())
        .context("reading the sparse stage's summary")?;
    Ok(HandheldSparseRun {
        ingest_seconds: stage_seconds(&reports, stage::INGEST)?,
        features_seconds: stage_seconds(&reports, stage::FEATURES)?,
        matches_seconds: stage_seconds(&reports, stage::MATCHES)?,
        sparse_seconds: sparse.seconds,
        total_seconds,
        models: summary.models,
        registered: summary.registered,
        total_images: summary.total_images,
        points: summary.points,
        mean_reprojection_error_px: summary.mean_reprojection_error_px,
        focal_px: summary.focal_px,
        eval: None,
    })
}

/// The scoring script: `script` when it is a file; otherwise, when it is a relative path that
/// does not resolve from the current folder (the default is relative to the repository root),
/// `tools/<its file name>` beside the data sets' folder of `gt` (`shared/datasets/X` →
/// `shared/tools/eval_sfm.py`), so the bench runs from any folder. `None` when neither exists.
fn eval_script_for(script: &Path, gt: &Path) -> Option<PathBuf> {
    if script.is_file() {
        return Some(script.to_path_buf());
    }
    if script.is_absolute() {
        return None;
    }
    let beside = gt
        .canonicalize()
        .ok()?
        .parent()?
        .parent()?
        .join("tools")
        .join(script.file_name()?);
    beside.is_file().then_some(beside)
}

/// Runs Handheld, then (with `colmap`) COLMAP 4.2, on the same images with the same threads, and
/// (with `gt`) scores both models once every timing is done.
pub fn bench_sparse(o: &SparseBenchOptions, progress: &dyn Progress) -> Result<SparseBenchReport> {
    o.validate()?;
    let script =
        o.gt.as_deref()
            .and_then(|gt| eval_script_for(&o.eval_script, gt))
            .unwrap_or_else(|| o.eval_script.clone());
    if let Some(gt) = &o.gt {
        if !script.is_file() {
            return Err(EvalError::option(
                "--eval-script",
                format!(
                    "{} is not a file (give the path of shared/tools/eval_sfm.py)",
                    o.eval_script.display()
                ),
            ));
        }
        if !gt.is_dir() {
            return Err(EvalError::option(
                "--gt",
                format!("{} is not a folder", gt.display()),
            ));
        }
    }
    if o.colmap {
        pycolmap_version()?;
    }
    let threads = o.threads.unwrap_or_else(rayon::current_num_threads);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .context("starting the thread pool")?;
    let work = Work::open(o.work.as_deref())?;
    let mut first: Option<(HandheldSparseRun, Option<ColmapSparseRun>)> = None;
    let mut rounds = Vec::with_capacity(o.rounds);
    for round in 0..o.rounds {
        // The first round's folders keep their plain names; later rounds are numbered.
        let name = |what: &str| match round {
            0 => what.to_string(),
            r => format!("{what}-{r}"),
        };
        let ws = work.path().join(name("handheld"));
        let handheld = run_handheld(o, &ws, &pool, progress)?;
        let colmap = if o.colmap {
            let dir = work.path().join(name("colmap"));
            std::fs::create_dir_all(&dir).map_err(|e| handheld_io::IoError::io(&dir, e))?;
            progress.start("COLMAP 4.2 (pycolmap): extraction, matching, mapping", 0);
            let run = run_pycolmap_sparse(&o.images, &dir, threads);
            progress.finish();
            let run = run?;
            Some(ColmapSparseRun {
                total_seconds: run.total_seconds(),
                run,
                eval: None,
            })
        } else {
            None
        };
        rounds.push(SparseRound::of(&handheld, colmap.as_ref().map(|c| &c.run)));
        if first.is_none() {
            first = Some((handheld, colmap));
        }
    }
    let (mut handheld, mut colmap) =
        first.ok_or_else(|| EvalError::option("--rounds", "must be at least 1"))?;
    let ws = work.path().join("handheld");
    if let Some(gt) = &o.gt {
        handheld.eval = Some(eval_sfm(&script, &ws.join(stage::SPARSE), gt)?);
        if let Some(c) = colmap.as_mut() {
            if let Some(model) = &c.run.model {
                c.eval = Some(eval_sfm(&script, model, gt)?);
            }
        }
    }
    let kept = match &work {
        Work::Kept(p) => Some(p.clone()),
        Work::Temporary(_) => None,
    };
    if kept.is_none() {
        // The temporary folder goes with `work`: no path into it is reported.
        if let Some(c) = colmap.as_mut() {
            c.run.model = None;
        }
    }
    Ok(SparseBenchReport::new(
        o.images.clone(),
        threads,
        handheld,
        colmap,
        rounds,
        kept,
    ))
}

impl SparseBenchReport {
    /// The report in a few lines, for people (the CLI prints it without `--json`).
    pub fn summary_text(&self) -> String {
        let h = &self.handheld;
        let mut text = format!(
            "handheld: ingest {:.2} s + features {:.2} s, matches {:.2} s, sparse {:.2} s; total {:.2} s; \
             {}/{} registered ({} threads)",
            h.ingest_seconds,
            h.features_seconds,
            h.matches_seconds,
            h.sparse_seconds,
            h.total_seconds,
            h.registered,
            h.total_images,
            self.threads
        );
        if let Some(c) = &self.colmap {
            text.push_str(&format!(
                "\ncolmap {}: extraction {:.2} s, matching {:.2} s, mapping {:.2} s; total {:.2} s; {}/{} registered",
                c.run.version,
                c.run.extraction_seconds,
                c.run.matching_seconds,
                c.run.mapping_seconds,
                c.total_seconds,
                c.run.registered,
                c.run.total_images
            ));
        }
        if self.rounds.len() > 1 {
            for (k, round) in self.rounds.iter().enumerate() {
                let c = round
                    .colmap_seconds
                    .map_or(String::new(), |c| format!(", colmap {:.2} s", c[3]));
                let q = round
                    .ratio
                    .as_ref()
                    .map_or(String::new(), |q| format!(", {:.2}×", q.total));
                text.push_str(&format!(
                    "\nround {}: handheld {:.2} s{c}{q}",
                    k + 1,
                    round.handheld_seconds[3]
                ));
            }
        }
        if let Some(q) = &self.ratio {
            text.push_str(&format!(
                "\nCOLMAP ÷ Handheld (median over the rounds): extraction {:.2}×, matching {:.2}×, mapping {:.2}×, total {:.2}× (target ≥ {})",
                q.extraction, q.matching, q.mapping, q.total, self.target_total_ratio
            ));
        }
        for (who, eval) in [
            ("handheld", h.eval.as_ref()),
            ("colmap", self.colmap.as_ref().and_then(|c| c.eval.as_ref())),
        ] {
            if let Some(e) = eval {
                text.push_str(&format!("\n{who} eval: {e}"));
            }
        }
        text
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_scoring_script_is_found_beside_the_data_sets_from_any_folder() {
        let dir = tempfile::tempdir().unwrap();
        let gt = dir.path().join("shared/datasets/fountain");
        std::fs::create_dir_all(&gt).unwrap();
        std::fs::create_dir_all(dir.path().join("shared/tools")).unwrap();
        let script = dir.path().join("shared/tools/eval_sfm.py");
        std::fs::write(&script, "").unwrap();
        let default = PathBuf::from("../no-such-folder/tools/eval_sfm.py");
        let found = eval_script_for(&default, &gt).expect("found beside the data sets");
        assert_eq!(
            found.canonicalize().unwrap(),
            script.canonicalize().unwrap()
        );
        // An explicit file is taken as it is; a missing absolute path is not searched for.
        assert_eq!(eval_script_for(&script, &gt), Some(script.clone()));
        assert_eq!(eval_script_for(&dir.path().join("none.py"), &gt), None);
    }
}
