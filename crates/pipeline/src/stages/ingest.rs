//! The ingest stage: photos validated in place, or video frames decoded into `ingest/frames/`.

use std::path::{Path, PathBuf};

use handheld_io::images::{list_image_folder, ImageIngestOptions};
use handheld_io::ingest::{ingest, IngestOptions, InputKind};
use serde::{Deserialize, Serialize};

use crate::error::{PipelineError, Result};
use crate::files::{stage, write_json, FRAMES_DIR, IMAGES_JSON};
use crate::manifest::Fingerprint;
use crate::stage::{Produced, Stage, StageContext};
use crate::warning::{code, Warning};

/// Options of the ingest stage.
pub type IngestStageOptions = IngestOptions;

/// What ingest found.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct IngestSummary {
    pub kind: InputKind,
    pub images: usize,
    pub skipped: usize,
    pub width: Option<u32>,
    pub height: Option<u32>,
    pub exif_focal_priors: usize,
}

/// The ingest stage on one input (a photo folder or a video file).
pub struct Ingest {
    pub input: PathBuf,
    pub options: IngestOptions,
}

impl Stage for Ingest {
    type Options = IngestOptions;
    type Summary = IngestSummary;

    const NAME: &'static str = stage::INGEST;
    const READS: &'static [&'static str] = &[];
    const ABOUT: &'static str = "validate the photos, or decode the video's frames";

    fn options(&self) -> &IngestOptions {
        &self.options
    }

    fn validate(&self) -> Result<()> {
        validate(&self.options)
    }

    fn fingerprint_inputs(&self, fp: &mut Fingerprint) -> Result<()> {
        if !self.input.exists() {
            return Err(PipelineError::Input {
                path: self.input.clone(),
                reason: "does not exist".into(),
            });
        }
        if self.input.is_dir() {
            // Only the listing and file identities: cheap, and any change to the photos
            // invalidates it.
            let listing = list_image_folder(
                &self.input,
                &ImageIngestOptions {
                    min_images: 0,
                    ..self.options.images.clone()
                },
            )?;
            for p in &listing.images {
                fp.add_file(p)?;
            }
        } else {
            fp.add_file(&self.input)?;
        }
        Ok(())
    }

    fn run(&self, ctx: &StageContext, dir: &Path) -> Result<Produced<IngestSummary>> {
        let result = ingest(
            &self.input,
            &dir.join(FRAMES_DIR),
            &self.options,
            ctx.progress,
        )?;
        write_json(&dir.join(IMAGES_JSON), &result)?;
        let warnings = result
            .skipped
            .iter()
            .map(|(p, why)| Warning::new(code::IMAGE, format!("{}: skipped ({why})", p.display())))
            .collect();
        let first = result.images.first().map(|i| &i.info);
        Ok(Produced::new(
            vec![IMAGES_JSON.into()],
            IngestSummary {
                kind: result.kind,
                images: result.images.len(),
                skipped: result.skipped.len(),
                width: first.map(|i| i.width),
                height: first.map(|i| i.height),
                exif_focal_priors: result
                    .images
                    .iter()
                    .filter(|i| i.info.focal_prior_px.is_some())
                    .count(),
            },
        )
        .warn(warnings))
    }
}

/// Range checks of the ingest options.
pub(crate) fn validate(o: &IngestOptions) -> Result<()> {
    o.validate()
        .map_err(|e| PipelineError::invalid(stage::INGEST, e))
}
