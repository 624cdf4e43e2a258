//! Fusion of exact synthetic depth maps, scored against the ground-truth mesh with the Middlebury
//! multi-view metrics (issue #7: accuracy at 90% ≤ 0.5% of the scene size, completeness within 1%
//! of the scene size ≥ 95%).

mod common;

use handheld_core::NoProgress;
use handheld_mesh::eval::visible_surface_samples;
use handheld_mesh::{evaluate, fuse_depth_maps, EvalOptions, FusionOptions, SimplifyOptions};
use handheld_mesh::{topology::edge_report, VoxelSize};

#[test]
fn fused_mesh_meets_the_middlebury_bounds() {
    let seq = common::sequence(10, 320);
    let views = common::depth_views(&seq);
    let size = seq.scene.extent();
    let mut opts = FusionOptions::default();
    opts.tsdf.voxel_size = VoxelSize::Absolute(0.02);
    opts.simplify = None;
    let t = std::time::Instant::now();
    let (mesh, summary) = fuse_depth_maps(&views, &opts, &NoProgress).unwrap();
    let fuse_s = t.elapsed().as_secs_f64();
    mesh.validate().unwrap();
    let gt_samples = visible_surface_samples(&views, 3).unwrap();
    let eval = EvalOptions {
        accuracy_fraction: 0.9,
        completeness_threshold: 0.01 * size,
        sample_spacing: 0.02,
    };
    let scores = evaluate(&mesh, &seq.mesh, &gt_samples, &eval).unwrap();
    let (simplified, s) = handheld_mesh::simplify(
        &mesh,
        &SimplifyOptions {
            target_faces: mesh.faces.len() / 10,
            max_relative_error: 0.002,
            lock_border: true,
        },
    )
    .unwrap();
    let simple_scores = evaluate(&simplified, &seq.mesh, &gt_samples, &eval).unwrap();
    println!(
        "scene size {size:.3}; {summary:?}; fused in {fuse_s:.2}s; edges (border, non-manifold, flipped) {:?}",
        edge_report(&mesh)
    );
    println!(
        "fused: accuracy@90 {:.4} ({:.3}% of size), mean {:.4}, completeness@1% {:.2}%",
        scores.accuracy,
        100.0 * scores.accuracy / size,
        scores.mean_distance,
        100.0 * scores.completeness
    );
    println!(
        "simplified {} -> {} faces: accuracy@90 {:.4} ({:.3}%), completeness {:.2}%",
        s.faces_before,
        s.faces_after,
        simple_scores.accuracy,
        100.0 * simple_scores.accuracy / size,
        100.0 * simple_scores.completeness
    );
    assert!(scores.accuracy <= 0.005 * size, "{scores:?}");
    assert!(scores.completeness >= 0.95, "{scores:?}");
    assert!(simple_scores.accuracy <= 0.005 * size, "{simple_scores:?}");
    assert!(simple_scores.completeness >= 0.95, "{simple_scores:?}");
    assert_eq!(edge_report(&mesh).1, 0, "no non-manifold edge");
}
