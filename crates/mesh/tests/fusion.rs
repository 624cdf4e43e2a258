//! Fusion of exact synthetic depth maps, scored against the ground-truth mesh with the Middlebury
//! multi-view metrics (issue #7: accuracy at 90% ≤ 0.5% of the scene size, completeness within 1%
//! of the scene size ≥ 95%).

mod common;

use handheld_core::NoProgress;
use handheld_mesh::eval::visible_surface_samples;
use handheld_mesh::{
    evaluate, fuse_depth_maps, EvalOptions, FusionOptions, PosedView, SimplifyOptions,
};
use handheld_mesh::{topology::edge_report, VoxelSize};

#[test]
fn fused_mesh_meets_the_middlebury_bounds() {
    let seq = common::sequence(10, 320);
    let views = common::views(&seq);
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
    // A stricter look than the bound: completeness within 0.1% of the scene size (under half a voxel).
    let strict = EvalOptions {
        completeness_threshold: 0.001 * size,
        ..eval.clone()
    };
    let tight = evaluate(&mesh, &seq.mesh, &gt_samples, &strict).unwrap();
    println!(
        "completeness within 0.1% of the size: {:.2}%",
        100.0 * tight.completeness
    );
    assert!(scores.accuracy <= 0.005 * size, "{scores:?}");
    assert!(scores.completeness >= 0.95, "{scores:?}");
    assert!(simple_scores.accuracy <= 0.005 * size, "{simple_scores:?}");
    assert!(simple_scores.completeness >= 0.95, "{simple_scores:?}");
    assert_eq!(edge_report(&mesh).1, 0, "no non-manifold edge");
    // The portable default: voxel size from the pixel footprint, simplification on.
    let (coarse, s) = fuse_depth_maps(&views, &FusionOptions::default(), &NoProgress).unwrap();
    println!(
        "defaults: voxel {:.4}, {} -> {} faces",
        s.voxel_size, s.faces_extracted, s.faces_final
    );
    assert!((0.01..0.1).contains(&s.voxel_size), "{s:?}");
    assert!(!coarse.faces.is_empty());
    // Watertight where observed: after hole filling and the non-manifold repair that follows
    // simplification, the only borders left are the outlines where the views stop.
    let loops = handheld_mesh::holes::boundary_loops(&coarse, 1.0);
    println!(
        "defaults: holes filled {:?}, after simplification {:?} ({} faces cut at non-manifold \
         edges); {} outer borders, {} open holes, edges {:?}",
        s.holes,
        s.holes_after_simplify,
        s.non_manifold_faces_removed,
        loops.iter().filter(|l| l.outer).count(),
        loops.iter().filter(|l| !l.outer).count(),
        edge_report(&coarse)
    );
    assert!(
        loops.iter().all(|l| l.outer),
        "an interior hole is left open"
    );
    let (_, non_manifold, flipped) = edge_report(&coarse);
    assert_eq!((non_manifold, flipped), (0, 0));
}

/// A hash-based uniform number in [0, 1) (deterministic, no generator state).
fn unit(i: u64) -> f64 {
    let mut z = i.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
}

