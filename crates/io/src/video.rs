//! Video ingest through the `ffmpeg` program run as a subprocess. Frames stream as binary PPM over a
//! pipe (`-f image2pipe -c:v ppm`): raw RGB with a tiny header that carries the size, so rotated phone
//! videos need no special case and nothing is dumped to disk. Stride and time range are applied by
//! ffmpeg (`select` filter, input seek), so skipped frames are never converted or piped.
//! Encoding (frames to H.264, [`encode_h264`], [`encode_h264_frames`]) lives in [`encode`].

use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdout, Command, Stdio};
use std::thread::JoinHandle;

use image::RgbImage;
use serde::{Deserialize, Serialize};

use crate::error::{IoError, Result};

pub mod encode;
pub use encode::{encode_h264, encode_h264_frames, EncodeOptions};

/// File extensions (lower case) recognised as video.
pub const VIDEO_EXTENSIONS: [&str; 6] = ["mp4", "mov", "avi", "mkv", "m4v", "webm"];

/// True when the file name has one of [`VIDEO_EXTENSIONS`].
pub fn has_video_extension(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .map(|e| VIDEO_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
        .unwrap_or(false)
}

/// Options of video ingest.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct VideoOptions {
    /// Keep every `stride`-th frame (default 1: every frame). Must be ≥ 1.
    pub stride: u32,
    /// Start time in seconds (default 0).
    pub start_s: f64,
    /// End time in seconds, exclusive; `None` reads to the end.
    pub end_s: Option<f64>,
    /// Stop after this many kept frames; `None` for no limit.
    pub max_frames: Option<usize>,
}

impl Default for VideoOptions {
    fn default() -> Self {
        Self {
            stride: 1,
            start_s: 0.0,
            end_s: None,
            max_frames: None,
        }
    }
}

impl VideoOptions {
    /// Checks the option ranges; the error names the option (and its command-line flag).
    pub fn validate(&self) -> Result<()> {
        let bad =
            |option: &'static str, reason: String| Err(IoError::InvalidOption { option, reason });
        if self.stride == 0 {
            return bad("stride", "--stride must be at least 1".into());
        }
        if !self.start_s.is_finite() || self.start_s < 0.0 {
            return bad(
                "start_s",
                format!("--start must be a time ≥ 0 s, got {}", self.start_s),
            );
        }
        if let Some(end) = self.end_s {
            if !end.is_finite() || end <= self.start_s {
                return bad(
                    "end_s",
                    format!(
                        "--end ({end} s) must come after --start ({} s)",
                        self.start_s
                    ),
                );
            }
        }
        if self.max_frames == Some(0) {
            return bad("max_frames", "--max-frames must be at least 1".into());
        }
        Ok(())
    }
}

/// Stream facts from `ffprobe`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct VideoInfo {
    pub codec: String,
    /// Coded size (before any rotation metadata is applied).
    pub width: u32,
    pub height: u32,
    /// Average frame rate in frames per second.
    pub fps: f64,
    /// Duration in seconds, when known.
    pub duration_s: Option<f64>,
    /// Number of frames, when the container records it.
    pub num_frames: Option<u64>,
    /// The 35 mm-equivalent focal length (mm) a phone wrote in the container's metadata
    /// ([`focal_35mm_from_tags`]), when present: a prior only.
    #[serde(default)]
    pub focal_length_35mm: Option<f64>,
}

/// Metadata keys (QuickTime/MP4 tags as `ffprobe` shows them, compared in lower case) that hold a
/// 35 mm-equivalent focal length in millimetres: Apple's (iPhone videos carry
/// `com.apple.quicktime.camera.focal_length.35mm_equivalent`) and the EXIF name some Android
/// recorders copy into their `udta` atoms.
pub const FOCAL_35MM_TAGS: [&str; 3] = [
    "com.apple.quicktime.camera.focal_length.35mm_equivalent",
    "focallengthin35mmfilm",
    "focal_length_35mm",
];

