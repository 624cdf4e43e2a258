//! The render stage (§5.2): a short fly-through of the reconstruction, rendered from the
//! recorded images and their depth maps (image-based, with the mesh as the geometric proxy where
//! it covers the view), written as `render/flight.mp4`, with its middle frame as
//! `render/flight.png` to look at. Without the `ffmpeg` program the video is skipped with a
//! warning and the PNG is still written.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::error::Result;
use crate::files::stage;
use crate::render::{load_scene, render_flight, scene_error, write_png, FlightSummary};
use crate::stage::{Produced, Stage, StageContext};
use crate::warning::{code, Warning};
use handheld_render::scene::FlightOptions;

/// `render/flight.mp4`.
pub const FLIGHT_MP4: &str = "flight.mp4";
/// `render/flight.png`: the fly-through's middle frame.
pub const FLIGHT_PNG: &str = "flight.png";

/// Options of the render stage.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct RenderStageOptions {
    pub flight: FlightOptions,
}

impl RenderStageOptions {
    pub fn validate(&self) -> Result<()> {
        self.flight.validate().map_err(scene_error)
    }
}

/// The render stage.
pub struct Render {
    pub options: RenderStageOptions,
}

impl Stage for Render {
    type Options = RenderStageOptions;
    type Summary = FlightSummary;

    const NAME: &'static str = stage::RENDER;
    const READS: &'static [&'static str] = &[stage::INGEST, stage::SPARSE];
    /// Without depth maps the views render with the fixed plane; without the mesh, no proxy.
    const READS_IF_PRESENT: &'static [&'static str] = &[stage::DENSE, stage::MESH];
    const ABOUT: &'static str =
        "image-based rendering (§5.2): a fly-through through the recorded cameras (flight.mp4)";

    fn options(&self) -> &RenderStageOptions {
        &self.options
    }

    fn validate(&self) -> Result<()> {
        self.options.validate()
    }

    fn run(&self, ctx: &StageContext, dir: &Path) -> Result<Produced<FlightSummary>> {
        let scene = load_scene(ctx.ws, &[], 1600)?;
        let mp4 = dir.join(FLIGHT_MP4);
        let mut outputs = Vec::new();
        let (mut summary, middle) =
            render_flight(&scene, &self.options.flight, &mp4, ctx.progress)?;
        if let Some(frame) = middle {
            write_png(&dir.join(FLIGHT_PNG), &frame)?;
            outputs.push(FLIGHT_PNG.to_string());
        }
        if mp4.exists() {
            outputs.push(FLIGHT_MP4.to_string());
        }
        summary.output = mp4;
        let warnings = summary
            .warnings
            .iter()
            .map(|w| Warning::new(code::FALLBACK, w.clone()))
            .collect();
        Ok(Produced::new(outputs, summary).warn(warnings))
    }
}
