//! `handheld stereo` (one already-rectified pair → the left view's disparity as PFM) and
//! `handheld bench stereo` (SGM and DP on the Middlebury pairs, scored as `eval_stereo.py` does,
//! timed against OpenCV's StereoSGBM in the same run).

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use clap::{Args, ValueEnum};
use handheld_core::FloatMap;
use handheld_dense::{Disparity, StereoMatcher, StereoMethod, StereoOptions};
use serde_json::json;

use crate::args::GlobalArgs;
use crate::ui::print_result;

/// The stereo method.
#[derive(Debug, Clone, Copy, ValueEnum, PartialEq, Eq)]
pub enum MethodArg {
    /// Semi-global matching (census cost, 8 paths).
    Sgm,
    /// Dynamic programming along each scanline (§4.2).
    Dp,
}

impl MethodArg {
    fn method(self) -> StereoMethod {
        match self {
            MethodArg::Sgm => StereoMethod::Sgm,
            MethodArg::Dp => StereoMethod::Dp,
        }
    }
}

#[derive(Debug, Args)]
pub struct StereoArgs {
    /// Left image of a rectified pair.
    #[arg(long)]
    pub left: PathBuf,
    /// Right image (left x matches right x − d).
    #[arg(long)]
    pub right: PathBuf,
    /// Largest disparity searched (inclusive).
    #[arg(long, allow_negative_numbers = true)]
    pub max_disparity: i32,
    /// Smallest disparity searched.
    #[arg(long, default_value_t = 0, allow_negative_numbers = true)]
    pub min_disparity: i32,
    #[arg(long, value_enum, default_value_t = MethodArg::Sgm)]
    pub method: MethodArg,
    /// Output PFM (left view's disparity; missing = NaN).
    #[arg(long, short)]
    pub output: PathBuf,
    /// Write only measured pixels (no hole filling of occlusions and mismatches).
    #[arg(long)]
    pub valid_only: bool,
}

#[derive(Debug, Args)]
pub struct BenchStereoArgs {
    /// Middlebury pair folders (`im2.png`, `im6.png`, `disp2.pgm` at GT scale 4).
    #[arg(long, num_args = 1.., default_values = ["../shared/datasets/stereo-teddy", "../shared/datasets/stereo-cones"])]
    pub pairs: Vec<PathBuf>,
    /// Largest disparity (inclusive); 63 gives OpenCV's 64 disparities.
    #[arg(long, default_value_t = 63)]
    pub max_disparity: i32,
    /// Timed runs per method (the median is reported; one matcher is reused, as OpenCV reuses its
    /// StereoSGBM object).
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(1..=100))]
    pub runs: u32,
    /// Also run OpenCV's StereoSGBM (python3 with opencv-python-headless) in the same run.
    #[arg(long)]
    pub opencv: bool,
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

fn options(method: MethodArg, min: i32, max: i32) -> Result<StereoOptions> {
    let o = StereoOptions {
        min_disparity: min,
        max_disparity: max,
        ..StereoOptions::for_method(method.method())
    };
    o.validate()
        .map_err(|e| anyhow::anyhow!("--min-disparity/--max-disparity: {e}"))?;
    Ok(o)
}

pub fn run(a: &StereoArgs, g: &GlobalArgs) -> Result<()> {
    let opts = options(a.method, a.min_disparity, a.max_disparity)?;
    let (l, r) = (load(&a.left)?, load(&a.right)?);
    let t0 = Instant::now();
    let d = handheld_dense::match_rectified(&l, &r, &opts).map_err(anyhow::Error::msg)?;
    let secs = t0.elapsed().as_secs_f64();
    let map = if a.valid_only {
        d.valid_float_map()
    } else {
        d.to_float_map()
    };
    handheld_io::pfm::write_pfm(&a.output, &map)?;
    let v = json!({
        "output": a.output,
        "method": format!("{:?}", a.method).to_lowercase(),
        "width": d.width,
        "height": d.height,
        "seconds": secs,
        "density": d.density(),
        "measured_fraction": d.valid_fraction(),
    });
    let human = format!(
        "{}: {}×{} in {:.3} s, density {:.1} % ({:.1} % measured, the rest filled)",
        a.output.display(),
        d.width,
        d.height,
        secs,
        100.0 * d.density(),
        100.0 * d.valid_fraction()
    );
    print_result(g, &v, &human);
    Ok(())
}

