//! Resumable runs: a finished stage is skipped until its inputs or options change; `--force` redoes
//! it; `--quiet` and `--json` behave on every command.

mod common;
use common::*;

fn ingest_status(o: &std::process::Output) -> String {
    let v: serde_json::Value = serde_json::from_str(&stdout(o))
        .unwrap_or_else(|e| panic!("bad JSON ({e}): {}", stdout(o)));
    v["stages"][0]["status"]
        .as_str()
        .unwrap_or_default()
        .to_string()
}

#[test]
fn stages_resume_and_rerun_on_change() {
    let dir = tempfile::tempdir().unwrap();
    let input = photo_folder(dir.path(), 2);
    let ws = dir.path().join("ws");
    let run = |extra: &[&str]| {
        // The blank test photos cannot give a model: stop after matching.
        let mut args = vec![
            "reconstruct",
            input.to_str().unwrap(),
            "-o",
            ws.to_str().unwrap(),
            "--json",
            "--until",
            "matches",
        ];
        args.extend_from_slice(extra);
        let o = handheld(&args);
        assert!(o.status.success(), "{}", stderr(&o));
        o
    };
    assert_eq!(ingest_status(&run(&[])), "ran");
    assert!(ws.join("ingest/manifest.json").exists());
    assert!(ws.join("ingest/images.json").exists());
    assert!(ws.join("timings.json").exists());
    assert_eq!(ingest_status(&run(&[])), "up_to_date");
    assert_eq!(ingest_status(&run(&["--force"])), "ran");
    write_image(&input.join("2.png"), 3);
    assert_eq!(
        ingest_status(&run(&[])),
        "ran",
        "a new photo invalidates ingest"
    );
    assert_eq!(
        ingest_status(&run(&["--skip-bad-images"])),
        "ran",
        "changed options invalidate ingest"
    );
    // A manifest removed by an interrupted rerun means the stage runs again.
    std::fs::remove_file(ws.join("ingest/manifest.json")).unwrap();
    assert_eq!(ingest_status(&run(&["--skip-bad-images"])), "ran");
}

#[test]
fn quiet_prints_nothing_and_json_is_one_object() {
    let dir = tempfile::tempdir().unwrap();
    let input = photo_folder(dir.path(), 2);
    let ws = dir.path().join("ws");
    let o = handheld(&[
        "reconstruct",
        input.to_str().unwrap(),
        "-o",
        ws.to_str().unwrap(),
        "--quiet",
        "--until",
        "matches",
    ]);
    assert!(o.status.success());
    assert!(
        stdout(&o).is_empty() && stderr(&o).is_empty(),
        "quiet: {:?} {:?}",
        stdout(&o),
        stderr(&o)
    );
    let o = handheld(&[
        "ingest",
        input.to_str().unwrap(),
        "-o",
        ws.to_str().unwrap(),
        "--json",
    ]);
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    assert!(v["stages"].is_array());
    // Errors are JSON too with --json.
    let o = handheld(&[
        "ingest",
        dir.path().join("nope").to_str().unwrap(),
        "-o",
        ws.to_str().unwrap(),
        "--json",
    ]);
    let v: serde_json::Value = serde_json::from_str(stdout(&o).trim()).unwrap();
    assert!(v["error"].as_str().unwrap().contains("nope"));
}
