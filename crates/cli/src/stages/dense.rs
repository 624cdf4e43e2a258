//! The dense stage (§4): reads the sparse model and the images, calls
//! `handheld_dense::dense_reconstruct` and writes `dense/`:
//! - `depth/<image>.pfm`: z-depth in the camera frame of the sparse model, model units, `NaN`
//!   where nothing was kept (full-resolution maps unless `--dense-max-size` downscaled the view;
//!   `cameras.json` holds the camera each map belongs to);
//! - `variance/<image>.pfm`: the Kalman-fused depth variance (model units²);
//! - `confidence/<image>.pfm`: `1 / (1 + σ/(0.005·z))`, 0.5 where the 1σ error is 0.5% of depth;
//! - `visibility/<image>.pfm`: V, the number of views linked (reference included);
//! - `preview/<image>.depth.png` and `preview/<image>.visibility.png`;
//! - `fused.ply`, the coloured point cloud; `summary.json`.
//!
//! Video workspaces use their key-frames only.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use handheld_core::{FloatMap, ImageId, MetricReconstruction, PosedView};
use handheld_dense::{
    dense_reconstruct, scale_camera, DenseOptions, LinkOptions, PairOptions, StereoMethod,
    StereoOptions,
};
use handheld_io::images::{load_image, ImageIngestOptions};
use handheld_io::workspace::{Fingerprint, Workspace};
use rayon::prelude::*;
use serde_json::json;

use crate::args::{DenseArgs, DenseModelArgs, StereoMethodArg};
use crate::pipeline::{run_stage, Stage, StageOutput, StageReport};
use crate::ui::Bars;

/// The dense stage's options plus the image size limit (an I/O concern of the CLI).
pub struct DenseStageOptions {
    pub dense: DenseOptions,
    pub max_size: u32,
    pub fingerprint: serde_json::Value,
}

pub fn options(a: &DenseArgs) -> Result<DenseStageOptions> {
    if a.link_views < 3 || a.link_views.is_multiple_of(2) {
        anyhow::bail!(
            "--link-views must be odd and at least 3, got {}",
            a.link_views
        );
    }
    if a.min_visibility < 1 || a.min_visibility > a.link_views {
        anyhow::bail!(
            "--min-visibility must be between 1 and --link-views ({}), got {}",
            a.link_views,
            a.min_visibility
        );
    }
    if a.preferred_visibility < 1 || a.preferred_visibility > a.link_views {
        anyhow::bail!(
            "--preferred-visibility must be between 1 and --link-views ({}), got {}",
            a.link_views,
            a.preferred_visibility
        );
    }
    let method = match a.stereo_method {
        StereoMethodArg::Sgm => StereoMethod::Sgm,
        StereoMethodArg::Dp => StereoMethod::Dp,
    };
    let dense = DenseOptions {
        pair: PairOptions {
            stereo: StereoOptions {
                sgm_paths: PairOptions::default().stereo.sgm_paths,
                hole_fill: PairOptions::default().stereo.hole_fill,
                ..StereoOptions::for_method(method)
            },
            ..Default::default()
        },
        link: LinkOptions {
            max_links: (a.link_views - 1) / 2,
            min_visibility: a.min_visibility,
            preferred_visibility: a.preferred_visibility,
            ..Default::default()
        },
        ..Default::default()
    };
    dense.validate()?;
    Ok(DenseStageOptions {
        fingerprint: json!({
            "max_size": a.dense_max_size,
            "method": format!("{method:?}"),
            "link_views": a.link_views,
            "min_visibility": a.min_visibility,
            "preferred_visibility": a.preferred_visibility,
        }),
        dense,
        max_size: a.dense_max_size,
    })
}

/// The views to densify, in sequence order: every registered view, or the key-frames of a video.
fn key_views(ws: &Workspace, rec: &MetricReconstruction) -> Result<Vec<ImageId>> {
    let ids: Vec<ImageId> = rec.views.keys().copied().collect();
    if let Some(tracks) = super::tracks::load_tracks(ws)? {
        let keys: BTreeSet<u32> = tracks.keyframes.iter().map(|k| k.0 as u32 + 1).collect();
        let kept: Vec<ImageId> = ids
            .iter()
            .copied()
            .filter(|i| keys.contains(&i.0))
            .collect();
        if kept.len() >= 2 {
            return Ok(kept);
        }
    }
    Ok(ids)
}

