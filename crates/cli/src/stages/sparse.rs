//! The sparse stage (§3, Table 2 and §3.4): reads the features and verified pairs, runs
//! uncalibrated structure and motion (`handheld_sfm::reconstruct`), colours the points from the
//! images, and writes `sparse/` — the largest model as a COLMAP text + binary model, `points.ply`
//! and `summary.json`; further models (a broken sequence) under `sparse/models/<k>/`.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::{Context, Result};
use handheld_core::{ImageId, MetricReconstruction, PointCloud, Progress};
use handheld_features::refine::{
    refine_track_keypoints, KeypointFrame, KeypointRefinementOptions, PairMatches,
    RefinementSummary,
};
use handheld_features::GrayImage;
use handheld_io::database::Database;
use handheld_io::features_file::read_features;
use handheld_io::images::{load_image, ImageIngestOptions};
use handheld_io::ingest::InputKind;
use handheld_io::workspace::{Fingerprint, Workspace};
use handheld_robust::TwoViewConfiguration;
use handheld_sfm::{reconstruct, KnownIntrinsics, SfmImage, SfmInput, SfmOptions, SfmPair};
use nalgebra::Vector2;
use rayon::prelude::*;

use crate::args::InputArgs;
use crate::pipeline::{run_stage, Stage, StageOutput, StageReport};
use crate::stages::features::feature_file_name;
use crate::ui::Bars;

/// Options of the sparse stage: keypoint refinement (photos), then SfM.
#[derive(Clone, Debug, serde::Serialize)]
pub struct SparseStageOptions {
    pub sfm: SfmOptions,
    /// Multi-view keypoint refinement before SfM; `None` keeps the detected positions. Video (KLT
    /// tracks, already registered to their first appearance) never uses it.
    pub refine_keypoints: Option<KeypointRefinementOptions>,
}

pub fn options(a: &InputArgs) -> Result<SparseStageOptions> {
    let distortion = match a.distortion {
        crate::args::DistortionArg::None => handheld_sfm::Distortion::None,
        crate::args::DistortionArg::K1 => handheld_sfm::Distortion::K1,
        crate::args::DistortionArg::K1k2 => handheld_sfm::Distortion::K1K2,
    };
    let o = SfmOptions {
        seed: a.seed,
        distortion,
        refine_principal_point: !a.fixed_principal_point,
        scale_weighted_observations: a.scale_weights,
        known_intrinsics: a.intrinsics.as_deref().map(parse_intrinsics).transpose()?,
        principal_point_prior: a.principal_point_prior,
        estimate_aspect: match a.aspect {
            crate::args::AspectArg::Auto => None,
            crate::args::AspectArg::Fixed => Some(false),
            crate::args::AspectArg::Free => Some(true),
        },
        ..Default::default()
    };
    o.validate().map_err(anyhow::Error::msg)?;
    Ok(SparseStageOptions {
        sfm: o,
        refine_keypoints: a.refine_keypoints.then(KeypointRefinementOptions::default),
    })
}

/// `--intrinsics FX,FY,CX,CY` (COLMAP convention) → Handheld's pixel convention.
fn parse_intrinsics(s: &str) -> Result<KnownIntrinsics> {
    let v: Vec<f64> = s
        .split(',')
        .map(|t| t.trim().parse::<f64>())
        .collect::<std::result::Result<_, _>>()
        .map_err(|e| anyhow::anyhow!("--intrinsics {s:?}: {e} (expected FX,FY,CX,CY in pixels)"))?;
    let [fx, fy, cx, cy] = v[..] else {
        anyhow::bail!(
            "--intrinsics {s:?}: expected 4 numbers FX,FY,CX,CY in pixels, got {}",
            v.len()
        );
    };
    Ok(KnownIntrinsics {
        fx,
        fy,
        cx: cx - handheld_core::PIXEL_CENTER_OFFSET_COLMAP,
        cy: cy - handheld_core::PIXEL_CENTER_OFFSET_COLMAP,
    })
}

