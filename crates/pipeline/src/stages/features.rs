//! The features stage: RootSIFT on every ingested image, in parallel, one `features/<index>.feat`
//! file per image (full-precision keypoints and descriptors); for video, KLT tracks and key-frames
//! instead (see [`super::tracks`]).

use std::path::Path;
use std::time::Instant;

use handheld_features::extract::{extract_features, ExtractionOptions};
use handheld_features::video::{tracking_verdict, VideoTrackingOptions, VideoTracks};
use handheld_io::features_file::{write_features, FeatureFile};
use handheld_io::images::{load_image, ImageIngestOptions};
use handheld_io::ingest::InputKind;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{Context, PipelineError, Result};
use crate::files::{feature_file_name, stage, thumbnail_file_name, THUMB, THUMBS_DIR, TRACKS_JSON};
use crate::policy::FEW_FEATURES;
use crate::stage::{Produced, Stage, StageContext};
use crate::warning::{code, Warning};

/// How correspondences are found.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TrackingMode {
    /// KLT for a video file, SIFT for photos; SIFT for a video too when KLT does not hold over
    /// it (`handheld_features::video::tracking_verdict`).
    Auto,
    /// KLT tracks and key-frames (also for a folder of consecutive frames).
    Klt,
    /// SIFT features and descriptor matching.
    Sift,
}

/// Options of the features stage.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(default)]
pub struct FeaturesStageOptions {
    pub extraction: ExtractionOptions,
    pub tracking: TrackingMode,
    /// Live KLT tracks kept per frame (video).
    pub klt_features: usize,
}

impl Default for FeaturesStageOptions {
    fn default() -> Self {
        Self {
            extraction: ExtractionOptions::default(),
            tracking: TrackingMode::Auto,
            klt_features: 1000,
        }
    }
}

impl FeaturesStageOptions {
    /// Whether this input is tracked with KLT rather than matched with SIFT.
    pub fn uses_klt(&self, kind: InputKind) -> bool {
        match self.tracking {
            TrackingMode::Auto => kind == InputKind::Video,
            TrackingMode::Klt => true,
            TrackingMode::Sift => false,
        }
    }

    /// The tracker's options.
    pub fn video_tracking(&self) -> VideoTrackingOptions {
        let mut v = VideoTrackingOptions::default();
        v.klt.target_features = self.klt_features;
        v
    }

    pub fn validate(&self) -> Result<()> {
        self.extraction
            .validate()
            .map_err(|e| PipelineError::invalid(stage::FEATURES, e))?;
        self.video_tracking()
            .validate()
            .map_err(|e| PipelineError::option("--klt-features", e.to_string()))
    }
}

/// What the features stage found (SIFT) or tracked (KLT).
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(untagged)]
pub enum FeaturesSummary {
    Sift {
        images: usize,
        features_per_image_median: usize,
        features_min: usize,
        extraction_seconds_median: Option<f64>,
    },
    Klt {
        images: usize,
        tracking: String,
        tracks_per_frame_median: Option<usize>,
        keyframes: usize,
        keyframe_frames: Vec<usize>,
    },
}

/// The features stage.
pub struct Features {
    pub options: FeaturesStageOptions,
}

impl Stage for Features {
    type Options = FeaturesStageOptions;
    type Summary = FeaturesSummary;

