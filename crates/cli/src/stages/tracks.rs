//! The video half of the features and matches stages (§2.1 tracking, §3.1 key-frames): KLT tracks
//! over every frame instead of SIFT, `features/tracks.json` with the stable track ids and the GRIC
//! key-frames, and key-frame pairs verified from their shared tracks.

use std::path::Path;

use anyhow::{Context, Result};
use handheld_core::Progress;
use handheld_features::video::{track_video, VideoTrackingOptions, VideoTracks};
use handheld_features::GrayImage;
use handheld_io::features_file::write_features;
use handheld_io::images::{load_image, ImageIngestOptions};
use handheld_io::ingest::IngestResult;
use handheld_io::workspace::Workspace;
use rayon::prelude::*;

use crate::pipeline::{Stage, StageOutput};
use crate::stages::features::feature_file_name;
use crate::ui::Bars;

/// Name of the tracks file in the features stage folder.
pub const TRACKS_FILE: &str = "tracks.json";

/// Frames decoded in parallel ahead of the (sequential) tracker.
const CHUNK: usize = 16;

/// Tracks every ingested frame, writes one feature file per frame (the live tracks as keypoints, no
/// descriptors) and `tracks.json`.
pub fn run_tracking(
    ingest: &IngestResult,
    dir: &Path,
    opts: &VideoTrackingOptions,
    bars: &Bars,
) -> Result<StageOutput> {
    let load_opts = ImageIngestOptions {
        min_dimension: 1,
        ..Default::default()
    };
    bars.start("tracking (KLT)", ingest.images.len() as u64);
    let chunks = ingest.images.chunks(CHUNK).flat_map(|chunk| {
        let loaded: Vec<Result<GrayImage>> = chunk
            .par_iter()
            .map(|img| {
                let l = load_image(&img.info.path, &load_opts).with_context(|| {
                    format!("{}: cannot read the frame", img.info.path.display())
                })?;
                Ok(GrayImage::from_dynamic(&l.image))
            })
            .collect();
        loaded
    });
    let tracks = track_video(chunks.map(|r| r.map_err(TrackError)), opts, bars).map_err(|e| e.0)?;
    bars.finish();
    for k in 0..tracks.num_frames() {
        write_features(
            &dir.join(feature_file_name(k)),
            &super::features::to_file(tracks.features(k)),
        )?;
    }
    handheld_io::atomic::write_bytes_atomic(&dir.join(TRACKS_FILE), &serde_json::to_vec(&tracks)?)?;
    let mut counts: Vec<usize> = tracks.points.iter().map(Vec::len).collect();
    counts.sort_unstable();
    let mut outputs: Vec<String> = (0..tracks.num_frames()).map(feature_file_name).collect();
    outputs.push(TRACKS_FILE.into());
    if tracks.keyframes.len() < 2 {
        tracing::warn!(
            "only {} key-frame(s): the camera hardly moves, or tracking failed",
            tracks.keyframes.len()
        );
    }
    Ok(StageOutput {
        outputs,
        summary: serde_json::json!({
            "images": tracks.num_frames(),
            "tracking": "klt",
            "tracks_per_frame_median": counts.get(counts.len() / 2),
            "keyframes": tracks.keyframes.len(),
            "keyframe_frames": tracks.keyframes.iter().map(|k| k.0).collect::<Vec<_>>(),
        }),
    })
}

/// An error that `track_video` can build from its option messages.
struct TrackError(anyhow::Error);

impl From<String> for TrackError {
    fn from(s: String) -> Self {
        Self(anyhow::Error::msg(s))
    }
}

/// The tracks of a video workspace, `None` when the features stage ran SIFT (photos).
pub fn load_tracks(ws: &Workspace) -> Result<Option<VideoTracks>> {
    let path = ws.root.join(Stage::Features.dir_name()).join(TRACKS_FILE);
    if !path.exists() {
        return Ok(None);
    }
    let bytes = std::fs::read(&path).with_context(|| {
        format!(
            "{}: cannot read (rerun features with --force)",
            path.display()
        )
    })?;
    let t: VideoTracks = serde_json::from_slice(&bytes)
        .with_context(|| format!("{}: corrupt (rerun features with --force)", path.display()))?;
    Ok(Some(t))
}
