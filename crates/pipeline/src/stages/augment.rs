//! The augment stage (§5.3): registered in the graph when an object is given
//! (`PipelineOptions::augment`); see [`crate::augment`]. It reads the sparse model; the mesh,
//! for occlusion, is used when the workspace has one (a large scene whose mesh stage fails can
//! still be augmented, without occlusion), so `handheld augment` runs the mesh stage first and
//! goes on without it when it fails.

use std::path::Path;

use crate::augment::{
    augment, AugmentOptions, AugmentSummary, CAMERA_CHAN, CAMERA_GLB, PLACEMENT_JSON,
};
use crate::error::Result;
use crate::files::{stage, write_json, SUMMARY_JSON};
use crate::stage::{Produced, Stage, StageContext};

/// The augment stage.
pub struct Augment {
    pub options: AugmentOptions,
}

impl Stage for Augment {
    type Options = AugmentOptions;
    type Summary = AugmentSummary;

    const NAME: &'static str = stage::AUGMENT;
    const READS: &'static [&'static str] = &[stage::INGEST, stage::SPARSE];
    const ABOUT: &'static str =
        "augmented video (§5.3): a virtual object composited into every frame; the camera track as glTF and .chan";

    fn options(&self) -> &AugmentOptions {
        &self.options
    }

    fn run(&self, ctx: &StageContext, dir: &Path) -> Result<Produced<AugmentSummary>> {
        let mut summary = augment(ctx.ws, &self.options, dir, ctx.progress)?;
        write_json(&dir.join(SUMMARY_JSON), &summary)?;
        summary.per_frame = None;
        let mut outputs: Vec<String> = [PLACEMENT_JSON, CAMERA_GLB, CAMERA_CHAN, SUMMARY_JSON]
            .iter()
            .map(|s| s.to_string())
            .collect();
        if summary.output.starts_with(dir) {
            if let Some(n) = summary.output.file_name() {
                outputs.push(n.to_string_lossy().into_owned());
            }
        }
        let warnings = summary.warnings.clone();
        Ok(Produced {
            outputs,
            summary,
            warnings,
        })
    }
}