    const NAME: &'static str = stage::FEATURES;
    const READS: &'static [&'static str] = &[stage::INGEST];
    const ABOUT: &'static str =
        "detect and describe features (RootSIFT), or track a video (KLT, GRIC key-frames)";

    fn options(&self) -> &FeaturesStageOptions {
        &self.options
    }

    fn validate(&self) -> Result<()> {
        self.options.validate()
    }

    fn units(&self, ctx: &StageContext) -> Result<usize> {
        let ingest = ctx.ws.read_ingest()?;
        Ok(if self.splits(&ingest) {
            ingest.images.len()
        } else {
            0
        })
    }

    fn run_unit(
        &self,
        ctx: &StageContext,
        dir: &Path,
        k: usize,
    ) -> Result<(Vec<String>, serde_json::Value)> {
        let ingest = ctx.ws.read_ingest()?;
        let img = ingest
            .images
            .get(k)
            .filter(|_| self.splits(&ingest))
            .ok_or_else(|| {
                PipelineError::Graph(format!(
                    "features: no unit {k} ({} images{})",
                    ingest.images.len(),
                    if self.splits(&ingest) {
                        ""
                    } else {
                        ", tracked with KLT: no units"
                    }
                ))
            })?;
        let r = extract_one(img, k, &self.options.extraction, dir)?;
        Ok((unit_files(k), serde_json::json!(r)))
    }

    fn run(&self, ctx: &StageContext, dir: &Path) -> Result<Produced<FeaturesSummary>> {
        let ingest = ctx.ws.read_ingest()?;
        let mut warnings = Vec::new();
        if self.options.uses_klt(ingest.kind) {
            let tracking = self.options.video_tracking();
            let tracks = super::tracks::track(&ingest, &tracking, ctx.progress)?;
            match tracking_verdict(&tracks, tracking.min_shared_tracks) {
                // Asked for KLT, or KLT held: the tracks are the features.
                Ok(()) => return write_tracking(&tracks, dir),
                Err(why) if self.options.tracking == TrackingMode::Klt => {
                    let mut p = write_tracking(&tracks, dir)?;
                    p.warnings.push(
                        Warning::new(code::TRACKING, why).advice("--tracking sift may do better"),
                    );
                    return Ok(p);
                }
                // Descriptor matching between the frames instead (issue #18: the video mode must
                // not break the sequence into pieces where tracking fails).
                Err(why) => {
                    warnings.push(Warning::new(
                        code::TRACKING,
                        format!("{why}; SIFT features and descriptor matching between the frames are used instead"),
                    ));
                }
            }
        }
        let opts = &self.options.extraction;
        let bars = ctx.progress;
        bars.start("features", ingest.images.len() as u64);
        let results: Vec<Result<(usize, f64)>> = ingest
            .images
            .par_iter()
            .enumerate()
            .map(|(k, img)| {
                // Done apart (a work unit on another machine): its files, moved in.
                let r = match ctx.take_unit(k, &unit_files(k), dir)? {
                    Some(v) => serde_json::from_value::<(usize, f64)>(v).ok(),
                    None => None,
                };
                let r = match r {
                    Some(r) => r,
                    None => extract_one(img, k, opts, dir)?,
                };
                bars.inc(1);
                Ok(r)
            })
            .collect();
        bars.finish();
        let results: Vec<(usize, f64)> = results.into_iter().collect::<Result<_>>()?;
        let counts: Vec<usize> = results.iter().map(|r| r.0).collect();
        let mut secs: Vec<f64> = results.iter().map(|r| r.1).collect();
        secs.sort_by(|a, b| a.total_cmp(b));
        let min = counts.iter().min().copied().unwrap_or(0);
        if min < FEW_FEATURES {
            warnings.push(Warning::new(
                code::IMAGE,
                format!("an image has only {min} features: textureless, blurred or tiny images match poorly"),
            ));
        }
        Ok(Produced::new(
            (0..counts.len()).map(feature_file_name).collect(),
            FeaturesSummary::Sift {
                images: counts.len(),
                features_per_image_median: median(&counts),
                features_min: min,
                extraction_seconds_median: secs.get(secs.len() / 2).copied(),
            },
        )
        .warn(warnings))
    }
}

/// A work unit (see [`crate::stage`]): one photo's features and thumbnail. A video tracked with
/// KLT does not split (the tracker runs through the frames in order).
impl Features {
    fn splits(&self, ingest: &handheld_io::ingest::IngestResult) -> bool {
        !self.options.uses_klt(ingest.kind)
    }
}

