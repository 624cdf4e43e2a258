//! `handheld demo`: render a synthetic hand-held sequence with exact ground truth (testkit), write it
//! with its ground truth in the field's formats, then run every pipeline stage that exists on it and
//! print a summary with the accuracy against ground truth.

use std::path::Path;
use std::time::Instant;

use anyhow::{Context, Result};
use handheld_io::atomic::write_bytes_atomic;
use handheld_io::ingest::write_png;
use handheld_testkit::path::PathOptions;
use handheld_testkit::render::{render_sequence, SequenceOptions, SyntheticSequence};
use serde_json::json;

use crate::args::{DemoArgs, GlobalArgs, PathKind};
use crate::ui::{print_result, Bars};

fn sequence_options(a: &DemoArgs) -> SequenceOptions {
    let n = a.frames as usize;
    let path = match a.path {
        PathKind::Orbit => PathOptions::orbit(n),
        PathKind::Walk => PathOptions::walk_through(n),
        PathKind::Forward => PathOptions::forward(n),
    };
    let path = PathOptions {
        seed: a.seed,
        ..path
    };
    SequenceOptions {
        seed: a.seed,
        width: a.width,
        height: a.height,
        num_frames: n,
        path,
        aspect: a.aspect_ratio,
        ..Default::default()
    }
}

/// Writes the rendered images and all ground truth; returns the image folder.
fn write_sequence(dir: &Path, seq: &SyntheticSequence, bars: &Bars) -> Result<()> {
    use handheld_core::Progress;
    let images = dir.join("images");
    let gt = dir.join("ground_truth");
    bars.start("writing frames", seq.images.len() as u64);
    for (view, (img, depth)) in seq
        .gt
        .views
        .values()
        .zip(seq.images.iter().zip(&seq.depths))
    {
        write_png(&images.join(&view.name), img)?;
        let stem = Path::new(&view.name)
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        handheld_io::pfm::write_pfm(&gt.join("depth").join(format!("{stem}.pfm")), depth)?;
        bars.inc(1);
    }
    bars.finish();
    handheld_io::colmap::write_reconstruction(&gt.join("sparse"), &seq.gt, true, true)?;
    handheld_io::ply::write_mesh(
        &gt.join("mesh.ply"),
        &seq.mesh,
        handheld_io::ply::PlyFormat::BinaryLittleEndian,
    )?;
    Ok(())
}

/// Ground-truth views keyed by the name the workspace gives them: the rendered file name for the
/// photo folder, `frame_<index>.png` (the ingest stage's name for decoded frames) for the video.
pub fn gt_by_name(
    gt: &handheld_core::MetricReconstruction,
    video: bool,
) -> std::collections::HashMap<String, &handheld_core::View> {
    let mut views: Vec<&handheld_core::View> = gt.views.values().collect();
    views.sort_by(|a, b| a.name.cmp(&b.name));
    views
        .into_iter()
        .enumerate()
        .map(|(k, v)| {
            let name = if video {
                format!("frame_{k:06}.png")
            } else {
                v.name.clone()
            };
            (name, v)
        })
        .collect()
}

/// Encodes the rendered frames as an H.264 video (`ffmpeg`), as a camcorder or phone would.
fn encode_video(out: &Path) -> Result<std::path::PathBuf> {
    let video = out.join("video.mp4");
    let pattern = out.join("images").join("frame_%04d.png");
    handheld_io::video::encode_h264(&pattern, &video, &Default::default())
        .context("encoding the demo video (or run the demo without --video)")?;
    Ok(video)
}

