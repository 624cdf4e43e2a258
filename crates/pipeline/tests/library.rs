//! The pipeline driven through its library API, without the CLI binary: a seeded synthetic
//! hand-held sequence with exact ground truth goes up to `sparse` only, then a stage registered by
//! the test that reads only `sparse` runs on that workspace (no dense or mesh folder exists), then
//! the whole standard graph resumes to the textured mesh. Accuracy is scored against the ground
//! truth.

use std::path::Path;

use handheld_core::{NoProgress, Rigid3};
use handheld_pipeline::files::{stage, write_json};
use handheld_pipeline::render::{render_view, RenderMethod, ViewSpec};
use handheld_pipeline::{
    Pipeline, PipelineOptions, Produced, Stage, StageContext, StageStatus, Workspace,
};
use handheld_testkit::render::{render_sequence, SequenceOptions, SyntheticSequence};
use serde::{Deserialize, Serialize};

fn scene(dir: &Path) -> SyntheticSequence {
    let mut opts = SequenceOptions {
        width: 320,
        height: 240,
        num_frames: 8,
        ..Default::default()
    };
    opts.path.sweep = 35.0;
    let seq = render_sequence(&opts).expect("render");
    let images = dir.join("images");
    for (view, img) in seq.gt.views.values().zip(&seq.images) {
        handheld_io::ingest::write_png(&images.join(&view.name), img).expect("write frame");
    }
    seq
}

/// A stage that needs only the sparse model: the camera centres as a table (what an exporter for
/// other tools would read).
struct CameraCentres;

#[derive(Serialize, Deserialize)]
struct CentresSummary {
    cameras: usize,
}

impl Stage for CameraCentres {
    type Options = ();
    type Summary = CentresSummary;

    const NAME: &'static str = "camera_centres";
    const READS: &'static [&'static str] = &[stage::SPARSE];
    const ABOUT: &'static str = "camera centres of the sparse model";

    fn options(&self) -> &() {
        &()
    }

    fn run(
        &self,
        ctx: &StageContext,
        dir: &Path,
    ) -> handheld_pipeline::Result<Produced<CentresSummary>> {
        let rec = ctx.ws.read_sparse_model()?;
        let centres: Vec<(String, [f64; 3])> = rec
            .views
            .values()
            .map(|v| (v.name.clone(), v.center().coords.into()))
            .collect();
        write_json(&dir.join("centres.json"), &centres)?;
        Ok(Produced::new(
            vec!["centres.json".into()],
            CentresSummary {
                cameras: centres.len(),
            },
        ))
    }
}

/// Largest error, in degrees, of the relative rotation between consecutive registered views.
fn relative_rotation_error_deg(est: &[(String, Rigid3)], seq: &SyntheticSequence) -> f64 {
    let gt = |name: &str| {
        seq.gt
            .views
            .values()
            .find(|v| v.name == name)
            .map(|v| v.cam_from_world)
            .expect("a ground-truth view of that name")
    };
    est.windows(2)
        .map(|w| {
            let (a, b) = (&w[0], &w[1]);
            let re = a.1.rotation * b.1.rotation.inverse();
            let (ga, gb) = (gt(&a.0), gt(&b.0));
            let rg = ga.rotation * gb.rotation.inverse();
            (re * rg.inverse()).angle().to_degrees()
        })
        .fold(0.0, f64::max)
}

