//! The demo: render a synthetic hand-held sequence with exact ground truth (testkit), write it with
//! its ground truth in the field's formats, run every pipeline stage on it (photos, or an H.264
//! video of the frames) and score each stage against the ground truth.

pub mod accuracy;
pub mod augment;
pub mod dense;
pub mod sequence;

use std::path::PathBuf;
use std::time::Instant;

use handheld_core::Progress;
use handheld_pipeline::{PipelineOptions, StageReport};
use serde::{Deserialize, Serialize};

pub use accuracy::{
    gt_by_name, matching_accuracy, sparse_accuracy, Aligned, MatchingAccuracy, SparseAccuracy,
};
pub use dense::{dense_accuracy, mesh_accuracy, DenseAccuracy, MeshAccuracy};
pub use sequence::{sequence_options, write_sequence, DemoStamp};

use crate::error::{EvalError, Result};
use handheld_pipeline::Context;

/// Camera path of the synthetic sequence.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CameraPath {
    /// Walk around the object.
    #[default]
    Orbit,
    /// Walk sideways past the scene.
    Walk,
    /// Move forwards into the scene.
    Forward,
    /// Walk all the way round the objects (a full turn, no back wall: a sculpture or a turntable).
    Ring,
    /// Three rings round the objects at rising elevations (no back wall).
    Hemisphere,
}

/// The synthetic scene.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DemoScene {
    /// Boxes and spheres on a textured ground before a back wall.
    #[default]
    Objects,
    /// A phone's capture: a patterned wall filling most of every frame (a dominant plane) with an
    /// object mounted on it, orbited at 1.7 m (the path is always this orbit).
    Wall,
    /// The wall papered with a repeated motif (a half-drop pattern about 0.3 m across): most of
    /// every frame is a pattern whose corners each have look-alikes a period away.
    Wallpaper,
    /// An indoor walk: a U-shaped corridor with plain walls and a tiled floor, walked with two
    /// quick turns (the path is always this walk; about 14.7 m).
    Corridor,
}

/// What the demo renders and how it reconstructs it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct DemoOptions {
    /// Output folder: input images, ground truth and the workspace go inside. Default `handheld-demo`.
    pub output: PathBuf,
    /// Number of frames to render, in 2..=1000. Default 20.
    pub frames: u32,
    /// Image width in pixels, in 64..=8192. Default 640.
    pub width: u32,
    /// Image height in pixels, in 48..=8192. Default 480.
    pub height: u32,
    /// Seed of the scene, the path, the noise and of SfM. Default 1.
    pub seed: u64,
    /// Camera path. Default orbit.
    pub path: CameraPath,
    /// Render again and redo every stage even when up to date. Default false.
    pub force: bool,
    /// Pixel aspect ratio f_y / f_x of the synthetic camera (1.09: the paper's camcorder, §3.4).
    /// Default 1.
    pub aspect_ratio: f64,
    /// Encode the frames as an H.264 video (needs ffmpeg) and reconstruct that in video mode.
    /// Default false.
    pub video: bool,
    /// Place the shipped box automatically, composite it into every frame, and score its
    /// projection against the exact cameras (§5.3). Default false.
    pub augment: bool,
    /// The scene. Default objects.
    pub scene: DemoScene,
    /// Field of view across the longer image side, degrees, in (10, 150); `None`: the focal
    /// length is 0.9 × the width.
    pub fov_deg: Option<f64>,
    /// First radial distortion coefficient (eq. 3; k2 is then 0), in [-0.3, 0.3]; `None`: k1 =
    /// −0.08 and k2 = 0.01.
    pub k1: Option<f64>,
    /// x264 constant rate factor of the video (0–51); `None`: 12, visually lossless. A phone's
    /// bit rate is about 23.
    pub crf: Option<u8>,
    /// Rolling shutter: the time from the first row's exposure to the last's, in frame intervals,
    /// in [0, 1] (a phone reads out in 0.5–0.9 of a 30 fps frame; a video of every k-th frame has
    /// 1/k of that). Default 0: a global shutter.
    pub rolling_shutter: f64,
    /// Exposure time of each row, in frame intervals, in [0, 1]: motion blur. Default 0.
    pub exposure: f64,
    /// Stop after this stage (and what it needs), as `handheld reconstruct --until`; the stages
    /// not run are reported as not scored. `None`: the whole graph.
    pub until: Option<String>,
}

