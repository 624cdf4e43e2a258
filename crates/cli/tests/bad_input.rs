//! Each bad input of the Foundation issue gets one clear error line naming the path (or option), a
//! non-zero exit, no panic, and nothing half-written in the workspace.

mod common;
use common::*;

fn assert_clean_failure(o: &std::process::Output, must_contain: &[&str], ws: &std::path::Path) {
    let err = stderr(o);
    assert!(!o.status.success(), "should fail: {err}");
    assert!(!err.contains("panicked"), "panic: {err}");
    let first = err
        .lines()
        .find(|l| l.starts_with("error"))
        .unwrap_or_default();
    for s in must_contain {
        assert!(
            first.contains(s),
            "error line {first:?} should contain {s:?}\nfull stderr:\n{err}"
        );
    }
    assert!(
        !ws.join("ingest").join("manifest.json").exists(),
        "a failed stage must not look finished"
    );
    assert!(no_temp_files(ws), "temporary files left behind");
}

#[test]
fn missing_path() {
    let dir = tempfile::tempdir().unwrap();
    let ws = dir.path().join("ws");
    let o = handheld(&[
        "reconstruct",
        dir.path().join("no_such_folder").to_str().unwrap(),
        "-o",
        ws.to_str().unwrap(),
    ]);
    assert_clean_failure(&o, &["no_such_folder", "does not exist"], &ws);
}

#[test]
fn empty_folder() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("empty");
    std::fs::create_dir(&input).unwrap();
    let ws = dir.path().join("ws");
    let o = handheld(&[
        "reconstruct",
        input.to_str().unwrap(),
        "-o",
        ws.to_str().unwrap(),
    ]);
    assert_clean_failure(&o, &["empty", "no images"], &ws);
}

