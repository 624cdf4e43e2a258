//! Video tests on a real mp4 encoded here by ffmpeg from frames whose brightness encodes their index.

use super::*;
use std::io::Write;

/// Panics, saying how to install it, unless ffmpeg runs. The tests that need it are marked
/// `cfg_attr(not(has_ffmpeg), ignore)` (set by `build.rs`, always on with `CI` set), so a missing
/// ffmpeg shows as ignored tests, and on CI as a failure that names it.
fn need_ffmpeg() {
    let ok = Command::new("ffmpeg")
        .arg("-version")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    assert!(
        ok,
        "needs ffmpeg on PATH (missing): apt-get install ffmpeg (.ci/run does)"
    );
}

/// Encodes `n` frames of 64×48 at 10 fps; frame k is uniformly grey at level 10·k + 5.
fn encode(path: &Path, n: u32) {
    let mut child = Command::new("ffmpeg")
        .args([
            "-v", "error", "-y", "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", "64x48", "-r", "10",
            "-i", "-",
        ])
        .args(["-c:v", "mpeg4", "-q:v", "2", "-pix_fmt", "yuv420p"])
        .arg(path)
        .stdin(Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdin = child.stdin.take().unwrap();
    for k in 0..n {
        stdin
            .write_all(&vec![(10 * k + 5) as u8; 64 * 48 * 3])
            .unwrap();
    }
    drop(stdin);
    assert!(child.wait().unwrap().success());
}

fn level(img: &RgbImage) -> f64 {
    img.as_raw().iter().map(|&v| v as f64).sum::<f64>() / img.as_raw().len() as f64
}

#[test]
#[cfg_attr(not(has_ffmpeg), ignore = "needs ffmpeg (missing)")]
fn streams_every_frame_with_stride_and_range() {
    need_ffmpeg();
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("clip.mp4");
    encode(&p, 20);
    let info = probe(&p).unwrap();
    assert_eq!((info.width, info.height), (64, 48));
    assert!((info.fps - 10.0).abs() < 1e-6);

    let all: Vec<_> = VideoReader::open(&p, &VideoOptions::default())
        .unwrap()
        .collect::<Result<_>>()
        .unwrap();
    assert_eq!(all.len(), 20);
    for f in &all {
        assert!(
            (level(&f.image) - (10 * f.index + 5) as f64).abs() < 3.0,
            "frame {} level {}",
            f.index,
            level(&f.image)
        );
    }

    let opts = VideoOptions {
        stride: 3,
        ..Default::default()
    };
    let strided: Vec<_> = VideoReader::open(&p, &opts)
        .unwrap()
        .collect::<Result<_>>()
        .unwrap();
    assert_eq!(
        strided.iter().map(|f| f.index).collect::<Vec<_>>(),
        vec![0, 3, 6, 9, 12, 15, 18]
    );
    for f in &strided {
        assert!((level(&f.image) - (10 * f.index + 5) as f64).abs() < 3.0);
    }

    let opts = VideoOptions {
        stride: 2,
        start_s: 0.5,
        end_s: Some(1.5),
        max_frames: None,
    };
    let ranged: Vec<_> = VideoReader::open(&p, &opts)
        .unwrap()
        .collect::<Result<_>>()
        .unwrap();
    assert_eq!(
        ranged.iter().map(|f| f.index).collect::<Vec<_>>(),
        vec![5, 7, 9, 11, 13]
    );
    for f in &ranged {
        assert!(
            (level(&f.image) - (10 * f.index + 5) as f64).abs() < 3.0,
            "frame {}",
            f.index
        );
        assert!((f.time_s - f.index as f64 / 10.0).abs() < 1e-9);
    }

    let opts = VideoOptions {
        max_frames: Some(4),
        ..Default::default()
    };
    assert_eq!(VideoReader::open(&p, &opts).unwrap().count(), 4);
}

#[test]
#[cfg_attr(not(has_ffmpeg), ignore = "needs ffmpeg (missing)")]
fn a_file_that_is_not_a_video_is_named() {
    need_ffmpeg();
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("fake.mp4");
    std::fs::write(&p, b"definitely not a movie").unwrap();
    let err = VideoReader::open(&p, &VideoOptions::default())
        .err()
        .unwrap()
        .to_string();
    assert!(
        err.contains("fake.mp4") && err.contains("cannot read this video"),
        "{err}"
    );
}

#[test]
fn missing_ffmpeg_says_how_to_install() {
    let err = spawn_error(
        "/nonexistent/ffmpeg",
        std::io::Error::from(std::io::ErrorKind::NotFound),
    )
    .to_string();
    assert!(err.contains("apt-get install ffmpeg"), "{err}");
}

#[test]
fn out_of_range_options_name_the_option() {
    let check = |o: VideoOptions, option: &str, flag: &str| {
        let err = o.validate().unwrap_err();
        assert!(
            matches!(&err, IoError::InvalidOption { option: name, .. } if *name == option),
            "{err:?}"
        );
        assert!(err.to_string().contains(flag), "{err}");
    };
    let d = VideoOptions::default;
    check(VideoOptions { stride: 0, ..d() }, "stride", "--stride");
    check(
        VideoOptions {
            end_s: Some(0.0),
            ..d()
        },
        "end_s",
        "--end",
    );
    check(
        VideoOptions {
            start_s: -1.0,
            ..d()
        },
        "start_s",
        "--start",
    );
    check(
        VideoOptions {
            max_frames: Some(0),
            ..d()
        },
        "max_frames",
        "--max-frames",
    );
}

/// Frame `k` of the encoding tests: uniformly grey at level 20·k + 30, 64×48.
fn grey_frame(k: u32) -> RgbImage {
    RgbImage::from_pixel(64, 48, image::Rgb([(20 * k + 30) as u8; 3]))
}

/// Decodes `path` with the reader and checks it holds the frames of [`grey_frame`] 0..n.
fn check_decoded(path: &Path, n: u32) {
    let info = probe(path).unwrap();
    assert_eq!(info.codec, "h264");
    assert_eq!((info.width, info.height), (64, 48));
    let frames: Vec<_> = VideoReader::open(path, &VideoOptions::default())
        .unwrap()
        .collect::<Result<_>>()
        .unwrap();
    assert_eq!(frames.len(), n as usize);
    for (k, f) in frames.iter().enumerate() {
        let want = level(&grey_frame(k as u32));
        assert!(
            (level(&f.image) - want).abs() < 3.0,
            "frame {k}: level {} for {want}",
            level(&f.image)
        );
    }
}

#[test]
#[cfg_attr(not(has_ffmpeg), ignore = "needs ffmpeg (missing)")]
fn encoded_frames_decode_back() {
    need_ffmpeg();
    let dir = tempfile::tempdir().unwrap();
    let frames: Vec<RgbImage> = (0..6).map(grey_frame).collect();
    let out = dir.path().join("memory.mp4");
    encode_h264_frames(&frames, &out, &EncodeOptions::default()).unwrap();
    assert!(!dir.path().join("memory.tmp.mp4").exists());
    check_decoded(&out, 6);

    // The same frames from numbered PNG files, as the demo writes them.
    for (k, f) in frames.iter().enumerate() {
        f.save(dir.path().join(format!("frame_{k:04}.png")))
            .unwrap();
    }
    let out = dir.path().join("files.mp4");
    encode_h264(
        &dir.path().join("frame_%04d.png"),
        &out,
        &EncodeOptions::default(),
    )
    .unwrap();
    check_decoded(&out, 6);

    // No input files: the error names the video and nothing is left behind.
    let out = dir.path().join("none.mp4");
    let err = encode_h264(
        &dir.path().join("missing_%04d.png"),
        &out,
        &EncodeOptions::default(),
    )
    .unwrap_err()
    .to_string();
    assert!(
        err.contains("none.mp4") && err.contains("could not encode"),
        "{err}"
    );
    assert!(!out.exists() && !dir.path().join("none.tmp.mp4").exists());
}

#[test]
fn encoding_checks_frames_and_options_first() {
    let out = Path::new("never_written.mp4");
    let odd = [RgbImage::new(63, 48)];
    let err = encode_h264_frames(&odd, out, &EncodeOptions::default())
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("never_written.mp4") && err.contains("even"),
        "{err}"
    );
    let none: [RgbImage; 0] = [];
    assert!(encode_h264_frames(&none, out, &EncodeOptions::default()).is_err());
    let bad = EncodeOptions {
        crf: 60,
        ..Default::default()
    };
    assert!(matches!(
        bad.validate(),
        Err(IoError::InvalidOption { option: "crf", .. })
    ));
    assert!(!out.exists());
}

