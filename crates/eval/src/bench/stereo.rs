//! Stereo of already-rectified pairs (§4.2): one pair's disparity written as PFM
//! ([`stereo_pair`]), and SGM and DP on the Middlebury pairs scored as `eval_stereo.py` does,
//! optionally timed against OpenCV's StereoSGBM in the same run ([`bench_stereo`]).

use std::path::{Path, PathBuf};
use std::time::Instant;

use handheld_core::FloatMap;
use handheld_dense::{Disparity, StereoMatcher, StereoMethod, StereoOptions};
use serde::{Deserialize, Serialize};

use crate::error::{EvalError, Result};
use handheld_pipeline::Context;

/// Options of one rectified pair's dense matching.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StereoPairOptions {
    /// Left image of a rectified pair.
    pub left: PathBuf,
    /// Right image (left x matches right x − d).
    pub right: PathBuf,
    /// Smallest and largest disparity searched (inclusive).
    pub min_disparity: i32,
    pub max_disparity: i32,
    /// Semi-global matching or scanline dynamic programming.
    pub method: StereoMethod,
    /// Output PFM (the left view's disparity; missing = NaN).
    pub output: PathBuf,
    /// Write only measured pixels (no hole filling of occlusions and mismatches).
    pub valid_only: bool,
}

impl StereoPairOptions {
    /// The stereo library's options (checked).
    pub fn stereo_options(&self) -> Result<StereoOptions> {
        stereo_options(self.method, self.min_disparity, self.max_disparity)
    }

    /// Checks the options.
    pub fn validate(&self) -> Result<()> {
        self.stereo_options().map(|_| ())
    }
}

fn stereo_options(method: StereoMethod, min: i32, max: i32) -> Result<StereoOptions> {
    let o = StereoOptions {
        min_disparity: min,
        max_disparity: max,
        ..StereoOptions::for_method(method)
    };
    o.validate()
        .map_err(|e| EvalError::option("--min-disparity/--max-disparity", e.to_string()))?;
    Ok(o)
}

/// What one pair's matching did.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct StereoPairReport {
    pub output: PathBuf,
    pub method: StereoMethod,
    pub width: usize,
    pub height: usize,
    pub seconds: f64,
    /// Fraction of pixels with a disparity (measured or filled).
    pub density: f64,
    /// Fraction of pixels measured.
    pub measured_fraction: f64,
}

fn load(path: &Path) -> Result<FloatMap> {
    let img = image::open(path)
        .with_context(|| format!("{}: cannot read the image", path.display()))?
        .to_rgb8();
    Ok(FloatMap {
        width: img.width() as usize,
        height: img.height() as usize,
        channels: 3,
        data: img.as_raw().iter().map(|v| f32::from(*v)).collect(),
    })
}

/// Matches one rectified pair and writes the left view's disparity as PFM.
pub fn stereo_pair(o: &StereoPairOptions) -> Result<StereoPairReport> {
    let opts = o.stereo_options()?;
    let (l, r) = (load(&o.left)?, load(&o.right)?);
    let t0 = Instant::now();
    let d = handheld_dense::match_rectified(&l, &r, &opts)?;
    let seconds = t0.elapsed().as_secs_f64();
    let map = if o.valid_only {
        d.valid_float_map()
    } else {
        d.to_float_map()
    };
    handheld_io::pfm::write_pfm(&o.output, &map)?;
    Ok(StereoPairReport {
        output: o.output.clone(),
        method: o.method,
        width: d.width,
        height: d.height,
        seconds,
        density: d.density(),
        measured_fraction: d.valid_fraction(),
    })
}

/// Options of the Middlebury stereo benchmark.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct StereoBenchOptions {
    /// Middlebury pair folders (`im2.png`, `im6.png`, `disp2.pgm` at GT scale 4). Default teddy
    /// and cones in `../shared/datasets/`.
    pub pairs: Vec<PathBuf>,
    /// Largest disparity (inclusive); 63 gives OpenCV's 64 disparities. Default 63.
    pub max_disparity: i32,
    /// Timed runs per method, in 1..=100 (the median is reported). Default 5.
    pub runs: u32,
    /// Also run OpenCV's StereoSGBM (python3 with opencv-python-headless). Default false.
    pub opencv: bool,
}

