//! The dense targets of issue #6:
//! - `linking`: a synthetic 15-view orbit (testkit, exact depth); the reference view is linked
//!   with N = 3, 5, …, 11 views (V_min = 3) and scored: fill over pixels with a surface, median
//!   relative depth error (the paper's Fig. 6).
//! - `polar_forward`: a synthetic forward-motion pair (epipole inside the image): polar
//!   rectification's worst row disagreement of corresponding points.
//! - `speed_640`: rectification (polar, forced) + SGM (the dense stage's 4 paths; 8 paths timed
//!   too) with 100 disparities on a 640×480 pair.
//! - `speed_large` (with a model and its images): the same on the model's first two views at
//!   full resolution (e.g. fountain-P11, 3072×2048).

use std::path::PathBuf;
use std::time::Instant;

use handheld_core::{FloatMap, PosedCamera, PosedView};
use handheld_dense::{
    link_depth, match_sequence_pairs, rectify_pair, LinkOptions, PairOptions, RectifyMethod,
    RectifyOptions, StereoMatcher, StereoOptions,
};
use handheld_testkit::path::PathOptions;
use handheld_testkit::render::{render_sequence, SequenceOptions};
use nalgebra::Point3;
use serde::{Deserialize, Serialize};

use crate::error::{EvalError, Result};
use handheld_pipeline::Context;

/// Options of the dense benchmark.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct DenseBenchOptions {
    /// Width of the synthetic images (height is 3/4 of it). Default 640.
    pub width: u32,
    /// A COLMAP model for the full-resolution timing (its first two views). Default none.
    pub model: Option<PathBuf>,
    /// The folder of the model's images (required with `model`).
    pub images: Option<PathBuf>,
    /// Timed runs (the median is reported). Default 5.
    pub runs: u32,
    /// With `model`: also run the whole dense stage on it, with the stage's defaults but this
    /// longer-side limit (0: the default, full size up to 24 MP). Default `None`: no stage run.
    pub stage_max_size: Option<u32>,
}

impl Default for DenseBenchOptions {
    fn default() -> Self {
        Self {
            width: 640,
            model: None,
            images: None,
            runs: 5,
            stage_max_size: None,
        }
    }
}

impl DenseBenchOptions {
    /// Checks the options.
    pub fn validate(&self) -> Result<()> {
        if !(16..=16384).contains(&self.width) {
            return Err(EvalError::option("--width", "must be in 16..=16384"));
        }
        if self.model.is_some() && self.images.is_none() {
            return Err(EvalError::option("--images", "is required with --model"));
        }
        if self.stage_max_size.is_some() && self.model.is_none() {
            return Err(EvalError::option("--stage", "needs --model and --images"));
        }
        Ok(())
    }
}

/// One point of the linking curve.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct LinkingPoint {
    /// N, the views linked (reference included).
    pub views: usize,
    pub fill: f64,
    pub median_relative_error: f64,
    pub linking_seconds: f64,
}

/// Multi-view linking on the synthetic orbit.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct LinkingReport {
    pub width: u32,
    pub height: u32,
    /// Rectification + stereo per consecutive pair.
    pub pair_seconds: f64,
    pub curve: Vec<LinkingPoint>,
}

/// Polar rectification of a forward-motion pair.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PolarReport {
    /// Whether the polar method was chosen.
    pub polar: bool,
    pub rectified_size: (usize, usize),
    /// Corresponding points checked, and their worst row disagreement.
    pub points: usize,
    pub max_row_error_px: f64,
}

/// Timing of rectification and SGM on one pair (medians).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PairTiming {
    pub image: [usize; 2],
    pub rectified_size: (usize, usize),
    pub disparities: u32,
    pub rectify_seconds: f64,
    pub sgm_seconds: f64,
    pub total_seconds: f64,
    pub sgm_8_paths_seconds: f64,
}

