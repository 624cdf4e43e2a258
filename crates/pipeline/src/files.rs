//! The workspace's files: every name, and a typed reader or writer for each file a stage hands to
//! another. No other module spells a workspace file name.
//!
//! ```text
//! WS/ingest/    images.json, frames/ (video)
//! WS/features/  <index>.feat (RootSIFT, or the KLT tracks' keypoints), tracks.json (video)
//! WS/matches/   database.db (COLMAP), pairs.json
//! WS/sparse/    cameras/images/points3D .txt and .bin, points.ply, summary.json, models/<k>/
//! WS/dense/     depth/ variance/ confidence/ visibility/ (PFM), preview/ (PNG), cameras.json,
//!               fused.ply, summary.json
//! WS/mesh/      model.obj/.mtl/.png, model.glb, model.ply, views/<image>.glb, holdout.png,
//!               summary.json
//! WS/<stage>/manifest.json, WS/timings.json
//! ```

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use handheld_core::MetricReconstruction;
use handheld_features::verify::PairSummary;
use handheld_features::video::VideoTracks;
use handheld_io::features_file::FeatureFile;
use handheld_io::ingest::IngestResult;
use serde::de::DeserializeOwned;
use serde::Serialize;

use crate::error::{PipelineError, Result};
use crate::manifest::Workspace;

/// Stage folder names of the standard graph.
pub mod stage {
    pub const INGEST: &str = "ingest";
    pub const FEATURES: &str = "features";
    pub const MATCHES: &str = "matches";
    pub const SPARSE: &str = "sparse";
    pub const DENSE: &str = "dense";
    pub const MESH: &str = "mesh";
    pub const RENDER: &str = "render";
    pub const AUGMENT: &str = "augment";
    pub const REPORT: &str = "report";
}

/// `ingest/images.json`: the ingested images in pipeline order.
pub const IMAGES_JSON: &str = "images.json";
/// `ingest/frames/`: decoded video frames.
pub const FRAMES_DIR: &str = "frames";
/// `features/tracks.json`: KLT tracks and key-frames (video).
pub const TRACKS_JSON: &str = "tracks.json";
/// `matches/database.db`: COLMAP's database.
pub const DATABASE: &str = "database.db";
/// `matches/pairs.json`: one summary per verified pair.
pub const PAIRS_JSON: &str = "pairs.json";
/// Every stage's own detailed summary file (written by the runner).
pub use crate::stage::SUMMARY_FILE as SUMMARY_JSON;
/// `sparse/points.ply`.
pub const POINTS_PLY: &str = "points.ply";
/// `sparse/models/<k>/`: the further models of a broken sequence.
pub const MODELS_DIR: &str = "models";
/// The COLMAP model files of a sparse model folder.
pub const COLMAP_MODEL_FILES: [&str; 6] = [
    "cameras.txt",
    "images.txt",
    "points3D.txt",
    "cameras.bin",
    "images.bin",
    "points3D.bin",
];
/// The longer side of the report's thumbnails (`features/thumbs/`, made while the image is decoded).
pub const THUMB: u32 = 240;
/// `dense/fused.ply`.
pub const FUSED_PLY: &str = "fused.ply";
/// `dense/preview/`.
pub const PREVIEW_DIR: &str = "preview";
/// `mesh/` outputs.
pub const MODEL_OBJ: &str = "model.obj";
pub const MODEL_GLB: &str = "model.glb";
pub const MODEL_PLY: &str = "model.ply";
pub const VIEWS_DIR: &str = "views";
pub const HOLDOUT_PNG: &str = "holdout.png";

/// The name of image `index`'s feature file.
pub fn feature_file_name(index: usize) -> String {
    format!("{index:06}.feat")
}

/// `features/thumbs/`: the report's thumbnail of each image, made while the features stage has it
/// decoded (the report then does not decode the full images again).
pub const THUMBS_DIR: &str = "thumbs";