impl Default for StereoBenchOptions {
    fn default() -> Self {
        Self {
            pairs: vec![
                PathBuf::from("../shared/datasets/stereo-teddy"),
                PathBuf::from("../shared/datasets/stereo-cones"),
            ],
            max_disparity: 63,
            runs: 5,
            opencv: false,
        }
    }
}

impl StereoBenchOptions {
    /// Checks the options.
    pub fn validate(&self) -> Result<()> {
        if !(1..=100).contains(&self.runs) {
            return Err(EvalError::option("--runs", "must be in 1..=100"));
        }
        if self.opencv && self.max_disparity != 63 {
            return Err(EvalError::option(
                "--max-disparity",
                "the OpenCV reference uses 64 disparities: run with --max-disparity 63",
            ));
        }
        stereo_options(StereoMethod::Sgm, 0, self.max_disparity).map(|_| ())
    }
}

/// `eval_stereo.py`'s scores of one disparity map.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct StereoScore {
    /// % of GT-valid pixels off by more than 1 / 2 px (a missing estimate counts as bad).
    pub bad1: f64,
    pub bad2: f64,
    /// Mean error over the estimated pixels.
    pub avgerr: f64,
    /// % of GT-valid pixels estimated.
    pub density: f64,
    /// Median seconds of one run.
    pub seconds: f64,
}

/// One of our methods on one pair.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct MethodScore {
    #[serde(flatten)]
    pub score: StereoScore,
    pub measured_fraction: f64,
    /// Our time over OpenCV's (with OpenCV).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub time_ratio_to_opencv: Option<f64>,
}

/// Every method on one Middlebury pair.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PairScores {
    /// The pair folder's name.
    pub pair: String,
    pub width: usize,
    pub height: usize,
    pub sgm: MethodScore,
    pub dp: MethodScore,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub opencv_sgbm: Option<StereoScore>,
}

/// What the stereo benchmark measured.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct StereoBenchReport {
    pub max_disparity: i32,
    pub runs: u32,
    pub threads: usize,
    pub pairs: Vec<PairScores>,
}