#[test]
fn non_image_file_is_skipped_with_a_warning() {
    let dir = tempfile::tempdir().unwrap();
    let input = photo_folder(dir.path(), 2);
    std::fs::write(input.join("notes.txt"), "not an image").unwrap();
    let ws = dir.path().join("ws");
    let o = handheld(&[
        "ingest",
        input.to_str().unwrap(),
        "-o",
        ws.to_str().unwrap(),
        "--json",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("notes.txt"),
        "warning names the file: {}",
        stderr(&o)
    );
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    assert_eq!(v["stages"][0]["summary"]["images"], 2);
    assert_eq!(v["stages"][0]["summary"]["skipped"], 1);

    // With only one image left, the same folder is refused.
    std::fs::remove_file(input.join("1.png")).unwrap();
    let o = handheld(&[
        "ingest",
        input.to_str().unwrap(),
        "-o",
        ws.to_str().unwrap(),
    ]);
    assert_clean_failure(&o, &["photos", "need at least 2"], &ws);
}

#[test]
fn truncated_jpeg() {
    let dir = tempfile::tempdir().unwrap();
    let input = photo_folder(dir.path(), 2);
    write_image(&input.join("c.jpg"), 3);
    let bytes = std::fs::read(input.join("c.jpg")).unwrap();
    std::fs::write(input.join("c.jpg"), &bytes[..bytes.len() / 2]).unwrap();
    let ws = dir.path().join("ws");
    let o = handheld(&[
        "reconstruct",
        input.to_str().unwrap(),
        "-o",
        ws.to_str().unwrap(),
    ]);
    assert_clean_failure(&o, &["c.jpg", "truncated"], &ws);
    // The user can choose to skip it (the blank test photos cannot give a model, so stop after matching).
    let o = handheld(&[
        "reconstruct",
        input.to_str().unwrap(),
        "-o",
        ws.to_str().unwrap(),
        "--skip-bad-images",
        "--until",
        "matches",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("c.jpg"));
}

#[test]
fn one_pixel_image() {
    let dir = tempfile::tempdir().unwrap();
    let input = photo_folder(dir.path(), 2);
    image::RgbImage::new(1, 1)
        .save(input.join("tiny.png"))
        .unwrap();
    let ws = dir.path().join("ws");
    let o = handheld(&[
        "reconstruct",
        input.to_str().unwrap(),
        "-o",
        ws.to_str().unwrap(),
    ]);
    assert_clean_failure(&o, &["tiny.png", "1×1"], &ws);
}

#[test]
#[cfg_attr(not(has_ffmpeg), ignore = "needs ffmpeg (missing)")]
fn video_that_is_not_one() {
    need_ffmpeg();
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("holiday.mp4");
    std::fs::write(&input, b"this is a text file pretending to be a movie").unwrap();
    let ws = dir.path().join("ws");
    let o = handheld(&[
        "reconstruct",
        input.to_str().unwrap(),
        "-o",
        ws.to_str().unwrap(),
    ]);
    assert_clean_failure(&o, &["holiday.mp4", "cannot read this video"], &ws);
}

#[test]
fn option_out_of_range() {
    let dir = tempfile::tempdir().unwrap();
    let ws = dir.path().join("ws");
    let o = handheld(&[
        "reconstruct",
        dir.path().to_str().unwrap(),
        "-o",
        ws.to_str().unwrap(),
        "--stride",
        "0",
    ]);
    assert_eq!(o.status.code(), Some(2));
    let err = stderr(&o);
    assert!(
        err.lines().next().unwrap_or_default().contains("--stride"),
        "{err}"
    );
    assert!(!err.contains("panicked"));

    let o = handheld(&[
        "reconstruct",
        dir.path().to_str().unwrap(),
        "-o",
        ws.to_str().unwrap(),
        "--start",
        "5",
        "--end",
        "2",
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("--end"), "{}", stderr(&o));

    let o = handheld(&["demo", "-o", ws.to_str().unwrap(), "--frames", "1"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("--frames"), "{}", stderr(&o));
}

#[test]
fn missing_ffmpeg_says_how_to_install_it() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("clip.mp4");
    std::fs::write(&input, b"whatever").unwrap();
    let ws = dir.path().join("ws");
    let o = handheld_env(
        &[
            "reconstruct",
            input.to_str().unwrap(),
            "-o",
            ws.to_str().unwrap(),
        ],
        &[("HANDHELD_FFMPEG", "/nonexistent/bin/ffmpeg")],
    );
    assert_clean_failure(&o, &["ffmpeg was not found", "apt-get install ffmpeg"], &ws);
}

/// Degenerate motion: a video of a still camera has no key-frame pair; the sparse stage says why
/// and does not mark itself finished.
#[test]
#[cfg_attr(not(has_ffmpeg), ignore = "needs ffmpeg (missing)")]
fn video_of_a_still_camera() {
    need_ffmpeg();
    let dir = tempfile::tempdir().unwrap();
    let still = dir.path().join("still.png");
    let img = image::RgbImage::from_fn(160, 120, |x, y| {
        let v = (((x as f32 * 0.31).sin() * (y as f32 * 0.27).cos()) * 100.0 + 128.0) as u8;
        image::Rgb([v, v.wrapping_add((x * 3) as u8), v])
    });
    img.save(&still).unwrap();
    let video = dir.path().join("still.mp4");
    let ok = std::process::Command::new("ffmpeg")
        .args(["-loglevel", "error", "-y", "-loop", "1", "-i"])
        .arg(&still)
        .args(["-t", "1", "-r", "10", "-pix_fmt", "yuv420p"])
        .arg(&video)
        .status()
        .unwrap()
        .success();
    assert!(ok, "ffmpeg could not encode the test video");
    let ws = dir.path().join("ws");
    let o = handheld(&[
        "reconstruct",
        video.to_str().unwrap(),
        "-o",
        ws.to_str().unwrap(),
        "--quiet",
    ]);
    let err = stderr(&o);
    assert!(!o.status.success(), "should fail: {err}");
    assert!(!err.contains("panicked"), "panic: {err}");
    assert!(err.contains("hardly moves"), "{err}");
    assert!(!ws.join("sparse").join("manifest.json").exists());
    assert!(no_temp_files(&ws), "temporary files left behind");
}

/// `handheld augment`: an object that is not glTF is named before any work is done; a video of
/// one frame is refused; a missing pose file for `render` is named.
#[test]
#[cfg_attr(not(has_ffmpeg), ignore = "needs ffmpeg (missing)")]
fn augment_and_render_bad_inputs() {
    need_ffmpeg();
    let dir = tempfile::tempdir().unwrap();
    let one = dir.path().join("one.mp4");
    let made = std::process::Command::new(handheld_io::video::ffmpeg_program())
        .args([
            "-loglevel",
            "error",
            "-y",
            "-f",
            "lavfi",
            "-i",
            "testsrc=size=320x240:rate=1",
        ])
        .args(["-frames:v", "1", "-c:v", "libx264", "-pix_fmt", "yuv420p"])
        .arg(&one)
        .status()
        .unwrap();
    assert!(made.success());
    let bad = dir.path().join("teapot.glb");
    std::fs::write(&bad, "not a model").unwrap();
    let ws = dir.path().join("ws");
    let args = |extra: &[&str]| {
        let mut a = vec!["augment", one.to_str().unwrap(), "-o", ws.to_str().unwrap()];
        a.extend_from_slice(extra);
        handheld(&a)
    };
    let o = args(&["--object", bad.to_str().unwrap()]);
    assert_clean_failure(&o, &["teapot.glb", "glTF"], &ws);
    assert!(!ws.exists(), "nothing is written for a bad object");
    let o = args(&[]);
    assert_clean_failure(&o, &["one.mp4", "at least 2"], &ws);
    let o = handheld(&[
        "render",
        ws.to_str().unwrap(),
        "--pose",
        dir.path().join("nowhere.json").to_str().unwrap(),
        "-o",
        dir.path().join("v.png").to_str().unwrap(),
    ]);
    let err = stderr(&o);
    assert!(!o.status.success() && !err.contains("panicked"), "{err}");
}

/// A kernel choice the matcher does not have is refused before any work, naming the variable.
#[test]
fn an_unknown_simd_choice_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let ws = dir.path().join("ws");
    let o = handheld_env(
        &[
            "reconstruct",
            dir.path().to_str().unwrap(),
            "-o",
            ws.to_str().unwrap(),
        ],
        &[("HANDHELD_SIMD", "avx9")],
    );
    assert_clean_failure(&o, &["HANDHELD_SIMD", "avx9", "avx2"], &ws);
    assert_eq!(o.status.code(), Some(2));
}