/// Registers the keypoints of every track to the track's reference (photos only; see
/// [`handheld_features::refine`]) and replaces the input's keypoints by the refined positions.
fn refine_input(
    ws: &Workspace,
    input: &mut SfmInput,
    opts: &KeypointRefinementOptions,
    bars: &Bars,
) -> Result<RefinementSummary> {
    opts.validate()
        .map_err(|e| anyhow::anyhow!("keypoint refinement: {e}"))?;
    let ingest = super::load_ingest(ws)?;
    let fdir = ws.root.join(Stage::Features.dir_name());
    let frames: Vec<Vec<KeypointFrame>> = (0..input.images.len())
        .into_par_iter()
        .map(|k| {
            let f = read_features(&fdir.join(feature_file_name(k)))
                .context("reading features (rerun the features stage with --force)")?;
            Ok(f.keypoints
                .iter()
                .map(|p| KeypointFrame {
                    x: p[0],
                    y: p[1],
                    scale: p[2],
                    orientation: p[3],
                })
                .collect())
        })
        .collect::<Result<_>>()?;
    let pairs: Vec<PairMatches> = input
        .pairs
        .iter()
        .map(|p| PairMatches {
            a: p.a,
            b: p.b,
            matches: &p.matches,
        })
        .collect();
    let load_opts = ImageIngestOptions {
        min_dimension: 1,
        ..Default::default()
    };
    let load = |k: usize| -> Result<GrayImage> {
        let path = &ingest
            .images
            .get(k)
            .ok_or_else(|| anyhow::anyhow!("image {k} is not in the ingest list"))?
            .info
            .path;
        let img = load_image(path, &load_opts)?;
        Ok(GrayImage::from_dynamic(&img.image))
    };
    bars.start("refine keypoints", 2 * input.images.len() as u64);
    let (refined, summary) = refine_track_keypoints(&frames, &pairs, &load, opts, &|| bars.inc(1))?;
    bars.finish();
    for (im, pts) in input.images.iter_mut().zip(refined) {
        if pts.len() == im.keypoints.len() {
            im.keypoints = pts
                .iter()
                .map(|p| Vector2::new(f64::from(p[0]), f64::from(p[1])))
                .collect();
        }
    }
    Ok(summary)
}

/// Builds the SfM input from the features and matches stages.
pub fn load_input(ws: &Workspace) -> Result<SfmInput> {
    let ingest = super::load_ingest(ws)?;
    let fdir = ws.root.join(Stage::Features.dir_name());
    let tracks = super::tracks::load_tracks(ws)?;
    if let Some(t) = &tracks {
        if t.num_frames() != ingest.images.len() {
            anyhow::bail!(
                "{}: {} frames, but ingest has {} (rerun features with --force)",
                fdir.join(super::tracks::TRACKS_FILE).display(),
                t.num_frames(),
                ingest.images.len()
            );
        }
    }
    let images: Vec<SfmImage> = ingest
        .images
        .par_iter()
        .enumerate()
        .map(|(k, img)| {
            let f = read_features(&fdir.join(feature_file_name(k)))
                .context("reading features (rerun the features stage with --force)")?;
            Ok(SfmImage {
                id: ImageId(k as u32 + 1),
                name: img.info.name.clone(),
                width: img.info.width,
                height: img.info.height,
                keypoints: f
                    .keypoints
                    .iter()
                    .map(|p| Vector2::new(p[0] as f64, p[1] as f64))
                    .collect(),
                keypoint_scales: f.keypoints.iter().map(|p| p[2]).collect(),
                camera_key: format!(
                    "{}|{}x{}",
                    img.info.exif.camera_key(),
                    img.info.width,
                    img.info.height
                ),
                focal_prior_px: img.info.focal_prior_px,
                frame: img.frame,
                track_ids: tracks
                    .as_ref()
                    .map(|t| t.ids[k].clone())
                    .unwrap_or_default(),
                descriptors: f
                    .descriptors
                    .iter()
                    .map(|v| (512.0 * v).round().clamp(0.0, 255.0) as u8)
                    .collect(),
                descriptor_dim: f.dim,
            })
        })
        .collect::<Result<_>>()?;
    let mdir = ws.root.join(Stage::Matches.dir_name());
    let summaries: Vec<handheld_features::verify::PairSummary> =
        serde_json::from_slice(&std::fs::read(mdir.join("pairs.json")).with_context(|| {
            format!(
                "{}: cannot read (rerun matches with --force)",
                mdir.join("pairs.json").display()
            )
        })?)
        .with_context(|| {
            format!(
                "{}: corrupt (rerun matches with --force)",
                mdir.join("pairs.json").display()
            )
        })?;
    let db = Database::open(&mdir.join("database.db"))?;
    let ids: Vec<u32> = db.images()?.into_iter().map(|(id, _, _)| id).collect();
    if ids.len() != images.len() {
        anyhow::bail!(
            "{}: {} images, but ingest has {} (rerun matches with --force)",
            mdir.join("database.db").display(),
            ids.len(),
            images.len()
        );
    }
    let mut pairs = Vec::new();
    for s in summaries {
        if s.configuration == TwoViewConfiguration::TooFewInliers
            || s.i >= ids.len()
            || s.j >= ids.len()
        {
            continue;
        }
        let Some(g) = db.read_two_view_geometry(ids[s.i], ids[s.j])? else {
            continue;
        };
        pairs.push(SfmPair {
            a: s.i,
            b: s.j,
            matches: g.inliers,
            f: g.f,
            configuration: s.configuration,
            view_distance_px: s.view_distance_px,
        });
    }
    Ok(SfmInput {
        images,
        pairs,
        video: ingest.kind == InputKind::Video,
    })
}

