//! Merging on pieces of a seeded synthetic scene with exact ground truth.

use std::collections::BTreeSet;

use handheld_core::{ImageId, MetricReconstruction, PointId, Sim3};
use nalgebra::{UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::*;
use crate::graph::CorrespondenceGraph;
use crate::input::SfmInput;
use crate::metric::ba as metric_ba;
use crate::options::SfmOptions;
use crate::summary::ModelSummary;
use crate::test_scene::scene;

fn relative_rotation_error_deg(est: &MetricReconstruction, gt: &MetricReconstruction) -> f64 {
    let ids: Vec<ImageId> = gt.views.keys().copied().collect();
    let mut worst = 0.0f64;
    for (k, a) in ids.iter().enumerate() {
        for b in &ids[k + 1..] {
            let r = |m: &MetricReconstruction| {
                m.views[a].cam_from_world.rotation * m.views[b].cam_from_world.rotation.inverse()
            };
            worst = worst.max((r(est) * r(gt).inverse()).angle().to_degrees());
        }
    }
    worst
}

/// The seeded scene's views 4.. (`first`) and ..4 (`second`), and the two pieces without them:
/// `(first, second, a, b)`, `a` holding views 0–3 and `b` views 4–7.
fn halves(
    gt: &MetricReconstruction,
) -> (
    BTreeSet<ImageId>,
    BTreeSet<ImageId>,
    MetricReconstruction,
    MetricReconstruction,
) {
    let ids: Vec<ImageId> = gt.views.keys().copied().collect();
    let first: BTreeSet<ImageId> = ids[4..].iter().copied().collect();
    let second: BTreeSet<ImageId> = ids[..4].iter().copied().collect();
    let a = metric_ba::without_views(gt, &first);
    let b = metric_ba::without_views(gt, &second);
    (first, second, a, b)
}

/// A frame of its own for the second piece: another scale, orientation and origin.
fn elsewhere() -> Sim3 {
    Sim3 {
        scale: 0.37,
        rotation: UnitQuaternion::from_scaled_axis(Vector3::new(0.3, -1.1, 0.4)),
        translation: Vector3::new(5.0, -2.0, 9.0),
    }
}

/// The merged model is as accurate as the whole scene adjusted in one piece from the truth
/// (0.5 px noise).
fn assert_as_accurate_as_the_whole(
    ctx: &Context,
    merged: &MetricReconstruction,
    gt: &MetricReconstruction,
) {
    let mut whole = gt.clone();
    metric_ba::refine_metric(ctx, &mut whole, false).expect("adjustment");
    let reference = relative_rotation_error_deg(&whole, gt);
    let err = relative_rotation_error_deg(merged, gt);
    assert!(
        err < reference + 0.02,
        "relative rotations {err}° off, the whole scene's {reference}°"
    );
}

#[test]
fn two_pieces_of_one_scene_in_different_frames_are_merged() {
    let (input, gt) = scene();
    let graph = CorrespondenceGraph::build(&input, 8);
    let opts = SfmOptions::default();
    let ctx = Context::new(&input, &graph, &opts);
    let (_, _, a, mut b) = halves(&gt);
    b.transform(&elsewhere());
    let (merged, _, record) = merge(&ctx, &a, &b, false).expect("the pieces share points");
    assert_eq!(merged.views.len(), 8);
    assert_eq!(record.views_added, 4);
    assert!(
        record.inliers as f64 > 0.9 * record.correspondences as f64,
        "{record:?}"
    );
    assert!(
        (record.scale - 1.0 / 0.37).abs() < 0.01 * record.scale,
        "{record:?}"
    );
    assert_as_accurate_as_the_whole(&ctx, &merged, &gt);
    // The shared points are one point each: fewer points than the two pieces hold together.
    assert!(merged.points.len() < a.points.len() + b.points.len());
    merged.validate().expect("consistent references");
}

#[test]
fn pieces_that_triangulated_none_of_their_common_points_merge_through_their_sightings() {
    let (input, gt) = scene();
    let graph = CorrespondenceGraph::build(&input, 8);
    let opts = SfmOptions::default();
    let ctx = Context::new(&input, &graph, &opts);
    let (first, second, a, mut b) = halves(&gt);
    // B never triangulated a point that A holds: no 3D–3D correspondence is left, only B's
    // keypoints matched to A's points (and A's to B's).
    let shared: Vec<PointId> = b
        .points
        .keys()
        .filter(|p| a.points.contains_key(p))
        .copied()
        .collect();
    assert!(!shared.is_empty());
    metric_ba::remove_points(&mut b, shared);
    b.transform(&elsewhere());
    let (merged, _, record) = merge(&ctx, &a, &b, false).expect("the pieces see common points");
    assert_eq!(record.correspondences, 0, "{record:?}");
    assert_eq!(merged.views.len(), 8);
    assert!(
        record.sighting_inliers as f64 > 0.9 * record.sightings as f64,
        "{record:?}"
    );
    assert!(
        (record.scale - 1.0 / 0.37).abs() < 0.01 * record.scale,
        "{record:?}"
    );
    assert_as_accurate_as_the_whole(&ctx, &merged, &gt);
    // The sightings joined A's points: the common points are one track each again.
    let long = merged
        .points
        .values()
        .filter(|p| {
            let v: BTreeSet<ImageId> = p.track.elements.iter().map(|e| e.image_id).collect();
            v.iter().any(|i| first.contains(i)) && v.iter().any(|i| second.contains(i))
        })
        .count();
    assert!(long > 0, "no track spans both pieces");
    merged.validate().expect("consistent references");
}

#[test]
fn pieces_linked_only_by_chance_matches_stay_apart() {
    let (mut input, gt) = scene();
    let ids: Vec<ImageId> = gt.views.keys().copied().collect();
    // Every pair between the pieces keeps its size, but its matches are drawn at random.
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    for pair in input.pairs.iter_mut().filter(|p| (p.a < 4) != (p.b < 4)) {
        let (na, nb) = (
            input.images[pair.a].keypoints.len() as u32,
            input.images[pair.b].keypoints.len() as u32,
        );
        for m in pair.matches.iter_mut() {
            *m = (rng.random_range(0..na), rng.random_range(0..nb));
        }
    }
    let graph = CorrespondenceGraph::build(&input, 8);
    let opts = SfmOptions::default();
    let ctx = Context::new(&input, &graph, &opts);
    let first: BTreeSet<ImageId> = ids[4..].iter().copied().collect();
    let second: BTreeSet<ImageId> = ids[..4].iter().copied().collect();
    let a = metric_ba::without_views(&gt, &first);
    let mut b = metric_ba::without_views(&gt, &second);
    let shared: Vec<PointId> = b
        .points
        .keys()
        .filter(|p| a.points.contains_key(p))
        .copied()
        .collect();
    metric_ba::remove_points(&mut b, shared);
    let err = merge(&ctx, &a, &b, false).expect_err("chance matches explain no similarity");
    assert!(err.contains("2D–3D links"), "{err}");
}

/// The seeded scene with no verified pair between its first four views and its last four.
fn split_scene() -> (
    SfmInput,
    MetricReconstruction,
    Vec<ImageId>,
    CorrespondenceGraph,
) {
    let (mut input, gt) = scene();
    let ids: Vec<ImageId> = gt.views.keys().copied().collect();
    input.pairs.retain(|p| (p.a < 4) == (p.b < 4));
    let graph = CorrespondenceGraph::build(&input, 8);
    (input, gt, ids, graph)
}

#[test]
fn pieces_that_share_no_point_stay_apart() {
    let (input, gt, ids, graph) = split_scene();
    let opts = SfmOptions::default();
    let ctx = Context::new(&input, &graph, &opts);
    let first: BTreeSet<ImageId> = ids[4..].iter().copied().collect();
    let second: BTreeSet<ImageId> = ids[..4].iter().copied().collect();
    let a = metric_ba::without_views(&gt, &first);
    let b = metric_ba::without_views(&gt, &second);
    let err = merge(&ctx, &a, &b, false).expect_err("nothing links them");
    assert!(err.contains("correspondences"), "{err}");
}

fn model(rec: MetricReconstruction) -> SfmModel {
    let mut summary = ModelSummary {
        registered: 0,
        total_images: 8,
        points: 0,
        observations: 0,
        mean_track_length: 0.0,
        mean_reprojection_error_px: 0.0,
        initial_pair: Default::default(),
        groups: Vec::new(),
        self_calibration: Default::default(),
        projective_ba: Vec::new(),
        planar_resections: Vec::new(),
        metric_ba: Vec::new(),
        points_without_depth: 0,
        uncertainty: None,
        uncertainty_note: None,
        view_consistency: Default::default(),
        rolling_shutter: None,
        merged: Vec::new(),
        timings_s: Default::default(),
    };
    summary.recount(&rec);
    SfmModel {
        reconstruction: rec,
        summary,
    }
}

#[test]
fn two_smaller_pieces_merge_even_when_the_largest_shares_nothing_with_them() {
    // The first four views are a scene of their own.
    let (input, gt, ids, graph) = split_scene();
    let opts = SfmOptions::default();
    let ctx = Context::new(&input, &graph, &opts);
    let piece = |keep: std::ops::Range<usize>| {
        let drop: BTreeSet<ImageId> = ids
            .iter()
            .enumerate()
            .filter(|(i, _)| !keep.contains(i))
            .map(|(_, &v)| v)
            .collect();
        metric_ba::without_views(&gt, &drop)
    };
    let mut second = piece(4..6);
    second.transform(&Sim3 {
        scale: 2.5,
        rotation: UnitQuaternion::from_scaled_axis(Vector3::new(-0.2, 0.7, 0.1)),
        translation: Vector3::new(1.0, 3.0, -4.0),
    });
    let mut models = vec![model(piece(0..4)), model(second), model(piece(6..8))];
    merge_models(&ctx, &mut models);
    let sizes: Vec<usize> = models.iter().map(|m| m.summary.registered).collect();
    assert_eq!(
        sizes,
        [4, 4],
        "the two small pieces are one model, the first stays apart"
    );
    let m = models
        .iter()
        .find(|m| !m.summary.merged.is_empty())
        .expect("a merged model");
    assert!(m.reconstruction.views.contains_key(&ids[4]));
    assert!(m.reconstruction.views.contains_key(&ids[7]));
    let truth = piece(4..8);
    let err = relative_rotation_error_deg(&m.reconstruction, &truth);
    // A wrong merge is degrees off. The merged 4-view model (0.5 px of noise) determines its
    // principal point to a few pixels, weighed against its prior by the measured noise, and
    // each pixel of it trades against ~0.05° of the rotations.
    assert!(err < 0.3, "relative rotations {err}° from the truth");
    assert_eq!(m.summary.points, m.reconstruction.points.len());
    assert!(
        m.summary.uncertainty.is_some() || m.summary.uncertainty_note.is_some(),
        "the merged model's uncertainty is measured again"
    );
}
