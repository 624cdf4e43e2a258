//! `handheld render`: new views of a workspace (§5.2), one view to PNG or a camera path to mp4.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use handheld_pipeline::render::{
    render_flight, render_view, FlightOptions, PathKind, RenderMethod, ViewSpec, DEFAULT_METHOD,
};
use handheld_pipeline::{PipelineError, Workspace};
use handheld_render::IbrOptions;

use crate::common::GlobalArgs;
use crate::ui;

#[derive(Debug, Args)]
#[command(group(clap::ArgGroup::new("what").required(true).args(["view", "pose", "path"])))]
pub struct RenderArgs {
    /// The workspace of a reconstruction (through the dense stage for view-dependent geometry).
    pub workspace: PathBuf,
    /// Render the camera of this recorded image (left out of the images rendered from).
    #[arg(long)]
    pub view: Option<String>,
    /// Render the camera of a pose file: JSON {"rotation": [w, x, y, z], "translation": [x, y, z]}
    /// (world → camera, as COLMAP), optionally "camera".
    #[arg(long)]
    pub pose: Option<PathBuf>,
    /// Render a camera path to an H.264 video: `through` the recorded cameras or `orbit` the scene.
    #[arg(long)]
    pub path: Option<String>,
    /// Output: a PNG for one view, an .mp4 for a path.
    #[arg(long, short)]
    pub output: PathBuf,
    /// plane, planes, subdivided (§5.2's three geometry levels), ulr (unstructured-lumigraph
    /// weights) or mesh (the textured model).
    #[arg(long, default_value = DEFAULT_METHOD.name())]
    pub method: String,
    /// Frames of a path.
    #[arg(long, default_value_t = FlightOptions::default().frames)]
    pub frames: usize,
    /// Output width (0: the camera's own for one view; the height follows).
    #[arg(long)]
    pub width: Option<u32>,
    /// Frames per second of a path's video.
    #[arg(long, default_value_t = FlightOptions::default().fps)]
    pub fps: u32,
    /// Split a triangle when its plane is off the scene by more than this (source pixels).
    #[arg(long, default_value_t = IbrOptions::default().subdivision_px)]
    pub subdivision_px: f64,
}

pub fn run(a: &RenderArgs, g: &GlobalArgs, bars: &ui::Bars) -> Result<()> {
    let method = RenderMethod::parse(&a.method).map_err(PipelineError::from)?;
    let ibr = IbrOptions {
        subdivision_px: a.subdivision_px,
        ..Default::default()
    };
    let ws = Workspace::open(&a.workspace)?;
    let value = if let Some(p) = &a.path {
        let o = FlightOptions {
            method,
            path: PathKind::parse(p).map_err(PipelineError::from)?,
            frames: a.frames,
            width: a.width.unwrap_or(FlightOptions::default().width),
            fps: a.fps,
            ibr,
        };
        o.validate().map_err(PipelineError::from)?;
        let scene = handheld_pipeline::render::load_scene(&ws, &[], 1600)?;
        serde_json::to_value(render_flight(&scene, &o, &a.output, bars)?.0)?
    } else {
        let spec = match (&a.view, &a.pose) {
            (Some(v), _) => ViewSpec::Image(v.clone()),
            (_, Some(p)) => ViewSpec::PoseFile(p.clone()),
            _ => unreachable!("clap requires one of --view, --pose, --path"),
        };
        serde_json::to_value(render_view(
            &ws,
            &spec,
            method,
            a.width.unwrap_or(0),
            &ibr,
            &a.output,
        )?)?
    };
    for w in value["warnings"].as_array().into_iter().flatten() {
        if let Some(w) = w.as_str() {
            tracing::warn!("{w}");
        }
    }
    let human = format!("render → {}\n  {value}", a.output.display());
    ui::print_result(g, &value, &human);
    Ok(())
}
