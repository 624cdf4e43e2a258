//! Work units (the distributed pipeline's tasks) against the single-machine run: a seeded
//! synthetic sequence goes up to the dense depth maps once through `reconstruct`, and once stage by
//! stage with the units of the features, matches and dense stages run apart (out of order, one
//! twice, and one unit of matching and of dense left for the stage itself). The files must be the
//! same bytes.

use std::path::Path;

use handheld_core::NoProgress;
use handheld_pipeline::files::stage;
use handheld_pipeline::stage::UNITS_DIR;
use handheld_pipeline::{Pipeline, PipelineOptions, StageStatus, Workspace};
use handheld_testkit::render::{render_sequence, SequenceOptions};

fn files(dir: &Path) -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).expect("stage folder") {
        let p = e.expect("entry").path();
        if p.is_dir() {
            out.extend(files(&p));
        } else {
            out.push(p);
        }
    }
    out.sort();
    out
}

#[test]
fn units_run_apart_give_the_same_files() {
    let dir = tempfile::tempdir().expect("temp dir");
    let opts = SequenceOptions {
        width: 320,
        height: 240,
        num_frames: 8,
        ..Default::default()
    };
    let seq = render_sequence(&opts).expect("render");
    let input = dir.path().join("images");
    for (view, img) in seq.gt.views.values().zip(&seq.images) {
        handheld_io::ingest::write_png(&input.join(&view.name), img).expect("write frame");
    }
    let options = PipelineOptions::default();
    let one = dir.path().join("one");
    handheld_pipeline::reconstruct(
        &input,
        &one,
        &options,
        Some(stage::DENSE),
        false,
        &NoProgress,
    )
    .expect("single-machine run");

    let p = Pipeline::standard(&input, &options).expect("graph");
    let ws = Workspace::open(&dir.path().join("apart")).expect("workspace");
    assert!(
        p.units(&ws, stage::FEATURES, false).is_err(),
        "ingest has not run"
    );
    assert_eq!(p.units(&ws, stage::INGEST, false).expect("no units"), 0);
    p.run_stage(&ws, stage::INGEST, false, &NoProgress)
        .expect("ingest");
    let n = p.units(&ws, stage::FEATURES, false).expect("feature units");
    assert_eq!(n, 8);
    for k in (0..n).rev() {
        p.run_unit(&ws, stage::FEATURES, k, &NoProgress)
            .expect("unit");
    }
    p.run_unit(&ws, stage::FEATURES, 3, &NoProgress)
        .expect("a retried unit");
    assert!(p.run_unit(&ws, stage::FEATURES, n, &NoProgress).is_err());
    p.run_stage(&ws, stage::FEATURES, false, &NoProgress)
        .expect("features");
    // 28 pairs (exhaustive), in units of 16: run the second apart, leave the first to the stage.
    let m = p.units(&ws, stage::MATCHES, false).expect("matching units");
    assert_eq!(m, 2);
    p.run_unit(&ws, stage::MATCHES, 1, &NoProgress)
        .expect("unit");
    let r = p
        .run_stage(&ws, stage::MATCHES, false, &NoProgress)
        .expect("matches");
    assert_eq!(r.status, StageStatus::Ran);
    assert!(
        !ws.root.join(UNITS_DIR).exists(),
        "the units' folder is cleared"
    );
    // Up to date now: no units, nothing to run.
    assert_eq!(p.units(&ws, stage::MATCHES, false).expect("up to date"), 0);
    let again = p
        .run_stage(&ws, stage::MATCHES, false, &NoProgress)
        .expect("skip");
    assert_eq!(again.status, StageStatus::UpToDate);

    // The sparse model, then the dense stage: 7 consecutive pairs, all but pair 2 matched apart.
    p.run_stage(&ws, stage::SPARSE, false, &NoProgress)
        .expect("sparse");
    let d = p.units(&ws, stage::DENSE, false).expect("dense units");
    assert_eq!(d, 7);
    for k in (0..d).filter(|&k| k != 2) {
        p.run_unit(&ws, stage::DENSE, k, &NoProgress)
            .expect("pair unit");
    }
    let r = p
        .run_stage(&ws, stage::DENSE, false, &NoProgress)
        .expect("dense");
    assert_eq!(r.status, StageStatus::Ran);
    assert!(!ws.root.join(UNITS_DIR).exists());

    for s in [stage::FEATURES, stage::MATCHES, stage::SPARSE, stage::DENSE] {
        let (a, b) = (files(&one.join(s)), files(&ws.root.join(s)));
        let rel = |v: &[std::path::PathBuf], root: &Path| -> Vec<std::path::PathBuf> {
            v.iter()
                .map(|p| p.strip_prefix(root).expect("inside").to_path_buf())
                .collect()
        };
        assert_eq!(rel(&a, &one), rel(&b, &ws.root), "{s}: the same files");
        for (x, y) in a.iter().zip(&b) {
            let name = x.file_name().and_then(|n| n.to_str()).unwrap_or("");
            if name == "manifest.json" || name == "summary.json" {
                continue; // clock readings
            }
            assert!(
                std::fs::read(x).expect("read") == std::fs::read(y).expect("read"),
                "{} differs",
                x.display()
            );
        }
        let (m1, m2) = (
            Workspace::open(&one)
                .expect("ws")
                .manifest(s)
                .expect("manifest"),
            ws.manifest(s).expect("manifest"),
        );
        assert_eq!(m1.input_hash, m2.input_hash);
        assert_eq!(m1.outputs, m2.outputs);
    }
}
