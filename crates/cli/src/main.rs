//! `handheld`: the thin command-line front end. It parses arguments, calls the library stages and
//! writes results; all the work lives in the stage crates.
//!
//! Where each piece lives: `args.rs` parses the arguments and maps them onto the libraries' `*Options` (every default
//! read from the library, never restated); `demo.rs`, `bench.rs`, `render.rs`, `augment.rs`, `report.rs` map one
//! command each onto `handheld_pipeline` or `handheld_eval`; `ui.rs` prints text or JSON (logs, progress bars). On
//! glibc, `main.rs` tells the allocator to keep freed memory for reuse. No domain logic. The commands shown in the
//! README and `docs/` are parse-checked by `tests/docs.rs`.

mod args;
mod augment;
mod bench;
mod common;
mod demo;
mod render;
mod report;
mod ui;

use std::process::ExitCode;

use clap::Parser;

use args::{BenchCommand, Cli, Command, GlobalArgs};
use handheld_pipeline::files;

/// Tells glibc's allocator to keep freed memory for reuse. By default it hands every block above
/// a dynamic threshold back to the kernel (mmap/munmap, and trimming the heap top), and bundle
/// adjustment and matching allocate and free such buffers in every iteration: on fountain-P11 the
/// sparse stage spent 1.4 s of its 3.1 s in the kernel (page faults, TLB shootdowns). With blocks
/// up to 32 MiB kept in the heap, no trimming, and the heap grown 64 MiB at a time, the kernel
/// share falls to a third and the whole sparse run is about 7 % faster. (mimalloc and jemalloc, tried
/// instead, were slower here: both return pages to the kernel on their own schedule.)
#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn keep_freed_memory() {
    // SAFETY: mallopt only sets allocator parameters; it is called before any thread starts.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, i32::MAX);
        libc::mallopt(libc::M_TOP_PAD, 64 << 20);
    }
}

#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
fn keep_freed_memory() {}

fn main() -> ExitCode {
    keep_freed_memory();
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => {
            use clap::error::ErrorKind;
            if matches!(
                e.kind(),
                ErrorKind::DisplayHelp
                    | ErrorKind::DisplayVersion
                    | ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand
            ) {
                let _ = e.print();
                return ExitCode::SUCCESS;
            }
            // One clear line naming the option, not a page of usage.
            let text = e.to_string();
            let line = text
                .lines()
                .find(|l| !l.trim().is_empty())
                .unwrap_or("invalid arguments");
            eprintln!("{line}");
            eprintln!("(run `handheld --help` for usage)");
            return ExitCode::from(2);
        }
    };
    ui::init_logging(&cli.global);
    if let Some(e) = handheld_features::quantized::simd_env_error() {
        eprintln!("error: {e}");
        return ExitCode::from(2);
    }
    match run(&cli.command, &cli.global) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            let msg = format!("{e:#}");
            if cli.global.json {
                println!("{}", serde_json::json!({ "error": msg }));
            }
            eprintln!("error: {msg}");
            ExitCode::FAILURE
        }
    }
}

fn run(cmd: &Command, g: &GlobalArgs) -> anyhow::Result<()> {
    let bars = ui::Bars::new(g);
    match cmd {
        Command::Demo(a) => demo::run(a, g, &bars),
        Command::Reconstruct(a) => run_until(g, &a.input, a.until.as_deref(), &bars),
        Command::Ingest(a) => run_until(g, &a.input, Some(files::stage::INGEST), &bars),
        Command::Features(a) => run_until(g, &a.input, Some(files::stage::FEATURES), &bars),
        Command::Match(a) => run_until(g, &a.input, Some(files::stage::MATCHES), &bars),
        Command::Bench(b) => match &b.which {
            BenchCommand::Bundle(a) => bench::bundle(a, g, &bars),
            BenchCommand::Matching(a) => bench::matching(a, g, &bars),
            BenchCommand::Sparse(a) => bench::sparse(a, g, &bars),
            BenchCommand::Stereo(a) => bench::bench_stereo(a, g),
            BenchCommand::Dense(a) => bench::dense(a, g),
            BenchCommand::Render(a) => bench::render(a, g, &bars),
            BenchCommand::Specular(a) => bench::specular(a, g),
            BenchCommand::Augment(a) => bench::augment(a, g),
            BenchCommand::Scale(a) => bench::scale(a, g, &bars),
            BenchCommand::Mesh(a) => bench::mesh(a, g),
        },
        Command::Stereo(a) => bench::stereo(a, g),
        Command::Render(a) => render::run(a, g, &bars),
        Command::Augment(a) => augment::run(a, g, &bars),
        Command::Report(a) => report::run(a, g),
        Command::Mesh(a) => {
            let summary = handheld_pipeline::stages::mesh::mesh_dense_folder(
                &a.depth_maps,
                &a.images,
                &a.mesh.options(),
                &a.output,
                &bars,
            )?;
            let value = serde_json::to_value(&summary)?;
            let human = format!(
                "mesh: {} → {}\n  {value}",
                a.depth_maps.display(),
                a.output.display(),
            );
            ui::print_result(g, &value, &human);
            Ok(())
        }
        Command::Dense(a) => {
            let summary = handheld_pipeline::stages::dense::densify_model(
                &a.model,
                &a.images,
                &a.dense.options()?,
                &a.output,
                &bars,
            )?;
            let value = serde_json::to_value(&summary)?;
            let human = format!(
                "dense: {} → {}\n  {value}",
                a.model.display(),
                a.output.display(),
            );
            ui::print_result(g, &value, &human);
            Ok(())
        }
    }
}

/// Runs what stage `until` needs (the whole graph with `None`) and prints one line per stage.
fn run_until(
    g: &GlobalArgs,
    a: &args::InputArgs,
    until: Option<&str>,
    bars: &ui::Bars,
) -> anyhow::Result<()> {
    let options = a.options()?;
    let reports =
        handheld_pipeline::reconstruct(&a.input, &a.output, &options, until, a.force, bars)?;
    ui::report_stages(g, &a.output, &reports);
    Ok(())
}
