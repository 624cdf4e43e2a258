//! Real data, scored by the shared evaluation tool: `handheld reconstruct` on iclnuim-5 (5 frames of
//! ICL-NUIM, 640×480) up to the sparse model, then `../shared/tools/eval_sfm.py` against the
//! ground-truth poses. View 3 sees only a part of the back wall that one other view sees, so it has
//! no 3D points in common with the model and is placed from the partner's depths (`register_pair`).
//! Skipped when the data set, python3 or numpy is absent.

mod common;
use common::*;

use std::path::PathBuf;
use std::process::Command;

fn shared() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared")
}

fn have_numpy() -> bool {
    Command::new("python3")
        .args(["-c", "import numpy"])
        .output()
        .is_ok_and(|o| o.status.success())
}

#[test]
fn iclnuim_all_five_views_registered_and_scored() {
    let data = shared().join("datasets/iclnuim-5");
    let eval = shared().join("tools/eval_sfm.py");
    if !data.join("images").is_dir() || !eval.is_file() || !have_numpy() {
        eprintln!("skipping: ../shared/datasets/iclnuim-5, eval_sfm.py or python3 + numpy missing");
        return;
    }
    let ws = tempfile::tempdir().unwrap();
    let images = data.join("images");
    let o = handheld(&[
        "--quiet",
        "reconstruct",
        images.to_str().unwrap(),
        "-o",
        ws.path().to_str().unwrap(),
        "--until",
        "sparse",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let e = Command::new("python3")
        .arg(&eval)
        .arg(ws.path().join("sparse"))
        .arg(&data)
        .output()
        .unwrap();
    assert!(e.status.success(), "{}", String::from_utf8_lossy(&e.stderr));
    let out = String::from_utf8_lossy(&e.stdout);
    let line = out.lines().last().unwrap_or_default();
    let v: serde_json::Value = serde_json::from_str(line).unwrap();
    println!("{v}");
    assert_eq!(v["registered"], 5, "{v}");
    let auc5 = v["auc@5"].as_f64().unwrap();
    assert!(auc5 >= 50.0, "AUC@5 {auc5}");
}
