//! The video half of the features stage (§2.1 tracking, §3.1 key-frames): KLT tracks over every
//! frame instead of SIFT, `features/tracks.json` with the stable track ids and the GRIC key-frames.

use std::path::Path;

use handheld_core::Progress;
use handheld_features::video::{track_video, VideoTrackingOptions, VideoTracks};
use handheld_features::GrayImage;
use handheld_io::features_file::write_features;
use handheld_io::images::{load_image, ImageIngestOptions};
use handheld_io::ingest::IngestResult;
use rayon::prelude::*;

use crate::error::{Context, PipelineError, Result};
use crate::files::{feature_file_name, TRACKS_JSON};
use crate::stage::Produced;
use crate::stages::features::{to_file, FeaturesSummary};

/// Frames decoded in parallel ahead of the (sequential) tracker.
const CHUNK: usize = 16;

/// Tracks every ingested frame.
pub fn track(
    ingest: &IngestResult,
    opts: &VideoTrackingOptions,
    bars: &dyn Progress,
) -> Result<VideoTracks> {
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
    Ok(tracks)
}

/// Writes one feature file per frame (the live tracks as keypoints, no descriptors) and
/// `tracks.json`.
pub fn write_tracking(tracks: &VideoTracks, dir: &Path) -> Result<Produced<FeaturesSummary>> {
    for k in 0..tracks.num_frames() {
        write_features(
            &dir.join(feature_file_name(k)),
            &to_file(tracks.features(k)),
        )?;
    }
    let bytes = serde_json::to_vec(&tracks)
        .map_err(|e| PipelineError::workspace(dir.join(TRACKS_JSON), e.to_string()))?;
    handheld_io::atomic::write_bytes_atomic(&dir.join(TRACKS_JSON), &bytes)?;
    let mut counts: Vec<usize> = tracks.points.iter().map(Vec::len).collect();
    counts.sort_unstable();
    let mut outputs: Vec<String> = (0..tracks.num_frames()).map(feature_file_name).collect();
    outputs.push(TRACKS_JSON.into());
    let mut warnings = Vec::new();
    if tracks.keyframes.len() < 2 {
        warnings.push(format!(
            "only {} key-frame(s): the camera hardly moves, or tracking failed",
            tracks.keyframes.len()
        ));
    }
    Ok(Produced {
        outputs,
        summary: FeaturesSummary::Klt {
            images: tracks.num_frames(),
            tracking: "klt".into(),
            tracks_per_frame_median: counts.get(counts.len() / 2).copied(),
            keyframes: tracks.keyframes.len(),
            keyframe_frames: tracks.keyframes.iter().map(|k| k.0).collect(),
        },
        warnings,
    })
}

/// An error that `track_video` can build from its option messages.
struct TrackError(PipelineError);

impl From<String> for TrackError {
    fn from(s: String) -> Self {
        Self(PipelineError::Step {
            context: "video tracking".into(),
            cause: s.into(),
        })
    }
}
