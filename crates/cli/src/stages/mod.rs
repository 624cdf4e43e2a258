//! One module per pipeline stage: each fingerprints its inputs, calls its library stage and writes
//! the results into its workspace folder through [`crate::pipeline::run_stage`].

pub mod dense;
pub mod features;
pub mod ingest;
pub mod matches;
pub mod mesh;
pub mod sparse;
pub mod tracks;

use anyhow::{Context, Result};
use handheld_io::ingest::IngestResult;
use handheld_io::workspace::Workspace;

/// The ingest stage's result, read back from the workspace.
pub fn load_ingest(ws: &Workspace) -> Result<IngestResult> {
    let path = ws.root.join("ingest").join("images.json");
    let text = std::fs::read_to_string(&path)
        .with_context(|| format!("{}: cannot read (rerun with --force)", path.display()))?;
    serde_json::from_str(&text)
        .with_context(|| format!("{}: corrupt (rerun with --force)", path.display()))
}
