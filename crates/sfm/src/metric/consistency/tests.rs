//! Tests of the view-consistency check (`consistency.rs`).

use super::*;
use crate::graph::CorrespondenceGraph;
use crate::test_scene::scene;
use crate::SfmOptions;
use handheld_core::ImageId;
use nalgebra::{UnitQuaternion, Vector3};

#[test]
fn a_model_whose_views_were_mostly_misplaced_is_doubted() {
    let d = |name: &str| ViewDisagreement {
        image: name.into(),
        median_deg: 30.0,
        allowed_deg: 5.0,
        partners: 2,
    };
    let mut r = ConsistencyReport {
        removed: vec![d("a"), d("b")],
        rebuilt_without: vec![d("b"), d("c")],
        ..Default::default()
    };
    // Three distinct views misplaced (b counted once) against four kept: no doubt.
    assert_eq!(r.misplaced_majority(4), None);
    assert_eq!(r.misplaced_majority(3), None);
    assert_eq!(r.misplaced_majority(2), Some(3));
    r.removed.clear();
    r.rebuilt_without.clear();
    assert_eq!(r.misplaced_majority(0), None);
}

#[test]
fn a_view_turned_away_from_its_pairs_is_flagged_and_no_other() {
    let (input, mut rec) = scene();
    let graph = CorrespondenceGraph::build(&input, 8);
    let opts = SfmOptions::default();
    let ctx = Context::new(&input, &graph, &opts);
    let (flagged, max_kept) = inconsistent_views(&ctx, &rec);
    assert!(flagged.is_empty(), "{flagged:?}");
    let max_kept = max_kept.expect("pairs were compared");
    // Each pair's rotation is refined on its noisy inliers (0.5 px): a few tenths of a degree.
    assert!(max_kept < 0.5, "the true poses disagree by {max_kept}°");
    // Turn view 3 by 12° about its own centre, as a registration to the wrong place would.
    let id = input.images[3].id;
    let turn = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), 12f64.to_radians());
    let v = rec.views.get_mut(&id).expect("view 3");
    v.cam_from_world = nalgebra::Isometry3::from_parts(
        (turn * v.cam_from_world.translation.vector).into(),
        turn * v.cam_from_world.rotation,
    );
    let (flagged, max_kept) = inconsistent_views(&ctx, &rec);
    assert_eq!(flagged.len(), 1, "{flagged:?}");
    assert_eq!(flagged[0].0, 3);
    assert!((flagged[0].1.median_deg - 12.0).abs() < 0.5, "{flagged:?}");
    assert_eq!(flagged[0].1.partners, 7);
    assert!(max_kept.expect("others") < 0.5);
}

#[test]
fn two_pieces_put_together_at_a_wrong_angle_show_only_across() {
    let (input, mut rec) = scene();
    let graph = CorrespondenceGraph::build(&input, 8);
    let opts = SfmOptions::default();
    let ctx = Context::new(&input, &graph, &opts);
    let ids: Vec<ImageId> = rec.views.keys().copied().collect();
    let (a, b): (BTreeSet<ImageId>, BTreeSet<ImageId>) = (
        ids[..4].iter().copied().collect(),
        ids[4..].iter().copied().collect(),
    );
    let (d, n) = across(&ctx, &rec, &a, &b).expect("pairs across");
    assert!(d < 0.2, "the true poses disagree by {d}°");
    assert_eq!(n, 16);
    // The second piece, turned by 11° about the scene's origin as a whole: its own pairs agree.
    let turn = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), 11f64.to_radians());
    for id in &b {
        let v = rec.views.get_mut(id).expect("view");
        v.cam_from_world.rotation *= turn.inverse();
    }
    let (d, _) = across(&ctx, &rec, &a, &b).expect("pairs across");
    assert!((d - 11.0).abs() < 0.5, "across {d}°");
    let inside = across(&ctx, &rec, &b, &b).expect("pairs inside");
    assert!(inside.0 < 0.2, "inside {inside:?}");
}

#[test]
fn pairs_that_do_not_fix_a_rotation_are_not_compared() {
    let (mut input, rec) = scene();
    for (k, p) in input.pairs.iter_mut().enumerate() {
        match k % 3 {
            0 => p.configuration = TwoViewConfiguration::Planar,
            1 => p.matches.truncate(MIN_PAIR_INLIERS - 1),
            _ => p.f = None,
        }
    }
    let graph = CorrespondenceGraph::build(&input, 8);
    let opts = SfmOptions::default();
    let ctx = Context::new(&input, &graph, &opts);
    assert!(input
        .pairs
        .iter()
        .all(|p| pair_disagreement(&ctx, &rec, p).is_none()));
    assert_eq!(inconsistent_views(&ctx, &rec).1, None);
}

#[test]
fn a_view_checked_only_against_removed_views_is_unconfirmed() {
    let (mut input, rec) = scene();
    // View 3 keeps its usable pairs with view 2 alone; views 4 and 5 keep theirs too.
    input.pairs.retain(|p| {
        let (a, b) = (p.a.min(p.b), p.a.max(p.b));
        (a != 3 && b != 3) || (a, b) == (2, 3)
    });
    let graph = CorrespondenceGraph::build(&input, 8);
    let opts = SfmOptions::default();
    let ctx = Context::new(&input, &graph, &opts);
    assert!(unconfirmed(&ctx, &rec, &BTreeSet::new()).is_empty());
    assert_eq!(unconfirmed(&ctx, &rec, &BTreeSet::from([2])), vec![3]);
    // Removing a view with many partners leaves every other view a kept partner.
    assert!(unconfirmed(&ctx, &rec, &BTreeSet::from([5])).is_empty());
}

