//! Candidates ranked cheaply first (issue #34): before its full adjustment, a candidate frame of a
//! large model is adjusted on a subsample of its points, which decides two cases alone:
//!
//! - it collapses there (the schedule's filters remove [`COLLAPSED_FRACTION`] of the observations):
//!   the full adjustment would collapse the same way, since the removals are a fraction of
//!   whatever points are kept, and would cost the whole schedule first (a focal hypothesis of 10 px
//!   on the demo's sideways walk took 100 iterations over 16 600 points to lose 99.9 %);
//! - it is sound there and converges to the calibration of a frame that already had its full
//!   adjustment (every focal length within [`SAME_FOCAL`]): the two are one frame reached from two
//!   starts, and it cannot show that the images leave the focal length open
//!   ([`super::focal_ambiguity`] needs one more than [`super::DISTINCT_FOCAL`] away). Asked only
//!   where that is the question (the candidate loop, the probes of a camera that only translates),
//!   not for a frame found along the focal profile, whose point is a better fit in the same place.
//!   The sideways walk's probes (the priors, the two-view focal length, a hypothesis) all came to
//!   within 0.02 % of the self-calibration's 576 px, each after a full schedule.
//!
//! Every other candidate gets the full adjustment, judged on all its observations: a sound frame
//! with its own calibration, or one that loses many observations without collapsing. That
//! adjustment starts where the subsample's ended ([`Screened::Warm`]): the subsample's cameras and
//! calibration, every point triangulated again under them (eqs. 19–20). The cameras of a new
//! frame are tens of pixels from their optimum, and the full schedule spent most of its time
//! walking them there with every point in tow (kitti-seq1's self-calibrated frame: 93 iterations
//! over 39 000 points from 28 px RMS), and its filter cut what did not fit the cameras on their
//! way; from the subsample's cameras it only settles. Models of at most [`MIN_SCREENED_POINTS`]
//! are not screened: there the subsample would not be much cheaper than the whole. (templeSparseRing's
//! 6 416 points, screened on 3 000: none of its four candidates was decided there, and its metric
//! adjustments went from 3.9 s to 6.3 s.)

use handheld_core::MetricReconstruction;
use nalgebra::Point3;
use rayon::prelude::*;

use super::{judge, observation_count, record_before, CandidateRecord};
use crate::metric::ba::{MetricBaRecord, COLLAPSED_FRACTION};
use crate::metric::profile::subsample_points;

/// Points of the subsample a candidate is screened on.
pub const SCREEN_POINTS: usize = 3000;
/// Observations every view keeps in the subsample (points added from the view's own when the
/// spread of the subsample left it fewer), so that no camera is left loose.
pub const MIN_VIEW_OBSERVATIONS: usize = 60;
/// Models of at most this many points are not screened: `4 × SCREEN_POINTS`.
pub const MIN_SCREENED_POINTS: usize = 4 * SCREEN_POINTS;
/// Relative difference between a subsample's focal length and a fully adjusted frame's below
/// which the two are one calibration: half of [`super::DISTINCT_FOCAL`], the guard's own bound for
/// "the same calibration reached by another path", so that a frame passed over can never have
/// been a distinct one. The margin is the subsample's own spread where the focal length is weakly
/// determined: on kitti-seq1 (forward motion, a flat focal profile) two probes came to 720 px on
/// a subsample of 2 805 points and to 709 px with all 39 377, against the kept 711 px.
pub const SAME_FOCAL: f64 = 0.5 * super::DISTINCT_FOCAL;

/// The subsample a candidate is screened on ([`subsample_points`]: every k-th point, each view
/// topped up to [`MIN_VIEW_OBSERVATIONS`]). `None` when `rec` has at most `4 × target` points.
pub(crate) fn subsample(rec: &MetricReconstruction, target: usize) -> Option<MetricReconstruction> {
    (target > 0 && rec.points.len() > 4 * target)
        .then(|| subsample_points(rec, target, MIN_VIEW_OBSERVATIONS))
}

/// What the subsample said of a candidate.
#[derive(Debug)]
pub(crate) enum Screened {
    /// Decided alone: the candidate's record (collapsed, or one calibration with a frame already
    /// adjusted).
    Decided(CandidateRecord),
    /// The full adjustment decides, and starts from this: the candidate with the subsample's
    /// adjusted cameras and every point triangulated again under them ([`warm_start`]).
    Warm(MetricReconstruction, usize),
    /// Not screened (a small model, or the subsample's adjustment failed): the full adjustment
    /// starts from the candidate itself.
    Cold,
}

