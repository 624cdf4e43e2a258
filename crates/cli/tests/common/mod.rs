//! Helpers for the CLI tests: run the built binary and write small input files.

#![allow(dead_code)]

use std::path::Path;
use std::process::{Command, Output, Stdio};

pub fn handheld(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_handheld"))
        .args(args)
        .stdin(Stdio::null())
        .output()
        .expect("the handheld binary runs")
}

/// Runs the binary with extra environment variables.
pub fn handheld_env(args: &[&str], env: &[(&str, &str)]) -> Output {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_handheld"));
    cmd.args(args).stdin(Stdio::null());
    for (k, v) in env {
        cmd.env(k, v);
    }
    cmd.output().expect("the handheld binary runs")
}

pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

pub fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// A textured test image (big enough for ingest).
pub fn write_image(path: &Path, seed: u32) {
    let img = image::RgbImage::from_fn(64, 48, |x, y| {
        image::Rgb([
            ((x * 7 + seed) % 256) as u8,
            ((y * 5) % 256) as u8,
            ((x ^ y) % 256) as u8,
        ])
    });
    img.save(path).expect("write test image");
}

/// A folder `photos` under `dir` holding `n` distinct test images `0.png`, `1.png`, …
pub fn photo_folder(dir: &Path, n: u32) -> std::path::PathBuf {
    let input = dir.join("photos");
    std::fs::create_dir_all(&input).expect("create photo folder");
    for k in 0..n {
        write_image(&input.join(format!("{k}.png")), k + 1);
    }
    input
}

/// No file under `dir` looks half-written (`*.tmp`).
pub fn no_temp_files(dir: &Path) -> bool {
    fn walk(d: &Path) -> bool {
        let Ok(rd) = std::fs::read_dir(d) else {
            return true;
        };
        rd.flatten().all(|e| {
            let p = e.path();
            if p.is_dir() {
                walk(&p)
            } else {
                !p.to_string_lossy().ends_with(".tmp")
            }
        })
    }
    walk(dir)
}

/// The data set folder the build script probed (`../shared/datasets`, or `$HANDHELD_DATASETS` at
/// build time): `datasets().join(name)`.
pub fn datasets() -> &'static str {
    env!("HANDHELD_DATASETS_DIR")
}

/// `<datasets>/<name>`, or a panic naming the missing folder (the test itself is marked
/// `cfg_attr(not(has_…), ignore)`, so this fails only on CI or when the data went after the build).
#[track_caller]
pub fn dataset(name: &'static str) -> std::path::PathBuf {
    handheld_testkit::needs::dataset(datasets(), name)
}

/// Panics, saying how to install it, unless ffmpeg runs (tests marked
/// `cfg_attr(not(has_ffmpeg), ignore)`).
#[track_caller]
pub fn need_ffmpeg() {
    handheld_testkit::needs::ffmpeg();
}