#[test]
fn the_stage_graph_runs_through_the_library() {
    let dir = tempfile::tempdir().expect("temp dir");
    let seq = scene(dir.path());
    let input = dir.path().join("images");
    let ws_path = dir.path().join("ws");
    let mut options = PipelineOptions::default();
    options
        .mesh
        .fusion
        .simplify
        .as_mut()
        .expect("simplification")
        .target_faces = 20_000;
    options.mesh.hold_out = Some("frame_0003.png".into());

    // 1. Up to sparse: only what sparse needs runs.
    let reports = handheld_pipeline::reconstruct(
        &input,
        &ws_path,
        &options,
        Some(stage::SPARSE),
        false,
        &NoProgress,
    )
    .expect("the sparse model");
    let ran: Vec<&str> = reports.iter().map(|r| r.stage.as_str()).collect();
    assert_eq!(ran, ["ingest", "features", "matches", "sparse"]);
    assert!(!ws_path.join(stage::DENSE).exists() && !ws_path.join(stage::MESH).exists());
    let ws = Workspace::open(&ws_path).expect("workspace");
    let sparse: handheld_pipeline::stages::sparse::SparseSummary = ws
        .summary(stage::SPARSE)
        .expect("summary parses")
        .expect("sparse ran");
    assert_eq!(sparse.registered, seq.images.len());
    check_sparse_model(&ws, &ws_path, &seq);
    // Rendering before the dense stage falls back to the fixed plane, and says so.
    let plane_only =
        handheld_pipeline::render::load_scene(&ws, &[], 1600).expect("scene without depth");
    assert!(
        plane_only
            .warnings
            .iter()
            .any(|w| w.contains("fixed plane")),
        "{:?}",
        plane_only.warnings
    );
    assert_eq!(
        plane_only.effective(RenderMethod::Subdivided),
        RenderMethod::Plane
    );

    // 2. A stage registered from outside, reading only sparse, runs on this workspace.
    let mut pipeline = Pipeline::standard(&input, &options).expect("graph");
    pipeline.register(CameraCentres).expect("registration");
    assert_eq!(
        pipeline.plan("camera_centres").expect("plan"),
        ["ingest", "features", "matches", "sparse", "camera_centres"]
    );
    let reports = pipeline
        .run(&ws, Some("camera_centres"), false, &NoProgress)
        .expect("custom stage");
    let status: Vec<StageStatus> = reports.iter().map(|r| r.status).collect();
    assert_eq!(
        status,
        [
            StageStatus::UpToDate,
            StageStatus::UpToDate,
            StageStatus::UpToDate,
            StageStatus::UpToDate,
            StageStatus::Ran
        ]
    );
    assert_eq!(reports[4].summary["cameras"], seq.images.len());
    assert!(!ws_path.join(stage::DENSE).exists() && !ws_path.join(stage::MESH).exists());

    // 3. The whole graph resumes: dense and mesh run, the rest is up to date.
    let reports = pipeline
        .run(&ws, None, false, &NoProgress)
        .expect("whole graph");
    let ran: Vec<(&str, StageStatus)> = reports
        .iter()
        .map(|r| (r.stage.as_str(), r.status))
        .collect();
    for (name, status) in &ran {
        let expect = match *name {
            "dense" | "mesh" | "render" => StageStatus::Ran,
            _ => StageStatus::UpToDate,
        };
        assert_eq!(*status, expect, "{name}");
    }
    assert_eq!(ran.len(), 8);
    let dense: handheld_pipeline::stages::dense::DenseStageSummary =
        ws.summary(stage::DENSE).expect("parses").expect("ran");
    assert_eq!(dense.views, seq.images.len());
    let mesh: handheld_pipeline::stages::mesh::MeshStageSummary =
        ws.summary(stage::MESH).expect("parses").expect("ran");
    let hold = mesh.hold_out.expect("hold-out comparison");
    assert!(hold.covered_fraction > 0.5, "{}", hold.covered_fraction);
    assert!(
        hold.mean_absolute_difference < 25.0,
        "{}",
        hold.mean_absolute_difference
    );
    assert!(ws_path.join("mesh/model.glb").exists());
    let flight: handheld_pipeline::render::FlightSummary =
        ws.summary(stage::RENDER).expect("parses").expect("ran");
    assert_eq!(flight.frames, 48);
    assert!(flight.mean_covered_fraction > 0.9, "{flight:?}");
    assert!(ws_path.join("render/flight.png").exists());

    // 3b. One held-out view, image-based, against its photo; a pose file that is not one.
    check_held_out_view(&ws, dir.path(), &seq);

    // 4. Changed options redo exactly the stages below the change.
    let mut finer = options.clone();
    finer.mesh.view_meshes = false;
    let reports =
        handheld_pipeline::reconstruct(&input, &ws_path, &finer, None, false, &NoProgress)
            .expect("rerun");
    let ran: Vec<&str> = reports
        .iter()
        .filter(|r| r.status == StageStatus::Ran)
        .map(|r| r.stage.as_str())
        .collect();
    assert_eq!(ran, ["mesh", "render"]);
}