/// What the dense benchmark measured.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct DenseBenchReport {
    pub linking: LinkingReport,
    pub polar_forward: PolarReport,
    pub speed_640: PairTiming,
    pub threads: usize,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub speed_large: Option<PairTiming>,
    /// The whole dense stage on `model` (`--stage`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stage: Option<StageRun>,
    /// Peak resident memory of the process over the whole bench (`VmHWM`, MB).
    pub peak_rss_mb: Option<f64>,
}

/// The whole dense stage on a real model: what issue #35 asks of full-size dense depth.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct StageRun {
    /// The size the views were matched at (the first view's).
    pub width: u32,
    pub height: u32,
    pub views: usize,
    pub pairs_matched: usize,
    /// Pairs that failed, with the reason.
    pub pairs_failed: Vec<String>,
    /// Fill of each view's depth map (fraction of its pixels).
    pub fill: Vec<f64>,
    pub fill_min: f64,
    pub fill_mean: f64,
    pub seconds: f64,
    /// Seconds per megapixel of one view (`seconds / (views · megapixels)`).
    pub seconds_per_megapixel_view: f64,
    /// Peak resident memory at the end of the stage (`VmHWM`, MB).
    pub peak_rss_mb: Option<f64>,
}

/// Runs the dense stage on `model` into a temporary folder.
fn stage_run(model: &std::path::Path, images: &std::path::Path, max_size: u32) -> Result<StageRun> {
    use handheld_pipeline::stages::dense::{densify_model, DenseStageOptions};
    let opts = DenseStageOptions {
        max_size,
        ..DenseStageOptions::default()
    };
    let tmp = tempfile::tempdir().with_context(|| "cannot make a temporary folder".to_string())?;
    let t = Instant::now();
    let summary = densify_model(model, images, &opts, tmp.path(), &handheld_core::NoProgress)?;
    let seconds = t.elapsed().as_secs_f64();
    let path = tmp.path().join(handheld_pipeline::files::SUMMARY_JSON);
    let text = std::fs::read_to_string(&path)
        .with_context(|| format!("{}: cannot read", path.display()))?;
    let full: handheld_pipeline::stages::dense::DenseStageSummary = serde_json::from_str(&text)
        .map_err(|e| EvalError::Data(format!("{}: {e}", path.display())))?;
    let per_view = full.per_view.unwrap_or_default();
    let fill: Vec<f64> = per_view.iter().map(|v| v.fill).collect();
    let (width, height) = per_view.first().map_or((0, 0), |v| (v.width, v.height));
    let mp = f64::from(width) * f64::from(height) / 1e6;
    Ok(StageRun {
        width,
        height,
        views: summary.views,
        pairs_matched: summary.pairs_matched,
        pairs_failed: summary
            .pairs_failed
            .iter()
            .map(|f| format!("{}–{}: {}", f.pair[0], f.pair[1], f.reason))
            .collect(),
        fill_min: fill.iter().copied().fold(f64::INFINITY, f64::min),
        fill_mean: fill.iter().sum::<f64>() / fill.len().max(1) as f64,
        fill,
        seconds,
        seconds_per_megapixel_view: seconds / (summary.views.max(1) as f64 * mp.max(1e-9)),
        peak_rss_mb: super::scale::peak_rss_mb(),
    })
}

