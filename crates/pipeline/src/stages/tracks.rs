//! The video half of the features stage (§2.1 tracking, §3.1 key-frames): KLT tracks over every
//! frame instead of SIFT, `features/tracks.json` with the stable track ids and the GRIC key-frames.

use handheld_core::Progress;
use handheld_features::video::{track_video, VideoTrackingOptions, VideoTracks};
use handheld_features::GrayImage;
use handheld_io::images::{load_image, ImageIngestOptions};
use handheld_io::ingest::IngestResult;
use rayon::prelude::*;

use crate::error::{Context, PipelineError, Result};

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
