//! `handheld bench bundle`: bundle adjustment on a BAL problem (compare with Ceres' `bundle_adjuster`:
//! cost `½Σ‖r‖²`, no gauge fixing, every camera refining its own `f, k1, k2`) or on a large synthetic
//! problem (`--synthetic 1000x200000`, testkit's ring scene) that exercises the sparse Schur solver.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use clap::{Args, ValueEnum};
use handheld_bundle::{
    bundle_adjust_metric, BundleOptions, BundleSummary, IntrinsicsMask, LinearSolverKind,
    MetricBundleConfig, RobustLoss,
};

use crate::args::GlobalArgs;
use crate::ui::{print_result, Bars};

#[derive(Debug, Clone, Copy, ValueEnum, PartialEq, Eq)]
pub enum RobustArg {
    None,
    Huber,
    Cauchy,
}

#[derive(Debug, Clone, Copy, ValueEnum, PartialEq, Eq)]
pub enum SolverArg {
    Auto,
    Dense,
    Sparse,
}

#[derive(Debug, Args)]
pub struct BenchBundleArgs {
    /// A BAL problem file (`problem-49-7776-pre.txt`).
    #[arg(
        long,
        required_unless_present = "synthetic",
        conflicts_with = "synthetic"
    )]
    pub bal: Option<PathBuf>,
    /// A synthetic problem `CAMERASxPOINTS` instead, e.g. `1000x200000`.
    #[arg(long)]
    pub synthetic: Option<String>,
    /// Maximum Levenberg–Marquardt iterations.
    #[arg(long, default_value_t = 50)]
    pub iterations: usize,
    /// Robust loss.
    #[arg(long, value_enum, default_value_t = RobustArg::None)]
    pub robust: RobustArg,
    /// Scale of the robust loss in pixels.
    #[arg(long, default_value_t = 1.0)]
    pub robust_scale: f64,
    /// Worker threads (0: all cores).
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
    /// Linear solver for the reduced camera system.
    #[arg(long, value_enum, default_value_t = SolverArg::Auto)]
    pub linear_solver: SolverArg,
    /// Seed of the synthetic problem.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

pub fn run(a: &BenchBundleArgs, g: &GlobalArgs, bars: &Bars) -> anyhow::Result<()> {
    let options = BundleOptions {
        max_iterations: a.iterations,
        loss: match a.robust {
            RobustArg::None => RobustLoss::None,
            RobustArg::Huber => RobustLoss::Huber(a.robust_scale),
            RobustArg::Cauchy => RobustLoss::Cauchy(a.robust_scale),
        },
        linear_solver: match a.linear_solver {
            SolverArg::Auto => LinearSolverKind::Auto,
            SolverArg::Dense => LinearSolverKind::DenseSchur,
            SolverArg::Sparse => LinearSolverKind::SparseSchur,
        },
        num_threads: a.threads,
        ..Default::default()
    };
    let t_load = Instant::now();
    let (name, summary, counts) = if let Some(path) = &a.bal {
        let bal = handheld_io::bal::read_bal(path)?;
        let mut rec = bal.to_metric_reconstruction();
        let counts = (bal.cameras.len(), bal.points.len(), bal.observations.len());
        let config = MetricBundleConfig {
            refine: IntrinsicsMask::focal_and_radial(),
            fix_first_view: false,
            ..Default::default()
        };
        let load = t_load.elapsed().as_secs_f64();
        tracing::info!(load_seconds = load, "loaded {}", path.display());
        let s = bundle_adjust_metric(&mut rec, &config, &options)
            .with_context(|| format!("bundle adjustment of {}", path.display()))?;
        (path.display().to_string(), s, counts)
    } else {
        let spec = a.synthetic.as_deref().unwrap_or_default();
        let (nc, np) = parse_size(spec)?;
        let set = handheld_testkit::ring_set(&handheld_testkit::RingOptions {
            num_views: nc,
            num_points: np,
            seed: a.seed,
            ..Default::default()
        })
        .map_err(anyhow::Error::msg)?;
        let mut rec = set.initial;
        let counts = (
            nc,
            rec.points.len(),
            rec.views.values().map(|v| v.observations.len()).sum(),
        );
        tracing::info!(
            load_seconds = t_load.elapsed().as_secs_f64(),
            "generated the testkit ring scene"
        );
        let config = MetricBundleConfig {
            refine: IntrinsicsMask::focal_and_radial(),
            fix_first_view: false,
            ..Default::default()
        };
        use handheld_core::Progress;
        bars.start("bundle adjustment", 0);
        let s = bundle_adjust_metric(&mut rec, &config, &options)
            .context("bundle adjustment of the synthetic ring");
        bars.finish();
        let s = s?;
        (format!("synthetic {spec}"), s, counts)
    };
    report(g, &name, &summary, counts, &options);
    Ok(())
}

fn report(
    g: &GlobalArgs,
    name: &str,
    s: &BundleSummary,
    (nc, np, no): (usize, usize, usize),
    o: &BundleOptions,
) {
    let per_iter = s.total_seconds / s.iterations.max(1) as f64;
    let threads = if o.num_threads == 0 {
        rayon::current_num_threads()
    } else {
        o.num_threads
    };
    let value = serde_json::json!({
        "problem": name,
        "cameras": nc,
        "points": np,
        "observations": no,
        "initial_cost": s.initial_cost,
        "final_cost": s.final_cost,
        "initial_rms_px": s.initial_rms_px,
        "final_rms_px": s.final_rms_px,
        "iterations": s.iterations,
        "successful_steps": s.successful_steps,
        "termination": s.termination.name(),
        "total_seconds": s.total_seconds,
        "seconds_per_iteration": per_iter,
        "linear_solver_seconds": s.linear_solver_seconds,
        "linear_solver": s.linear_solver.name(),
        "reduced_parameters": s.num_camera_parameters,
        "threads": threads,
    });
    let human = format!(
        "{name}: {nc} cameras, {np} points, {no} observations\ncost {:.6e} -> {:.6e} (rms {:.3} -> {:.3} px) in {} iterations ({}), \
         {:.3} s ({:.4} s/iteration, {} solver)",
        s.initial_cost,
        s.final_cost,
        s.initial_rms_px,
        s.final_rms_px,
        s.iterations,
        s.termination.name(),
        s.total_seconds,
        per_iter,
        s.linear_solver.name()
    );
    print_result(g, &value, &human);
}

fn parse_size(spec: &str) -> anyhow::Result<(usize, usize)> {
    let bad =
        || anyhow::anyhow!("--synthetic expects CAMERASxPOINTS (e.g. 1000x200000), got `{spec}`");
    let (c, p) = spec.split_once(['x', 'X']).ok_or_else(bad)?;
    let (c, p): (usize, usize) = (
        c.trim().parse().map_err(|_| bad())?,
        p.trim().parse().map_err(|_| bad())?,
    );
    if c < 2 || p < 1 {
        return Err(bad());
    }
    Ok((c, p))
}