/// Colours every point from the first image that sees it.
fn colorize(ws: &Workspace, rec: &mut MetricReconstruction) -> Result<()> {
    let ingest = super::load_ingest(ws)?;
    let paths: BTreeMap<String, std::path::PathBuf> = ingest
        .images
        .iter()
        .map(|i| (i.info.name.clone(), i.info.path.clone()))
        .collect();
    let opts = ImageIngestOptions {
        min_dimension: 1,
        ..Default::default()
    };
    let views: Vec<(ImageId, String)> =
        rec.views.values().map(|v| (v.id, v.name.clone())).collect();
    let imgs: BTreeMap<ImageId, image::RgbImage> = views
        .par_iter()
        .filter_map(|(id, name)| {
            let p = paths.get(name)?;
            load_image(p, &opts).ok().map(|l| (*id, l.image.to_rgb8()))
        })
        .collect();
    for pt in rec.points.values_mut() {
        let Some(el) = pt.track.elements.first() else {
            continue;
        };
        let (Some(img), Some(v)) = (imgs.get(&el.image_id), rec.views.get(&el.image_id)) else {
            continue;
        };
        let xy = v.observations[el.point2d_idx as usize].xy;
        let (x, y) = (
            xy.x.round().clamp(0.0, img.width() as f64 - 1.0) as u32,
            xy.y.round().clamp(0.0, img.height() as f64 - 1.0) as u32,
        );
        pt.color = img.get_pixel(x, y).0;
    }
    Ok(())
}

fn write_model(dir: &Path, rec: &MetricReconstruction, summary: &serde_json::Value) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create", dir.display()))?;
    handheld_io::colmap::write_reconstruction(dir, rec, true, true)?;
    let cloud = PointCloud {
        positions: rec
            .points
            .values()
            .map(|p| [p.xyz.x as f32, p.xyz.y as f32, p.xyz.z as f32])
            .collect(),
        colors: rec.points.values().map(|p| p.color).collect(),
        normals: Vec::new(),
    };
    handheld_io::ply::write_point_cloud(&dir.join("points.ply"), &cloud, Default::default())?;
    handheld_io::atomic::write_bytes_atomic(
        &dir.join("summary.json"),
        &serde_json::to_vec_pretty(summary)?,
    )?;
    Ok(())
}

