//! Runs bundle adjustment on a BAL file without the CLI: `cargo run --release -p handheld-bundle
//! --example bal -- FILE [ITERATIONS] [THREADS]` (the CLI's `handheld bench bundle --bal` does the same).

use handheld_bundle::{bundle_adjust_metric, BundleOptions, IntrinsicsMask, MetricBundleConfig};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let path = args
        .get(1)
        .ok_or("usage: bal FILE [ITERATIONS] [THREADS]")?;
    let iterations = args.get(2).map(|s| s.parse()).transpose()?.unwrap_or(50);
    let threads = args.get(3).map(|s| s.parse()).transpose()?.unwrap_or(2);
    let bal = handheld_io::bal::read_bal(std::path::Path::new(path))?;
    let mut rec = bal.to_metric_reconstruction();
    let config = MetricBundleConfig {
        refine: IntrinsicsMask::focal_and_radial(),
        fix_first_view: false,
        ..Default::default()
    };
    let opts = BundleOptions {
        max_iterations: iterations,
        num_threads: threads,
        ..Default::default()
    };
    let s = bundle_adjust_metric(&mut rec, &config, &opts)?;
    println!(
        "{path}: {} cameras {} points {} observations\ninitial_cost {:.6e} final_cost {:.6e} iterations {} ({} successful, {}) \
         total {:.3} s, {:.4} s/iteration, linear {:.3} s, solver {}",
        bal.cameras.len(),
        bal.points.len(),
        bal.observations.len(),
        s.initial_cost,
        s.final_cost,
        s.iterations,
        s.successful_steps,
        s.termination.name(),
        s.total_seconds,
        s.total_seconds / s.iterations.max(1) as f64,
        s.linear_solver_seconds,
        s.linear_solver.name()
    );
    Ok(())
}