#[test]
fn noisy_depth_with_outliers_is_cleaned_by_confidence_and_views() {
    let seq = common::sequence(10, 320);
    let size = seq.scene.extent();
    // Depth noise of about 0.5% (uniform, ±0.87%) and 2% wild outliers, which a confidence map
    // (as multi-view linking gives) marks with weight 0.
    let mut noisy = seq.depths.clone();
    let mut conf = Vec::new();
    for (v, d) in noisy.iter_mut().enumerate() {
        let mut c = handheld_core::FloatMap::filled(d.width, d.height, 1, 1.0);
        for (i, z) in d.data.iter_mut().enumerate() {
            let k = (v as u64) << 32 | i as u64;
            if unit(3 * k) < 0.02 {
                *z = (1.0 + 8.0 * unit(3 * k + 1)) as f32;
                c.data[i] = 0.0;
            } else {
                *z *= (1.0 + 0.015 * (unit(3 * k + 2) - 0.5)) as f32;
            }
        }
        conf.push(c);
    }
    let views: Vec<_> = common::views(&seq)
        .into_iter()
        .enumerate()
        .map(|(i, v)| handheld_mesh::PosedView {
            depth: Some(noisy[i].clone()),
            confidence: Some(conf[i].clone()),
            ..v
        })
        .collect();
    let mut opts = FusionOptions::default();
    opts.tsdf.voxel_size = VoxelSize::Absolute(0.02);
    opts.tsdf.truncation_voxels = 5.0;
    opts.min_component_faces = 50;
    opts.simplify = None;
    let (mesh, summary) = fuse_depth_maps(&views, &opts, &NoProgress).unwrap();
    let gt_samples = visible_surface_samples(&common::views(&seq), 3).unwrap();
    let eval = EvalOptions {
        accuracy_fraction: 0.9,
        completeness_threshold: 0.01 * size,
        sample_spacing: 0.02,
    };
    let s = evaluate(&mesh, &seq.mesh, &gt_samples, &eval).unwrap();
    println!(
        "noisy: {} -> {} faces after speck removal; accuracy@90 {:.4} ({:.3}%), completeness {:.2}%",
        summary.faces_extracted,
        summary.faces_cleaned,
        s.accuracy,
        100.0 * s.accuracy / size,
        100.0 * s.completeness
    );
    assert!(s.accuracy <= 0.005 * size, "{s:?}");
    assert!(s.completeness >= 0.95, "{s:?}");
}

/// The sequence's views with every depth given the standard deviation `footprints · z/f`.
fn views_with_noise(seq: &handheld_testkit::SyntheticSequence, footprints: f32) -> Vec<PosedView> {
    let mut views = common::views(seq);
    for v in &mut views {
        let f = v.posed.camera.intrinsics.f as f32;
        let d = v.depth.as_ref().unwrap();
        let mut var = handheld_core::FloatMap::filled(d.width, d.height, 1, f32::NAN);
        for (o, z) in var.data.iter_mut().zip(&d.data) {
            let s = footprints * z / f;
            *o = s * s;
        }
        v.variance = Some(var);
    }
    views
}

#[test]
fn a_model_under_the_face_budget_is_fused_again_finer_where_its_depth_is_precise_enough() {
    let seq = common::sequence(8, 160);
    let opts = FusionOptions::default();
    // Depth within one footprint: the second pass goes to `finest_footprints`, twice as fine.
    let (fine, s) = fuse_depth_maps(&views_with_noise(&seq, 1.0), &opts, &NoProgress).unwrap();
    let first = s.first_pass.clone().expect("a second, finer pass");
    println!(
        "first pass {:.4} ({} faces), second {:.4} ({} faces)",
        first.voxel_size, first.faces_extracted, s.voxel_size, s.faces_extracted
    );
    assert!(
        (s.voxel_size / first.voxel_size - 0.5).abs() < 1e-9,
        "{s:?}"
    );
    assert!(s.faces_extracted > 3 * first.faces_extracted);
    assert!(fine.faces.len() <= opts.simplify.as_ref().unwrap().target_faces);
    // Depth noisier than 2.7 footprints: a finer voxel would resolve only noise.
    let (_, noisy) = fuse_depth_maps(&views_with_noise(&seq, 2.8), &opts, &NoProgress).unwrap();
    assert!(noisy.first_pass.is_none(), "{noisy:?}");
    // Without variance maps the noise is unknown: one pass.
    let (_, unknown) = fuse_depth_maps(&common::views(&seq), &opts, &NoProgress).unwrap();
    assert!(unknown.first_pass.is_none());
    // Over the budget: one pass.
    let mut small = opts.clone();
    small.simplify.as_mut().unwrap().target_faces = first.faces_extracted / 2;
    let (_, over) = fuse_depth_maps(&views_with_noise(&seq, 1.0), &small, &NoProgress).unwrap();
    assert!(over.first_pass.is_none());
}
