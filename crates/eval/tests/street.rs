//! The synthetic street of issue #35 (depths 1.5–150 m) through the dense stage and the fusion
//! with their defaults and exact cameras, scored against the exact depth and scene: a small
//! version of `handheld bench mesh`.

use handheld_eval::bench::{bench_mesh, MeshBenchOptions};

#[test]
fn street_depth_and_mesh_hold_against_the_truth() {
    let r = bench_mesh(&MeshBenchOptions {
        width: 480,
        frames: 12,
        ..Default::default()
    })
    .expect("bench runs");
    for run in &r.runs {
        let m = run.mesh.as_ref().expect("a mesh");
        println!(
            "{}: depth fill {:.3}, median relative error {:.4}; mesh accuracy (90 %) {:.4} of the \
             distance, completeness {:.3}; {:.0} % of the samples left out; peak {:?} MB",
            run.path,
            run.depth.fill,
            run.depth.relative_error_median,
            m.relative_accuracy_90,
            m.completeness,
            100.0 * m.fusion.uncertain_fraction,
            run.peak_rss_mb
        );
        // Depths from 1.5 m to 150 m: several voxel sizes.
        assert!(m.fusion.levels.len() >= 2, "{:?}", m.fusion.levels);
        // Issue #35's accuracy bound: 90 % of the mesh within 1 % of its distance from the camera.
        assert!(
            m.relative_accuracy_90 <= 0.01,
            "{}: {}",
            run.path,
            m.relative_accuracy_90
        );
        assert!(
            run.depth.relative_error_median <= 0.01,
            "{}: {:?}",
            run.path,
            run.depth
        );
        // Most of the surface two views see is meshed within 1 % of its distance (#35 asks 90 %
        // of the full-size bench; this small version, 12 frames of 480 px, holds 83–90 %).
        assert!(m.completeness >= 0.8, "{}: {}", run.path, m.completeness);
        // The near surfaces get depth (they did not while the disparity range trimmed 1 % of the
        // sparse points, most of which are far).
        let near = &run.depth.by_depth[0];
        assert!(near.fraction >= 0.3, "{}: near fill {near:?}", run.path);
    }
    let walk = r.runs.iter().find(|x| x.path == "walk").expect("walk");
    assert!(walk.depth.fill >= 0.8, "{:?}", walk.depth);
}
