//! Options are checked with errors naming the option, and reports serialise as the CLI prints them.

use handheld_eval::bench::{
    BundleBenchOptions, BundleProblem, DenseBenchOptions, StereoBenchOptions, StereoPairOptions,
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
