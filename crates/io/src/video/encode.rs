//! Video encoding through the `ffmpeg` program: frames to an H.264 video, as a camcorder or phone
//! would record it. Either numbered image files (`frame_%04d.png`, ffmpeg's image2 pattern) or
//! frames in memory, streamed as raw RGB over a pipe. The video is written next to its final name
//! (same extension, so ffmpeg picks the same container) and renamed when complete, so a failed or
//! interrupted run never leaves a truncated file under the final name.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use image::RgbImage;
use serde::{Deserialize, Serialize};

use super::{ffmpeg_program, first_line, spawn_error};
use crate::error::{IoError, Result};

/// Options of [`encode_h264`] and [`encode_h264_frames`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EncodeOptions {
    /// Frames per second of the video. Default 25.
    pub fps: u32,
    /// x264 constant rate factor, 0 (lossless) to 51 (worst). Default 12 (visually lossless).
    pub crf: u8,
}

impl Default for EncodeOptions {
    fn default() -> Self {
        Self { fps: 25, crf: 12 }
    }
}

impl EncodeOptions {
    /// Checks the option ranges; the error names the option.
    pub fn validate(&self) -> Result<()> {
        if self.fps == 0 {
            return Err(IoError::InvalidOption {
                option: "fps",
                reason: "must be at least 1 frame per second".into(),
            });
        }
        if self.crf > 51 {
            return Err(IoError::InvalidOption {
                option: "crf",
                reason: format!("must be in 0..=51, got {}", self.crf),
            });
        }
        Ok(())
    }
}

/// The temporary sibling of `output`: `video.mp4` → `video.tmp.mp4`.
fn temporary_path(output: &Path) -> PathBuf {
    let stem = output
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let name = match output.extension() {
        Some(ext) => format!("{stem}.tmp.{}", ext.to_string_lossy()),
        None => format!("{stem}.tmp"),
    };
    output.with_file_name(name)
}

/// The common tail of the command: H.264 in yuv420p (what players and phones decode) to `tmp`.
fn h264_args(cmd: &mut Command, opts: &EncodeOptions, tmp: &Path) {
    cmd.args(["-c:v", "libx264", "-crf", &opts.crf.to_string()])
        .args(["-pix_fmt", "yuv420p"])
        .arg(tmp);
}

/// Waits for ffmpeg, then renames the temporary file to `output` (removing it on failure).
fn finish(
    mut child: std::process::Child,
    stderr: std::thread::JoinHandle<Vec<u8>>,
    tmp: &Path,
    output: &Path,
) -> Result<()> {
    let status = child.wait().map_err(|e| IoError::io(output, e));
    let err_text = stderr.join().unwrap_or_default();
    let fail = |reason: String| {
        let _ = std::fs::remove_file(tmp);
        Err(IoError::Encode {
            path: output.to_path_buf(),
            reason,
        })
    };
    match status {
        Ok(s) if s.success() => {}
        Ok(s) => return fail(format!("{} ({s})", first_line(&err_text))),
        Err(e) => return fail(e.to_string()),
    }
    std::fs::rename(tmp, output).map_err(|e| {
        let _ = std::fs::remove_file(tmp);
        IoError::io(output, e)
    })
}

/// Starts `cmd` with stderr collected on a thread (so a chatty ffmpeg cannot block on it).
fn spawn(
    mut cmd: Command,
    program: &str,
) -> Result<(std::process::Child, std::thread::JoinHandle<Vec<u8>>)> {
    let mut child = cmd
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| spawn_error(program, e))?;
    let stderr = super::collect_stderr(&mut child);
    Ok((child, stderr))
}

/// Encodes the numbered images matching `pattern` (ffmpeg's image2 syntax, e.g.
/// `images/frame_%04d.png`, numbered from 0 or 1) as an H.264 video at `output`, whose extension
/// picks the container (`.mp4`, `.mkv`, …). Image sizes must be even (yuv420p). Runs
/// `ffmpeg -framerate FPS -i PATTERN -c:v libx264 -crf CRF -pix_fmt yuv420p OUTPUT`.
pub fn encode_h264(pattern: &Path, output: &Path, opts: &EncodeOptions) -> Result<()> {
    opts.validate()?;
    let program = ffmpeg_program();
    let tmp = temporary_path(output);
    let mut cmd = Command::new(&program);
    cmd.args(["-nostdin", "-y", "-loglevel", "error"])
        .args(["-framerate", &opts.fps.to_string(), "-i"])
        .arg(pattern)
        .stdin(Stdio::null());
    h264_args(&mut cmd, opts, &tmp);
    let (child, stderr) = spawn(cmd, &program)?;
    finish(child, stderr, &tmp, output)
}