#[test]
fn views_tied_to_the_model_only_through_removed_views_are_unconfirmed_together() {
    let (mut input, rec) = scene();
    // Views 3 and 4 keep their pair with each other and their pairs with view 2 alone.
    input.pairs.retain(|p| {
        let (a, b) = (p.a.min(p.b), p.a.max(p.b));
        let inside = |v: usize| v == 3 || v == 4;
        (!inside(a) && !inside(b)) || (a, b) == (3, 4) || (a == 2 && inside(b))
    });
    let graph = CorrespondenceGraph::build(&input, 8);
    let opts = SfmOptions::default();
    let ctx = Context::new(&input, &graph, &opts);
    // With view 2 in the model, it ties them to the rest.
    assert!(unconfirmed(&ctx, &rec, &BTreeSet::from([6])).is_empty());
    // Without it, they agree with each other and with nothing else.
    assert_eq!(unconfirmed(&ctx, &rec, &BTreeSet::from([2])), vec![3, 4]);
}

#[test]
fn a_view_beside_a_removed_one_that_rests_on_two_view_tracks_is_unconfirmed() {
    let (input, mut rec) = scene();
    let graph = CorrespondenceGraph::build(&input, 8);
    let opts = SfmOptions::default();
    let ctx = Context::new(&input, &graph, &opts);
    assert!(unconfirmed(&ctx, &rec, &BTreeSet::from([2])).is_empty());
    // View 3 keeps 10 of its points (each seen by every view): its usable pairs still tie it
    // to the model, but fewer points than a registration needs place it.
    let v3 = input.images[3].id;
    let dropped: Vec<handheld_core::PointId> = rec.points.keys().skip(10).copied().collect();
    for pid in &dropped {
        if let Some(p) = rec.points.get_mut(pid) {
            p.track.elements.retain(|e| e.image_id != v3);
        }
    }
    for o in &mut rec.views.get_mut(&v3).expect("view 3").observations {
        if o.point_id.is_some_and(|pid| dropped.contains(&pid)) {
            o.point_id = None;
        }
    }
    assert_eq!(unconfirmed(&ctx, &rec, &BTreeSet::from([2])), vec![3]);
    // Nothing was removed: nothing to say.
    assert!(unconfirmed(&ctx, &rec, &BTreeSet::new()).is_empty());
}

#[test]
fn weighted_median_follows_the_weights() {
    assert_eq!(
        weighted_median(vec![(1.0, 1.0), (2.0, 1.0), (30.0, 1.0)]),
        2.0
    );
    assert_eq!(
        weighted_median(vec![(1.0, 10.0), (20.0, 1.0), (30.0, 1.0)]),
        1.0
    );
    assert_eq!(
        weighted_median(vec![(1.0, 1.0), (20.0, 5.0), (30.0, 5.0)]),
        20.0
    );
}

#[test]
fn a_pair_is_held_by_points_a_third_view_sees_where_they_reproject() {
    let (input, mut rec) = scene();
    let graph = CorrespondenceGraph::build(&input, 8);
    let opts = SfmOptions::default();
    let ctx = Context::new(&input, &graph, &opts);
    let pair = input
        .pairs
        .iter()
        .max_by_key(|p| p.matches.len())
        .expect("a pair");
    let (a, b) = (input.images[pair.a].id, input.images[pair.b].id);
    let held = |rec: &MetricReconstruction| {
        held_by_structure(&ctx, rec, pair, (&rec.views[&a], &rec.views[&b]))
    };
    assert!(held(&rec), "the true model holds its pairs");
    // Turned by 12°, view b no longer reprojects the points onto its matches.
    let mut turned = rec.clone();
    let turn = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), 12f64.to_radians());
    let v = turned.views.get_mut(&b).expect("view b");
    v.cam_from_world = nalgebra::Isometry3::from_parts(
        (turn * v.cam_from_world.translation.vector).into(),
        turn * v.cam_from_world.rotation,
    );
    assert!(!held(&turned));
    // Points seen by the two views alone (two-view tracks) hold nothing beyond the pair.
    for p in rec.points.values_mut() {
        if p.track.elements.iter().any(|e| e.image_id == a)
            && p.track.elements.iter().any(|e| e.image_id == b)
        {
            p.track
                .elements
                .retain(|e| e.image_id == a || e.image_id == b);
        }
    }
    assert!(!held(&rec));
}

#[test]
fn held_pairs_are_allowed_only_inside_the_largest_piece_they_join() {
    let d = |held| Disagreement {
        deg: 20.0,
        allowed_deg: 5.0,
        held,
    };
    // Views 0-3 joined by held pairs; 4 and 5 hold each other but not the rest (a group mirrored
    // together); pair 3-4 is not held.
    let pairs = vec![
        (0, 1, d(true), 100.0),
        (1, 2, d(true), 100.0),
        (2, 3, d(true), 100.0),
        (3, 4, d(false), 100.0),
        (4, 5, d(true), 100.0),
    ];
    let out = exempt_held(pairs);
    let allowed: Vec<f64> = out.iter().map(|x| x.2.allowed_deg).collect();
    assert_eq!(allowed, vec![20.0, 20.0, 20.0, 5.0, 5.0]);
}
