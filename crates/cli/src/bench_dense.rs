//! `handheld bench dense`: the dense targets of issue #6 as one JSON object.
//! - `linking`: a synthetic 15-view orbit (testkit, exact depth); the reference view is linked
//!   with N = 3, 5, …, 11 views (V_min = 3) and scored: fill over pixels with a surface, median
//!   relative depth error (the paper's Fig. 6).
//! - `polar_forward`: a synthetic forward-motion pair (epipole inside the image): polar
//!   rectification's worst row disagreement of corresponding points.
//! - `speed_640`: rectification (polar, forced) + SGM (the dense stage's 4 paths; 8 paths timed
//!   too) with 100 disparities on a 640×480 pair.
//! - `speed_large` (with `--model` and `--images`): the same on the model's first two views at
//!   full resolution (e.g. fountain-P11, 3072×2048).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::Args;
use handheld_core::{Camera, FloatMap, PosedView, Rigid3};
use handheld_dense::{
    link_depth, match_sequence_pairs, rectify_pair, LinkOptions, PairOptions, RectifyMethod,
    RectifyOptions, StereoMatcher, StereoOptions,
};
use handheld_testkit::path::PathOptions;
use handheld_testkit::render::{render_sequence, SequenceOptions};
use nalgebra::Point3;
use serde_json::json;

use crate::args::GlobalArgs;
use crate::ui::print_result;

#[derive(Debug, Args)]
pub struct BenchDenseArgs {
    /// Width of the synthetic images (height is 3/4 of it).
    #[arg(long, default_value_t = 640)]
    pub width: u32,
    /// A COLMAP model and its images for the full-resolution timing (first two views).
    #[arg(long, requires = "images")]
    pub model: Option<PathBuf>,
    #[arg(long)]
    pub images: Option<PathBuf>,
    /// Timed runs (median reported).
    #[arg(long, default_value_t = 5)]
    pub runs: u32,
}

fn to_map(img: &image::RgbImage) -> FloatMap {
    FloatMap::from_u8(img.width() as usize, img.height() as usize, 3, img.as_raw())
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn linking(width: u32) -> Result<serde_json::Value> {
    let mut opts = SequenceOptions {
        width,
        height: width * 3 / 4,
        num_frames: 15,
        ..Default::default()
    };
    opts.path.sweep = 28.0;
    let seq = render_sequence(&opts).map_err(anyhow::Error::msg)?;
    let frames: Vec<(&Camera, &Rigid3)> = (0..15)
        .map(|i| seq.frame(i).context("frame"))
        .collect::<Result<_>>()?;
    let points: Vec<Point3<f64>> = seq.gt.points.values().map(|p| p.xyz).collect();
    let views: Vec<PosedView> = frames
        .iter()
        .zip(&seq.images)
        .enumerate()
        .map(|(i, ((c, p), image))| {
            PosedView::new(format!("frame{i}"), (*c).clone(), **p, image.clone())
        })
        .collect();
    let t = Instant::now();
    let pairs = match_sequence_pairs(&views, &points, &PairOptions::default())?;
    let pair_s = t.elapsed().as_secs_f64() / pairs.len() as f64;
    let reference = 7;
    let truth = &seq.depths[reference];
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
        let fill = errs.len() as f64 / n.max(1) as f64;
        curve.push(json!({
            "views": 2 * half + 1,
            "fill": fill,
            "median_relative_error": if errs.is_empty() { f64::NAN } else { median(errs) },
            "linking_seconds": secs,
        }));
    }
    Ok(
        json!({ "width": opts.width, "height": opts.height, "pair_seconds": pair_s, "curve": curve }),
    )
}

/// A forward-motion pair: worst row disagreement and the timing of polar rectification + SGM.
fn forward_pair(width: u32, runs: u32) -> Result<(serde_json::Value, serde_json::Value)> {
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
    let seq = render_sequence(&opts).map_err(anyhow::Error::msg)?;
    let (c0, p0) = seq.frame(0).context("frame 0")?;
    let (c1, p1) = seq.frame(1).context("frame 1")?;
    let rect = rectify_pair(c0, p0, c1, p1, &RectifyOptions::default())?;
    let mut worst = 0.0f64;
    let mut n = 0;
    let truth = &seq.depths[0];
    let inv = p0.inverse();
    for y in (0..truth.height).step_by(4) {
        for x in (0..truth.width).step_by(4) {
            let z = f64::from(truth.get(x, y, 0));
            if z <= 0.0 {
                continue;
            }
            let ray = c0.ray_in_cam(nalgebra::Vector2::new(x as f64, y as f64));
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
    let polar = json!({
        "polar": rect.is_polar(),
        "rectified_size": rect.size(),
        "points": n,
        "max_row_error_px": worst,
    });
    let (l, r) = (to_map(&seq.images[0]), to_map(&seq.images[1]));
    let speed = time_pair(c0, p0, &l, c1, p1, &r, runs)?;
    Ok((polar, speed))
}

/// Median time of polar rectification (maps + resampling) plus SGM over 100 disparities.
fn time_pair(
    c0: &Camera,
    p0: &Rigid3,
    l: &FloatMap,
    c1: &Camera,
    p1: &Rigid3,
    r: &FloatMap,
    runs: u32,
) -> Result<serde_json::Value> {
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
        let rect = rectify_pair(c0, p0, c1, p1, &ropts)?;
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
    Ok(json!({
        "image": [l.width, l.height],
        "rectified_size": size,
        "disparities": 100,
        "rectify_seconds": tr,
        "sgm_seconds": tm,
        "total_seconds": tr + tm,
        "sgm_8_paths_seconds": t8,
    }))
}

pub fn run(a: &BenchDenseArgs, g: &GlobalArgs) -> Result<()> {
    let link = linking(a.width)?;
    let (polar, speed) = forward_pair(a.width, a.runs)?;
    let mut out = json!({
        "linking": link,
        "polar_forward": polar,
        "speed_640": speed,
        "threads": rayon::current_num_threads(),
    });
    if let (Some(model), Some(images)) = (&a.model, &a.images) {
        let rec = handheld_io::colmap::read_reconstruction(model)?;
        let views: Vec<_> = rec.views.values().take(2).collect();
        if views.len() < 2 {
            anyhow::bail!("{}: fewer than two views", model.display());
        }
        let load = |name: &str| -> Result<FloatMap> {
            let p = images.join(name);
            let img = image::open(&p).with_context(|| format!("{}: cannot read", p.display()))?;
            Ok(to_map(&img.to_rgb8()))
        };
        let (l, r) = (load(&views[0].name)?, load(&views[1].name)?);
        let cam = |v: &handheld_core::View| rec.cameras.get(&v.camera_id).context("camera");
        out["speed_large"] = time_pair(
            cam(views[0])?,
            &views[0].cam_from_world,
            &l,
            cam(views[1])?,
            &views[1].cam_from_world,
            &r,
            1,
        )?;
    }
    let human = serde_json::to_string_pretty(&out)?;
    print_result(g, &out, &human);
    Ok(())
}
