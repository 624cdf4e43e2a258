//! End to end: a real mp4 encoded by ffmpeg from testkit frames goes through `handheld ingest`, and
//! `handheld demo` writes its sequence, ground truth and workspace.

mod common;
use common::*;

use std::io::Write;
use std::process::{Command, Stdio};

#[test]
#[cfg_attr(not(has_ffmpeg), ignore = "needs ffmpeg (missing)")]
fn video_ingest_of_a_real_mp4() {
    need_ffmpeg();
    let opts = handheld_testkit::render::SequenceOptions {
        width: 160,
        height: 120,
        num_frames: 12,
        samples_per_axis: 2,
        ..Default::default()
    };
    let seq = handheld_testkit::render::render_sequence(&opts).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let video = dir.path().join("walk.mp4");
    let mut ff = Command::new("ffmpeg")
        .args([
            "-v", "error", "-y", "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", "160x120", "-r",
            "25", "-i", "-",
        ])
        .args(["-c:v", "libx264", "-crf", "12", "-pix_fmt", "yuv420p"])
        .arg(&video)
        .stdin(Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdin = ff.stdin.take().unwrap();
    for img in &seq.images {
        stdin.write_all(img.as_raw()).unwrap();
    }
    drop(stdin);
    assert!(ff.wait().unwrap().success());

    let ws = dir.path().join("ws");
    let o = handheld(&[
        "ingest",
        video.to_str().unwrap(),
        "-o",
        ws.to_str().unwrap(),
        "--stride",
        "3",
        "--json",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    assert_eq!(v["stages"][0]["summary"]["kind"], "video");
    assert_eq!(v["stages"][0]["summary"]["images"], 4);

    let listing: serde_json::Value =
        serde_json::from_slice(&std::fs::read(ws.join("ingest/images.json")).unwrap()).unwrap();
    let images = listing["images"].as_array().unwrap();
    let indices: Vec<u64> = images
        .iter()
        .map(|i| i["frame"]["index"].as_u64().unwrap())
        .collect();
    assert_eq!(indices, vec![0, 3, 6, 9]);
    // Each stored frame matches the synthetic frame it was encoded from (lossy codec: small mean error).
    for (img, &k) in images.iter().zip(&indices) {
        let stored = image::open(img["info"]["path"].as_str().unwrap())
            .unwrap()
            .to_rgb8();
        assert_eq!(stored.dimensions(), (160, 120));
        let truth = &seq.images[k as usize];
        let mad: f64 = stored
            .as_raw()
            .iter()
            .zip(truth.as_raw())
            .map(|(a, b)| (*a as f64 - *b as f64).abs())
            .sum::<f64>()
            / truth.as_raw().len() as f64;
        assert!(mad < 6.0, "frame {k}: mean abs difference {mad}");
        let t = img["frame"]["time_s"].as_f64().unwrap();
        assert!((t - k as f64 / 25.0).abs() < 1e-9);
    }
}

#[test]
fn demo_writes_sequence_ground_truth_and_workspace() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo");
    let args = [
        "demo",
        "-o",
        out.to_str().unwrap(),
        "--frames",
        "20",
        "--width",
        "320",
        "--height",
        "240",
        "--json",
    ];
    let o = handheld(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    assert_eq!(v["frames"], 20);
    assert_eq!(v["stages"][0]["stage"], "ingest");
    assert_eq!(v["stages"][0]["summary"]["images"], 20);
    // The cameras, uncalibrated, against the exact ones.
    let s = &v["accuracy"]["sparse"];
    assert_eq!(s["registered"], 20, "{s}");
    assert!(s["focal_error_pct"].as_f64().unwrap() < 2.0, "{s}");
    assert!(
        s["relative_rotation_error_deg_median"].as_f64().unwrap() < 1.0,
        "{s}"
    );
    // Matching is scored against the exact relative poses.
    let m = &v["accuracy"]["matching"];
    assert!(m["verified_pairs"].as_u64().unwrap() >= 1, "{m}");
    assert!(
        m["inlier_epipolar_error_median_px"].as_f64().unwrap() < 0.5,
        "{m}"
    );
    // The depth maps against the exact rendered depth (in metres, through the similarity that
    // aligns the camera centres): most pixels with a true surface have a depth, and a correct
    // depth is within 1 % of the truth at the median.
    let d = &v["accuracy"]["dense"];
    assert_eq!(d["depth_maps"], 20, "{d}");
    assert!(d["fill"].as_f64().expect("dense scored") > 0.8, "{d}");
    assert!(d["relative_error_median"].as_f64().unwrap() < 0.01, "{d}");
    // The fused mesh against the exact scene mesh: 90 % of it within 2 % of the scene size of the
    // true surface, and 95 % of the seen true surface within 1 % of the mesh. (At this half
    // resolution a pixel covers twice the surface it does at the default 640×480, where the
    // README's 0.37 % was measured, and the 90th percentile lies on the triangles that bridge depth
    // edges: 1 % is the bound at 640×480, 2 % here; a wrong focal length or scale is far beyond.)
    let m = &v["accuracy"]["mesh"];
    println!("accuracy: {}", v["accuracy"]);
    assert!(m["faces"].as_u64().expect("mesh scored") > 0, "{m}");
    assert!(m["accuracy_90_pct_of_scene"].as_f64().unwrap() < 2.0, "{m}");
    assert!(
        m["completeness_within_1pct"].as_f64().unwrap() > 0.95,
        "{m}"
    );
    for f in [
        "images/frame_0000.png",
        "ground_truth/sparse/cameras.txt",
        "ground_truth/sparse/images.bin",
        "ground_truth/mesh.ply",
        "ground_truth/depth/frame_0003.pfm",
        "workspace/ingest/manifest.json",
        "workspace/dense/fused.ply",
        "workspace/dense/depth/frame_0003.png.pfm",
        "workspace/mesh/model.glb",
        "workspace/mesh/model.obj",
        "workspace/mesh/model.png",
    ] {
        assert!(out.join(f).exists(), "{f} missing");
    }
    // The written ground truth reads back and is self-consistent.
    let gt = handheld_io::colmap::read_reconstruction(&out.join("ground_truth/sparse")).unwrap();
    assert_eq!(gt.views.len(), 20);
    assert!(gt.mean_reprojection_error() < 1e-6);
    let depth = handheld_io::pfm::read_pfm(&out.join("ground_truth/depth/frame_0000.pfm")).unwrap();
    assert_eq!((depth.width, depth.height), (320, 240));
    assert!(depth.fill_ratio() > 0.5);
    // A second run is up to date.
    let o = handheld(&args);
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    assert_eq!(v["stages"][0]["status"], "up_to_date");
}

/// The demo's orbit at 320×240 with `frames` frames into `out`, with one more flag.
fn small_orbit(
    out: &std::path::Path,
    frames: &str,
    seed: &str,
    flag: &str,
) -> std::process::Output {
    handheld(&[
        "demo",
        "-o",
        out.to_str().unwrap(),
        "--frames",
        frames,
        "--seed",
        seed,
        "--width",
        "320",
        "--height",
        "240",
        flag,
    ])
}

/// Two frames of the demo's orbit at 320×240: no pair can start the projective model, and two
/// views do not determine the calibration, so the calibrated candidate builds none either (a
/// 2-view model would report the focal length it started from: 27 % off, silently). The run must
/// fail with one error that names the step and says why, and leave no sparse model that looks
/// complete. (The library test `a_collapsed_metric_frame_fails_the_run_and_leaves_no_model`
/// covers the failure of every metric frame, with its advice to give `--intrinsics`.)
#[test]
fn a_demo_too_short_to_reconstruct_fails_and_writes_no_model() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo");
    let o = small_orbit(&out, "2", "1", "--quiet");
    assert!(!o.status.success());
    let err = stderr(&o);
    assert!(err.contains("structure from motion"), "{err}");
    assert!(err.contains("no model could be built"), "{err}");
    assert!(
        err.contains("two views do not determine the calibration"),
        "{err}"
    );
    assert_eq!(
        err.lines().filter(|l| l.starts_with("error")).count(),
        1,
        "{err}"
    );
    assert!(!out.join("workspace/sparse/images.bin").exists());
    assert!(!out.join("workspace/sparse/manifest.json").exists());
}

/// Four frames of the same orbit lie too far apart for any pair to start the projective model
/// (issue #18: the run failed). The calibrated incremental candidate builds them: every frame,
/// the focal length within 2 %, the relative rotations within 0.5°.
#[test]
fn four_frames_too_far_apart_for_the_projective_start_are_right() {
    demo_is_right(&["--frames", "4", "--width", "320", "--height", "240"]);
}

/// Eight frames of an orbit: a short arc, but enough for a sound model. Its adjustments drifted
/// along the scale gauge until every camera and point lay within 10⁻⁹ of one spot, and texturing
/// then found no face any view sees (`metric_ba::keep_scale`). Scene seed 2: without
/// `keep_scale` its cameras end within 2·10⁻⁵ of each other. (Seed 1's 8-frame arc is on the
/// edge of self-calibration: since guided matching rejects matches its seeds' F cannot check,
/// no metric frame survives there, and the run fails with the advice to give `--intrinsics`.)
#[test]
fn a_short_demo_keeps_a_usable_scale() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo");
    let o = small_orbit(&out, "8", "2", "--json");
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    let sparse = &v["accuracy"]["sparse"];
    assert!(
        sparse["focal_error_pct"].as_f64().unwrap() < 5.0,
        "{sparse}"
    );
    assert!(
        sparse["center_error_rel_extent_median"].as_f64().unwrap() < 0.02,
        "{sparse}"
    );
    let rec = handheld_io::colmap::read_reconstruction(&out.join("workspace/sparse")).unwrap();
    let c: Vec<_> = rec.views.values().map(|v| v.center().coords).collect();
    let spread = c.iter().map(|p| (p - c[0]).norm()).fold(0.0f64, f64::max);
    assert!(
        spread > 1e-3,
        "camera centres within {spread} of each other"
    );
}

/// Twelve frames of the same orbit: the focal length and the cameras are right (issue #18: no
/// wrong model reported as a success). The 12-frame orbit used to keep a focal length 34 % off
/// with no warning, its relative rotations 9° wrong, while another frame that explained the
/// images better had been rejected for what its adjustment filtered on the way; the focal profile
/// now also walks from that frame to the right one. A warning does not excuse a wrong model.
#[test]
fn a_twelve_frame_demo_finds_the_focal_length() {
    demo_is_right(&["--frames", "12", "--width", "320", "--height", "240"]);
}

/// The demo's sideways walk at 640×480 (optical axes within 8° of each other: nearly critical)
/// used to keep a focal length 45 % off, its relative rotations 2.3° wrong, with no warning: its
/// only candidate frame was sound and the camera turned just enough to skip the translation
/// probes. Its focal profile fell away from it, and now leads to the right frame.
#[test]
fn the_sideways_walk_finds_the_focal_length() {
    demo_is_right(&["--path", "walk"]);
}

/// A phone held upright (portrait 360×640, 68° across the long side, k1 = 0.06) orbiting an object
/// mounted on a patterned wall that fills most of every frame (issue #37): every frame, the focal
/// length within 2 % and the rotations within 0.2°. Before the twin test (forty-first session,
/// `matching/twins.rs`) the stratified upgrade failed here (every candidate's metric adjustment
/// removed 52–100 % of its observations, even with the exact calibration given) and the
/// calibrated incremental candidate built the model; without the matches between look-alike
/// corners of the wall the self-calibrated frame holds (0.1 % of its observations removed).
#[test]
fn a_phone_orbit_before_a_wall_with_distortion_is_right() {
    phone_is_right(&["--k1", "0.06"]);
}

/// The same wall without distortion: a homography explains all but 2 of the 66 pairs (the object
/// on the wall is a minority of the matches), so no pair could start the projective model and the
/// run failed; the calibrated candidate starts from a planar pair's F.
#[test]
fn a_phone_orbit_before_a_wall_where_no_pair_is_general_is_right() {
    phone_is_right(&["--k1", "0"]);
}

/// The demo's wall scene, portrait, 12 frames, up to the sparse model, with `extra` arguments:
/// every frame registered, the focal length within 2 %, the rotations within 0.2° at the median.
fn phone_is_right(extra: &[&str]) {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo");
    let mut args = vec![
        "demo",
        "-o",
        out.to_str().unwrap(),
        "--json",
        "--scene",
        "wall",
        "--width",
        "360",
        "--height",
        "640",
        "--fov",
        "68",
        "--frames",
        "12",
        "--until",
        "sparse",
    ];
    args.extend_from_slice(extra);
    let o = handheld(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    let s = &v["accuracy"]["sparse"];
    println!("{extra:?}: {s}");
    assert_eq!(s["registered"], 12, "{extra:?}: {s}");
    let focal_error = s["focal_error_pct"].as_f64().expect("sparse scored");
    assert!(
        focal_error < 2.0,
        "{extra:?}: focal length {focal_error:.2} % off: {s}"
    );
    let rot = s["rotation_error_deg_median"].as_f64().unwrap();
    assert!(
        rot <= 0.2,
        "{extra:?}: rotations {rot:.3}° off at the median: {s}"
    );
    // Every candidate that ran says what it cost.
    let summary: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(out.join("workspace/sparse/summary.json")).unwrap(),
    )
    .unwrap();
    let candidates = summary["self_calibration"]["candidates"]
        .as_array()
        .unwrap();
    assert!(!candidates.is_empty());
    for c in candidates.iter().filter(|c| c["tried"] == true) {
        assert!(c["seconds"].as_f64().is_some_and(|t| t > 0.0), "{c}");
    }
}

/// Runs the demo with `extra` arguments up to the sparse model and checks it against the exact
/// cameras: every frame registered, the focal length within 2 % of the truth and the relative
/// rotations within 0.5° at the median (a wrong focal length tilts them by degrees), whether or
/// not the run warned that the images do not determine the focal length.
fn demo_is_right(extra: &[&str]) {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo");
    let mut args = vec![
        "demo",
        "-o",
        out.to_str().unwrap(),
        "--json",
        "--until",
        "sparse",
    ];
    args.extend_from_slice(extra);
    let o = handheld(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    let s = &v["accuracy"]["sparse"];
    println!("{extra:?}: {s}");
    assert_eq!(s["registered"], v["frames"], "{extra:?}: {s}");
    let focal_error = s["focal_error_pct"].as_f64().expect("sparse scored");
    assert!(
        focal_error < 2.0,
        "{extra:?}: focal length {focal_error:.2} % off: {s}"
    );
    let rot = s["relative_rotation_error_deg_median"].as_f64().unwrap();
    assert!(
        rot < 0.5,
        "{extra:?}: relative rotations {rot:.2}° off at the median: {s}"
    );
}

/// Video mode end to end (§3.1, Table 2): the demo's frames encoded as H.264, KLT tracks, GRIC
/// key-frames, and a metric pose for every frame and the camcorder's aspect ratio, scored against the
/// exact cameras.
#[test]
#[cfg_attr(not(has_ffmpeg), ignore = "needs ffmpeg (missing)")]
fn demo_video_gives_every_frame_a_pose() {
    need_ffmpeg();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo");
    let o = handheld(&[
        "demo",
        "--video",
        "-o",
        out.to_str().unwrap(),
        "--frames",
        "30",
        "--width",
        "320",
        "--height",
        "240",
        "--aspect-ratio",
        "1.09",
        "--augment",
        "--json",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    let features = &v["stages"][1]["summary"];
    assert_eq!(features["tracking"], "klt", "{features}");
    let keys = features["keyframes"].as_u64().unwrap();
    assert!((3..30).contains(&keys), "{keys} key-frames of 30");
    let s = &v["accuracy"]["sparse"];
    assert_eq!(s["registered"], 30, "{s}");
    assert!(s["focal_error_pct"].as_f64().unwrap() < 2.0, "{s}");
    // Video: a constant aspect ratio is estimated (§3.4, the camcorder's 1.09).
    assert!((s["aspect"].as_f64().unwrap() - 1.09).abs() < 0.01, "{s}");
    assert!(
        s["relative_rotation_error_deg_median"].as_f64().unwrap() < 0.2,
        "{s}"
    );
    assert!(
        s["center_error_rel_extent_median"].as_f64().unwrap() < 0.01,
        "{s}"
    );
    assert!(out.join("workspace-video/features/tracks.json").exists());
    // §5.3: the shipped box, placed automatically and drawn through our cameras, lands where the
    // exact cameras put it (after the similarity that aligns the models). This small camcorder
    // sequence (320×240, aspect 1.09, 30 frames) measured median 0.38 px, max 0.51 px; the
    // default `demo --video --augment` (640×480) 0.12 / 0.18 px. Without the radial distortion
    // it is further off.
    let a = &v["accuracy"]["augment"];
    let with = &a["with_distortion"];
    assert_eq!(a["frames"], 30, "{a}");
    assert!(with["median_px"].as_f64().unwrap() < 0.5, "{a}");
    assert!(with["max_px"].as_f64().unwrap() < 1.0, "{a}");
    assert!(with["jitter_above_gt_px"].as_f64().unwrap() < 0.05, "{a}");
    assert!(
        a["without_distortion"]["max_px"].as_f64().unwrap() > with["max_px"].as_f64().unwrap(),
        "{a}"
    );
    let aug = out.join("workspace-video/augment");
    for f in [
        "augmented.mp4",
        "camera.glb",
        "camera.chan",
        "placement.json",
    ] {
        assert!(aug.join(f).exists(), "{f}");
    }
    let chan = std::fs::read_to_string(aug.join("camera.chan")).unwrap();
    assert_eq!(chan.lines().count(), 30);
}