impl Screened {
    /// Where the full adjustment starts: the warm start and the subsample's points, or `None` for
    /// the candidate itself.
    pub(crate) fn start(self) -> Option<(MetricReconstruction, usize)> {
        match self {
            Screened::Warm(rec, points) => Some((rec, points)),
            Screened::Decided(_) | Screened::Cold => None,
        }
    }
}

/// Screens a candidate on a subsample of its points. `tried` holds the frames adjusted so far;
/// `adjust` is the full metric adjustment, run here on the subsample; `same` asks whether it comes
/// to a calibration already adjusted.
pub(crate) fn screen(
    source: &str,
    rec: &MetricReconstruction,
    projective_rms_px: Option<f64>,
    adjust: &mut impl FnMut(
        &mut MetricReconstruction,
        Option<f64>,
    ) -> Result<Vec<MetricBaRecord>, String>,
    tried: &[CandidateRecord],
    same: bool,
) -> Screened {
    if rec.points.len() <= MIN_SCREENED_POINTS {
        return Screened::Cold;
    }
    let Some(mut sub) = subsample(rec, SCREEN_POINTS) else {
        return Screened::Cold;
    };
    let mut record = record_before(source, &sub);
    let points = sub.points.len();
    let Ok(adjustments) = adjust(&mut sub, None) else {
        return Screened::Cold;
    };
    let why = judge(&mut record, &sub, &adjustments, projective_rms_px);
    let removed = record.removed_fraction.unwrap_or(0.0);
    let verdict = if removed >= COLLAPSED_FRACTION {
        Some((
            false,
            format!(
                "on a subsample of {points} points its adjustment removed {:.0} % of the observations",
                100.0 * removed
            ),
        ))
    } else if why.is_none() && same {
        same_calibration(&record.focal_after_px, tried).map(|(other, f)| {
            (
                true,
                format!(
                    "on a subsample of {points} points it converged to the calibration of the frame from {other} (f = {:.0} px against {f:.0} px)",
                    record.focal_after_px.first().copied().unwrap_or(f64::NAN)
                ),
            )
        })
    } else {
        None
    };
    let Some(verdict) = verdict else {
        tracing::debug!(
            focal = ?record.focal_after_px,
            removed,
            why,
            "metric frame from {source} on a subsample of {points} points: the full adjustment decides, from the subsample's cameras"
        );
        return Screened::Warm(warm_start(rec, &sub), points);
    };
    let (sound, why) = verdict;
    tracing::debug!("metric frame from {source} decided on a subsample: {why}");
    let mut out = record_before(source, rec);
    out.tried = true;
    out.sound = sound;
    out.removed_fraction = record.removed_fraction;
    out.final_rms_px = record.final_rms_px;
    out.focal_after_px = record.focal_after_px;
    out.screened_points = Some(points);
    out.rejected = Some(why);
    debug_assert_eq!(observation_count(rec), out.observations);
    Screened::Decided(out)
}

/// `rec` with the cameras and calibration of its adjusted subsample `sub`, and every point
/// triangulated again under them from all its observations (the iterated linear method, eqs.
/// 19–20, on undistorted normalised coordinates). A point whose rays do not determine it keeps
/// its subsample position, or its own. Nothing is removed: the full adjustment's filters judge
/// every observation, and the guard counts what they remove against all of them.
pub(crate) fn warm_start(
    rec: &MetricReconstruction,
    sub: &MetricReconstruction,
) -> MetricReconstruction {
    let mut out = rec.clone();
    out.cameras.clone_from(&sub.cameras);
    for (id, v) in out.views.iter_mut() {
        if let Some(s) = sub.views.get(id) {
            v.cam_from_world = s.cam_from_world;
        }
    }
    let moved: Vec<(handheld_core::PointId, Option<Point3<f64>>)> = out
        .points
        .par_iter()
        .map(|(id, p)| {
            let mut cams = Vec::with_capacity(p.track.len());
            let mut xs = Vec::with_capacity(p.track.len());
            for el in &p.track.elements {
                let Some(v) = out.views.get(&el.image_id) else {
                    continue;
                };
                let Some(cam) = out.cameras.get(&v.camera_id) else {
                    continue;
                };
                let Some(o) = v.observations.get(el.point2d_idx as usize) else {
                    continue;
                };
                cams.push(crate::metric::register::normalized_camera(v));
                xs.push(cam.intrinsics.pixel_to_normalized(o.xy));
            }
            let x = handheld_geometry::triangulate_iterative(&cams, &xs, 2)
                .ok()
                .filter(|m| m.w.abs() > 1e-12)
                .map(|m| Point3::from(m.xyz() / m.w))
                .filter(|x| x.iter().all(|c| c.is_finite()))
                .or_else(|| sub.points.get(id).map(|q| q.xyz));
            (*id, x)
        })
        .collect();
    for (id, x) in moved {
        if let (Some(x), Some(p)) = (x, out.points.get_mut(&id)) {
            p.xyz = x;
        }
    }
    out
}