/// `VideoWriter` streams frames into an H.264 video at a fractional rate and copies the audio of
/// the source video; the frames come back in order; an unfinished writer leaves nothing behind.
#[test]
#[cfg_attr(not(has_ffmpeg), ignore = "needs ffmpeg (missing)")]
fn video_writer_keeps_the_source_audio() {
    need_ffmpeg();
    let dir = tempfile::tempdir().unwrap();
    let source = dir.path().join("with_audio.mp4");
    let ok = Command::new("ffmpeg")
        .args([
            "-v",
            "error",
            "-y",
            "-f",
            "lavfi",
            "-i",
            "testsrc=size=64x48:rate=10",
        ])
        .args(["-f", "lavfi", "-i", "sine=frequency=440:sample_rate=44100"])
        .args([
            "-t", "2", "-c:v", "libx264", "-pix_fmt", "yuv420p", "-c:a", "aac",
        ])
        .arg(&source)
        .status()
        .unwrap();
    assert!(ok.success());
    let out = dir.path().join("augmented.mp4");
    let mut w = encode::VideoWriter::create(&out, 64, 48, 10.0, 18, Some(&source)).unwrap();
    for k in 0..20u32 {
        w.push(&RgbImage::from_pixel(
            64,
            48,
            image::Rgb([(10 * k + 5) as u8; 3]),
        ))
        .unwrap();
    }
    assert_eq!(w.finish().unwrap(), 20);
    let probe = Command::new("ffprobe")
        .args([
            "-v",
            "error",
            "-show_entries",
            "stream=codec_type",
            "-of",
            "csv=p=0",
        ])
        .arg(&out)
        .output()
        .unwrap();
    let kinds = String::from_utf8_lossy(&probe.stdout);
    assert!(
        kinds.contains("video") && kinds.contains("audio"),
        "{kinds}"
    );
    let all: Vec<_> = VideoReader::open(&out, &VideoOptions::default())
        .unwrap()
        .collect::<Result<_>>()
        .unwrap();
    assert_eq!(all.len(), 20);
    for (k, f) in all.iter().enumerate() {
        assert!(
            (level(&f.image) - (10 * k + 5) as f64).abs() < 4.0,
            "frame {k}"
        );
    }
    // Dropped before `finish`: no file under either name.
    let gone = dir.path().join("gone.mp4");
    let mut w = encode::VideoWriter::create(&gone, 64, 48, 29.97, 18, None).unwrap();
    w.push(&RgbImage::new(64, 48)).unwrap();
    drop(w);
    assert!(std::fs::read_dir(dir.path()).unwrap().all(|e| !e
        .unwrap()
        .file_name()
        .to_string_lossy()
        .starts_with("gone")));
}

