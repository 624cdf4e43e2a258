//! Compositing and encoding speed of augmented video (issue #20), not counting SfM: a testkit
//! sequence (its exact cameras and points, so no reconstruction runs), its frames upsampled to the
//! benchmark's size, the shipped box placed automatically on the ground, composited into every
//! frame (with occlusion by the scene's mesh, and without) and encoded as H.264 by `ffmpeg`.

use std::time::Instant;

use handheld_core::{FloatMap, Rigid3};
use handheld_io::video::encode::VideoWriter;
use handheld_render::augment::{auto_place, object_box, Compositor, PlaceOptions};
use handheld_testkit::path::PathOptions;
use handheld_testkit::render::{render_sequence, SequenceOptions};
use nalgebra::Point3;
use serde::{Deserialize, Serialize};

use crate::error::{EvalError, Result};

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(default)]
pub struct AugmentBenchOptions {
    pub width: u32,
    pub height: u32,
    pub frames: usize,
}

impl Default for AugmentBenchOptions {
    fn default() -> Self {
        Self {
            width: 1280,
            height: 720,
            frames: 60,
        }
    }
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct AugmentSpeed {
    pub occlusion: bool,
    /// Frames per second of compositing + encoding (wall clock, the encoder running alongside).
    pub fps: f64,
    pub seconds: f64,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct AugmentBenchReport {
    pub width: u32,
    pub height: u32,
    pub frames: usize,
    pub mesh_faces: usize,
    pub runs: Vec<AugmentSpeed>,
    pub threads: usize,
}

pub fn bench_augment(o: &AugmentBenchOptions) -> Result<AugmentBenchReport> {
    if !o.width.is_multiple_of(2) || !o.height.is_multiple_of(2) || o.width < 64 || o.height < 48 {
        return Err(EvalError::option(
            "--width",
            "width and height must be even, at least 64×48",
        ));
    }
    // Render at half size (cheap), then upsample frames and cameras.
    let seq_opts = SequenceOptions {
        seed: 1,
        width: o.width / 2,
        height: o.height / 2,
        num_frames: o.frames,
        path: PathOptions::orbit(o.frames),
        samples_per_axis: 1,
        ..Default::default()
    };
    let seq = render_sequence(&seq_opts).map_err(|e| EvalError::option("--width", e))?;
    let mut frames = Vec::new();
    for (i, img) in seq.images.iter().enumerate() {
        let Some(frame) = seq.frame(i) else {
            continue;
        };
        let big = image::imageops::resize(
            img,
            o.width,
            o.height,
            image::imageops::FilterType::Triangle,
        );
        frames.push((big, frame.scaled(2.0, 2.0)));
    }
    let points: Vec<(Point3<f64>, usize)> = seq
        .gt
        .points
        .values()
        .map(|p| (p.xyz, p.track.elements.len()))
        .collect();
    let cams: Vec<Rigid3> = frames.iter().map(|f| f.1.cam_from_world).collect();
    let (object, texture) = object_box();
    let (placement, _) = auto_place(&object, &points, &cams, &PlaceOptions::default())
        .map_err(|e| EvalError::Data(e.to_string()))?;
    let placed = placement.transform(&object);
    let dir = tempfile::tempdir().map_err(|e| EvalError::Data(e.to_string()))?;
    let mut runs = Vec::new();
    for occlusion in [false, true] {
        let out = dir.path().join(format!("augmented-{occlusion}.mp4"));
        let t = Instant::now();
        let mut writer = VideoWriter::create(&out, o.width, o.height, 25.0, 18, None)?;
        let mut compositor = Compositor::new();
        let mut zbuf = Vec::new();
        let mut depth = FloatMap::filled(o.width as usize, o.height as usize, 1, f32::NAN);
        for (img, view) in &frames {
            let mut frame = img.clone();
            let occ = if occlusion {
                handheld_render::augment::scene_depth(
                    &seq.mesh, view, &placed, &mut zbuf, &mut depth,
                );
                Some(&depth)
            } else {
                None
            };
            compositor.composite(&mut frame, &placed, Some(&texture), view, occ);
            writer.push(&frame)?;
        }
        writer.finish()?;
        let seconds = t.elapsed().as_secs_f64();
        runs.push(AugmentSpeed {
            occlusion,
            fps: frames.len() as f64 / seconds,
            seconds,
        });
    }
    Ok(AugmentBenchReport {
        width: o.width,
        height: o.height,
        frames: frames.len(),
        mesh_faces: seq.mesh.faces.len(),
        runs,
        threads: rayon::current_num_threads(),
    })
}