/// The files of image `k`'s unit, relative to the stage folder.
fn unit_files(k: usize) -> Vec<String> {
    vec![
        feature_file_name(k),
        format!("{THUMBS_DIR}/{}", thumbnail_file_name(k)),
    ]
}

/// Extracts image `k`'s features, writes its feature file and thumbnail into `dir`; returns the
/// number of features and the extraction's seconds.
fn extract_one(
    img: &handheld_io::ingest::IngestedImage,
    k: usize,
    opts: &ExtractionOptions,
    dir: &Path,
) -> Result<(usize, f64)> {
    let load_opts = ImageIngestOptions {
        min_dimension: 1,
        ..Default::default()
    };
    let loaded = load_image(&img.info.path, &load_opts)?;
    let t0 = Instant::now();
    let f = extract_features(&loaded.image, opts);
    let secs = t0.elapsed().as_secs_f64();
    let mut file = to_file(f);
    file.colors = keypoint_colors(&loaded.image, &file.keypoints);
    write_thumbnail(
        &dir.join(THUMBS_DIR).join(thumbnail_file_name(k)),
        &loaded.image,
    )
    .with_context(|| format!("thumbnail of {}", img.info.name))?;
    write_features(&dir.join(feature_file_name(k)), &file)
        .with_context(|| format!("features of {}", img.info.name))?;
    Ok((file.keypoints.len(), secs))
}

/// Writes the report's thumbnail of `image` (at most [`THUMB`] pixels on a side,
/// JPEG), atomically.
fn write_thumbnail(path: &Path, image: &image::DynamicImage) -> Result<()> {
    let t = image.thumbnail(THUMB, THUMB).to_rgb8();
    let mut bytes = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut bytes, 90)
        .encode_image(&t)
        .map_err(|e| PipelineError::workspace(path, e.to_string()))?;
    handheld_io::atomic::write_atomic(path, |w| w.write_all(&bytes))?;
    Ok(())
}

/// The image's RGB at each keypoint (the nearest pixel; Handheld's convention puts the top-left
/// pixel's centre at (0, 0)), so later stages colour points without decoding the image again.
pub fn keypoint_colors(image: &image::DynamicImage, keypoints: &[[f32; 5]]) -> Vec<[u8; 3]> {
    use image::{GenericImageView, Pixel};
    let (w, h) = image.dimensions();
    if w == 0 || h == 0 {
        return Vec::new();
    }
    keypoints
        .iter()
        .map(|k| {
            let x = (k[0].round().max(0.0) as u32).min(w - 1);
            let y = (k[1].round().max(0.0) as u32).min(h - 1);
            image.get_pixel(x, y).to_rgb().0
        })
        .collect()
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
        colors: Vec::new(),
    }
}

/// The in-memory form of one image's features.
pub fn from_file(f: FeatureFile) -> handheld_features::Features {
    use handheld_features::{Descriptors, Keypoint};
    handheld_features::Features {
        keypoints: f
            .keypoints
            .iter()
            .map(|k| Keypoint {
                x: k[0],
                y: k[1],
                scale: k[2],
                orientation: k[3],
                response: k[4],
            })
            .collect(),
        descriptors: Descriptors {
            dim: f.dim,
            data: f.descriptors,
        },
    }
}

fn median(v: &[usize]) -> usize {
    let mut s = v.to_vec();
    s.sort_unstable();
    s.get(s.len() / 2).copied().unwrap_or(0)
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
        warnings.push(Warning::new(
            code::TRACKING,
            format!(
                "only {} key-frame(s): the camera hardly moves, or tracking failed",
                tracks.keyframes.len()
            ),
        ));
    }
    Ok(Produced::new(
        outputs,
        FeaturesSummary::Klt {
            images: tracks.num_frames(),
            tracking: "klt".into(),
            tracks_per_frame_median: counts.get(counts.len() / 2).copied(),
            keyframes: tracks.keyframes.len(),
            keyframe_frames: tracks.keyframes.iter().map(|k| k.0).collect(),
        },
    )
    .warn(warnings))
}
