//! Fly-throughs: a camera path through or around the recorded views, rendered and streamed to an
//! H.264 video.

use std::path::{Path, PathBuf};

use handheld_core::{PosedCamera, Progress};
use handheld_render::scene::{FlightOptions, PathKind, RenderMethod, RenderScene};
use handheld_render::{Rendered, Renderer};
use image::RgbImage;
use serde::{Deserialize, Serialize};

use super::load::scene_error;
use crate::error::Result;

/// What a path rendering did.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct FlightSummary {
    pub output: PathBuf,
    pub method: RenderMethod,
    pub path: PathKind,
    pub frames: usize,
    pub width: u32,
    pub height: u32,
    /// Median and maximum seconds per frame (rendering only).
    pub median_frame_seconds: f64,
    pub max_frame_seconds: f64,
    pub mean_covered_fraction: f64,
    pub warnings: Vec<String>,
}

/// Renders a camera path and encodes it as H.264 at `output` (written under a temporary name and
/// renamed when complete).
/// Returns the summary and the middle frame. When the `ffmpeg` program cannot be run, the video
/// is skipped with a warning (the frames were rendered; `output` does not exist).
pub fn render_flight(
    scene: &RenderScene,
    opts: &FlightOptions,
    output: &Path,
    progress: &dyn Progress,
) -> Result<(FlightSummary, Option<RgbImage>)> {
    opts.validate().map_err(scene_error)?;
    let (camera, poses) = scene.flight_poses(opts);
    let mut renderer = Renderer::new();
    let mut times = Vec::with_capacity(poses.len());
    let mut covered = 0.0;
    let mut out = Rendered {
        image: RgbImage::new(0, 0),
        covered: Vec::new(),
        depth: handheld_core::FloatMap::filled(0, 0, 1, 0.0),
    };
    let mut warnings = scene.warnings.clone();
    // Frames are streamed to ffmpeg as they are rendered (none kept but the middle one).
    let mut writer = match handheld_io::video::encode::VideoWriter::create(
        output,
        camera.width,
        camera.height,
        f64::from(opts.fps),
        18,
        None,
    ) {
        Ok(w) => Some(w),
        Err(e @ handheld_io::IoError::FfmpegMissing { .. }) => {
            warnings.push(format!("the fly-through video was not written: {e}"));
            None
        }
        Err(e) => return Err(e.into()),
    };
    let mut middle = None;
    progress.start("rendering the fly-through", poses.len() as u64);
    for (k, pose) in poses.iter().enumerate() {
        let t = std::time::Instant::now();
        scene
            .render(
                &mut renderer,
                &PosedCamera::new(camera.clone(), *pose),
                opts.method,
                &opts.ibr,
                &mut out,
            )
            .map_err(scene_error)?;
        times.push(t.elapsed().as_secs_f64());
        covered += out.covered.iter().filter(|c| **c).count() as f64 / out.covered.len() as f64;
        if let Some(w) = writer.as_mut() {
            w.push(&out.image)?;
        }
        if k == poses.len() / 2 {
            middle = Some(out.image.clone());
        }
        progress.inc(1);
    }
    progress.finish();
    if let Some(w) = writer {
        w.finish()?;
    }
    let frames = poses.len();
    times.sort_by(f64::total_cmp);
    if scene.effective(opts.method) != opts.method {
        warnings.push(format!(
            "method {} fell back to the fixed plane (no depth maps)",
            opts.method.name()
        ));
    }
    let summary = FlightSummary {
        output: output.to_path_buf(),
        method: scene.effective(opts.method),
        path: opts.path,
        frames,
        width: camera.width,
        height: camera.height,
        median_frame_seconds: times[times.len() / 2],
        max_frame_seconds: times[times.len() - 1],
        mean_covered_fraction: covered / frames.max(1) as f64,
        warnings,
    };
    Ok((summary, middle))
}