/// Accuracy of the stages that exist so far against the ground truth: for every pair verified as
/// general, the epipolar distance of its inliers under the exact relative pose (keypoints undistorted
/// with the GT intrinsics, distance scaled back to pixels).
/// Camera accuracy of the sparse model against the exact cameras: registered views, rotation and
/// centre error after a similarity fit of the centres (as `eval_sfm.py`), focal error, and the focal
/// error of self-calibration before metric BA.
fn sparse_accuracy(out: &Path, workspace: &Path, video: bool) -> Result<serde_json::Value> {
    let sparse = workspace.join("sparse");
    let summary: serde_json::Value =
        serde_json::from_slice(&std::fs::read(sparse.join("summary.json"))?)?;
    let aligned = crate::demo_dense::Aligned::load(out, workspace, video)?;
    let (gt, est, sim) = (&aligned.gt, &aligned.est, aligned.sim);
    let pairs = aligned.pairs();
    let dst: Vec<_> = pairs.iter().map(|p| p.1.center()).collect();
    let mut rot: Vec<f64> = Vec::new();
    let mut cen: Vec<f64> = Vec::new();
    for (e, g) in &pairs {
        let pose = sim.transform_pose(&e.cam_from_world);
        rot.push(
            (pose.rotation * g.cam_from_world.rotation.inverse())
                .angle()
                .to_degrees(),
        );
        cen.push((handheld_core::pose::center_of(&pose) - g.center()).norm());
    }
    let med = |v: &mut Vec<f64>| {
        v.sort_by(|a, b| a.total_cmp(b));
        v[v.len() / 2]
    };
    let rot_max = rot.iter().fold(0.0f64, |a, b| a.max(*b));
    // Relative rotations between all pairs (gauge-free, the basis of the pose AUC).
    let mut rel: Vec<f64> = Vec::new();
    for (k, (ea, ga)) in pairs.iter().enumerate() {
        for (eb, gb) in &pairs[k + 1..] {
            let re = ea.cam_from_world.rotation * eb.cam_from_world.rotation.inverse();
            let rg = ga.cam_from_world.rotation * gb.cam_from_world.rotation.inverse();
            rel.push((re * rg.inverse()).angle().to_degrees());
        }
    }
    let rel_max = rel.iter().fold(0.0f64, |a, b| a.max(*b));
    let f_true = gt
        .cameras
        .values()
        .next()
        .map(|c| c.intrinsics.f)
        .unwrap_or(f64::NAN);
    let f_est = est
        .cameras
        .values()
        .next()
        .map(|c| c.intrinsics.f)
        .unwrap_or(f64::NAN);
    let f_selfcal = summary["self_calibration"]["focal_before_ba_px"]
        .as_object()
        .and_then(|m| m.values().next())
        .and_then(|v| v.as_f64())
        .unwrap_or(f64::NAN);
    let extent = dst
        .iter()
        .map(|c| (c - dst[0]).norm())
        .fold(0.0f64, f64::max);
    Ok(json!({
        "registered": pairs.len(),
        "total": gt.views.len(),
        "rotation_error_deg_median": med(&mut rot),
        "rotation_error_deg_max": rot_max,
        "relative_rotation_error_deg_median": med(&mut rel),
        "relative_rotation_error_deg_max": rel_max,
        "center_error_median_m": med(&mut cen),
        "center_error_rel_extent_median": med(&mut cen) / extent.max(1e-12),
        "focal_error_pct": 100.0 * (f_est / f_true - 1.0).abs(),
        "self_calibration_focal_error_pct": 100.0 * (f_selfcal / f_true - 1.0).abs(),
        "aspect": est.cameras.values().next().map(|c| c.intrinsics.aspect),
        "aspect_true": gt.cameras.values().next().map(|c| c.intrinsics.aspect),
        "k1": est.cameras.values().next().map(|c| c.intrinsics.k1),
        "k1_true": gt.cameras.values().next().map(|c| c.intrinsics.k1),
        "mean_reprojection_error_px": summary["mean_reprojection_error_px"],
    }))
}

fn matching_accuracy(out: &Path, workspace: &Path, video: bool) -> Result<serde_json::Value> {
    let gt = handheld_io::colmap::read_reconstruction(&out.join("ground_truth").join("sparse"))?;
    let db = handheld_io::database::Database::open(&workspace.join("matches").join("database.db"))?;
    let images = db.images()?;
    let views = gt_by_name(&gt, video);
    let mut errors = Vec::new();
    let mut verified = 0;
    let mut keypoints = std::collections::HashMap::new();
    for (ia, (a, name_a, _)) in images.iter().enumerate() {
        for (b, name_b, _) in &images[ia + 1..] {
            let Some(g) = db.read_two_view_geometry(*a, *b)? else {
                continue;
            };
            if g.config != handheld_io::database::TwoViewConfig::Uncalibrated as i64 {
                continue;
            }
            let (Some(va), Some(vb)) = (views.get(name_a.as_str()), views.get(name_b.as_str()))
            else {
                continue;
            };
            verified += 1;
            let (ca, cb) = (&gt.cameras[&va.camera_id], &gt.cameras[&vb.camera_id]);
            let rel = vb.cam_from_world * va.cam_from_world.inverse();
            let e = handheld_geometry::skew(&rel.translation.vector)
                * rel.rotation.to_rotation_matrix().matrix();
            for id in [*a, *b] {
                if let std::collections::hash_map::Entry::Vacant(slot) = keypoints.entry(id) {
                    slot.insert(db.read_keypoints(id)?);
                }
            }
            let (ka, kb) = (&keypoints[a], &keypoints[b]);
            for &(i, j) in &g.inliers {
                let (pa, pb) = (ka[i as usize], kb[j as usize]);
                let na = ca
                    .intrinsics
                    .pixel_to_normalized(nalgebra::Vector2::new(pa[0] as f64, pa[1] as f64));
                let nb = cb
                    .intrinsics
                    .pixel_to_normalized(nalgebra::Vector2::new(pb[0] as f64, pb[1] as f64));
                let l = e * nalgebra::Vector3::new(na.x, na.y, 1.0);
                let d = (l.x * nb.x + l.y * nb.y + l.z).abs() / (l.x * l.x + l.y * l.y).sqrt();
                errors.push(d * cb.intrinsics.f);
            }
        }
    }
    errors.sort_by(|x, y| x.total_cmp(y));
    let within = errors.iter().filter(|&&d| d <= 1.0).count();
    Ok(json!({
        "verified_pairs": verified,
        "inliers": errors.len(),
        "inlier_epipolar_error_median_px": errors.get(errors.len() / 2),
        "inliers_within_1px_of_true_epipolar_line": within as f64 / errors.len().max(1) as f64,
    }))
}

