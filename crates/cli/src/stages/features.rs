//! The features stage: RootSIFT on every ingested image, in parallel, one `features/<index>.feat`
//! file per image (full-precision keypoints and descriptors); for video, KLT tracks and key-frames
//! instead (see [`super::tracks`]).

use std::time::Instant;

use anyhow::{Context, Result};
use handheld_core::Progress;
use handheld_features::extract::{extract_features, ExtractionOptions};
use handheld_features::sift::SiftOptions;
use handheld_io::features_file::{write_features, FeatureFile};
use handheld_io::images::{load_image, ImageIngestOptions};
use handheld_io::workspace::{Fingerprint, Workspace};
use rayon::prelude::*;

use handheld_features::video::VideoTrackingOptions;
use handheld_io::ingest::InputKind;
use serde::Serialize;

use crate::args::{InputArgs, TrackingMode};
use crate::pipeline::{run_stage, Stage, StageOutput, StageReport};
use crate::ui::Bars;

/// The file name of image `index`'s features.
pub fn feature_file_name(index: usize) -> String {
    format!("{index:06}.feat")
}

/// Options of the features stage.
#[derive(Clone, Debug, Serialize)]
pub struct FeatureStageOptions {
    pub extraction: ExtractionOptions,
    pub tracking: TrackingMode,
    /// Live KLT tracks kept per frame (video).
    pub klt_features: usize,
}

impl FeatureStageOptions {
    /// Whether this input is tracked with KLT rather than matched with SIFT.
    pub fn uses_klt(&self, kind: InputKind) -> bool {
        match self.tracking {
            TrackingMode::Auto => kind == InputKind::Video,
            TrackingMode::Klt => true,
            TrackingMode::Sift => false,
        }
    }

    pub fn video_tracking(&self) -> VideoTrackingOptions {
        let mut v = VideoTrackingOptions::default();
        v.klt.target_features = self.klt_features;
        v
    }
}

pub fn options(a: &InputArgs) -> Result<FeatureStageOptions> {
    let extraction = ExtractionOptions {
        sift: SiftOptions {
            max_features: Some(a.max_features),
            ..ExtractionOptions::default().sift
        },
        max_image_size: a.max_image_size,
        ..ExtractionOptions::default()
    };
    extraction.validate().map_err(anyhow::Error::msg)?;
    let opts = FeatureStageOptions {
        extraction,
        tracking: a.tracking,
        klt_features: a.klt_features,
    };
    opts.video_tracking()
        .validate()
        .map_err(|e| anyhow::anyhow!("--klt-features: {e}"))?;
    Ok(opts)
}

pub fn run(
    ws: &Workspace,
    stage_opts: &FeatureStageOptions,
    force: bool,
    bars: &Bars,
) -> Result<StageReport> {
    let ingest = super::load_ingest(ws)?;
    let klt = stage_opts.uses_klt(ingest.kind);
    let opts = &stage_opts.extraction;
    let fp_opts = if klt {
        serde_json::json!({"tracking": "klt", "klt_features": stage_opts.klt_features})
    } else {
        serde_json::to_value(opts)?
    };
    run_stage(
        ws,
        Stage::Features,
        Fingerprint::new(),
        fp_opts,
        force,
        |dir| {
            if klt {
                return super::tracks::run_tracking(
                    &ingest,
                    dir,
                    &stage_opts.video_tracking(),
                    bars,
                );
            }
            bars.start("features", ingest.images.len() as u64);
            let load_opts = ImageIngestOptions {
                min_dimension: 1,
                ..Default::default()
            };
            let results: Vec<Result<(usize, f64)>> = ingest
                .images
                .par_iter()
                .enumerate()
                .map(|(k, img)| {
                    let loaded = load_image(&img.info.path, &load_opts)?;
                    let t0 = Instant::now();
                    let f = extract_features(&loaded.image, opts);
                    let secs = t0.elapsed().as_secs_f64();
                    let file = to_file(f);
                    write_features(&dir.join(feature_file_name(k)), &file)
                        .with_context(|| format!("features of {}", img.info.name))?;
                    bars.inc(1);
                    Ok((file.keypoints.len(), secs))
                })
                .collect();
            bars.finish();
            let results: Vec<(usize, f64)> = results.into_iter().collect::<Result<_>>()?;
            let counts: Vec<usize> = results.iter().map(|r| r.0).collect();
            let mut secs: Vec<f64> = results.iter().map(|r| r.1).collect();
            secs.sort_by(|a, b| a.total_cmp(b));
            let min = counts.iter().min().copied().unwrap_or(0);
            if min < 50 {
                tracing::warn!("an image has only {min} features: textureless, blurred or tiny images match poorly");
            }
            Ok(StageOutput {
                outputs: (0..counts.len()).map(feature_file_name).collect(),
                summary: serde_json::json!({
                    "images": counts.len(),
                    "features_per_image_median": median_usize(&counts),
                    "features_min": min,
                    "extraction_seconds_median": secs.get(secs.len() / 2),
                }),
            })
        },
    )
}

/// The on-disk form of one image's features.
pub fn to_file(f: handheld_features::Features) -> FeatureFile {
    FeatureFile {
        keypoints: f
            .keypoints
            .iter()
            .map(|k| [k.x, k.y, k.scale, k.orientation, k.response])
            .collect(),
        dim: f.descriptors.dim,
        descriptors: f.descriptors.data,
    }
}

fn median_usize(v: &[usize]) -> usize {
    let mut s = v.to_vec();
    s.sort_unstable();
    s.get(s.len() / 2).copied().unwrap_or(0)
}
