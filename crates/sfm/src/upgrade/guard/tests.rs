//! The guard's checks on small hand-made models and records.

use super::*;
use handheld_core::{
    Camera, CameraId, ImageId, Intrinsics, Observation, Point3D, PointId, Rigid3, Track,
    TrackElement, View,
};
use nalgebra::{Point3, Vector3};

/// Two cameras 1 m apart looking down +z at 20 points 4–6 m away; exact observations.
fn model(f: f64) -> MetricReconstruction {
    model_of(f, 2, 20)
}

/// `views` cameras 1 m apart along x looking down +z at `points` points 4–6 m away, each seen by
/// every camera; exact observations.
pub(crate) fn model_of(f: f64, views: u32, points: u32) -> MetricReconstruction {
    let cam = Camera {
        id: CameraId(1),
        width: 640,
        height: 480,
        intrinsics: Intrinsics::pinhole(f, 319.5, 239.5),
    };
    let mut rec = MetricReconstruction::default();
    rec.cameras.insert(cam.id, cam.clone());
    for k in 0..views {
        let id = ImageId(k + 1);
        rec.views.insert(
            id,
            View {
                id,
                camera_id: cam.id,
                name: format!("{k}.png"),
                cam_from_world: Rigid3::new(
                    Vector3::new(-f64::from(k), 0.0, 0.0),
                    Vector3::zeros(),
                ),
                observations: Vec::new(),
                frame: None,
            },
        );
    }
    for i in 0..points {
        let t = f64::from(i) / f64::from(points);
        let xyz = Point3::new(-1.0 + 2.0 * t, 0.5 - t, 4.0 + 2.0 * t);
        let pid = PointId(i.into());
        let mut track = Track::default();
        for (id, v) in rec.views.iter_mut() {
            let xy = cam.project(&v.cam_from_world, &xyz).expect("in front");
            track.elements.push(TrackElement {
                image_id: *id,
                point2d_idx: v.observations.len() as u32,
            });
            v.observations.push(Observation {
                xy,
                point_id: Some(pid),
            });
        }
        rec.points.insert(
            pid,
            Point3D {
                xyz,
                color: [0; 3],
                error: 0.0,
                track,
            },
        );
    }
    rec
}

fn adjusted(removed: usize, rms: f64) -> Vec<MetricBaRecord> {
    vec![MetricBaRecord {
        step: "final".into(),
        iterations: 3,
        initial_rms_px: rms,
        final_rms_px: rms,
        seconds: 0.0,
        observations_removed: removed,
        points_removed: 0,
        loss_scale_px: 1.5,
        noise_px: None,
        initial_cost: 0.0,
        final_cost: 0.0,
    }]
}

#[test]
fn a_sound_candidate_passes() {
    let rec = model(800.0);
    let mut r = record_before("self-calibration", &rec);
    assert_eq!(r.observations, 40);
    assert_eq!(r.in_front_fraction, 1.0);
    assert_eq!(judge(&mut r, &rec, &adjusted(1, 0.6), Some(0.5)), None);
    assert!(r.accepted);
}

#[test]
fn a_collapsed_candidate_is_rejected_for_each_reason() {
    // Most observations removed (the building-entrance failure: 52,108 removed, 34 points kept).
    let rec = model(800.0);
    let mut r = record_before("priors", &rec);
    let why = judge(&mut r, &rec, &adjusted(38, 0.3), Some(0.5)).expect("rejected");
    assert!(why.contains("removed 95 %"), "{why}");
    assert!(!r.accepted);
    // An absurd focal length (f = 0.32 px).
    let rec = model(0.32);
    let mut r = record_before("priors", &rec);
    let why = judge(&mut r, &rec, &adjusted(0, 0.3), Some(0.5)).expect("rejected");
    assert!(why.contains("implausible focal length 0.3 px"), "{why}");
    // A fit far worse than the projective model's.
    let rec = model(800.0);
    let mut r = record_before("focal hypothesis", &rec);
    let why = judge(&mut r, &rec, &adjusted(0, 9.0), Some(0.5)).expect("rejected");
    assert!(why.contains("reprojection error 9.00 px"), "{why}");
    // The mirror frame: every point behind the cameras.
    let mut rec = model(800.0);
    for p in rec.points.values_mut() {
        p.xyz.z = -p.xyz.z;
    }
    let mut r = record_before("self-calibration", &rec);
    let why = judge(&mut r, &rec, &adjusted(0, 0.5), Some(0.5)).expect("rejected");
    assert!(why.contains("in front"), "{why}");
    let text = describe_rejections(&[r]);
    assert!(text.starts_with("self-calibration (f = 800 px):"), "{text}");
}