pub fn run(a: &DemoArgs, g: &GlobalArgs, bars: &Bars) -> Result<()> {
    let opts = sequence_options(a);
    opts.validate().map_err(anyhow::Error::msg)?;
    std::fs::create_dir_all(&a.output)
        .with_context(|| format!("{}: cannot create the demo folder", a.output.display()))?;
    let stamp_path = a.output.join("ground_truth").join("demo.json");
    let stamp = json!({ "version": handheld_pipeline::HANDHELD_VERSION, "frames": a.frames, "width": a.width,
        "height": a.height, "seed": a.seed, "path": format!("{:?}", a.path), "aspect": a.aspect_ratio });
    let fresh = !a.force
        && std::fs::read_to_string(&stamp_path)
            .ok()
            .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
            == Some(stamp.clone());

    let t0 = Instant::now();
    let mut gt_summary = json!(null);
    if fresh {
        tracing::info!("synthetic sequence in {} is up to date", a.output.display());
    } else {
        use handheld_core::Progress;
        tracing::info!(
            "rendering {} frames of {}×{} ({:?} path, seed {})",
            a.frames,
            a.width,
            a.height,
            a.path,
            a.seed
        );
        bars.start("rendering", 0);
        let seq = render_sequence(&opts).map_err(anyhow::Error::msg)?;
        bars.finish();
        write_sequence(&a.output, &seq, bars)?;
        write_bytes_atomic(
            &stamp_path,
            serde_json::to_string_pretty(&stamp)?.as_bytes(),
        )?;
        gt_summary = json!({
            "views": seq.gt.views.len(),
            "landmarks": seq.gt.points.len(),
            "mesh_faces": seq.mesh.faces.len(),
            "scene_extent_m": seq.scene.extent(),
        });
    }
    let render_s = t0.elapsed().as_secs_f64();

    let (input_path, workspace) = if a.video {
        let v = a.output.join("video.mp4");
        let v = if fresh && v.exists() {
            v
        } else {
            encode_video(&a.output)?
        };
        (v, a.output.join("workspace-video"))
    } else {
        (a.output.join("images"), a.output.join("workspace"))
    };
    let mut options = handheld_pipeline::PipelineOptions::default();
    options.sparse.sfm.seed = a.seed;
    let reports =
        handheld_pipeline::reconstruct(&input_path, &workspace, &options, None, a.force, bars)?;
    let matching = matching_accuracy(&a.output, &workspace, a.video)
        .unwrap_or_else(|e| json!({ "error": format!("{e:#}") }));
    let sparse = sparse_accuracy(&a.output, &workspace, a.video)
        .unwrap_or_else(|e| json!({ "error": format!("{e:#}") }));
    let dense = crate::demo_dense::dense_accuracy(&a.output, &workspace, a.video)
        .unwrap_or_else(|e| json!({ "error": format!("{e:#}") }));
    let mesh = crate::demo_dense::mesh_accuracy(&a.output, &workspace, a.video)
        .unwrap_or_else(|e| json!({ "error": format!("{e:#}") }));
    let summary = json!({
        "demo": a.output,
        "frames": a.frames,
        "width": a.width,
        "height": a.height,
        "seed": a.seed,
        "input": if a.video { "video (H.264)" } else { "photos" },
        "path": format!("{:?}", a.path).to_lowercase(),
        "render_seconds": render_s,
        "ground_truth": gt_summary,
        "stages": reports,
        "accuracy": { "matching": matching.clone(), "sparse": sparse.clone(), "dense": dense.clone(), "mesh": mesh.clone() },
        "accuracy_note": "matching is scored against the exact relative poses; cameras against the exact cameras after a similarity fit of the centres; the input was uncalibrated (no focal given)",
    });
    let human = format!(
        "demo: {} frames {}×{} in {}\n  rendering + ground truth: {:.2} s\n  stages: {}\n  matching accuracy: {}\n  camera accuracy (uncalibrated): {}\n  depth accuracy: {}\n  mesh accuracy: {}",
        a.frames,
        a.width,
        a.height,
        a.output.display(),
        render_s,
        reports.iter().map(|r| format!("{} ({}, {:.2} s)", r.stage, r.status, r.seconds)).collect::<Vec<_>>().join(", "),
        matching,
        sparse,
        dense,
        mesh
    );
    print_result(g, &summary, &human);
    Ok(())
}
