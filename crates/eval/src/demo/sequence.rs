//! The demo's synthetic sequence on disk: the rendered frames, every ground truth in the field's
//! formats (COLMAP model, PFM depth, PLY mesh), the freshness stamp, and the H.264 encoding.

use std::path::{Path, PathBuf};

use handheld_core::Progress;
use handheld_io::atomic::write_bytes_atomic;
use handheld_io::ingest::write_png;
use handheld_testkit::path::PathOptions;
use handheld_testkit::render::{SequenceOptions, SyntheticSequence};
use handheld_testkit::Shutter;
use serde::{Deserialize, Serialize};

use super::{CameraPath, DemoOptions, DemoScene};
use crate::error::Result;
use handheld_pipeline::Context;

/// The demo folder's sub-folder of rendered frames.
pub const IMAGES_DIR: &str = "images";
/// The demo folder's sub-folder of ground truth.
pub const GROUND_TRUTH_DIR: &str = "ground_truth";

/// The testkit sequence a demo renders.
pub fn sequence_options(o: &DemoOptions) -> SequenceOptions {
    let n = o.frames as usize;
    let path = match (o.scene, o.path) {
        (DemoScene::Wall | DemoScene::Wallpaper, _) => PathOptions::wall_orbit(n),
        (DemoScene::Corridor, _) => PathOptions::corridor_walk(n),
        (_, CameraPath::Orbit) => PathOptions::orbit(n),
        (_, CameraPath::Walk) => PathOptions::walk_through(n),
        (_, CameraPath::Forward) => PathOptions::forward(n),
        (_, CameraPath::Ring) => PathOptions::ring(n),
        (_, CameraPath::Hemisphere) => PathOptions::hemisphere(n),
    };
    let path = PathOptions {
        seed: o.seed,
        ..path
    };
    let defaults = SequenceOptions::default();
    let (k1, k2) = o.k1.map_or((defaults.k1, defaults.k2), |k| (k, 0.0));
    SequenceOptions {
        seed: o.seed,
        width: o.width,
        height: o.height,
        num_frames: n,
        path,
        aspect: o.aspect_ratio,
        focal_px: o
            .fov_deg
            .map(|fov| f64::from(o.width.max(o.height)) / 2.0 / (fov.to_radians() / 2.0).tan()),
        k1,
        k2,
        shutter: Shutter {
            readout: o.rolling_shutter,
            exposure: o.exposure,
        },
        ..defaults
    }
}

/// The testkit scene a demo renders.
pub fn scene(o: &DemoOptions) -> handheld_testkit::Scene {
    match (o.scene, o.path) {
        (DemoScene::Objects, CameraPath::Ring | CameraPath::Hemisphere) => {
            handheld_testkit::Scene::turntable_scene(o.seed)
        }
        (DemoScene::Objects, _) => handheld_testkit::Scene::default_scene(o.seed),
        (DemoScene::Wall, _) => handheld_testkit::Scene::wall_scene(o.seed),
        (DemoScene::Wallpaper, _) => handheld_testkit::Scene::wallpaper_scene(o.seed),
        (DemoScene::Corridor, _) => handheld_testkit::Scene::corridor_scene(o.seed),
    }
}

/// `ground_truth/demo.json`: what the sequence on disk was rendered with. A demo whose stamp
/// matches its options reuses the sequence.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DemoStamp {
    pub version: String,
    pub frames: u32,
    pub width: u32,
    pub height: u32,
    pub seed: u64,
    /// The camera path's name (`Orbit`, `Walk`, `Forward`).
    pub path: String,
    pub aspect: f64,
    #[serde(default)]
    pub scene: DemoScene,
    #[serde(default)]
    pub fov_deg: Option<f64>,
    #[serde(default)]
    pub k1: Option<f64>,
    #[serde(default)]
    pub rolling_shutter: f64,
    #[serde(default)]
    pub exposure: f64,
}

impl DemoStamp {
    /// The stamp of a demo's options.
    pub fn of(o: &DemoOptions) -> Self {
        Self {
            version: handheld_pipeline::HANDHELD_VERSION.to_string(),
            frames: o.frames,
            width: o.width,
            height: o.height,
            seed: o.seed,
            path: format!("{:?}", o.path),
            aspect: o.aspect_ratio,
            scene: o.scene,
            fov_deg: o.fov_deg,
            k1: o.k1,
            rolling_shutter: o.rolling_shutter,
            exposure: o.exposure,
        }
    }

    /// Where the stamp of the demo folder `out` lives.
    pub fn path(out: &Path) -> PathBuf {
        out.join(GROUND_TRUTH_DIR).join("demo.json")
    }

    /// Whether the demo folder `out` holds a sequence with this stamp.
    pub fn matches(&self, out: &Path) -> bool {
        std::fs::read_to_string(Self::path(out))
            .ok()
            .and_then(|t| serde_json::from_str::<DemoStamp>(&t).ok())
            .is_some_and(|s| s == *self)
    }

    /// Writes the stamp (atomically).
    pub fn write(&self, out: &Path) -> Result<()> {
        let text = serde_json::to_string_pretty(self).context("serialising the demo stamp")?;
        write_bytes_atomic(&Self::path(out), text.as_bytes())?;
        Ok(())
    }
}

/// The file stem of a view's name (`frame_0003.png` → `frame_0003`).
pub fn stem(name: &str) -> String {
    Path::new(name)
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// The ground-truth depth map of the view named `name` in the demo folder `out`.
pub fn gt_depth_path(out: &Path, name: &str) -> PathBuf {
    out.join(GROUND_TRUTH_DIR)
        .join("depth")
        .join(format!("{}.pfm", stem(name)))
}

/// Writes the rendered images and all ground truth into the demo folder `dir`.
pub fn write_sequence(dir: &Path, seq: &SyntheticSequence, progress: &dyn Progress) -> Result<()> {
    let images = dir.join(IMAGES_DIR);
    let gt = dir.join(GROUND_TRUTH_DIR);
    progress.start("writing frames", seq.images.len() as u64);
    for (view, (img, depth)) in seq
        .gt
        .views
        .values()
        .zip(seq.images.iter().zip(&seq.depths))
    {
        write_png(&images.join(&view.name), img)?;
        handheld_io::pfm::write_pfm(&gt_depth_path(dir, &view.name), depth)?;
        progress.inc(1);
    }
    progress.finish();
    handheld_io::colmap::write_reconstruction(&gt.join("sparse"), &seq.gt, true, true)?;
    handheld_io::ply::write_mesh(
        &gt.join("mesh.ply"),
        &seq.mesh,
        handheld_io::ply::PlyFormat::BinaryLittleEndian,
    )?;
    Ok(())
}

/// Encodes the rendered frames as an H.264 video (`ffmpeg`), as a camcorder or phone would.
pub(crate) fn encode_video(out: &Path, crf: Option<u8>) -> Result<PathBuf> {
    let video = out.join("video.mp4");
    let defaults = handheld_io::video::EncodeOptions::default();
    handheld_io::video::encode_h264(
        &out.join(IMAGES_DIR).join("frame_%04d.png"),
        &video,
        &handheld_io::video::EncodeOptions {
            crf: crf.unwrap_or(defaults.crf),
            ..defaults
        },
    )?;
    Ok(video)
}