/// The 35 mm-equivalent focal length in the format's or the stream's tags (an `ffprobe -of json`
/// `tags` object each), when one of [`FOCAL_35MM_TAGS`] holds a number in 5–500 mm.
pub fn focal_35mm_from_tags(tags: &[&serde_json::Value]) -> Option<f64> {
    tags.iter()
        .filter_map(|t| t.as_object())
        .flat_map(|o| o.iter())
        .filter(|(k, _)| FOCAL_35MM_TAGS.contains(&k.to_ascii_lowercase().as_str()))
        .filter_map(|(_, v)| {
            v.as_str()
                .and_then(|s| s.trim().trim_end_matches("mm").trim().parse::<f64>().ok())
                .or_else(|| v.as_f64())
        })
        .find(|f| (5.0..=500.0).contains(f))
}

/// One decoded frame.
#[derive(Clone, Debug)]
pub struct VideoFrame {
    /// Index of the frame in the full stream (before stride), counting from the start of the file.
    pub index: u64,
    /// Time from the start of the video in seconds (index / fps).
    pub time_s: f64,
    pub image: RgbImage,
}

/// The `ffmpeg` program: `$HANDHELD_FFMPEG` or `ffmpeg` on the PATH.
pub fn ffmpeg_program() -> String {
    std::env::var("HANDHELD_FFMPEG").unwrap_or_else(|_| "ffmpeg".into())
}

/// The `ffprobe` program: `$HANDHELD_FFPROBE`, else the sibling of a custom ffmpeg, else `ffprobe`.
pub fn ffprobe_program() -> String {
    if let Ok(p) = std::env::var("HANDHELD_FFPROBE") {
        return p;
    }
    let ff = ffmpeg_program();
    let path = Path::new(&ff);
    match path.parent().filter(|p| !p.as_os_str().is_empty()) {
        Some(dir) => dir.join("ffprobe").to_string_lossy().into_owned(),
        None => "ffprobe".into(),
    }
}

fn spawn_error(program: &str, e: std::io::Error) -> IoError {
    if e.kind() == std::io::ErrorKind::NotFound {
        IoError::FfmpegMissing {
            program: program.into(),
        }
    } else {
        IoError::io(program, e)
    }
}

fn first_line(stderr: &[u8]) -> String {
    let text = String::from_utf8_lossy(stderr);
    let line = text
        .lines()
        .map(str::trim)
        .rfind(|l| !l.is_empty())
        .unwrap_or("no video stream found");
    line.to_string()
}

fn parse_rate(s: &str) -> Option<f64> {
    let (n, d) = s.split_once('/').unwrap_or((s, "1"));
    let (n, d): (f64, f64) = (n.parse().ok()?, d.parse().ok()?);
    (d != 0.0 && n > 0.0).then_some(n / d)
}

/// Probes the first video stream of a file.
pub fn probe(path: &Path) -> Result<VideoInfo> {
    if !path.exists() {
        return Err(IoError::NotFound {
            path: path.to_path_buf(),
        });
    }
    let program = ffprobe_program();
    let out = Command::new(&program)
        .args(["-v", "error", "-select_streams", "v:0", "-show_entries"])
        .arg("stream=codec_name,width,height,avg_frame_rate,r_frame_rate,nb_frames,duration:stream_tags:format=duration:format_tags")
        .args(["-of", "json"])
        .arg(path)
        .stdin(Stdio::null())
        .output()
        .map_err(|e| spawn_error(&program, e))?;
    let video_err = |reason: String| IoError::Video {
        path: path.to_path_buf(),
        reason,
    };
    if !out.status.success() {
        return Err(video_err(first_line(&out.stderr)));
    }
    let json: serde_json::Value = serde_json::from_slice(&out.stdout)
        .map_err(|e| video_err(format!("unreadable ffprobe output: {e}")))?;
    let stream = json["streams"]
        .get(0)
        .ok_or_else(|| video_err("the file has no video stream".into()))?;
    let num = |v: &serde_json::Value| {
        v.as_str()
            .and_then(|s| s.parse::<f64>().ok())
            .or_else(|| v.as_f64())
    };
    let width = stream["width"].as_u64().unwrap_or(0) as u32;
    let height = stream["height"].as_u64().unwrap_or(0) as u32;
    if width == 0 || height == 0 {
        return Err(video_err("the video stream has no frame size".into()));
    }
    let fps = stream["avg_frame_rate"]
        .as_str()
        .and_then(parse_rate)
        .or_else(|| stream["r_frame_rate"].as_str().and_then(parse_rate))
        .ok_or_else(|| video_err("the video stream has no frame rate".into()))?;
    Ok(VideoInfo {
        codec: stream["codec_name"]
            .as_str()
            .unwrap_or("unknown")
            .to_string(),
        width,
        height,
        fps,
        duration_s: num(&stream["duration"]).or_else(|| num(&json["format"]["duration"])),
        num_frames: num(&stream["nb_frames"]).map(|n| n as u64),
        focal_length_35mm: focal_35mm_from_tags(&[&json["format"]["tags"], &stream["tags"]]),
    })
}

