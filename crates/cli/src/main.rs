//! `handheld`: the thin command-line front end. It parses arguments, calls the library stages and
//! writes results; all the work lives in the stage crates.

mod args;
mod bench_bundle;
mod bench_dense;
mod bench_matching;
mod demo;
mod demo_dense;
mod pipeline;
mod stages;
mod stereo;
mod ui;

use std::process::ExitCode;

use clap::Parser;

use args::{BenchCommand, Cli, Command, GlobalArgs};

fn main() -> ExitCode {
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
        Command::Reconstruct(a) => {
            let reports = pipeline::run(&a.input, a.until, &bars)?;
            report_stages(g, &a.input.output, &reports);
            Ok(())
        }
        Command::Bench(b) => match &b.which {
            BenchCommand::Bundle(a) => bench_bundle::run(a, g, &bars),
            BenchCommand::Matching(a) => bench_matching::run(a, g, &bars),
            BenchCommand::Stereo(a) => stereo::bench(a, g),
            BenchCommand::Dense(a) => bench_dense::run(a, g),
        },
        Command::Stereo(a) => stereo::run(a, g),
        Command::Mesh(a) => {
            let summary = stages::mesh::run_standalone(a, &bars)?;
            let human = format!(
                "mesh: {} → {}\n  {}",
                a.depth_maps.display(),
                a.output.display(),
                summary
            );
            ui::print_result(g, &summary, &human);
            Ok(())
        }
        Command::Dense(a) => {
            let summary = stages::dense::run_on_model(a, &bars)?;
            let human = format!(
                "dense: {} → {}\n  {}",
                a.model.display(),
                a.output.display(),
                summary
            );
            ui::print_result(g, &summary, &human);
            Ok(())
        }
        Command::Ingest(a) => run_until(g, a, pipeline::Stage::Ingest, &bars),
        Command::Features(a) => run_until(g, a, pipeline::Stage::Features, &bars),
        Command::Match(a) => run_until(g, a, pipeline::Stage::Matches, &bars),
    }
}

/// Runs the pipeline up to one stage (the per-stage subcommands).
fn run_until(
    g: &GlobalArgs,
    a: &args::IngestArgs,
    stage: pipeline::Stage,
    bars: &ui::Bars,
) -> anyhow::Result<()> {
    let reports = pipeline::run(&a.input, stage, bars)?;
    report_stages(g, &a.input.output, &reports);
    Ok(())
}

fn report_stages(g: &GlobalArgs, workspace: &std::path::Path, reports: &[pipeline::StageReport]) {
    let value = serde_json::json!({ "workspace": workspace, "stages": reports });
    let mut human = format!("workspace: {}", workspace.display());
    for r in reports {
        human.push_str(&format!(
            "\n  {:<10} {:<11} {:>7.2} s  {}",
            r.stage.dir_name(),
            r.status,
            r.seconds,
            r.summary
        ));
    }
    ui::print_result(g, &value, &human);
}
