//! The ingest stage: photos validated in place, or video frames decoded into `ingest/frames/`.

use std::path::Path;

use anyhow::Result;
use handheld_io::images::{list_image_folder, ImageIngestOptions};
use handheld_io::ingest::{ingest, IngestOptions};
use handheld_io::workspace::{Fingerprint, Workspace};

use crate::pipeline::{run_stage, Stage, StageOutput, StageReport};
use crate::ui::Bars;

fn fingerprint(input: &Path, opts: &IngestOptions) -> Result<Fingerprint> {
    let mut fp = Fingerprint::new();
    if input.is_dir() {
        // Only the listing and file identities: cheap, and any change to the photos invalidates it.
        let listing = list_image_folder(
            input,
            &ImageIngestOptions {
                min_images: 0,
                ..opts.images.clone()
            },
        )?;
        for p in &listing.images {
            fp.add_file(p)?;
        }
    } else {
        fp.add_file(input)?;
    }
    Ok(fp)
}

pub fn run(
    ws: &Workspace,
    input: &Path,
    opts: &IngestOptions,
    force: bool,
    bars: &Bars,
) -> Result<StageReport> {
    let fp = fingerprint(input, opts)?;
    run_stage(
        ws,
        Stage::Ingest,
        fp,
        serde_json::to_value(opts)?,
        force,
        |dir| {
            let result = ingest(input, &dir.join("frames"), opts, bars)?;
            handheld_io::atomic::write_bytes_atomic(
                &dir.join("images.json"),
                &serde_json::to_vec_pretty(&result)?,
            )?;
            for (p, why) in &result.skipped {
                tracing::warn!("{}: skipped ({why})", p.display());
            }
            Ok(StageOutput {
                outputs: vec!["images.json".into()],
                summary: serde_json::json!({
                    "kind": result.kind,
                    "images": result.images.len(),
                    "skipped": result.skipped.len(),
                    "width": result.images.first().map(|i| i.info.width),
                    "height": result.images.first().map(|i| i.info.height),
                    "exif_focal_priors": result.images.iter().filter(|i| i.info.focal_prior_px.is_some()).count(),
                }),
            })
        },
    )
}
