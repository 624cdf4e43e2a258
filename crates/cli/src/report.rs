//! `handheld report WS`: rebuilds `WS/report.html` from whatever the workspace holds.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use handheld_pipeline::Workspace;

use crate::common::GlobalArgs;
use crate::ui;

#[derive(Debug, Args)]
pub struct ReportArgs {
    /// The workspace.
    pub workspace: PathBuf,
}

pub fn run(a: &ReportArgs, g: &GlobalArgs) -> Result<()> {
    if !a.workspace.is_dir() {
        anyhow::bail!("{}: not a workspace folder", a.workspace.display());
    }
    let ws = Workspace::open(&a.workspace)?;
    let t = std::time::Instant::now();
    let s = handheld_pipeline::write_report(&ws)?;
    let mut value = serde_json::to_value(&s)?;
    value["seconds"] = serde_json::json!(t.elapsed().as_secs_f64());
    let human = format!(
        "report → {} ({:.1} MB, {:.2} s){}",
        s.html.display(),
        s.bytes as f64 / 1e6,
        t.elapsed().as_secs_f64(),
        if s.missing.is_empty() {
            String::new()
        } else {
            format!("; not run yet: {}", s.missing.join(", "))
        }
    );
    ui::print_result(g, &value, &human);
    Ok(())
}