fn load_views(
    paths: &BTreeMap<String, PathBuf>,
    rec: &MetricReconstruction,
    ids: &[ImageId],
    max_size: u32,
) -> Result<Vec<PosedView>> {
    let opts = ImageIngestOptions {
        min_dimension: 1,
        ..Default::default()
    };
    ids.par_iter()
        .map(|id| {
            let view = &rec.views[id];
            let path = paths
                .get(&view.name)
                .with_context(|| format!("{}: no such image among the inputs", view.name))?;
            let camera = rec
                .cameras
                .get(&view.camera_id)
                .with_context(|| format!("{}: camera missing from the sparse model", view.name))?;
            let img = load_image(path, &opts)
                .with_context(|| format!("{}: cannot read the image", path.display()))?
                .image
                .to_rgb8();
            if (img.width(), img.height()) != (camera.width, camera.height) {
                anyhow::bail!(
                    "{}: image is {}x{} but the sparse model says {}x{} (rerun with --force)",
                    path.display(),
                    img.width(),
                    img.height(),
                    camera.width,
                    camera.height
                );
            }
            let longer = img.width().max(img.height());
            let (img, camera) = if max_size > 0 && longer > max_size {
                let s = max_size as f64 / longer as f64;
                let w = (img.width() as f64 * s).round() as u32;
                let h = (img.height() as f64 * s).round() as u32;
                let small =
                    image::imageops::resize(&img, w, h, image::imageops::FilterType::Triangle);
                let c = scale_camera(
                    camera,
                    w as f64 / img.width() as f64,
                    h as f64 / img.height() as f64,
                );
                (small, c)
            } else {
                (img, camera.clone())
            };
            Ok(PosedView::new(
                view.name.clone(),
                camera,
                view.cam_from_world,
                img,
            ))
        })
        .collect()
}

/// A false-colour preview of a map (turbo-like ramp between robust min and max; black = missing).
fn preview(map: &FloatMap, path: &Path) -> Result<()> {
    let mut vals: Vec<f32> = map
        .data
        .iter()
        .copied()
        .filter(|v| v.is_finite() && *v > 0.0)
        .collect();
    vals.sort_by(f32::total_cmp);
    let (lo, hi) = match vals.len() {
        0 => (0.0, 1.0),
        n => (vals[n / 50], vals[n - 1 - n / 50].max(vals[n / 50] + 1e-6)),
    };
    let mut img = image::RgbImage::new(map.width as u32, map.height as u32);
    for (i, p) in img.pixels_mut().enumerate() {
        let v = map.data[i];
        if v.is_finite() && v > 0.0 {
            let t = ((v - lo) / (hi - lo)).clamp(0.0, 1.0);
            p.0 = ramp(t);
        }
    }
    let mut bytes = Vec::new();
    img.write_to(
        &mut std::io::Cursor::new(&mut bytes),
        image::ImageFormat::Png,
    )?;
    handheld_io::atomic::write_bytes_atomic(path, &bytes)?;
    Ok(())
}

/// Blue → cyan → yellow → red.
fn ramp(t: f32) -> [u8; 3] {
    let c = |a: f32, b: f32, s: f32| (a + (b - a) * s).round().clamp(0.0, 255.0) as u8;
    if t < 0.33 {
        let s = t / 0.33;
        [c(40.0, 30.0, s), c(30.0, 200.0, s), c(160.0, 230.0, s)]
    } else if t < 0.66 {
        let s = (t - 0.33) / 0.33;
        [c(30.0, 250.0, s), c(200.0, 220.0, s), c(230.0, 40.0, s)]
    } else {
        let s = (t - 0.66) / 0.34;
        [c(250.0, 200.0, s), c(220.0, 30.0, s), c(40.0, 20.0, s)]
    }
}

pub fn run(
    ws: &Workspace,
    opts: &DenseStageOptions,
    force: bool,
    bars: &Bars,
) -> Result<StageReport> {
    run_stage(
        ws,
        Stage::Dense,
        Fingerprint::new(),
        opts.fingerprint.clone(),
        force,
        |dir| {
            let sparse = ws.root.join(Stage::Sparse.dir_name());
            let rec = handheld_io::colmap::read_reconstruction(&sparse)
                .with_context(|| format!("{}: cannot read the sparse model", sparse.display()))?;
            let ids = key_views(ws, &rec)?;
            let paths = super::load_ingest(ws)?
                .images
                .into_iter()
                .map(|i| (i.info.name, i.info.path))
                .collect();
            densify(&rec, &paths, &ids, opts, dir, bars)
        },
    )
}