/// The name of image `index`'s thumbnail in [`THUMBS_DIR`].
pub fn thumbnail_file_name(index: usize) -> String {
    format!("{index:06}.jpg")
}

/// Writes `value` as pretty JSON, atomically.
pub fn write_json<T: Serialize>(path: &Path, value: &T) -> Result<()> {
    let bytes = serde_json::to_vec_pretty(value)
        .map_err(|e| PipelineError::workspace(path, format!("cannot serialise: {e}")))?;
    handheld_io::atomic::write_bytes_atomic(path, &bytes)?;
    Ok(())
}

/// Reads a JSON file a stage wrote; errors say which stage to redo.
pub fn read_json<T: DeserializeOwned>(path: &Path, stage: &str) -> Result<T> {
    let bytes = std::fs::read(path).map_err(|e| {
        PipelineError::workspace(
            path,
            format!("cannot read ({e}); rerun the {stage} stage with --force"),
        )
    })?;
    serde_json::from_slice(&bytes).map_err(|e| {
        PipelineError::workspace(
            path,
            format!("corrupt ({e}); rerun the {stage} stage with --force"),
        )
    })
}

impl Workspace {
    /// `WS/<stage>/<file>`.
    pub fn path(&self, stage: &str, file: &str) -> PathBuf {
        self.root.join(stage).join(file)
    }

    /// The ingest stage's result.
    pub fn read_ingest(&self) -> Result<IngestResult> {
        read_json(&self.path(stage::INGEST, IMAGES_JSON), stage::INGEST)
    }

    /// Image name → file, for every ingested image.
    pub fn image_paths(&self) -> Result<BTreeMap<String, PathBuf>> {
        Ok(self
            .read_ingest()?
            .images
            .into_iter()
            .map(|i| (i.info.name, i.info.path))
            .collect())
    }

    /// `features/<index>.feat`.
    pub fn feature_path(&self, index: usize) -> PathBuf {
        self.path(stage::FEATURES, &feature_file_name(index))
    }

    /// The features of image `index`.
    pub fn read_features(&self, index: usize) -> Result<FeatureFile> {
        let path = self.feature_path(index);
        handheld_io::features_file::read_features(&path).map_err(|e| {
            PipelineError::workspace(&path, format!("{e}; rerun the features stage with --force"))
        })
    }

    /// The KLT tracks of a video workspace; `None` when the features stage ran SIFT (photos).
    pub fn read_tracks(&self) -> Result<Option<VideoTracks>> {
        let path = self.path(stage::FEATURES, TRACKS_JSON);
        if !path.exists() {
            return Ok(None);
        }
        read_json(&path, stage::FEATURES).map(Some)
    }

    /// `matches/database.db`.
    pub fn database_path(&self) -> PathBuf {
        self.path(stage::MATCHES, DATABASE)
    }

    /// The verified pairs' summaries.
    pub fn read_pairs(&self) -> Result<Vec<PairSummary>> {
        read_json(&self.path(stage::MATCHES, PAIRS_JSON), stage::MATCHES)
    }

    /// The largest sparse model.
    pub fn read_sparse_model(&self) -> Result<MetricReconstruction> {
        let dir = self.root.join(stage::SPARSE);
        handheld_io::colmap::read_reconstruction(&dir).map_err(|e| {
            PipelineError::workspace(
                &dir,
                format!("cannot read the sparse model ({e}); rerun the sparse stage"),
            )
        })
    }

    /// The typed summary a finished stage recorded in its manifest; `None` when the stage has not
    /// run.
    pub fn summary<T: DeserializeOwned>(&self, stage: &str) -> Result<Option<T>> {
        let Some(m) = self.manifest(stage) else {
            return Ok(None);
        };
        serde_json::from_value(m.summary).map(Some).map_err(|e| {
            PipelineError::workspace(
                self.path(stage, "manifest.json"),
                format!("summary does not parse ({e}); rerun the {stage} stage with --force"),
            )
        })
    }
}