impl Default for DemoOptions {
    fn default() -> Self {
        Self {
            output: PathBuf::from("handheld-demo"),
            frames: 20,
            width: 640,
            height: 480,
            seed: 1,
            path: CameraPath::Orbit,
            force: false,
            aspect_ratio: 1.0,
            video: false,
            augment: false,
            scene: DemoScene::Objects,
            fov_deg: None,
            k1: None,
            crf: None,
            rolling_shutter: 0.0,
            exposure: 0.0,
            until: None,
        }
    }
}

impl DemoOptions {
    /// Checks every option's range.
    pub fn validate(&self) -> Result<()> {
        let range = |option: &str, v: u32, lo: u32, hi: u32| {
            if (lo..=hi).contains(&v) {
                Ok(())
            } else {
                Err(EvalError::option(
                    option,
                    format!("{v} is not in {lo}..={hi}"),
                ))
            }
        };
        range("--frames", self.frames, 2, 1000)?;
        range("--width", self.width, 64, 8192)?;
        range("--height", self.height, 48, 8192)?;
        if !(0.5..=2.0).contains(&self.aspect_ratio) {
            return Err(EvalError::option(
                "--aspect-ratio",
                format!("{} is not in [0.5, 2]", self.aspect_ratio),
            ));
        }
        if let Some(f) = self.fov_deg {
            if !(f > 10.0 && f < 150.0) {
                return Err(EvalError::option(
                    "--fov",
                    format!("{f} is not in (10, 150)"),
                ));
            }
        }
        if let Some(k) = self.k1 {
            if !(-0.3..=0.3).contains(&k) {
                return Err(EvalError::option(
                    "--k1",
                    format!("{k} is not in [-0.3, 0.3]"),
                ));
            }
        }
        if let Some(c) = self.crf {
            if c > 51 {
                return Err(EvalError::option("--crf", format!("{c} is not in 0..=51")));
            }
        }
        for (option, v) in [
            ("--rolling-shutter", self.rolling_shutter),
            ("--exposure", self.exposure),
        ] {
            if !(0.0..=1.0).contains(&v) {
                return Err(EvalError::option(
                    option,
                    format!("{v} is not in [0, 1] frame intervals"),
                ));
            }
        }
        sequence_options(self)
            .validate()
            .map_err(|e| EvalError::option("demo sequence", e))
    }
}

/// What the freshly rendered ground truth holds.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct GroundTruthSummary {
    pub views: usize,
    pub landmarks: usize,
    pub mesh_faces: usize,
    pub scene_extent_m: f64,
}

/// One accuracy evaluation: its scores, or why there are none.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(untagged)]
pub enum Scored<T> {
    /// The scores.
    Ok(T),
    /// The evaluation could not run (e.g. too few views registered).
    Failed { error: String },
}

impl<T> Scored<T> {
    fn of(r: Result<T>) -> Self {
        match r {
            Ok(v) => Scored::Ok(v),
            Err(e) => Scored::Failed {
                error: crate::error_chain(&e),
            },
        }
    }
}

/// Every stage's accuracy against the ground truth.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct DemoAccuracy {
    pub matching: Scored<MatchingAccuracy>,
    pub sparse: Scored<SparseAccuracy>,
    pub dense: Scored<DenseAccuracy>,
    pub mesh: Scored<MeshAccuracy>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub augment: Option<Scored<augment::AugmentAccuracy>>,
}

