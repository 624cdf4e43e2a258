//! `handheld augment`: a virtual object composited into a video (§5.3), and the camera track.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use handheld_pipeline::augment::{AugmentOptions, ObjectSource, PlacementMode};
use handheld_pipeline::files::stage;

use crate::common::{GlobalArgs, InputArgs};
use crate::ui;

#[derive(Debug, Args)]
pub struct AugmentArgs {
    #[command(flatten)]
    pub input: InputArgs,
    /// The virtual object: a glTF 2.0 file (.glb or .gltf), or `box` / `axes` (shipped).
    #[arg(long, default_value = "box")]
    pub object: String,
    /// Placement: `auto` (standing on the dominant supporting plane of the sparse points).
    #[arg(long, default_value = "auto", conflicts_with = "transform")]
    pub place: String,
    /// Placement: a similarity in the model's frame, JSON {"scale": s, "rotation": [w, x, y, z],
    /// "translation": [x, y, z]} (the format of WORKSPACE/augment/placement.json).
    #[arg(long)]
    pub transform: Option<PathBuf>,
    /// The augmented video (default WORKSPACE/augment/augmented.mp4).
    #[arg(long)]
    pub video_out: Option<PathBuf>,
    /// Draw the object over everything (no occlusion by the reconstructed scene; skips the
    /// dense and mesh stages' use, not their run).
    #[arg(long)]
    pub no_occlusion: bool,
    /// The object's height as a fraction of the cameras' distance to it (automatic placement).
    #[arg(long, default_value_t = handheld_render::augment::PlaceOptions::default().height_fraction)]
    pub object_height: f64,
}

pub fn run(a: &AugmentArgs, g: &GlobalArgs, bars: &ui::Bars) -> Result<()> {
    if a.place != "auto" {
        anyhow::bail!(
            "--place: only `auto` is known (or give --transform FILE), got `{}`",
            a.place
        );
    }
    let mut options = a.input.options()?;
    let mut aug = AugmentOptions {
        object: ObjectSource::parse(&a.object),
        placement: match &a.transform {
            Some(p) => PlacementMode::Transform(p.clone()),
            None => PlacementMode::Auto,
        },
        output: a.video_out.clone(),
        occlusion: !a.no_occlusion,
        ..Default::default()
    };
    aug.place.height_fraction = a.object_height;
    // A bad object file is named before any work is done.
    aug.object.load()?;
    options.augment = Some(aug);
    // One run: the augment stage uses the mesh when there is one (for occlusion), so the graph
    // runs the mesh stage first and goes on without it when it fails (e.g. a scene too large
    // for the volume): the object is then drawn over everything, with a warning.
    let reports = handheld_pipeline::reconstruct(
        &a.input.input,
        &a.input.output,
        &options,
        Some(stage::AUGMENT),
        a.input.force,
        bars,
    )?;
    ui::report_stages(g, &a.input.output, &reports);
    Ok(())
}
