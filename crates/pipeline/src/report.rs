//! Gathering a workspace's report (see `handheld-report`): whatever stages exist are read
//! through their typed summaries and files; what is missing is said, never an error.

use std::collections::BTreeMap;
use std::path::Path;

use handheld_core::MetricReconstruction;
use handheld_mesh::{simplify, SimplifyOptions};
use handheld_report::{ImageEntry, ReportInput, ReportSummary, ReportWarning, ViewerCamera};
use nalgebra::Vector3;
use rayon::prelude::*;

use crate::error::Result;
use crate::files::{
    stage, thumbnail_file_name, MODEL_GLB, PAIRS_JSON, PREVIEW_DIR, SUMMARY_JSON, THUMB, THUMBS_DIR,
};
use crate::manifest::Workspace;
use crate::stages::dense::DenseStageSummary;
use crate::stages::sparse::SparseSummary;
use crate::warning::{code, Warning};

/// Faces of the mesh shown in the viewer, and the atlas's longer side.
pub const VIEWER_FACES: usize = 100_000;
pub const VIEWER_ATLAS: u32 = 2048;

/// A stage's warning for the report: the stage, the message and what to do; the details folded.
fn report_warning(stage: &str, w: &Warning) -> ReportWarning {
    ReportWarning {
        code: w.code.clone(),
        text: format!("{stage}: {}", w.message),
        advice: w.advice.clone(),
        details: w.details.clone(),
    }
}

/// Gathers the report of `ws` and writes it (`report.html`, `report/`). `stages` are the graph's
/// stages in run order ([`crate::Pipeline::names`]): those without a manifest are "not run yet".
pub fn write_workspace_report(ws: &Workspace, stages: &[&str]) -> Result<ReportSummary> {
    let mut input = ReportInput {
        title: format!("Handheld report: {}", ws.root.display()),
        ..Default::default()
    };
    for s in stages {
        match ws.manifest(s) {
            Some(m) => {
                for w in &m.warnings {
                    input.warnings.push(report_warning(s, w));
                }
            }
            None => input.missing.push(s.to_string()),
        }
    }
    let timings = ws.timings();
    input.stage_times = stages
        .iter()
        .filter_map(|s| {
            timings
                .get(*s)
                .and_then(|v| v.as_f64())
                .map(|t| (s.to_string(), t))
        })
        .collect();
    input.verdict.total_seconds = input.stage_times.iter().map(|t| t.1).sum();
    // Images.
    let ingest = ws.read_ingest().ok();
    let names: Vec<(String, std::path::PathBuf)> = ingest
        .as_ref()
        .map(|i| {
            i.images
                .iter()
                .map(|im| (im.info.name.clone(), im.info.path.clone()))
                .collect()
        })
        .unwrap_or_default();
    input.verdict.images_in = names.len();
    // Thumbnails for at most 400 images (a long video keeps every k-th).
    let step = names.len().div_ceil(400).max(1);
    let opts = handheld_io::images::ImageIngestOptions {
        min_dimension: 1,
        ..Default::default()
    };
    input.images = names
        .par_iter()
        .enumerate()
        .map(|(k, (name, path))| ImageEntry {
            name: name.clone(),
            thumb: (k % step == 0)
                .then(|| {
                    // The features stage's thumbnail when there is one, else the image itself.
                    let made = ws
                        .path(stage::FEATURES, THUMBS_DIR)
                        .join(thumbnail_file_name(k));
                    image::open(&made).ok().map(|t| t.to_rgb8()).or_else(|| {
                        handheld_io::images::load_image(path, &opts)
                            .ok()
                            .map(|im| im.image.thumbnail(THUMB, THUMB).to_rgb8())
                    })
                })
                .flatten(),
            ..Default::default()
        })
        .collect();
    let index: BTreeMap<String, usize> = names
        .iter()
        .enumerate()
        .map(|(k, n)| (n.0.clone(), k))
        .collect();
    // Sparse.
    let rec: Option<MetricReconstruction> = ws
        .manifest(stage::SPARSE)
        .and_then(|_| ws.read_sparse_model().ok());
    if let Some(rec) = &rec {
        sparse_part(ws, rec, &index, &mut input);
    }
    // Pairs.
    if let Ok(pairs) = ws.read_pairs() {
        let cells = pairs
            .iter()
            .filter(|p| p.inliers > 0)
            .map(|p| (p.i, p.j, p.inliers as f64))
            .collect();
        input.pairs = Some((names.len(), cells));
    }
    let _ = PAIRS_JSON;
    dense_part(ws, &index, &mut input);
    input.mesh = viewer_mesh(ws);
    input.renders = renders(ws);
    let out = handheld_report::render_report(&input)
        .map_err(|e| crate::error::PipelineError::workspace(&ws.root, e.to_string()))?;
    for (rel, bytes) in &out.files {
        let path = ws.root.join(rel);
        if let Some(parent) = path.parent() {
            std::fs::create_dir_all(parent).map_err(|e| handheld_io::IoError::io(parent, e))?;
        }
        handheld_io::atomic::write_bytes_atomic(&path, bytes)?;
    }
    let mut summary = out.summary;
    summary.html = ws.root.join(&summary.html);
    Ok(summary)
}

