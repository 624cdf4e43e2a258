//! The ingest stage: turns the user's input (a folder of photos or a video file) into a validated list
//! of images with metadata. Photos stay where they are (decoded again, with their EXIF orientation, by
//! later stages); video frames are streamed from ffmpeg and stored as PNG in the stage folder, because
//! every later stage (and the per-frame cameras of augmented video) needs them.

use std::path::{Path, PathBuf};

use handheld_core::{FrameInfo, Progress};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::atomic::write_bytes_atomic;
use crate::error::{IoError, Result};
use crate::images::{
    has_image_extension, list_image_folder, load_image, ExifInfo, ImageInfo, ImageIngestOptions,
};
use crate::video::{has_video_extension, VideoInfo, VideoOptions, VideoReader};

/// Options of the ingest stage.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct IngestOptions {
    pub images: ImageIngestOptions,
    pub video: VideoOptions,
}

impl IngestOptions {
    /// Checks option ranges; the error names the option.
    pub fn validate(&self) -> Result<()> {
        self.video.validate()?;
        self.images.validate()
    }
}

/// Photos or video.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum InputKind {
    Photos,
    Video,
}

/// One image ready for the pipeline.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct IngestedImage {
    pub info: ImageInfo,
    /// Frame index and time for video; `None` for photos.
    pub frame: Option<FrameInfo>,
}

/// The result of the ingest stage (saved as `ingest/images.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct IngestResult {
    pub kind: InputKind,
    pub input: PathBuf,
    pub images: Vec<IngestedImage>,
    /// Input files left out, with the reason.
    pub skipped: Vec<(PathBuf, String)>,
    pub video: Option<VideoInfo>,
}

/// Runs ingest on `input`; video frames are written to `frames_dir`.
pub fn ingest(
    input: &Path,
    frames_dir: &Path,
    opts: &IngestOptions,
    progress: &dyn Progress,
) -> Result<IngestResult> {
    opts.validate()?;
    if !input.exists() {
        return Err(IoError::NotFound {
            path: input.to_path_buf(),
        });
    }
    if input.is_dir() {
        return ingest_photos(input, opts, progress);
    }
    if has_image_extension(input) {
        return Err(IoError::Input {
            path: input.to_path_buf(),
            reason: "is a single image; give the folder that holds all the photos of the scene"
                .into(),
        });
    }
    if !has_video_extension(input) {
        tracing::warn!(
            "{}: unknown extension, trying to read it as a video",
            input.display()
        );
    }
    ingest_video(input, frames_dir, opts, progress)
}

fn ingest_photos(
    dir: &Path,
    opts: &IngestOptions,
    progress: &dyn Progress,
) -> Result<IngestResult> {
    let listing = list_image_folder(dir, &opts.images)?;
    for (path, why) in &listing.skipped {
        tracing::warn!("{}: skipped ({why})", path.display());
    }
    progress.start("reading images", listing.images.len() as u64);
    let loaded: Vec<Result<ImageInfo>> = listing
        .images
        .par_iter()
        .map(|p| {
            let r = load_image(p, &opts.images).map(|l| l.info);
            progress.inc(1);
            r
        })
        .collect();
    progress.finish();
    let mut images = Vec::new();
    let mut skipped = listing.skipped;
    for (path, r) in listing.images.iter().zip(loaded) {
        match r {
            Ok(info) => images.push(IngestedImage { info, frame: None }),
            Err(e) if opts.images.skip_unreadable => {
                tracing::warn!("skipped: {e}");
                skipped.push((path.clone(), e.to_string()));
            }
            Err(e) => return Err(e),
        }
    }
    if images.len() < opts.images.min_images {
        return Err(IoError::Input {
            path: dir.to_path_buf(),
            reason: format!(
                "only {} readable image(s) remain; need at least {}",
                images.len(),
                opts.images.min_images
            ),
        });
    }
    Ok(IngestResult {
        kind: InputKind::Photos,
        input: dir.to_path_buf(),
        images,
        skipped,
        video: None,
    })
}

fn ingest_video(
    path: &Path,
    frames_dir: &Path,
    opts: &IngestOptions,
    progress: &dyn Progress,
) -> Result<IngestResult> {
    let reader = VideoReader::open(path, &opts.video)?;
    let info = reader.info().clone();
    progress.start("decoding video", reader.estimated_frames().unwrap_or(0));
    std::fs::create_dir_all(frames_dir).map_err(|e| IoError::io(frames_dir, e))?;
    let mut images = Vec::new();
    for frame in reader {
        let frame = frame?;
        let name = format!("frame_{:06}.png", frame.index);
        let out = frames_dir.join(&name);
        write_png(&out, &frame.image)?;
        let (width, height) = frame.image.dimensions();
        if width < opts.images.min_dimension || height < opts.images.min_dimension {
            return Err(IoError::Input {
                path: path.to_path_buf(),
                reason: format!("video frames are only {width}×{height} pixels"),
            });
        }
        images.push(IngestedImage {
            info: ImageInfo {
                path: out,
                name,
                width,
                height,
                bit_depth: 8,
                channels: 3,
                exif: ExifInfo {
                    focal_length_35mm: info.focal_length_35mm,
                    ..Default::default()
                },
                focal_prior_px: ExifInfo {
                    focal_length_35mm: info.focal_length_35mm,
                    ..Default::default()
                }
                .focal_prior_px(width, height),
            },
            frame: Some(FrameInfo {
                index: frame.index,
                time_s: frame.time_s,
                keyframe: false,
            }),
        });
        progress.inc(1);
    }
    progress.finish();
    if images.len() < opts.images.min_images {
        return Err(IoError::Input {
            path: path.to_path_buf(),
            reason: format!(
                "only {} frame(s) in the requested range; need at least {}",
                images.len(),
                opts.images.min_images
            ),
        });
    }
    Ok(IngestResult {
        kind: InputKind::Video,
        input: path.to_path_buf(),
        images,
        skipped: Vec::new(),
        video: Some(info),
    })
}

/// Encodes an RGB image as PNG and writes it atomically.
pub fn write_png(path: &Path, image: &image::RgbImage) -> Result<()> {
    let mut png = Vec::new();
    image
        .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .map_err(|e| IoError::format(path, e.to_string()))?;
    write_bytes_atomic(path, &png)
}