/// What one demo run did and how accurate each stage was.
#[derive(Debug, Clone, Serialize)]
pub struct DemoReport {
    /// The demo folder.
    pub demo: PathBuf,
    pub frames: u32,
    pub width: u32,
    pub height: u32,
    pub seed: u64,
    /// `photos` or `video (H.264)`.
    pub input: String,
    pub path: CameraPath,
    /// Rendering and writing the ground truth (about 0 when the sequence was up to date).
    pub render_seconds: f64,
    /// The rendered ground truth; `None` when the sequence on disk was up to date.
    pub ground_truth: Option<GroundTruthSummary>,
    /// One report per pipeline stage.
    pub stages: Vec<StageReport>,
    pub accuracy: DemoAccuracy,
    /// How the accuracy is measured.
    pub accuracy_note: String,
}

/// Renders (unless up to date), reconstructs and scores a synthetic sequence.
pub fn run_demo(o: &DemoOptions, progress: &dyn Progress) -> Result<DemoReport> {
    o.validate()?;
    let seq_opts = sequence_options(o);
    std::fs::create_dir_all(&o.output)
        .with_context(|| format!("{}: cannot create the demo folder", o.output.display()))?;
    let stamp = DemoStamp::of(o);
    let fresh = !o.force && stamp.matches(&o.output);

    let t0 = Instant::now();
    let mut ground_truth = None;
    if fresh {
        tracing::info!("synthetic sequence in {} is up to date", o.output.display());
    } else {
        tracing::info!(
            "rendering {} frames of {}×{} ({:?} scene, {:?} path, seed {})",
            o.frames,
            o.width,
            o.height,
            o.scene,
            seq_opts.path.kind,
            o.seed
        );
        progress.start("rendering", 0);
        let seq =
            handheld_testkit::render::render_sequence_with_scene(sequence::scene(o), &seq_opts);
        progress.finish();
        let seq = seq.context("rendering the synthetic sequence")?;
        write_sequence(&o.output, &seq, progress)?;
        stamp.write(&o.output)?;
        ground_truth = Some(GroundTruthSummary {
            views: seq.gt.views.len(),
            landmarks: seq.gt.points.len(),
            mesh_faces: seq.mesh.faces.len(),
            scene_extent_m: seq.scene.extent(),
        });
    }
    let render_seconds = t0.elapsed().as_secs_f64();

    let (input, workspace) = if o.video {
        let v = o.output.join("video.mp4");
        // A given --crf always encodes again (it changes only the video, not the frames).
        let v = if fresh && v.exists() && o.crf.is_none() {
            v
        } else {
            sequence::encode_video(&o.output, o.crf)?
        };
        (v, o.output.join("workspace-video"))
    } else {
        (
            o.output.join(sequence::IMAGES_DIR),
            o.output.join("workspace"),
        )
    };
    let mut options = PipelineOptions::default();
    options.sparse.sfm.seed = o.seed;
    if o.augment {
        options.augment = Some(handheld_pipeline::augment::AugmentOptions::default());
    }
    let stages = handheld_pipeline::reconstruct(
        &input,
        &workspace,
        &options,
        o.until.as_deref(),
        o.force,
        progress,
    )?;
    let (out, ws, video) = (&o.output, &workspace, o.video);
    let accuracy = DemoAccuracy {
        matching: Scored::of(matching_accuracy(out, ws, video)),
        sparse: Scored::of(sparse_accuracy(out, ws, video)),
        dense: Scored::of(dense_accuracy(out, ws, video)),
        mesh: Scored::of(mesh_accuracy(out, ws, video)),
        augment: o
            .augment
            .then(|| Scored::of(augment::augment_accuracy(out, ws, video))),
    };
    Ok(DemoReport {
        demo: o.output.clone(),
        frames: o.frames,
        width: o.width,
        height: o.height,
        seed: o.seed,
        input: if o.video { "video (H.264)" } else { "photos" }.to_string(),
        path: o.path,
        render_seconds,
        ground_truth,
        stages,
        accuracy,
        accuracy_note: "matching is scored against the exact relative poses; cameras against the exact cameras after a similarity fit of the centres; the input was uncalibrated (no focal given)".to_string(),
    })
}