pub fn run(
    ws: &Workspace,
    stage_opts: &SparseStageOptions,
    force: bool,
    bars: &Bars,
) -> Result<StageReport> {
    let opts = &stage_opts.sfm;
    run_stage(
        ws,
        Stage::Sparse,
        Fingerprint::new(),
        serde_json::to_value(stage_opts)?,
        force,
        |dir| {
            let mut input = load_input(ws)?;
            let refinement = match &stage_opts.refine_keypoints {
                Some(r) if !input.video => {
                    let t0 = std::time::Instant::now();
                    let s = refine_input(ws, &mut input, r, bars)?;
                    tracing::info!(
                        "keypoint refinement: {} of {} keypoints moved (median {:.2} px) in {:.1} s",
                        s.moved,
                        s.attempted,
                        s.median_shift_px,
                        t0.elapsed().as_secs_f64()
                    );
                    Some((s, t0.elapsed().as_secs_f64()))
                }
                _ => None,
            };
            let mut result = reconstruct(&input, opts, bars).context("structure from motion")?;
            for m in result.models.iter_mut() {
                colorize(ws, &mut m.reconstruction)?;
            }
            let mut outputs = vec![
                "cameras.txt".into(),
                "images.txt".into(),
                "points3D.txt".into(),
                "cameras.bin".into(),
                "images.bin".into(),
                "points3D.bin".into(),
                "points.ply".into(),
                "summary.json".into(),
            ];
            let models_json: Vec<serde_json::Value> = result
                .models
                .iter()
                .map(|m| serde_json::to_value(&m.summary))
                .collect::<std::result::Result<_, _>>()?;
            let unregistered: Vec<serde_json::Value> = result
                .unregistered
                .iter()
                .map(|(n, why)| serde_json::json!({"image": n, "reason": why}))
                .collect();
            for (k, m) in result.models.iter().enumerate() {
                let mut s = serde_json::to_value(&m.summary)?;
                if let Some((r, secs)) = &refinement {
                    s["keypoint_refinement"] = serde_json::to_value(r)?;
                    s["keypoint_refinement"]["seconds"] = serde_json::json!(secs);
                }
                if k == 0 {
                    s["unregistered"] = serde_json::Value::Array(unregistered.clone());
                    s["other_models"] = serde_json::Value::Array(models_json[1..].to_vec());
                    write_model(dir, &m.reconstruction, &s)?;
                } else {
                    let sub = dir.join("models").join(k.to_string());
                    write_model(&sub, &m.reconstruction, &s)?;
                    outputs.push(format!("models/{k}"));
                }
            }
            for (n, why) in &result.unregistered {
                tracing::warn!("{n}: not registered ({why})");
            }
            if result.models.len() > 1 {
                tracing::warn!("the images form {} separate models; the largest is in sparse/, the others in sparse/models/", result.models.len());
            }
            let best = &result.models[0].summary;
            // Under critical motion (§3.4) the focal length comes from the priors and the focal
            // hypotheses, not from the data: say so, since a wrong one gives a consistent-looking
            // but distorted model (dinoSparseRing, where the BA leaves f uncertain by 4.5 %). A
            // focal that the final adjustment determines to 1 % or better is only noted.
            if let (Some(why), None) = (&best.self_calibration.degenerate, &opts.known_intrinsics) {
                let rel: Vec<Option<f64>> = best
                    .groups
                    .iter()
                    .map(|g| {
                        best.uncertainty
                            .as_ref()
                            .and_then(|u| u.relative_focal_sigma(g.camera_id, g.f))
                    })
                    .collect();
                let f: Vec<String> = best
                    .groups
                    .iter()
                    .zip(&rel)
                    .map(|(g, r)| match r {
                        Some(r) => format!("{:.0} px ± {:.2} %", g.f, 100.0 * r),
                        None => format!("{:.0} px", g.f),
                    })
                    .collect();
                if rel.iter().all(|r| r.is_some_and(|r| r <= 0.01)) {
                    tracing::info!(
                        "self-calibration was degenerate ({why}); the focal length ({}) was chosen among the priors' hypotheses, and the bundle adjustment determines it well",
                        f.join(", ")
                    );
                } else {
                    tracing::warn!(
                        "self-calibration was degenerate ({why}); the focal length ({}) was chosen among the priors' hypotheses and may be wrong: check it, or give the calibration with --intrinsics",
                        f.join(", ")
                    );
                }
            }
            Ok(StageOutput {
                outputs,
                summary: serde_json::json!({
                    "models": result.models.len(),
                    "registered": best.registered,
                    "total_images": best.total_images,
                    "points": best.points,
                    "mean_reprojection_error_px": best.mean_reprojection_error_px,
                    "focal_px": best.groups.iter().map(|g| g.f).collect::<Vec<_>>(),
                    "self_calibration_degenerate": best.self_calibration.degenerate,
                    "unregistered": unregistered,
                }),
            })
        },
    )
}
