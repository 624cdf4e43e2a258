//! Options are checked with errors naming the option, and reports serialise as the CLI prints them.

use handheld_eval::bench::{
    BundleBenchOptions, BundleProblem, ColmapSparseRun, DenseBenchOptions, HandheldSparseRun,
    PycolmapSparseRun, SparseBenchOptions, SparseBenchReport, SparseRound, StereoBenchOptions,
    StereoPairOptions,
};
use handheld_eval::demo::Scored;
use handheld_eval::{DemoOptions, EvalError};

#[test]
fn demo_options_are_checked_by_name() {
    assert!(DemoOptions::default().validate().is_ok());
    let bad = DemoOptions {
        frames: 1,
        ..Default::default()
    };
    let e = bad.validate().unwrap_err();
    assert_eq!(e.invalid_option(), Some("--frames"), "{e}");
    let bad = DemoOptions {
        aspect_ratio: 3.0,
        ..Default::default()
    };
    assert_eq!(
        bad.validate().unwrap_err().invalid_option(),
        Some("--aspect-ratio")
    );
    // Serde round trip with defaults for missing fields.
    let o: DemoOptions = serde_json::from_str(r#"{"frames": 8, "path": "walk"}"#).unwrap();
    assert_eq!(o.frames, 8);
    assert_eq!(o.width, DemoOptions::default().width);
    assert_eq!(o.path, handheld_eval::CameraPath::Walk);
}

#[test]
fn synthetic_bundle_problem_parses() {
    assert_eq!(
        "1000x200000".parse::<BundleProblem>().unwrap(),
        BundleProblem::Synthetic {
            cameras: 1000,
            points: 200_000
        }
    );
    for bad in ["", "12", "1x5", "ax5", "10x0"] {
        let e = bad.parse::<BundleProblem>().unwrap_err();
        assert_eq!(e.invalid_option(), Some("--synthetic"), "{bad}: {e}");
    }
    assert!(BundleBenchOptions::default().validate().is_ok());
}

#[test]
fn stereo_and_dense_options_are_checked() {
    let pair = StereoPairOptions {
        left: "l.png".into(),
        right: "r.png".into(),
        min_disparity: 0,
        max_disparity: -5,
        method: handheld_dense::StereoMethod::Sgm,
        output: "d.pfm".into(),
        valid_only: false,
    };
    let e = pair.validate().unwrap_err();
    assert!(e.to_string().contains("disparity"), "{e}");
    let bench = StereoBenchOptions {
        opencv: true,
        max_disparity: 40,
        ..Default::default()
    };
    assert_eq!(
        bench.validate().unwrap_err().invalid_option(),
        Some("--max-disparity")
    );
    let dense = DenseBenchOptions {
        model: Some("sparse".into()),
        ..Default::default()
    };
    assert_eq!(
        dense.validate().unwrap_err().invalid_option(),
        Some("--images")
    );
}

#[test]
fn stereo_pair_writes_a_disparity_and_reports_missing_files() {
    let dir = tempfile::tempdir().unwrap();
    // A textured pair shifted by 4 pixels.
    let tex = |x: u32, y: u32| ((x * 7919 + y * 104_729) % 251) as u8;
    let l = image::RgbImage::from_fn(64, 48, |x, y| image::Rgb([tex(x, y); 3]));
    let r = image::RgbImage::from_fn(64, 48, |x, y| image::Rgb([tex(x + 4, y); 3]));
    let (lp, rp) = (dir.path().join("l.png"), dir.path().join("r.png"));
    l.save(&lp).unwrap();
    r.save(&rp).unwrap();
    let mut o = StereoPairOptions {
        left: lp,
        right: rp,
        min_disparity: 0,
        max_disparity: 15,
        method: handheld_dense::StereoMethod::Sgm,
        output: dir.path().join("d.pfm"),
        valid_only: false,
    };
    let report = handheld_eval::bench::stereo_pair(&o).unwrap();
    assert_eq!((report.width, report.height), (64, 48));
    assert!(o.output.exists());
    let v = serde_json::to_value(&report).unwrap();
    assert_eq!(v["method"], "sgm");
    o.right = dir.path().join("nope.png");
    o.output = dir.path().join("e.pfm");
    let e = handheld_eval::bench::stereo_pair(&o).unwrap_err();
    assert!(e.to_string().contains("nope.png"), "{e}");
    assert!(!o.output.exists());
}

#[test]
fn a_failed_evaluation_serialises_as_its_error() {
    let s: Scored<u32> = Scored::Failed {
        error: EvalError::Data("only 2 views registered".into()).to_string(),
    };
    assert_eq!(
        serde_json::to_value(&s).unwrap(),
        serde_json::json!({ "error": "only 2 views registered" })
    );
    assert_eq!(serde_json::to_value(Scored::Ok(3u32)).unwrap(), 3);
}

#[test]
fn sparse_bench_options_are_checked_by_name() {
    let ok = SparseBenchOptions {
        images: "images".into(),
        ..Default::default()
    };
    assert!(ok.validate().is_ok());
    let name = |o: SparseBenchOptions| {
        o.validate()
            .unwrap_err()
            .invalid_option()
            .map(str::to_string)
    };
    assert_eq!(
        name(SparseBenchOptions::default()).as_deref(),
        Some("--images")
    );
    let threads = SparseBenchOptions {
        threads: Some(0),
        ..ok.clone()
    };
    assert_eq!(name(threads).as_deref(), Some("--threads"));
    let rounds = SparseBenchOptions {
        rounds: 0,
        ..ok.clone()
    };
    assert_eq!(name(rounds).as_deref(), Some("--rounds"));
    let no_script = SparseBenchOptions {
        gt: Some("dataset".into()),
        eval_script: "".into(),
        ..ok.clone()
    };
    assert_eq!(name(no_script).as_deref(), Some("--eval-script"));
    let mut bad_pipeline = ok.clone();
    bad_pipeline.pipeline.features.extraction.sift.max_features = Some(0);
    let e = bad_pipeline.validate().unwrap_err();
    assert_eq!(e.invalid_option(), Some("pipeline options"), "{e}");
    assert!(e.to_string().contains("max_features"), "{e}");
    // Missing files and a used --work folder are named before anything runs.
    let dir = tempfile::tempdir().unwrap();
    let missing_script = SparseBenchOptions {
        gt: Some(dir.path().to_path_buf()),
        eval_script: dir.path().join("nope.py"),
        ..ok.clone()
    };
    let e = handheld_eval::bench::bench_sparse(&missing_script, &handheld_core::NoProgress)
        .unwrap_err();
    assert_eq!(e.invalid_option(), Some("--eval-script"), "{e}");
    std::fs::write(dir.path().join("something"), b"x").unwrap();
    let used = SparseBenchOptions {
        work: Some(dir.path().to_path_buf()),
        ..ok.clone()
    };
    let e = handheld_eval::bench::bench_sparse(&used, &handheld_core::NoProgress).unwrap_err();
    assert_eq!(e.invalid_option(), Some("--work"), "{e}");
    // Serde with defaults for missing fields.
    let o: SparseBenchOptions =
        serde_json::from_str(r#"{"images": "x", "threads": 2, "colmap": true}"#).unwrap();
    assert_eq!((o.threads, o.colmap), (Some(2), true));
    assert_eq!(o.eval_script, SparseBenchOptions::default().eval_script);
}

#[test]
fn sparse_bench_report_has_the_ratio_per_stage() {
    let handheld = HandheldSparseRun {
        ingest_seconds: 1.0,
        features_seconds: 3.0,
        matches_seconds: 2.0,
        sparse_seconds: 4.0,
        total_seconds: 10.0,
        models: 1,
        registered: 11,
        total_images: 11,
        points: 5000,
        mean_reprojection_error_px: 0.4,
        focal_px: vec![2760.0],
        eval: None,
    };
    let run = PycolmapSparseRun {
        version: "4.2.1".into(),
        extraction_seconds: 40.0,
        matching_seconds: 30.0,
        mapping_seconds: 20.0,
        models: 1,
        registered: 10,
        total_images: 11,
        points: 6000,
        mean_reprojection_error_px: Some(0.5),
        model: None,
    };
    let colmap = ColmapSparseRun {
        total_seconds: run.total_seconds(),
        run,
        eval: Some(serde_json::json!({ "registered": 10 })),
    };
    let rounds = vec![SparseRound::of(&handheld, Some(&colmap.run))];
    let report = SparseBenchReport::new(
        "images".into(),
        2,
        handheld.clone(),
        Some(colmap.clone()),
        rounds,
        None,
    );
    let v = serde_json::to_value(&report).unwrap();
    assert_eq!(
        v["ratio"],
        serde_json::json!({ "extraction": 10.0, "matching": 15.0, "mapping": 5.0, "total": 9.0 })
    );
    assert_eq!(v["meets_target"], true);
    assert_eq!(v["target_total_ratio"], 5.0);
    assert_eq!(v["colmap"]["version"], "4.2.1");
    assert_eq!(v["colmap"]["total_seconds"], 90.0);
    assert_eq!(v["colmap"]["eval"]["registered"], 10);
    assert_eq!(v["handheld"]["sparse_seconds"], 4.0);
    assert!(v["handheld"].get("eval").is_none());
    let back: SparseBenchReport = serde_json::from_value(v).unwrap();
    assert_eq!(back, report);
    // Three rounds, one of them on a slow spell of the machine: the median of the rounds' ratios.
    let slow = HandheldSparseRun {
        total_seconds: 30.0,
        features_seconds: 13.0,
        ..handheld.clone()
    };
    let fast_colmap = PycolmapSparseRun {
        extraction_seconds: 20.0,
        ..colmap.run.clone()
    };
    let rounds = vec![
        SparseRound::of(&handheld, Some(&colmap.run)),
        SparseRound::of(&slow, Some(&colmap.run)),
        SparseRound::of(&handheld, Some(&fast_colmap)),
    ];
    let three = SparseBenchReport::new(
        "images".into(),
        2,
        handheld.clone(),
        Some(colmap),
        rounds,
        None,
    );
    let r = three.ratio.expect("ratio");
    // Extraction: 10, 40 / 16 = 2.5 and 20 / 4 = 5 → 5; total: 9, 90 / 30 = 3 and 70 / 10 = 7 → 7.
    assert_eq!((r.extraction, r.total), (5.0, 7.0));
    assert_eq!(
        three.rounds[1].ratio.as_ref().expect("round ratio").total,
        3.0
    );
    // Handheld alone: no COLMAP, no ratio, no verdict.
    let rounds = vec![SparseRound::of(&handheld, None)];
    let alone = SparseBenchReport::new("images".into(), 2, handheld, None, rounds, None);
    let v = serde_json::to_value(&alone).unwrap();
    for key in ["colmap", "ratio", "meets_target", "work"] {
        assert!(v.get(key).is_none(), "{key} in {v}");
    }
}