/// "the same photo as X" / "nearly repeats X" under each duplicate shot of the sparse summary.
fn duplicate_notes(
    full: &serde_json::Value,
    index: &BTreeMap<String, usize>,
    input: &mut ReportInput,
) {
    for d in full["duplicates"].as_array().into_iter().flatten() {
        let (Some(image), Some(of)) = (d["image"].as_str(), d["of"].as_str()) else {
            continue;
        };
        let Some(&k) = index.get(image) else {
            continue;
        };
        input.images[k].note = Some(if d["identical"] == true {
            format!("the same photo as {of}")
        } else {
            format!(
                "nearly repeats {of} (moved {:.1} px)",
                d["shift_px"].as_f64().unwrap_or(0.0)
            )
        });
    }
}

fn sparse_part(
    ws: &Workspace,
    rec: &MetricReconstruction,
    index: &BTreeMap<String, usize>,
    input: &mut ReportInput,
) {
    let summary: Option<SparseSummary> = ws.summary(stage::SPARSE).ok().flatten();
    input.verdict.registered = Some(rec.views.len());
    if let Some(s) = &summary {
        input.verdict.reprojection_px = Some(s.mean_reprojection_error_px);
        for u in &s.unregistered {
            if let Some(&k) = index.get(&u.image) {
                input.images[k].registered = Some(false);
                input.images[k].reason = Some(u.reason.clone());
            }
        }
        if let Some(d) = &s.self_calibration_degenerate {
            input.warnings.push(report_warning(
                stage::SPARSE,
                &Warning::new(
                    code::FOCAL_UNDETERMINED,
                    "the camera's motion does not fix the calibration by itself (critical motion)",
                )
                .advice("give the calibration with --intrinsics FX,FY,CX,CY, or add views that rotate the camera")
                .details(d.clone()),
            ));
        }
    }
    // Focal length and σ from the full summary.
    let full: Option<serde_json::Value> = std::fs::read(ws.path(stage::SPARSE, SUMMARY_JSON))
        .ok()
        .and_then(|b| serde_json::from_slice(&b).ok());
    if let Some(full) = &full {
        duplicate_notes(full, index, input);
        input.verdict.metric_frame = full["self_calibration"]["candidates"]
            .as_array()
            .and_then(|c| c.iter().find(|c| c["accepted"] == true))
            .and_then(|c| c["source"].as_str())
            .map(str::to_string);
    }
    if let Some(cam) = rec.cameras.values().next() {
        let i = &cam.intrinsics;
        let model = if i.k2 != 0.0 {
            "pinhole + radial k1, k2"
        } else if i.k1 != 0.0 {
            "pinhole + radial k1"
        } else {
            "pinhole"
        };
        input.verdict.camera_model = Some(format!(
            "{model}, {} camera{}",
            rec.cameras.len(),
            if rec.cameras.len() == 1 { "" } else { "s" }
        ));
        input.verdict.focal_px = Some(i.f);
        input.verdict.focal_sigma_px = full
            .as_ref()
            .and_then(|f| f["uncertainty"]["intrinsics_sigma"].as_array()?.first()?["f"].as_f64());
    }
    for v in rec.views.values() {
        if let Some(&k) = index.get(&v.name) {
            input.images[k].registered = Some(true);
            input.images[k].observations = Some(
                v.observations
                    .iter()
                    .filter(|o| o.point_id.is_some())
                    .count(),
            );
        }
        let Some(cam) = rec.cameras.get(&v.camera_id) else {
            continue;
        };
        for o in &v.observations {
            if let Some(p) = o.point_id.and_then(|id| rec.points.get(&id)) {
                if let Some(px) = cam.project(&v.cam_from_world, &p.xyz) {
                    input.reprojection_errors.push((px - o.xy).norm());
                }
            }
        }
    }
    for im in &mut input.images {
        if im.registered.is_none() {
            im.registered = Some(false);
            im.reason.get_or_insert_with(|| "not in the model".into());
        }
    }
    input.track_lengths = rec
        .points
        .values()
        .map(|p| p.track.elements.len())
        .collect();
    input.points = rec
        .points
        .values()
        .map(|p| ([p.xyz.x as f32, p.xyz.y as f32, p.xyz.z as f32], p.color))
        .collect();
    let mut up = Vector3::zeros();
    for v in rec.views.values() {
        let Some(cam) = rec.cameras.get(&v.camera_id) else {
            continue;
        };
        let r = v.cam_from_world.rotation.inverse().to_rotation_matrix();
        up += r.matrix() * Vector3::new(0.0, -1.0, 0.0);
        let k = index.get(&v.name).copied().unwrap_or(0);
        let posed = handheld_core::PosedCamera::new(cam.clone(), v.cam_from_world);
        input
            .cameras
            .push((k, ViewerCamera::from_posed(&v.name, &posed)));
    }
    input.cameras.sort_by_key(|c| c.0);
    let mut up = up.try_normalize(1e-9).unwrap_or(Vector3::z());
    // Cameras that span a plane (a ring, an arc at one height): its normal is the up direction
    // (photos taken sideways would tilt the cameras' own up); the sign follows the cameras'.
    if input.cameras.len() >= 3 {
        let cs: Vec<Vector3<f64>> = input.cameras.iter().map(|c| Vector3::from(c.1.c)).collect();
        let mean = cs.iter().sum::<Vector3<f64>>() / cs.len() as f64;
        let cov = cs.iter().fold(nalgebra::Matrix3::zeros(), |a, c| {
            a + (c - mean) * (c - mean).transpose()
        });
        let eig = cov.symmetric_eigen();
        let mut order = [0usize, 1, 2];
        order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
        if eig.eigenvalues[order[1]] > 0.05 * eig.eigenvalues[order[2]] {
            let n: Vector3<f64> = eig.eigenvectors.column(order[0]).into_owned();
            up = if n.dot(&up) < 0.0 { -n } else { n };
        }
    }
    input.up = [up.x, up.y, up.z];
}

