//! Terminal output: tracing logs on stderr, indicatif progress bars, and the final result as text or
//! JSON on stdout.

use std::io::IsTerminal;
use std::sync::Mutex;

use handheld_core::Progress;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

use handheld_pipeline::StageReport;

use crate::common::GlobalArgs;

/// Sets up `tracing` on stderr at the level the flags ask for (`RUST_LOG` overrides).
pub fn init_logging(g: &GlobalArgs) {
    let level = if g.quiet {
        "error"
    } else {
        match g.verbose {
            0 => "info",
            1 => "debug",
            _ => "trace",
        }
    };
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(level));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_target(false)
        .without_time()
        .try_init();
}

/// Progress bars on stderr, hidden with `--quiet`, `--json` or when stderr is not a terminal.
pub struct Bars {
    enabled: bool,
    bar: Mutex<Option<ProgressBar>>,
}

impl Bars {
    pub fn new(g: &GlobalArgs) -> Self {
        Self {
            enabled: !g.quiet && !g.json && std::io::stderr().is_terminal(),
            bar: Mutex::new(None),
        }
    }
}

impl Progress for Bars {
    fn start(&self, label: &str, len: u64) {
        if !self.enabled {
            return;
        }
        let bar = if len > 0 {
            ProgressBar::new(len)
        } else {
            ProgressBar::new_spinner()
        };
        bar.set_draw_target(ProgressDrawTarget::stderr());
        let template = if len > 0 {
            "{msg:>18} [{bar:40.cyan/blue}] {pos}/{len} ({eta})"
        } else {
            "{msg:>18} {spinner} {pos} ({elapsed})"
        };
        if let Ok(style) = ProgressStyle::with_template(template) {
            bar.set_style(style.progress_chars("=> "));
        }
        bar.set_message(label.to_string());
        if len == 0 {
            bar.enable_steady_tick(std::time::Duration::from_millis(120));
        }
        if let Ok(mut slot) = self.bar.lock() {
            *slot = Some(bar);
        }
    }

    fn inc(&self, n: u64) {
        if let Ok(slot) = self.bar.lock() {
            if let Some(b) = slot.as_ref() {
                b.inc(n);
            }
        }
    }

    fn finish(&self) {
        if let Ok(mut slot) = self.bar.lock() {
            if let Some(b) = slot.take() {
                b.finish_and_clear();
            }
        }
    }
}

/// Prints a command's result: pretty JSON with `--json`, else the human summary unless `--quiet`.
pub fn print_result(g: &GlobalArgs, value: &serde_json::Value, human: &str) {
    if g.json {
        println!(
            "{}",
            serde_json::to_string_pretty(value).unwrap_or_default()
        );
    } else if !g.quiet {
        println!("{human}");
    }
}

/// Prints what each stage of a run did (`--json`: the reports as one object).
pub fn report_stages(g: &GlobalArgs, workspace: &std::path::Path, reports: &[StageReport]) {
    let value = serde_json::json!({ "workspace": workspace, "stages": reports });
    let mut human = format!("workspace: {}", workspace.display());
    for r in reports {
        human.push_str(&format!(
            "\n  {:<10} {:<11} {:>7.2} s  {}",
            r.stage, r.status, r.seconds, r.summary
        ));
    }
    print_result(g, &value, &human);
}