/// The source and focal length of a fully adjusted sound frame whose focal lengths all lie within
/// [`SAME_FOCAL`] of `focal` (a subsample's), or whose own subsample came to within it of `focal`.
///
/// The second compares like with like. Where the focal length is weakly determined, a subsample's
/// optimum lies away from the full one by more than the margin, the same way for every start: on
/// kitti-seq1 with slightly different matches, the self-calibrated frame's subsample came to
/// 771 px and its full adjustment to 708 px; the three probes' subsamples came to 753, 768 and
/// 768 px, were not settled against 708, and each got a full adjustment (3.1–3.8 s) that ended at
/// 708 px too, doubling the sparse stage.
fn same_calibration<'a>(focal: &[f64], tried: &'a [CandidateRecord]) -> Option<(&'a str, f64)> {
    tried
        .iter()
        .filter(|r| r.sound && r.screened_points.is_none() && r.score.is_some())
        .find(|r| {
            super::same_focal(&r.focal_after_px, focal)
                || r.subsample_focal_px
                    .as_ref()
                    .is_some_and(|s| super::same_focal(s, focal))
        })
        .map(|r| (r.source.as_str(), r.focal_after_px[0]))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn model(points: u32, views: u32) -> MetricReconstruction {
        crate::upgrade::guard::tests::model_of(500.0, views, points)
    }

    /// An adjustment that sets the focal length to `f` and removes `fraction` of what it is given,
    /// counting the points it saw.
    fn fake(
        f: f64,
        fraction: f64,
        seen: &mut Vec<usize>,
    ) -> impl FnMut(&mut MetricReconstruction, Option<f64>) -> Result<Vec<MetricBaRecord>, String> + '_
    {
        move |rec, _| {
            seen.push(rec.points.len());
            for c in rec.cameras.values_mut() {
                c.intrinsics.f = f;
            }
            let removed = (fraction * observation_count(rec) as f64) as usize;
            Ok(vec![MetricBaRecord {
                step: "final".into(),
                iterations: 3,
                initial_rms_px: 0.5,
                final_rms_px: 0.5,
                seconds: 0.0,
                observations_removed: removed,
                points_removed: 0,
                loss_scale_px: 1.5,
                noise_px: None,
                initial_cost: 0.0,
                final_cost: 0.0,
            }])
        }
    }

    fn adjusted_in_full(source: &str, f: f64) -> CandidateRecord {
        CandidateRecord {
            source: source.into(),
            focal_after_px: vec![f],
            tried: true,
            sound: true,
            score: Some(1000.0),
            ..Default::default()
        }
    }

    #[test]
    fn a_subsample_spreads_over_the_scene_and_keeps_every_view_held() {
        assert!(subsample(&model(MIN_SCREENED_POINTS as u32, 3), SCREEN_POINTS).is_none());
        let rec = model(13_001, 3);
        let sub = subsample(&rec, SCREEN_POINTS).expect("large enough");
        assert!(sub.points.len() <= SCREEN_POINTS && sub.points.len() > 3 * SCREEN_POINTS / 4);
        // Its points are the model's own, untouched, and every view still observes them.
        for (id, p) in &sub.points {
            assert_eq!(p.xyz, rec.points[id].xyz);
            assert_eq!(p.track.len(), 3);
        }
        for v in sub.views.values() {
            let seen = v
                .observations
                .iter()
                .filter(|o| o.point_id.is_some())
                .count();
            assert_eq!(seen, sub.points.len());
        }
    }

    #[test]
    fn a_candidate_that_collapses_on_the_subsample_is_rejected_without_the_full_adjustment() {
        let rec = model(13_001, 3);
        let mut seen = Vec::new();
        let r = screen(
            "focal hypothesis",
            &rec,
            None,
            &mut fake(500.0, 0.95, &mut seen),
            &[],
            true,
        );
        let Screened::Decided(r) = r else {
            panic!("not decided on the subsample: {r:?}")
        };
        assert_eq!(seen.len(), 1, "only the subsample was adjusted");
        assert!(seen[0] <= SCREEN_POINTS);
        assert!(!r.sound && r.tried && !r.accepted);
        assert_eq!(r.screened_points, Some(seen[0]));
        assert_eq!(r.observations, observation_count(&rec));
        assert!(
            r.rejected
                .as_deref()
                .is_some_and(|w| w.contains("removed 95 %")),
            "{r:?}"
        );
    }

    #[test]
    fn a_candidate_that_comes_to_an_adjusted_calibration_is_passed_over() {
        let rec = model(13_001, 3);
        let mut seen = Vec::new();
        let tried = [adjusted_in_full("self-calibration", 520.0)];
        let r = screen(
            "priors",
            &rec,
            None,
            &mut fake(500.0, 0.01, &mut seen),
            &tried,
            true,
        );
        let Screened::Decided(r) = r else {
            panic!("not the same calibration: {r:?}")
        };
        assert!(r.sound && !r.accepted && r.score.is_none(), "{r:?}");
        assert!(r
            .rejected
            .as_deref()
            .is_some_and(|w| w.contains("self-calibration")));
        // Not an ambiguity: it has no score of its own.
        assert!(super::super::focal_ambiguity(&[
            CandidateRecord {
                accepted: true,
                ..tried[0].clone()
            },
            r
        ])
        .is_none());
    }

    #[test]
    fn a_candidate_whose_subsample_comes_where_an_adjusted_frames_subsample_came_is_passed_over() {
        // kitti-seq1: the self-calibrated frame's subsample at 771 px, its full adjustment 708 px.
        let tried = [CandidateRecord {
            subsample_focal_px: Some(vec![771.0]),
            ..adjusted_in_full("self-calibration", 708.0)
        }];
        let mut seen = Vec::new();
        // A probe's subsample at 753 px: 6 % from 708 px, 2 % from 771 px.
        let r = screen(
            "priors",
            &model(13_001, 3),
            None,
            &mut fake(753.0, 0.01, &mut seen),
            &tried,
            true,
        );
        assert!(matches!(r, Screened::Decided(ref r) if r.sound), "{r:?}");
        // 840 px, 9 % from 771 px and 19 % from 708 px: a calibration of its own.
        assert!(warm(screen(
            "priors",
            &model(13_001, 3),
            None,
            &mut fake(840.0, 0.01, &mut seen),
            &tried,
            true
        )));
    }

    #[test]
    fn a_candidate_with_its_own_calibration_or_a_small_model_gets_the_full_adjustment() {
        let tried = [adjusted_in_full("self-calibration", 503.0)];
        let mut seen = Vec::new();
        // 8 % away from the adjusted one: a calibration of its own.
        assert!(warm(screen(
            "priors",
            &model(13_001, 3),
            None,
            &mut fake(543.0, 0.01, &mut seen),
            &tried,
            true
        )));
        // The same calibration, where that is not asked (a frame along the focal profile).
        assert!(warm(screen(
            "priors",
            &model(13_001, 3),
            None,
            &mut fake(503.0, 0.01, &mut seen),
            &tried,
            false
        )));
        // Many removals but no collapse: the full adjustment judges them.
        assert!(warm(screen(
            "priors",
            &model(13_001, 3),
            None,
            &mut fake(500.0, 0.5, &mut seen),
            &tried,
            true
        )));
        assert_eq!(seen.len(), 3);
        // A small model is not screened at all.
        assert!(matches!(
            screen(
                "priors",
                &model(500, 3),
                None,
                &mut fake(500.0, 0.95, &mut seen),
                &tried,
                true
            ),
            Screened::Cold
        ));
        assert_eq!(seen.len(), 3);
    }

    #[test]
    fn the_warm_start_takes_the_subsample_cameras_and_triangulates_every_point_under_them() {
        let truth = model(13_001, 3);
        // A candidate far from its optimum: a focal length 40 % short, cameras and points off.
        let mut far = truth.clone();
        for c in far.cameras.values_mut() {
            c.intrinsics.f = 300.0;
        }
        for v in far.views.values_mut() {
            v.cam_from_world.translation.vector *= 0.7;
        }
        for p in far.points.values_mut() {
            p.xyz.coords *= 1.3;
        }
        // Its subsample, adjusted to the optimum: here the truth's own.
        let sub = subsample(&truth, SCREEN_POINTS).expect("large enough");
        let warm = warm_start(&far, &sub);
        assert_eq!(observation_count(&warm), observation_count(&far));
        assert_eq!(
            warm.cameras[&handheld_core::CameraId(1)].intrinsics.f,
            500.0
        );
        let worst = warm.reprojection_errors().into_iter().fold(0.0, f64::max);
        assert!(worst < 1e-6, "worst reprojection error {worst} px");
        for (id, p) in &warm.points {
            assert!((p.xyz - truth.points[id].xyz).norm() < 1e-6);
        }
    }

    /// Whether the full adjustment decides, from the subsample's cameras.
    fn warm(s: Screened) -> bool {
        matches!(s, Screened::Warm(..))
    }
}