#[test]
fn out_of_range_options_are_named() {
    let mut options = PipelineOptions::default();
    options.dense.dense.link.min_visibility = 40;
    let err = Pipeline::standard(Path::new("nowhere"), &options)
        .err()
        .expect("rejected");
    assert_eq!(err.invalid_option(), Some("--min-visibility"), "{err}");
    let mut options = PipelineOptions::default();
    options.matches.verification.matching.ratio = 1.5;
    let err = Pipeline::standard(Path::new("nowhere"), &options)
        .err()
        .expect("rejected");
    assert_eq!(err.invalid_option(), Some("--ratio"), "{err}");
    let err = Pipeline::standard(Path::new("nowhere"), &PipelineOptions::default())
        .expect("graph")
        .plan("paint")
        .expect_err("no such stage");
    assert!(err.to_string().contains("ingest, features"), "{err}");
}

#[test]
fn a_second_round_matches_the_images_the_first_left_weakly_verified() {
    // One most-similar image each: the first round verifies at most a couple of pairs per image,
    // fewer than the window, so the weakest images are matched with every other one in the second
    // round, up to as many pairs as the first round had, or one image's row.
    let dir = tempfile::tempdir().expect("temp dir");
    let seq = scene(dir.path());
    let n = seq.images.len();
    let mut options = PipelineOptions::default();
    options.matches.pairs = handheld_pipeline::policy::PairMode::Retrieval;
    options.matches.retrieval.neighbours = 1;
    let run = |options: &PipelineOptions, ws: &str| {
        let ws_path = dir.path().join(ws);
        handheld_pipeline::reconstruct(
            &dir.path().join("images"),
            &ws_path,
            options,
            Some(stage::MATCHES),
            false,
            &NoProgress,
        )
        .expect("matches");
        let s: handheld_pipeline::stages::matches::MatchesSummary = Workspace::open(&ws_path)
            .expect("workspace")
            .summary(stage::MATCHES)
            .expect("summary parses")
            .expect("matches ran");
        s
    };
    let with = run(&options, "with");
    assert!(with.pairs <= n * (n - 1) / 2, "{with:?}");
    assert!(
        with.second_round_pairs > 0 && with.second_round_verified > 0,
        "{with:?}"
    );
    options.matches.second_round = false;
    let without = run(&options, "without");
    assert_eq!(without.second_round_pairs, 0);
    assert_eq!(without.pairs + with.second_round_pairs, with.pairs);
    assert!(
        with.second_round_pairs <= without.pairs.max(n - 1),
        "{with:?} {without:?}"
    );
    // The sweep's frames all overlap: the second round verifies pairs the first never tried.
    let verified = |s: &handheld_pipeline::stages::matches::MatchesSummary| {
        s.verified_general + s.verified_planar_or_rotation
    };
    assert!(verified(&with) > verified(&without), "{with:?} {without:?}");
}

