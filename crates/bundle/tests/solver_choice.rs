//! `LinearSolverKind::Auto` between the dense and the sparse Cholesky of the reduced camera system:
//! by the sparse factor's work against the dense one's, not by the dimension alone. A ring of views, each point seen by a
//! few neighbours (a walk's banded pattern), goes sparse; views that all see the same points go
//! dense. Either way the optimum is the one the other solver reaches.

use handheld_bundle::{bundle_adjust_metric, BundleOptions, LinearSolverKind, MetricBundleConfig};
use handheld_core::MetricReconstruction;
use handheld_testkit::multiview::{multi_view_set, MultiViewOptions};
use handheld_testkit::{ring_set, RingOptions};

fn adjust(rec: &MetricReconstruction, solver: LinearSolverKind) -> (LinearSolverKind, f64) {
    let mut r = rec.clone();
    let opts = BundleOptions {
        linear_solver: solver,
        num_threads: 1,
        max_iterations: 20,
        ..Default::default()
    };
    let s = bundle_adjust_metric(&mut r, &MetricBundleConfig::default(), &opts).expect("runs");
    (s.linear_solver, s.final_cost)
}

#[test]
fn a_banded_system_between_the_bounds_is_solved_sparse_to_the_same_optimum() {
    // 60 views: 360 pose parameters, above the size below which the pattern is not looked at and
    // far below `dense_max_dimension`.
    let set = ring_set(&RingOptions {
        num_views: 60,
        num_points: 3000,
        seed: 3,
        ..Default::default()
    })
    .expect("valid options");
    let (auto, auto_cost) = adjust(&set.initial, LinearSolverKind::Auto);
    let (_, dense_cost) = adjust(&set.initial, LinearSolverKind::DenseSchur);
    println!("auto {auto:?} {auto_cost}, dense {dense_cost}");
    assert_eq!(auto, LinearSolverKind::SparseSchur);
    assert!(
        (auto_cost - dense_cost).abs() <= 1e-8 * dense_cost,
        "{auto_cost} against {dense_cost}"
    );
}

#[test]
fn views_that_all_see_the_same_points_are_solved_dense() {
    let set = multi_view_set(&MultiViewOptions {
        num_views: 50,
        num_points: 600,
        noise_px: 0.5,
        shared_intrinsics: true,
        seed: 5,
        ..Default::default()
    })
    .expect("valid options");
    let (auto, _) = adjust(&set.reconstruction, LinearSolverKind::Auto);
    assert_eq!(auto, LinearSolverKind::DenseSchur);
}