/// bad1, bad2, mean error over the estimated pixels and density: `eval_stereo.py`'s definitions.
fn score(d: &Disparity, gt: &image::GrayImage, scale: f32, seconds: f64) -> StereoScore {
    let (mut n, mut bad1, mut bad2, mut est, mut err_sum) =
        (0usize, 0usize, 0usize, 0usize, 0.0f64);
    for (i, g) in gt.as_raw().iter().enumerate() {
        if *g == 0 {
            continue;
        }
        n += 1;
        let g = f32::from(*g) / scale;
        let e = d.data.get(i).copied().unwrap_or(f32::NAN);
        if !(e.is_finite() && e > 0.0) {
            bad1 += 1;
            bad2 += 1;
            continue;
        }
        est += 1;
        let err = (e - g).abs();
        err_sum += f64::from(err);
        bad1 += usize::from(err > 1.0);
        bad2 += usize::from(err > 2.0);
    }
    let pct = |k: usize| 100.0 * k as f64 / n.max(1) as f64;
    StereoScore {
        bad1: pct(bad1),
        bad2: pct(bad2),
        avgerr: err_sum / est.max(1) as f64,
        density: pct(est),
        seconds,
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

/// OpenCV StereoSGBM on one pair through python3: `(median seconds, its disparity)`.
fn opencv(left: &Path, right: &Path, runs: u32, tmp: &Path) -> Result<(f64, FloatMap)> {
    let script = tmp.join("opencv_sgbm.py");
    std::fs::write(
        &script,
        include_str!("../../../dense/examples/opencv_sgbm.py"),
    )
    .map_err(|e| handheld_io::IoError::io(&script, e))?;
    let out = tmp.join("opencv.pfm");
    let o = std::process::Command::new("python3")
        .arg(&script)
        .arg(left)
        .arg(right)
        .arg(&out)
        .args(["--runs", &runs.to_string()])
        .output()
        .map_err(|e| {
            EvalError::tool(
                "python3",
                format!("cannot run it for the OpenCV reference ({e})"),
            )
        })?;
    if !o.status.success() {
        return Err(EvalError::tool(
            "python3",
            format!(
                "OpenCV reference failed (pip install opencv-python-headless numpy): {}",
                String::from_utf8_lossy(&o.stderr).trim()
            ),
        ));
    }
    let v: serde_json::Value =
        serde_json::from_slice(&o.stdout).context("reading the OpenCV reference's JSON line")?;
    let secs = v["seconds"]
        .as_f64()
        .ok_or_else(|| EvalError::tool("python3", "OpenCV reference: no seconds"))?;
    Ok((secs, handheld_io::pfm::read_pfm(&out)?))
}

/// One of our methods on one pair: `runs` timed runs of one reused matcher.
fn run_method(
    method: StereoMethod,
    (l, r): (&FloatMap, &FloatMap),
    gt: &image::GrayImage,
    o: &StereoBenchOptions,
) -> Result<MethodScore> {
    let mut matcher = StereoMatcher::new(stereo_options(method, 0, o.max_disparity)?)?;
    let mut times = Vec::new();
    let mut last = None;
    for _ in 0..o.runs.max(1) {
        let t0 = Instant::now();
        let d = matcher.match_pair(l, r)?;
        times.push(t0.elapsed().as_secs_f64());
        last = Some(d);
    }
    let d = last.ok_or_else(|| EvalError::Data("no stereo run".into()))?;
    Ok(MethodScore {
        score: score(&d, gt, 4.0, median(times)),
        measured_fraction: d.valid_fraction(),
        time_ratio_to_opencv: None,
    })
}

/// Scores SGM and DP (and optionally OpenCV) on every pair.
pub fn bench_stereo(o: &StereoBenchOptions) -> Result<StereoBenchReport> {
    o.validate()?;
    let tmp = tempfile::tempdir().context("creating a temporary folder")?;
    let mut pairs = Vec::new();
    for dir in &o.pairs {
        let pair = dir
            .file_name()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        let (lp, rp, gp) = (
            dir.join("im2.png"),
            dir.join("im6.png"),
            dir.join("disp2.pgm"),
        );
        let (l, r) = (load(&lp)?, load(&rp)?);
        let gt = image::open(&gp)
            .with_context(|| format!("{}: cannot read the ground truth", gp.display()))?
            .to_luma8();
        let mut entry = PairScores {
            pair,
            width: l.width,
            height: l.height,
            sgm: run_method(StereoMethod::Sgm, (&l, &r), &gt, o)?,
            dp: run_method(StereoMethod::Dp, (&l, &r), &gt, o)?,
            opencv_sgbm: None,
        };
        if o.opencv {
            let (secs, map) = opencv(&lp, &rp, o.runs, tmp.path())?;
            let d = Disparity {
                width: map.width,
                height: map.height,
                valid: map.data.iter().map(|v| v.is_finite()).collect(),
                data: map.data,
                right: Vec::new(),
                scale: Vec::new(),
                right_scale: Vec::new(),
            };
            entry.opencv_sgbm = Some(score(&d, &gt, 4.0, secs));
            for m in [&mut entry.sgm, &mut entry.dp] {
                m.time_ratio_to_opencv = Some(m.score.seconds / secs);
            }
        }
        pairs.push(entry);
    }
    Ok(StereoBenchReport {
        max_disparity: o.max_disparity,
        runs: o.runs,
        threads: rayon::current_num_threads(),
        pairs,
    })
}