/// Streams the frames of a video; an iterator of `Result<VideoFrame>`.
pub struct VideoReader {
    path: PathBuf,
    info: VideoInfo,
    opts: VideoOptions,
    child: Child,
    stdout: BufReader<ChildStdout>,
    stderr: Option<JoinHandle<Vec<u8>>>,
    first_index: u64,
    emitted: usize,
    done: bool,
}

impl VideoReader {
    /// Probes the file and starts ffmpeg.
    pub fn open(path: &Path, opts: &VideoOptions) -> Result<Self> {
        opts.validate()?;
        let info = probe(path)?;
        let program = ffmpeg_program();
        let mut cmd = Command::new(&program);
        cmd.args(["-nostdin", "-hide_banner", "-v", "error"]);
        if opts.start_s > 0.0 {
            cmd.args(["-ss", &format!("{}", opts.start_s)]);
        }
        cmd.arg("-i").arg(path);
        if let Some(end) = opts.end_s {
            cmd.args(["-t", &format!("{}", end - opts.start_s)]);
        }
        if opts.stride > 1 {
            cmd.args(["-vf", &format!("select=not(mod(n\\,{}))", opts.stride)]);
        }
        cmd.args([
            "-fps_mode",
            "passthrough",
            "-an",
            "-f",
            "image2pipe",
            "-c:v",
            "ppm",
            "pipe:1",
        ]);
        let mut child = cmd
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| spawn_error(&program, e))?;
        let stdout = child.stdout.take().ok_or_else(|| IoError::Video {
            path: path.to_path_buf(),
            reason: "no output pipe".into(),
        })?;
        let stderr = collect_stderr(&mut child);
        let first_index = (opts.start_s * info.fps).round() as u64;
        Ok(Self {
            path: path.to_path_buf(),
            info,
            opts: opts.clone(),
            child,
            stdout: BufReader::with_capacity(1 << 20, stdout),
            stderr: Some(stderr),
            first_index,
            emitted: 0,
            done: false,
        })
    }

    pub fn info(&self) -> &VideoInfo {
        &self.info
    }

    /// An estimate of how many frames the options will yield (for progress bars).
    pub fn estimated_frames(&self) -> Option<u64> {
        let duration = self.info.duration_s?;
        let end = self.opts.end_s.map_or(duration, |e| e.min(duration));
        let frames = ((end - self.opts.start_s).max(0.0) * self.info.fps / self.opts.stride as f64)
            .ceil() as u64;
        Some(
            self.opts
                .max_frames
                .map_or(frames, |m| frames.min(m as u64)),
        )
    }

    fn video_err(&self, reason: String) -> IoError {
        IoError::Video {
            path: self.path.clone(),
            reason,
        }
    }

    /// Reads one PPM token (header field), skipping whitespace and comments.
    fn token(&mut self) -> std::io::Result<Option<String>> {
        let mut tok = Vec::new();
        loop {
            let buf = self.stdout.fill_buf()?;
            if buf.is_empty() {
                return Ok((!tok.is_empty()).then(|| String::from_utf8_lossy(&tok).into_owned()));
            }
            let c = buf[0];
            if c == b'#' && tok.is_empty() {
                let mut line = Vec::new();
                self.stdout.read_until(b'\n', &mut line)?;
                continue;
            }
            self.stdout.consume(1);
            if c.is_ascii_whitespace() {
                if tok.is_empty() {
                    continue;
                }
                return Ok(Some(String::from_utf8_lossy(&tok).into_owned()));
            }
            tok.push(c);
        }
    }

    fn read_frame(&mut self) -> Result<Option<RgbImage>> {
        let io = |e: std::io::Error| IoError::Video {
            path: PathBuf::new(),
            reason: e.to_string(),
        };
        let Some(magic) = self.token().map_err(io)? else {
            return Ok(None);
        };
        if magic != "P6" {
            return Err(self.video_err(format!("unexpected frame header {magic:?} from ffmpeg")));
        }
        let mut fields = [0u32; 3];
        for f in &mut fields {
            let t = self
                .token()
                .map_err(io)?
                .ok_or_else(|| self.video_err("truncated frame header".into()))?;
            *f = t
                .parse()
                .map_err(|_| self.video_err(format!("bad frame header field {t:?}")))?;
        }
        let [w, h, maxval] = fields;
        if maxval != 255 {
            return Err(self.video_err(format!("unexpected frame depth {maxval}")));
        }
        let mut data = vec![0u8; w as usize * h as usize * 3];
        self.stdout
            .read_exact(&mut data)
            .map_err(|e| self.video_err(format!("frame cut short: {e}")))?;
        RgbImage::from_raw(w, h, data)
            .map(Some)
            .ok_or_else(|| self.video_err("frame size mismatch".into()))
    }

    fn finish(&mut self) -> Result<()> {
        self.done = true;
        let status = self.child.wait().map_err(|e| IoError::io(&self.path, e))?;
        let stderr = self
            .stderr
            .take()
            .and_then(|h| h.join().ok())
            .unwrap_or_default();
        if !status.success() && self.emitted == 0 {
            return Err(self.video_err(first_line(&stderr)));
        }
        if self.emitted == 0 {
            return Err(self.video_err("no frames in the requested range".into()));
        }
        Ok(())
    }
}