#[test]
fn a_collapsed_candidate_gives_way_to_the_next() {
    // The first candidate's adjustment collapses (it keeps 2 of 40 observations); the
    // second's is sound and is the one returned.
    let (collapsed, sound) = (model(0.32), model(800.0));
    let candidates = [(1, "self-calibration", &collapsed), (2, "priors", &sound)];
    let mut tried = Vec::new();
    let (winner, rec, adjustments) = first_sound(
        candidates.iter().map(|(id, s, r)| (id, *s, *r)),
        Some(0.5),
        |rec, _| {
            let collapse = rec.cameras.values().any(|c| c.intrinsics.f < 1.0);
            Ok(adjusted(if collapse { 38 } else { 1 }, 0.4))
        },
        &mut tried,
    )
    .expect("the second candidate survives");
    assert_eq!(*winner, 2);
    assert_eq!(
        rec.cameras.values().next().map(|c| c.intrinsics.f),
        Some(800.0)
    );
    assert_eq!(adjustments[0].observations_removed, 1);
    assert_eq!(tried.len(), 2);
    assert!(!tried[0].accepted && tried[1].accepted);
    assert!(tried[0]
        .rejected
        .as_deref()
        .unwrap_or("")
        .contains("removed 95 %"));
    // None survives: nothing is returned, and both are recorded with their reasons.
    let mut tried = Vec::new();
    let none = first_sound(
        candidates.iter().map(|(id, s, r)| (id, *s, *r)),
        Some(0.5),
        |_, _| Err("metric bundle adjustment (f+k1): diverged".to_string()),
        &mut tried,
    );
    assert!(none.is_none());
    assert_eq!(tried.len(), 2);
    assert!(describe_rejections(&tried).contains("priors (f = 800 px): metric bundle adjustment"));
}

#[test]
fn with_several_sound_candidates_the_best_adjusted_one_is_kept() {
    // Both pass; the second keeps more observations after its adjustment and wins, although it
    // was ranked second.
    let (a, b) = (model(800.0), model(820.0));
    let candidates = [(1, "focal hypothesis", &a), (2, "priors", &b)];
    let mut tried = Vec::new();
    let (winner, _, _) = choose(
        true,
        candidates.iter().map(|(id, s, r)| (id, *s, *r)),
        Some(0.5),
        |rec, _| {
            let f = rec.cameras.values().next().map_or(0.0, |c| c.intrinsics.f);
            Ok(adjusted(if f < 810.0 { 10 } else { 2 }, 0.5))
        },
        &mut tried,
    )
    .expect("a sound candidate");
    assert_eq!(*winner, 2);
    assert_eq!(tried.len(), 2);
    assert!(!tried[0].accepted && tried[1].accepted);
    assert!(tried[0].score < tried[1].score);
    // Each frame records the time it cost (the summary's per-candidate `seconds`).
    assert!(
        tried.iter().all(|r| r.seconds.is_some_and(|s| s >= 0.0)),
        "{tried:?}"
    );
}

#[test]
fn a_candidate_after_a_sound_one_may_stop_below_what_could_matter() {
    // The first candidate has no bar (nothing is kept yet); each later one gets CLOSE_SCORE × the
    // best sound score so far, and a frame that stopped early there is rejected, as it would have
    // been in full.
    let (a, b, c) = (model(800.0), model(820.0), model(840.0));
    let candidates = [
        (1, "self-calibration", &a),
        (2, "priors", &b),
        (3, "focal hypothesis", &c),
    ];
    let mut tried = Vec::new();
    let mut bars = Vec::new();
    let (winner, _, _) = choose(
        true,
        candidates.iter().map(|(id, s, r)| (id, *s, *r)),
        Some(0.5),
        |rec, bar| {
            bars.push(bar);
            let f = rec.cameras.values().next().map_or(0.0, |c| c.intrinsics.f);
            // The second stops early after removing 20 of 40.
            Ok(adjusted(
                if f < 810.0 {
                    1
                } else if f < 830.0 {
                    20
                } else {
                    2
                },
                0.5,
            ))
        },
        &mut tried,
    )
    .expect("a sound candidate");
    assert_eq!(*winner, 1);
    let first = tried[0].score.expect("scored");
    assert_eq!(bars[0], None);
    assert_eq!(bars[1], Some(CLOSE_SCORE * first));
    assert_eq!(bars[2], Some(CLOSE_SCORE * first));
    assert!(tried[1].rejected.is_some() && !tried[1].sound);
    assert!(focal_ambiguity(&tried).is_none());
}

fn record(source: &str, focal: f64, score: f64, sound: bool, accepted: bool) -> CandidateRecord {
    CandidateRecord {
        source: source.into(),
        focal_after_px: vec![focal],
        score: Some(score),
        sound,
        accepted,
        tried: true,
        ..Default::default()
    }
}

#[test]
fn two_sound_frames_with_different_focal_lengths_and_close_scores_are_ambiguous() {
    // kitti-seq1 as photos: 570 px kept, 1163 px sound and 4 % behind.
    let tried = [
        record("priors", 1163.0, 99_582.0, true, false),
        record("focal hypothesis", 570.0, 103_473.0, true, true),
    ];
    let w = focal_ambiguity(&tried).expect("ambiguous");
    assert!(w.contains("1163") && w.contains("570"), "{w}");
    // Far behind, or the same calibration reached another way, or rejected: not ambiguous.
    for other in [
        record("priors", 1163.0, 60_000.0, true, false),
        record("priors", 600.0, 103_000.0, true, false),
        record("priors", 1163.0, 103_000.0, false, false),
    ] {
        let tried = [
            other,
            record("focal hypothesis", 570.0, 103_473.0, true, true),
        ];
        assert_eq!(focal_ambiguity(&tried), None);
    }
}