/// bad1, bad2 (% of GT-valid pixels off by more than 1 / 2 px, a missing estimate counting as bad),
/// mean error over the estimated ones and density: `eval_stereo.py`'s definitions.
fn score(d: &Disparity, gt: &image::GrayImage, scale: f32) -> serde_json::Value {
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
    json!({
        "bad1": pct(bad1),
        "bad2": pct(bad2),
        "avgerr": err_sum / est.max(1) as f64,
        "density": pct(est),
    })
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

/// OpenCV StereoSGBM on one pair through python3: `(median seconds, its disparity)`.
fn opencv(left: &Path, right: &Path, runs: u32, max_d: i32, tmp: &Path) -> Result<(f64, FloatMap)> {
    let script = tmp.join("opencv_sgbm.py");
    std::fs::write(&script, include_str!("../../dense/examples/opencv_sgbm.py"))?;
    let out = tmp.join("opencv.pfm");
    if max_d != 63 {
        anyhow::bail!("the OpenCV reference uses 64 disparities: run with --max-disparity 63");
    }
    let o = std::process::Command::new("python3")
        .arg(&script)
        .arg(left)
        .arg(right)
        .arg(&out)
        .args(["--runs", &runs.to_string()])
        .output()
        .context("running python3 for the OpenCV reference")?;
    if !o.status.success() {
        anyhow::bail!(
            "OpenCV reference failed (pip install opencv-python-headless numpy): {}",
            String::from_utf8_lossy(&o.stderr).trim()
        );
    }
    let v: serde_json::Value =
        serde_json::from_slice(&o.stdout).context("reading the OpenCV reference's JSON line")?;
    let secs = v["seconds"]
        .as_f64()
        .context("OpenCV reference: no seconds")?;
    Ok((secs, handheld_io::pfm::read_pfm(&out)?))
}

pub fn bench(a: &BenchStereoArgs, g: &GlobalArgs) -> Result<()> {
    let tmp = tempfile::tempdir().context("creating a temporary folder")?;
    let mut results = Vec::new();
    let mut human = String::new();
    for dir in &a.pairs {
        let name = dir
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
        let mut entry = json!({ "pair": name, "width": l.width, "height": l.height });
        for m in [MethodArg::Sgm, MethodArg::Dp] {
            let key = format!("{m:?}").to_lowercase();
            let mut matcher =
                StereoMatcher::new(options(m, 0, a.max_disparity)?).map_err(anyhow::Error::msg)?;
            let mut times = Vec::new();
            let mut last = None;
            for _ in 0..a.runs {
                let t0 = Instant::now();
                let d = matcher.match_pair(&l, &r).map_err(anyhow::Error::msg)?;
                times.push(t0.elapsed().as_secs_f64());
                last = Some(d);
            }
            let d = last.context("no run")?;
            let mut s = score(&d, &gt, 4.0);
            s["seconds"] = json!(median(times));
            s["measured_fraction"] = json!(d.valid_fraction());
            entry[&key] = s;
        }
        if a.opencv {
            let (secs, map) = opencv(&lp, &rp, a.runs, a.max_disparity, tmp.path())?;
            let d = Disparity {
                width: map.width,
                height: map.height,
                valid: map.data.iter().map(|v| v.is_finite()).collect(),
                data: map.data,
                right: Vec::new(),
            };
            let mut s = score(&d, &gt, 4.0);
            s["seconds"] = json!(secs);
            entry["opencv_sgbm"] = s;
            for m in ["sgm", "dp"] {
                let ratio = entry[m]["seconds"].as_f64().unwrap_or(f64::NAN) / secs;
                entry[m]["time_ratio_to_opencv"] = json!(ratio);
            }
        }
        human.push_str(&format!("{name}: {entry}\n"));
        results.push(entry);
    }
    let v = json!({ "max_disparity": a.max_disparity, "runs": a.runs, "threads": rayon::current_num_threads(), "pairs": results });
    print_result(g, &v, human.trim_end());
    Ok(())
}