fn to_map(img: &image::RgbImage) -> FloatMap {
    FloatMap::from_u8(img.width() as usize, img.height() as usize, 3, img.as_raw())
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

fn linking(width: u32) -> Result<LinkingReport> {
    let mut opts = SequenceOptions {
        width,
        height: width * 3 / 4,
        num_frames: 15,
        ..Default::default()
    };
    opts.path.sweep = 28.0;
    let seq = render_sequence(&opts).context("rendering the linking orbit")?;
    let frames: Vec<PosedCamera> = (0..15)
        .map(|i| {
            seq.frame(i)
                .ok_or_else(|| EvalError::Data(format!("no frame {i}")))
        })
        .collect::<Result<_>>()?;
    let points: Vec<Point3<f64>> = seq.gt.points.values().map(|p| p.xyz).collect();
    let views: Vec<PosedView> = frames
        .iter()
        .zip(&seq.images)
        .enumerate()
        .map(|(i, (frame, image))| {
            PosedView::from_posed(format!("frame{i}"), frame.clone(), image.clone())
        })
        .collect();
    let t = Instant::now();
    let pairs = match_sequence_pairs(&views, &points, &PairOptions::default())?;
    let pair_seconds = t.elapsed().as_secs_f64() / pairs.len() as f64;
    let reference = 7;
    let truth = seq
        .depths
        .get(reference)
        .ok_or_else(|| EvalError::Data("no reference depth".into()))?;
    let mut curve = Vec::new();
    for half in 1..=5 {
        let o = LinkOptions {
            max_links: half,
            min_visibility: 3,
            ..Default::default()
        };
        let t = Instant::now();
        let linked = link_depth(&views, &pairs, reference, &o)?;
        let secs = t.elapsed().as_secs_f64();
        let (mut n, mut errs) = (0usize, Vec::new());
        for (z, g) in linked.depth.data.iter().zip(&truth.data) {
            if *g > 0.0 {
                n += 1;
                if z.is_finite() {
                    errs.push(f64::from(((z - g) / g).abs()));
                }
            }
        }
        curve.push(LinkingPoint {
            views: 2 * half + 1,
            fill: errs.len() as f64 / n.max(1) as f64,
            median_relative_error: median(errs),
            linking_seconds: secs,
        });
    }
    Ok(LinkingReport {
        width: opts.width,
        height: opts.height,
        pair_seconds,
        curve,
    })
}

/// A forward-motion pair: worst row disagreement and the timing of polar rectification + SGM.
fn forward_pair(width: u32, runs: u32) -> Result<(PolarReport, PairTiming)> {
    let opts = SequenceOptions {
        width,
        height: width * 3 / 4,
        num_frames: 2,
        path: PathOptions {
            sweep: 0.5,
            ..PathOptions::forward(2)
        },
        ..Default::default()
    };
    let seq = render_sequence(&opts).context("rendering the forward pair")?;
    let no_frame = || EvalError::Data("the forward pair has no two frames".into());
    let v0 = seq.frame(0).ok_or_else(no_frame)?;
    let v1 = seq.frame(1).ok_or_else(no_frame)?;
    let rect = rectify_pair(&v0, &v1, &RectifyOptions::default())?;
    let mut worst = 0.0f64;
    let mut n = 0;
    let truth = seq.depths.first().ok_or_else(no_frame)?;
    let inv = v0.cam_from_world.inverse();
    for y in (0..truth.height).step_by(4) {
        for x in (0..truth.width).step_by(4) {
            let z = f64::from(truth.get(x, y, 0));
            if z <= 0.0 {
                continue;
            }
            let ray = v0
                .camera
                .ray_in_cam(nalgebra::Vector2::new(x as f64, y as f64));
            let pw = inv.transform_point(&Point3::from(ray / ray.z * z));
            let (Some(m0), Some(m1)) = (rect.project(0, &pw), rect.project(1, &pw)) else {
                continue;
            };
            if let (Some(a), Some(b)) = (rect.to_rect(0, m0), rect.to_rect(1, m1)) {
                worst = worst.max((a.y - b.y).abs());
                n += 1;
            }
        }
    }
    let polar = PolarReport {
        polar: rect.is_polar(),
        rectified_size: rect.size(),
        points: n,
        max_row_error_px: worst,
    };
    let (l, r) = (to_map(&seq.images[0]), to_map(&seq.images[1]));
    let speed = time_pair((&v0, &l), (&v1, &r), runs)?;
    Ok((polar, speed))
}

/// Median time of polar rectification (maps + resampling) plus SGM over 100 disparities.
fn time_pair(
    (v0, l): (&PosedCamera, &FloatMap),
    (v1, r): (&PosedCamera, &FloatMap),
    runs: u32,
) -> Result<PairTiming> {
    let ropts = RectifyOptions {
        method: RectifyMethod::Polar,
        ..Default::default()
    };
    let stereo = StereoOptions {
        min_disparity: -50,
        max_disparity: 49,
        ..PairOptions::default().stereo
    };
    let eight = StereoOptions {
        sgm_paths: handheld_dense::SgmPaths::Eight,
        ..stereo.clone()
    };
    // One matcher per setting, reused across runs (as OpenCV reuses its StereoSGBM object).
    let mut m4 = StereoMatcher::new(stereo)?;
    let mut m8 = StereoMatcher::new(eight)?;
    let (mut tr, mut tm, mut t8, mut size) = (Vec::new(), Vec::new(), Vec::new(), (0, 0));
    for _ in 0..runs.max(1) {
        let t = Instant::now();
        let rect = rectify_pair(v0, v1, &ropts)?;
        let (a, _) = rect.resample(0, &handheld_dense::pair::to_grey(l));
        let (b, _) = rect.resample(1, &handheld_dense::pair::to_grey(r));
        tr.push(t.elapsed().as_secs_f64());
        let t = Instant::now();
        m4.match_pair(&a, &b)?;
        tm.push(t.elapsed().as_secs_f64());
        let t = Instant::now();
        m8.match_pair(&a, &b)?;
        t8.push(t.elapsed().as_secs_f64());
        size = rect.size();
    }
    let (tr, tm, t8) = (median(tr), median(tm), median(t8));
    Ok(PairTiming {
        image: [l.width, l.height],
        rectified_size: size,
        disparities: 100,
        rectify_seconds: tr,
        sgm_seconds: tm,
        total_seconds: tr + tm,
        sgm_8_paths_seconds: t8,
    })
}

/// The full-resolution timing on a model's first two views.
fn speed_large(model: &std::path::Path, images: &std::path::Path) -> Result<PairTiming> {
    let rec = handheld_io::colmap::read_reconstruction(model)?;
    let views: Vec<_> = rec.views.values().take(2).collect();
    let [v0, v1] = views[..] else {
        return Err(EvalError::Data(format!(
            "{}: fewer than two views",
            model.display()
        )));
    };
    let load = |name: &str| -> Result<FloatMap> {
        let p = images.join(name);
        let img = image::open(&p).with_context(|| format!("{}: cannot read", p.display()))?;
        Ok(to_map(&img.to_rgb8()))
    };
    let (l, r) = (load(&v0.name)?, load(&v1.name)?);
    let posed = |v: &handheld_core::View| {
        let camera = rec.cameras.get(&v.camera_id).ok_or_else(|| {
            EvalError::Data(format!("{}: no camera for {}", model.display(), v.name))
        })?;
        Ok::<_, EvalError>(PosedCamera::new(camera.clone(), v.cam_from_world))
    };
    time_pair((&posed(v0)?, &l), (&posed(v1)?, &r), 1)
}

/// Runs every dense target.
pub fn bench_dense(o: &DenseBenchOptions) -> Result<DenseBenchReport> {
    o.validate()?;
    super::scale::reset_peak_rss();
    let linking = linking(o.width)?;
    let (polar_forward, speed_640) = forward_pair(o.width, o.runs)?;
    let speed_large = match (&o.model, &o.images) {
        (Some(model), Some(images)) => Some(speed_large(model, images)?),
        _ => None,
    };
    let stage = match (&o.model, &o.images, o.stage_max_size) {
        (Some(model), Some(images), Some(max_size)) => Some(stage_run(model, images, max_size)?),
        _ => None,
    };
    Ok(DenseBenchReport {
        linking,
        polar_forward,
        speed_640,
        threads: rayon::current_num_threads(),
        speed_large,
        stage,
        peak_rss_mb: super::scale::peak_rss_mb(),
    })
}