#[test]
fn a_frame_rejected_only_for_its_removals_that_explains_the_images_better_is_an_ambiguity() {
    // The 12-view synthetic orbit (seed 1): 195 px kept (the true focal length is 288 px),
    // while the frame at 303 px removed 22 % on its way and still scored higher.
    let kept = record("focal hypothesis", 195.0, 8056.0, true, true);
    let mut better = record("focal hypothesis", 303.0, 9103.0, false, false);
    better.removals_only = true;
    let w = focal_ambiguity(&[better.clone(), kept.clone()]).expect("ambiguous");
    assert!(w.contains("303") && w.contains("195"), "{w}");
    // Rejected for anything else (points behind, an absurd focal length, a poor fit): no.
    better.removals_only = false;
    assert_eq!(focal_ambiguity(&[better, kept]), None);
}

#[test]
fn a_frame_rejected_for_removals_alone_is_marked_so() {
    let rec = model(800.0);
    let mut r = record_before("priors", &rec);
    let why = judge(&mut r, &rec, &adjusted(30, 0.5), Some(0.5)).expect("rejected");
    assert!(why.contains("removed"), "{why}");
    assert!(r.removals_only);
    // The same removals from a frame with an implausible focal length: not removals alone.
    let rec = model(1.0);
    let mut r = record_before("priors", &rec);
    assert!(judge(&mut r, &rec, &adjusted(30, 0.5), Some(0.5)).is_some());
    assert!(!r.removals_only);
}

#[test]
fn a_flat_focal_profile_is_an_ambiguity() {
    let rec = model(800.0);
    // fountain-P11: the cost rises 30-fold with the focal length held 20 % off.
    assert_eq!(flat_profile(&rec, [38.4, 30.7]), None);
    // templeSparseRing (a turntable, yet determined): 1.6-fold.
    assert_eq!(flat_profile(&rec, [1.78, 1.56]), None);
    // Hardly any rise on one side, or a better fit there (an adjustment stopped on a slope).
    for ratios in [[1.01, 3.0], [4.0, 0.42]] {
        let w = flat_profile(&rec, ratios).expect("flat");
        assert!(w.contains("do not determine the focal length"), "{w}");
    }
    assert!(flat_profile(&rec, [f64::NAN, 2.0]).is_none());
}

#[test]
fn an_aspect_ratio_estimated_under_pure_translation_is_flagged_when_not_square() {
    let mut rec = model(800.0);
    assert_eq!(aspect_undetermined(&rec, "it translates"), None);
    for c in rec.cameras.values_mut() {
        c.intrinsics.aspect = 1.31;
    }
    let w = aspect_undetermined(&rec, "it translates").expect("flagged");
    assert!(w.contains("1.310") && w.contains("--aspect fixed"), "{w}");
}

#[test]
fn a_camera_that_only_translates_is_flagged() {
    // The test model's second view is the first moved sideways, without turning.
    let mut rec = model(800.0);
    assert!(translation_only(&rec)
        .expect("flagged")
        .contains("translates"));
    // Turned by 30°: the motion determines the focal length.
    let v = rec
        .views
        .values_mut()
        .nth(1)
        .expect("the test model has two views");
    v.cam_from_world = Rigid3::new(Vector3::new(-1.0, 0.0, 0.0), Vector3::new(0.0, 0.52, 0.0));
    assert_eq!(translation_only(&rec), None);
}

#[test]
fn an_adjustment_after_the_frame_that_removes_most_observations_is_a_collapse() {
    // The model keeps 40 observations; 2 more were filtered (5 %): sound.
    let rec = model(500.0);
    assert_eq!(collapsed(&rec, &adjusted(2, 0.3)), None);
    // 160 filtered: 80 % of the 200 it started from.
    let why = collapsed(&rec, &adjusted(160, 0.3)).expect("a collapse");
    assert!(why.contains("80 %"), "{why}");
}

#[test]
fn candidate_records_survive_a_format_without_field_names() {
    // A cluster's model travels between processes as postcard (the pipeline's sparse units, the
    // Python package's Dask tasks), which writes no field names: a field skipped when empty
    // shifts every byte after it (a skipped `disagreeing_views` broke the Dask benchmark's merge).
    let full = CandidateRecord {
        disagreeing_views: Some(3),
        subsample_focal_px: Some(vec![771.0]),
        ..record("self-calibration", 708.0, 1.0, true, true)
    };
    for r in [full, CandidateRecord::default()] {
        let bytes = postcard::to_stdvec(&r).expect("encodes");
        let back: CandidateRecord = postcard::from_bytes(&bytes).expect("decodes");
        assert_eq!(back, r);
    }
}