/// A phone's focal length in the container's metadata (iPhone: the 35 mm equivalent under Apple's
/// QuickTime key) is read by the probe; a file without it has none; a value that is no focal
/// length is ignored.
#[test]
#[cfg_attr(not(has_ffmpeg), ignore = "needs ffmpeg (missing)")]
fn the_35mm_focal_length_a_phone_writes_is_read() {
    need_ffmpeg();
    let dir = tempfile::tempdir().unwrap();
    let tagged = |name: &str, value: Option<&str>| {
        let p = dir.path().join(name);
        let mut cmd = Command::new("ffmpeg");
        cmd.args([
            "-v",
            "error",
            "-y",
            "-f",
            "lavfi",
            "-i",
            "testsrc=size=64x48:rate=10",
        ])
        .args(["-t", "0.5", "-c:v", "mpeg4"]);
        if let Some(v) = value {
            cmd.args(["-movflags", "use_metadata_tags", "-metadata"])
                .arg(format!("{}={v}", FOCAL_35MM_TAGS[0]));
        }
        assert!(cmd.arg(&p).status().unwrap().success());
        probe(&p).unwrap().focal_length_35mm
    };
    assert_eq!(tagged("phone.mov", Some("26")), Some(26.0));
    assert_eq!(tagged("plain.mov", None), None);
    assert_eq!(tagged("odd.mov", Some("0")), None);

    let tags = serde_json::json!({"FocalLengthIn35mmFilm": "28 mm"});
    assert_eq!(focal_35mm_from_tags(&[&tags]), Some(28.0));
}
