//! Real BAL data from `../shared/datasets/bal` (skipped when absent): the converted problem's initial
//! cost must equal BAL's own formula (and Ceres' figure), and a few iterations must decrease it.

use std::path::PathBuf;

use handheld_bundle::{bundle_adjust_metric, BundleOptions, IntrinsicsMask, MetricBundleConfig};

fn dataset(name: &str) -> Option<PathBuf> {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/datasets/bal")
        .join(name);
    if p.exists() {
        Some(p)
    } else {
        eprintln!("skipping: {} not found", p.display());
        None
    }
}

#[test]
fn ladybug_initial_cost_matches_bal_and_ceres() {
    let Some(path) = dataset("problem-49-7776-pre.txt") else {
        return;
    };
    let bal = handheld_io::bal::read_bal(&path).expect("readable");
    let bal_cost = bal.cost();
    assert!(
        (bal_cost / 8.509125e5 - 1.0).abs() < 1e-6,
        "BAL formula cost {bal_cost}"
    );
    let mut rec = bal.to_metric_reconstruction();
    let config = MetricBundleConfig {
        refine: IntrinsicsMask::focal_and_radial(),
        fix_first_view: false,
        ..Default::default()
    };
    let opts = BundleOptions {
        max_iterations: 3,
        num_threads: 2,
        ..Default::default()
    };
    let s = bundle_adjust_metric(&mut rec, &config, &opts).expect("runs");
    assert!(
        (s.initial_cost / bal_cost - 1.0).abs() < 1e-10,
        "{} vs {bal_cost}",
        s.initial_cost
    );
    assert!(s.final_cost < 0.2 * s.initial_cost, "{s:?}");
}