impl Iterator for VideoReader {
    type Item = Result<VideoFrame>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.done {
            return None;
        }
        if self.opts.max_frames.is_some_and(|m| self.emitted >= m) {
            self.done = true;
            let _ = self.child.kill();
            let _ = self.child.wait();
            return None;
        }
        match self.read_frame() {
            Ok(Some(image)) => {
                let index = self.first_index + self.emitted as u64 * self.opts.stride as u64;
                self.emitted += 1;
                Some(Ok(VideoFrame {
                    index,
                    time_s: index as f64 / self.info.fps,
                    image,
                }))
            }
            Ok(None) => self.finish().err().map(Err),
            Err(e) => {
                self.done = true;
                let _ = self.child.kill();
                let _ = self.child.wait();
                Some(Err(e))
            }
        }
    }
}

impl Drop for VideoReader {
    fn drop(&mut self) {
        if !self.done {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}

/// Collects a child's stderr on a thread, so a chatty ffmpeg never blocks on a full pipe.
pub(crate) fn collect_stderr(child: &mut std::process::Child) -> std::thread::JoinHandle<Vec<u8>> {
    let mut err_pipe = child.stderr.take();
    std::thread::spawn(move || {
        let mut buf = Vec::new();
        if let Some(p) = err_pipe.as_mut() {
            let _ = p.read_to_end(&mut buf);
        }
        buf
    })
}

#[cfg(test)]
#[path = "video_tests.rs"]
mod tests;