/// Encodes frames held in memory as an H.264 video at `output` (see [`encode_h264`]); every frame
/// must have the size of the first, with even width and height (yuv420p).
pub fn encode_h264_frames<'a>(
    frames: impl IntoIterator<Item = &'a RgbImage>,
    output: &Path,
    opts: &EncodeOptions,
) -> Result<()> {
    opts.validate()?;
    let mut frames = frames.into_iter().peekable();
    let (w, h) = match frames.peek() {
        Some(f) => f.dimensions(),
        None => {
            return Err(IoError::Input {
                path: output.to_path_buf(),
                reason: "no frames to encode".into(),
            })
        }
    };
    let mut writer = VideoWriter::create(output, w, h, f64::from(opts.fps), opts.crf, None)?;
    for frame in frames {
        writer.push(frame)?;
    }
    writer.finish().map(|_| ())
}

/// An H.264 video written frame by frame (frames streamed to `ffmpeg` as raw RGB, none kept in
/// memory), optionally with the audio of another file (the input video's, copied through
/// `-map 1:a?`: a source without audio gives a silent video). The video is written next to its
/// final name and renamed by [`VideoWriter::finish`]; dropped unfinished, it is removed.
pub struct VideoWriter {
    child: Option<std::process::Child>,
    stdin: Option<std::process::ChildStdin>,
    stderr: Option<std::thread::JoinHandle<Vec<u8>>>,
    tmp: PathBuf,
    output: PathBuf,
    size: (u32, u32),
    frames: usize,
}

impl VideoWriter {
    /// Starts ffmpeg for `width × height` frames (even sizes) at `fps` frames per second.
    pub fn create(
        output: &Path,
        width: u32,
        height: u32,
        fps: f64,
        crf: u8,
        audio_from: Option<&Path>,
    ) -> Result<Self> {
        let input = |reason: String| IoError::Input {
            path: output.to_path_buf(),
            reason,
        };
        if width == 0 || height == 0 || !width.is_multiple_of(2) || !height.is_multiple_of(2) {
            return Err(input(format!(
                "frames of {width}×{height} cannot be encoded: H.264 in yuv420p needs an even, non-zero width and height"
            )));
        }
        if !(fps.is_finite() && fps > 0.0) {
            return Err(IoError::InvalidOption {
                option: "fps",
                reason: format!("must be positive, got {fps}"),
            });
        }
        let opts = EncodeOptions { fps: 1, crf };
        opts.validate()?;
        let program = ffmpeg_program();
        let tmp = temporary_path(output);
        let mut cmd = Command::new(&program);
        cmd.args([
            "-y",
            "-loglevel",
            "error",
            "-f",
            "rawvideo",
            "-pix_fmt",
            "rgb24",
        ])
        .args([
            "-s",
            &format!("{width}x{height}"),
            "-framerate",
            &format!("{fps}"),
        ])
        .args(["-i", "pipe:0"]);
        if let Some(a) = audio_from {
            cmd.arg("-i").arg(a).args([
                "-map",
                "0:v:0",
                "-map",
                "1:a?",
                "-c:a",
                "aac",
                "-shortest",
            ]);
        }
        cmd.stdin(Stdio::piped());
        h264_args(&mut cmd, &opts, &tmp);
        let (mut child, stderr) = spawn(cmd, &program)?;
        let stdin = child.stdin.take();
        Ok(Self {
            child: Some(child),
            stdin,
            stderr: Some(stderr),
            tmp,
            output: output.to_path_buf(),
            size: (width, height),
            frames: 0,
        })
    }

    /// Sends one frame (it must have the writer's size).
    pub fn push(&mut self, frame: &RgbImage) -> Result<()> {
        if frame.dimensions() != self.size {
            return Err(IoError::Input {
                path: self.output.clone(),
                reason: format!(
                    "frame {} is {}×{}, the video {}×{}",
                    self.frames,
                    frame.width(),
                    frame.height(),
                    self.size.0,
                    self.size.1
                ),
            });
        }
        if let Some(stdin) = self.stdin.as_mut() {
            if stdin.write_all(frame.as_raw()).is_err() {
                // ffmpeg stopped; `finish` reports its own message.
                self.stdin = None;
            }
        }
        self.frames += 1;
        Ok(())
    }

    /// Closes the stream, waits for ffmpeg and renames the video to its final name.
    pub fn finish(mut self) -> Result<usize> {
        self.stdin = None;
        let (Some(child), Some(stderr)) = (self.child.take(), self.stderr.take()) else {
            return Ok(self.frames);
        };
        finish(child, stderr, &self.tmp, &self.output)?;
        Ok(self.frames)
    }
}

impl Drop for VideoWriter {
    fn drop(&mut self) {
        self.stdin = None;
        if let Some(mut child) = self.child.take() {
            let _ = child.kill();
            let _ = child.wait();
            let _ = std::fs::remove_file(&self.tmp);
        }
    }
}