/// Densifies the views `ids` of `rec` (images found through `paths`, by view name) into `dir`.
pub fn densify(
    rec: &MetricReconstruction,
    paths: &BTreeMap<String, PathBuf>,
    ids: &[ImageId],
    opts: &DenseStageOptions,
    dir: &Path,
    bars: &Bars,
) -> Result<StageOutput> {
    let views = load_views(paths, rec, ids, opts.max_size)?;
    let points: Vec<_> = rec.points.values().map(|p| p.xyz).collect();
    for sub in ["depth", "variance", "confidence", "visibility", "preview"] {
        std::fs::create_dir_all(dir.join(sub))?;
    }
    let mut per_view = Vec::new();
    let mut outputs = Vec::new();
    let (cloud, summary) = dense_reconstruct(&views, &points, &opts.dense, bars, |r| {
        let v = &r.view;
        let name = &v.name;
        let write = || -> Result<Vec<String>> {
            let written = handheld_io::dense_folder::write_view(dir, v)?;
            for (map, kind) in [(&v.depth, "depth"), (&v.visibility, "visibility")] {
                if let Some(map) = map {
                    preview(map, &dir.join("preview").join(format!("{name}.{kind}.png")))?;
                }
            }
            Ok(written)
        };
        let written = write().map_err(|e| handheld_dense::DenseError::Linking {
            reason: format!("{name}: cannot write the maps: {e:#}"),
        })?;
        outputs.extend(written);
        tracing::info!(
            "dense: {name}: {:.1} % filled in {:.2} s",
            v.fill() * 100.0,
            r.seconds
        );
        per_view.push(json!({
            "image": name,
            "width": v.camera.width,
            "height": v.camera.height,
            "fill": v.fill(),
            "seconds": r.seconds,
        }));
        Ok(())
    })?;
    handheld_io::ply::write_point_cloud(&dir.join("fused.ply"), &cloud, Default::default())?;
    handheld_io::dense_folder::write_cameras(dir, &views)?;
    let s = json!({
        "views": summary.views,
        "pairs_matched": summary.pairs_matched,
        "polar_pairs": summary.polar_pairs,
        "pairs_failed": summary.pairs_failed.iter().map(|f| json!({"pair": [views[f.first].name, views[f.first + 1].name], "reason": f.reason})).collect::<Vec<_>>(),
        "fused_points": summary.fused_points,
        "seconds_pairs": summary.seconds_pairs,
        "seconds_linking": summary.seconds_linking,
        "seconds_per_view": (summary.seconds_pairs + summary.seconds_linking) / summary.views.max(1) as f64,
        "per_view": per_view,
    });
    handheld_io::atomic::write_bytes_atomic(
        &dir.join("summary.json"),
        &serde_json::to_vec_pretty(&s)?,
    )?;
    outputs.extend([
        "fused.ply".into(),
        "cameras.json".into(),
        "summary.json".into(),
    ]);
    let mut short = s.clone();
    short["per_view"] = json!(null);
    Ok(StageOutput {
        outputs,
        summary: short,
    })
}

/// `handheld dense --model M --images I -o OUT`: the dense stage on any COLMAP model.
pub fn run_on_model(a: &DenseModelArgs, bars: &Bars) -> Result<serde_json::Value> {
    let opts = options(&a.dense)?;
    let rec = handheld_io::colmap::read_reconstruction(&a.model)
        .with_context(|| format!("{}: cannot read the COLMAP model", a.model.display()))?;
    let paths: BTreeMap<String, PathBuf> = rec
        .views
        .values()
        .map(|v| (v.name.clone(), a.images.join(&v.name)))
        .collect();
    let ids: Vec<ImageId> = rec.views.keys().copied().collect();
    std::fs::create_dir_all(&a.output)
        .with_context(|| format!("{}: cannot create", a.output.display()))?;
    let out = densify(&rec, &paths, &ids, &opts, &a.output, bars)?;
    Ok(out.summary)
}