#[test]
fn options_round_trip_through_json() {
    let o = PipelineOptions::default();
    let text = serde_json::to_string(&o).expect("serialise");
    let back: PipelineOptions = serde_json::from_str(&text).expect("deserialise");
    assert_eq!(serde_json::to_string(&back).expect("again"), text);
    // A partial file takes the defaults for what it leaves out.
    let partial: PipelineOptions =
        serde_json::from_str(r#"{"dense": {"max_size": 800}}"#).expect("partial");
    assert_eq!(partial.dense.max_size, 800);
    assert_eq!(partial.mesh.view_meshes, o.mesh.view_meshes);
}

#[test]
fn a_collapsed_metric_frame_fails_the_run_and_leaves_no_model() {
    // A calibration 100× too short: every metric frame collapses in its bundle adjustment (the
    // outlier filter removes nearly every observation). The run must fail, saying what was tried,
    // and the sparse folder must hold nothing that could pass for a model.
    let dir = tempfile::tempdir().expect("temp dir");
    let seq = scene(dir.path());
    let k = &seq.gt.cameras.values().next().expect("a camera").intrinsics;
    let ws = dir.path().join("ws");
    let mut options = PipelineOptions::default();
    options.sparse.sfm.known_intrinsics = Some(handheld_sfm::KnownIntrinsics {
        fx: k.f / 100.0,
        fy: k.f / 100.0,
        cx: k.pp.x,
        cy: k.pp.y,
    });
    let err = handheld_pipeline::reconstruct(
        &dir.path().join("images"),
        &ws,
        &options,
        Some(stage::SPARSE),
        false,
        &NoProgress,
    )
    .expect_err("a collapsed model is not a success");
    let text = err.to_string();
    assert!(text.contains("no metric frame survived"), "{text}");
    assert!(text.contains("--intrinsics"), "{text}");
    let sparse = ws.join(stage::SPARSE);
    assert!(!sparse.join("manifest.json").exists());
    assert!(!sparse.join("cameras.bin").exists() && !sparse.join("summary.json").exists());
}

/// The sparse model against the truth: relative rotations, the points' colours (recorded by the
/// features stage: the sparse stage decodes no image), and the report's thumbnails.
fn check_sparse_model(ws: &Workspace, ws_path: &Path, seq: &SyntheticSequence) {
    let rec = ws.read_sparse_model().expect("model");
    let est: Vec<(String, Rigid3)> = rec
        .views
        .values()
        .map(|v| (v.name.clone(), v.cam_from_world))
        .collect();
    let err = relative_rotation_error_deg(&est, seq);
    assert!(err < 0.5, "relative rotation error {err}°");
    // Points take the colour of their first observation's pixel, recorded by the features stage
    // (the sparse stage decodes no image), and the features stage made the report's thumbnails.
    let mut checked = 0;
    for p in rec.points.values().step_by(50) {
        let el = p.track.elements[0];
        let v = &rec.views[&el.image_id];
        let xy = v.observations[el.point2d_idx as usize].xy;
        let k = seq
            .gt
            .views
            .values()
            .position(|g| g.name == v.name)
            .expect("view");
        let img = &seq.images[k];
        let px = img.get_pixel(
            (xy.x.round().max(0.0) as u32).min(img.width() - 1),
            (xy.y.round().max(0.0) as u32).min(img.height() - 1),
        );
        assert_eq!(
            p.color,
            [px[0], px[1], px[2]],
            "point at {xy:?} in {}",
            v.name
        );
        checked += 1;
    }
    assert!(checked > 10);
    for k in 0..seq.images.len() {
        let t = ws_path
            .join(stage::FEATURES)
            .join(format!("thumbs/{k:06}.jpg"));
        let t = image::open(&t).unwrap_or_else(|e| panic!("{}: {e}", t.display()));
        assert_eq!(t.width().max(t.height()), 240);
    }
}

/// One held-out view, image-based, against its photo; a pose file that is not one is refused,
/// naming it.
fn check_held_out_view(ws: &Workspace, dir: &Path, seq: &SyntheticSequence) {
    let png = dir.join("view.png");
    let view = render_view(
        ws,
        &ViewSpec::Image("frame_0003.png".into()),
        RenderMethod::Ulr,
        0,
        &Default::default(),
        &png,
    )
    .expect("one view");
    assert!(view.covered_fraction > 0.9, "{view:?}");
    let rendered = image::open(&png).expect("png").to_rgb8();
    let mask = vec![true; (rendered.width() * rendered.height()) as usize];
    let q = handheld_render::quality(&rendered, &seq.images[3], &mask);
    assert!(q.psnr > 20.0, "PSNR {} against the photo", q.psnr);
    let bad = dir.join("pose.json");
    std::fs::write(&bad, "{\"rotation\": [1, 0, 0]}").expect("write");
    let err = render_view(
        ws,
        &ViewSpec::PoseFile(bad.clone()),
        RenderMethod::Ulr,
        0,
        &Default::default(),
        &png,
    )
    .expect_err("not a pose");
    assert!(
        err.to_string().contains("pose.json") && err.to_string().contains("rotation"),
        "{err}"
    );
}

/// Augmenting the image sequence (§5.3) as one run of the graph: the shipped box on the ground,
/// one output frame per image; a placement behind every camera and a file that is not glTF are
/// refused, naming them.
#[test]
#[cfg_attr(not(has_ffmpeg), ignore = "needs ffmpeg (missing)")]
fn augmenting_the_sequence_composites_every_frame() {
    handheld_testkit::needs::ffmpeg();
    let dir = tempfile::tempdir().expect("temp dir");
    let seq = scene(dir.path());
    let input = dir.path().join("images");
    let ws_path = dir.path().join("ws");
    let options = PipelineOptions {
        augment: Some(handheld_pipeline::augment::AugmentOptions {
            occlusion: false,
            ..Default::default()
        }),
        ..Default::default()
    };
    // Without occlusion the augment stage needs only the sparse model: no dense or mesh runs.
    let reports = handheld_pipeline::reconstruct(
        &input,
        &ws_path,
        &options,
        Some(stage::AUGMENT),
        false,
        &NoProgress,
    )
    .expect("augmented");
    let ran: Vec<&str> = reports.iter().map(|r| r.stage.as_str()).collect();
    assert_eq!(ran, ["ingest", "features", "matches", "sparse", "augment"]);
    let ws = Workspace::open(&ws_path).expect("workspace");
    let aug: handheld_pipeline::augment::AugmentSummary =
        ws.summary(stage::AUGMENT).expect("parses").expect("ran");
    assert_eq!(aug.frames, seq.images.len());
    assert_eq!(aug.posed_frames, seq.images.len());
    assert!(!aug.occlusion);
    assert!(ws_path.join("augment/augmented.mp4").exists());
    assert_eq!(
        std::fs::read_to_string(ws_path.join("augment/camera.chan"))
            .expect("chan")
            .lines()
            .count(),
        seq.images.len()
    );
    // Called directly with occlusion and no mesh: drawn over everything, with a typed warning.
    let aug_dir = dir.path().join("augment-again");
    {
        let aug = handheld_pipeline::augment::augment(
            &ws,
            &handheld_pipeline::augment::AugmentOptions::default(),
            &aug_dir,
            &NoProgress,
        )
        .expect("augmented");
        assert_eq!(aug.frames, seq.images.len());
        assert!(aug
            .warnings
            .iter()
            .any(|w| w.code == handheld_pipeline::warning::code::INPUT_MISSING));
        assert!(aug_dir.join("augmented.mp4").exists());
        let behind = dir.path().join("behind.json");
        let rec = ws.read_sparse_model().expect("model");
        let v0 = rec.views.values().next().expect("a view");
        let c0 = v0.center();
        let back = v0.cam_from_world.rotation.inverse() * nalgebra::Vector3::new(0.0, 0.0, -1000.0);
        let far = c0.coords + back;
        std::fs::write(
            &behind,
            format!(
                "{{\"scale\": 0.001, \"rotation\": [1, 0, 0, 0], \"translation\": [{}, {}, {}]}}",
                far.x, far.y, far.z
            ),
        )
        .expect("write");
        let err = handheld_pipeline::augment::augment(
            &ws,
            &handheld_pipeline::augment::AugmentOptions {
                placement: handheld_pipeline::augment::PlacementMode::Transform(behind),
                ..Default::default()
            },
            &aug_dir,
            &NoProgress,
        )
        .expect_err("behind every camera");
        assert!(err.to_string().contains("behind every camera"), "{err}");
    }
    let not_gltf = dir.path().join("object.glb");
    std::fs::write(&not_gltf, "not a model").expect("write");
    let err = handheld_pipeline::augment::ObjectSource::File(not_gltf)
        .load()
        .expect_err("not glTF");
    assert!(err.to_string().contains("object.glb"), "{err}");
}
