//! Real BAL data from `../shared/datasets/bal` (ignored when absent, a failure when absent on CI):
//! the converted problem's initial cost must equal BAL's own formula (and Ceres' figure), and a few
//! iterations must decrease it.

use std::path::PathBuf;

use handheld_bundle::{bundle_adjust_metric, BundleOptions, IntrinsicsMask, MetricBundleConfig};

/// `../shared/datasets/bal/<name>`; a panic naming it when it is missing.
#[track_caller]
fn dataset(name: &str) -> PathBuf {
    let p = handheld_testkit::needs::dataset(env!("HANDHELD_DATASETS_DIR"), "bal").join(name);
    assert!(p.is_file(), "needs {} (missing)", p.display());
    p
}

#[test]
#[cfg_attr(not(has_bal), ignore = "needs ../shared/datasets/bal (missing)")]
fn ladybug_initial_cost_matches_bal_and_ceres() {
    let path = dataset("problem-49-7776-pre.txt");
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