/// Whether a path is inside the workspace (the report links only to such files).
pub fn inside(ws: &Path, p: &Path) -> bool {
    p.starts_with(ws)
}

/// The dense stage's depth previews and fill, per image.
fn dense_part(ws: &Workspace, index: &BTreeMap<String, usize>, input: &mut ReportInput) {
    if let Ok(Some(d)) = ws.summary::<DenseStageSummary>(stage::DENSE) {
        let full: Option<DenseStageSummary> = std::fs::read(ws.path(stage::DENSE, SUMMARY_JSON))
            .ok()
            .and_then(|b| serde_json::from_slice(&b).ok());
        let per_view = full.and_then(|f| f.per_view).unwrap_or_default();
        for v in per_view {
            if let Some(&k) = index.get(&v.image) {
                let preview = format!("{}/{PREVIEW_DIR}/{}.depth.png", stage::DENSE, v.image);
                if ws.root.join(&preview).exists() {
                    input.images[k].depth_preview = Some(preview);
                }
                input.images[k].fill = Some(v.fill);
            }
        }
        let _ = d;
    }
}

/// The mesh for the viewer: decimated to [`VIEWER_FACES`], its atlas reduced to [`VIEWER_ATLAS`].
fn viewer_mesh(ws: &Workspace) -> Option<(handheld_core::TriMesh, Option<image::RgbImage>)> {
    let glb = ws.path(stage::MESH, MODEL_GLB);
    if ws.manifest(stage::MESH).is_some() && glb.exists() {
        if let Ok((mesh, tex)) = handheld_io::glb::read_glb(&glb) {
            let mesh = if mesh.faces.len() > VIEWER_FACES {
                simplify(
                    &mesh,
                    &SimplifyOptions {
                        target_faces: VIEWER_FACES,
                        max_relative_error: 1.0,
                        lock_border: false,
                    },
                )
                .map(|m| m.0)
                .unwrap_or(mesh)
            } else {
                mesh
            };
            let tex = tex.map(|t| {
                if t.width().max(t.height()) > VIEWER_ATLAS {
                    image::DynamicImage::ImageRgb8(t)
                        .resize(
                            VIEWER_ATLAS,
                            VIEWER_ATLAS,
                            image::imageops::FilterType::Triangle,
                        )
                        .to_rgb8()
                } else {
                    t
                }
            });
            return Some((mesh, tex));
        }
    }
    None
}

/// The renders beside the workspace's stages: held-out view, fly-through, augmented video, and the
/// novel-view benchmark's images.
fn renders(ws: &Workspace) -> Vec<(String, String)> {
    let mut renders = Vec::new();
    for (label, path) in [
        (
            "Held-out view: the model | the photo | the difference",
            "mesh/holdout.png",
        ),
        ("Image-based fly-through (§5.2)", "render/flight.mp4"),
        ("Augmented video (§5.3)", "augment/augmented.mp4"),
    ] {
        if ws.root.join(path).exists() {
            renders.push((label.to_string(), path.to_string()));
        }
    }
    if let Ok(rd) = std::fs::read_dir(ws.root.join("bench").join("render-every-8").join("images")) {
        let mut v: Vec<String> = rd
            .flatten()
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|n| n.ends_with(".png"))
            .collect();
        v.sort();
        for n in v {
            renders.push((
                format!("Novel-view hold-out {n}: photo | each method"),
                format!("bench/render-every-8/images/{n}"),
            ));
        }
    }
    renders
}
