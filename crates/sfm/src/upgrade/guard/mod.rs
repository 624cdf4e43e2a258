//! The checks an adjusted metric frame must pass before it is reported: a wrong upgrade (a
//! self-calibration that is not positive semi-definite, a prior fallback with an absurd focal
//! length) does not fail loudly inside bundle adjustment. It collapses instead: the outlier filter
//! after each adjustment removes almost every observation, and the few points left fit well. So a
//! candidate is judged by what its adjustment did, not only by how well the survivors fit:
//!
//! - the fraction of its observations the metric adjustment removed (a collapse removes nearly all;
//!   sound models on the project's data sets lose 1–3 %);
//! - the focal length after adjustment, which must lie in the range the focal hypotheses search
//!   (0.2–5 × (w + h), a 150° to 8° diagonal field of view);
//! - its final reprojection RMS against the projective model's (the metric model has fewer
//!   degrees of freedom, but not a worse fit by a large factor);
//! - the fraction of observations in front of their camera before adjustment (the oriented
//!   projective reconstruction puts every point in front of every camera that sees it; an upgrade
//!   that puts most of them behind is the wrong one of the two mirror frames, or no frame at all).
//!
//! The same judge runs the candidate loop of `upgrade/frame.rs` ([`first_sound`], [`best_sound`]:
//! every candidate adjusted, the sound one with the best score kept; [`challenge`] for one more
//! frame that contests the kept one; `screen.rs`: a large model's candidates first adjusted on a
//! subsample, which rejects the ones that collapse and passes over the ones that come to a
//! calibration already adjusted), and undoes a later step whose adjustment removed too many
//! observations ([`collapsed`]: the predicted matches, the consistency check, the principal
//! point's test, a merge). It also says when the images do not determine the focal length: another
//! sound frame (or one rejected only for its removals) with a different focal length fits about as
//! well ([`focal_ambiguity`]), the camera only translates ([`translation_only`], Sturm 1997; the
//! aspect ratio too, [`aspect_undetermined`]), or the kept frame's focal profile is flat
//! ([`flat_profile`]).

use std::time::Instant;

use handheld_core::MetricReconstruction;
use serde::Serialize;

use crate::metric::ba::MetricBaRecord;
use crate::upgrade::hypotheses::RANGE;

/// Largest fraction of a candidate's observations its metric adjustment may remove. The
/// projective adjustment has already removed the outliers at the same threshold, so what the
/// metric one removes is what the metric constraints (one calibration per camera, square pixels,
/// a rigid motion) cannot explain: a sound frame loses a few per cent (0.7–7 % on the project's
/// data sets, the most on forward motion), a wrong focal length a fifth or more (19 % for the
/// priors' focal length on dinoSparseRing, 75 % off; 47 % for a frame that also moved k1 to 0.56).
pub const MAX_REMOVED_FRACTION: f64 = 0.15;
/// A candidate whose final RMS exceeds `MAX_RMS_RATIO ×` the projective RMS plus
/// [`RMS_SLACK_PX`] explains the images far worse than the projective model.
pub const MAX_RMS_RATIO: f64 = 3.0;
/// See [`MAX_RMS_RATIO`].
pub const RMS_SLACK_PX: f64 = 1.0;
/// Smallest fraction of observations in front of their camera before adjustment.
pub const MIN_IN_FRONT: f64 = 0.5;

/// One metric frame that was tried, for the summary.
#[derive(Clone, Debug, Default, PartialEq, Serialize, serde::Deserialize)]
pub struct CandidateRecord {
    /// `self-calibration`, `known calibration`, `priors` or `focal hypothesis`.
    pub source: String,
    /// Focal length of each intrinsics group before adjustment, pixels.
    pub focal_before_px: Vec<f64>,
    /// Observations before adjustment, and the fraction of them in front of their camera.
    pub observations: usize,
    pub in_front_fraction: f64,
    /// What the full adjustment did, when it ran.
    pub removed_fraction: Option<f64>,
    pub final_rms_px: Option<f64>,
    pub focal_after_px: Vec<f64>,
    /// Whether it was adjusted and judged (candidates ranked below the accepted one are not).
    pub tried: bool,
    /// After the full adjustment: the observations kept, discounted by their RMS (higher is
    /// better); ranks the candidates that pass when several are adjusted.
    pub score: Option<f64>,
    pub accepted: bool,
    /// Whether it passed every check (a sound candidate may still lose to a better-scoring one).
    pub sound: bool,
    /// Adjusted because the camera only translates, to test whether the images determine the
    /// focal length; kept only when it explains the images better than the frame it probed.
    pub probe: bool,
    /// Rejected for the observations its adjustment removed alone: every other check passed.
    pub removals_only: bool,
    /// Why it was rejected.
    pub rejected: Option<String>,
    /// Points of the subsample whose adjustment decided it alone ([`screen`]): it collapsed there,
    /// or came to the calibration of a frame already adjusted in full. `None`: the full adjustment
    /// judged it (or it was not tried).
    pub screened_points: Option<usize>,
    /// Points of the subsample whose adjusted cameras the full adjustment started from (the warm
    /// start, [`screen`]). `None`: it started from the frame itself.
    pub warm_start_points: Option<usize>,
    /// Wall-clock seconds spent on it: its adjustment on a subsample and its full one (a
    /// calibrated incremental start: its whole build, from the initial pair to the last
    /// adjustment).
    pub seconds: Option<f64>,
    /// Registered views whose pose disagrees with their verified image pairs
    /// (`metric::consistency`): judged on the calibrated incremental candidate's sound models,
    /// which are ranked by the views that agree.
    #[serde(default)]
    pub disagreeing_views: Option<usize>,
    /// The focal lengths its subsample's adjustment came to, when its full adjustment started from
    /// there ([`screen`]): another candidate whose subsample comes to them is the same frame.
    #[serde(default)]
    pub subsample_focal_px: Option<Vec<f64>>,
}

/// Records on the last candidate tried the time since `clock`.
fn stamp(tried: &mut [CandidateRecord], clock: Instant) {
    if let Some(r) = tried.last_mut() {
        r.seconds = Some(clock.elapsed().as_secs_f64());
    }
}

/// Observations of the model's points.
pub(crate) fn observation_count(rec: &MetricReconstruction) -> usize {
    rec.points.values().map(|p| p.track.len()).sum()
}

/// Fraction of the observations whose point is in front of the observing camera.
pub(crate) fn in_front_fraction(rec: &MetricReconstruction) -> f64 {
    let (mut n, mut front) = (0usize, 0usize);
    for pt in rec.points.values() {
        for el in &pt.track.elements {
            let Some(v) = rec.views.get(&el.image_id) else {
                continue;
            };
            n += 1;
            if v.cam_from_world.transform_point(&pt.xyz).z > 0.0 {
                front += 1;
            }
        }
    }
    if n == 0 {
        0.0
    } else {
        front as f64 / n as f64
    }
}

/// Focal length of every intrinsics group, pixels.
pub(crate) fn focal_lengths(rec: &MetricReconstruction) -> Vec<f64> {
    rec.cameras.values().map(|c| c.intrinsics.f).collect()
}

/// Why an adjustment that was run on a sound model broke it, if it did: its filters removed more
/// than the guard allows a candidate frame (`MAX_REMOVED_FRACTION`) of the observations it
/// started from. (The 12-frame 320×240 demo with seed 1: after the predicted matches, the final
/// adjustment's filter removed 17 809 observations and kept 3 points, and that model was reported
/// as a success.)
pub(crate) fn collapsed(rec: &MetricReconstruction, records: &[MetricBaRecord]) -> Option<String> {
    let removed: usize = records.iter().map(|r| r.observations_removed).sum();
    let total = observation_count(rec) + removed;
    let fraction = removed as f64 / total.max(1) as f64;
    (fraction > MAX_REMOVED_FRACTION).then(|| {
        format!(
            "removed {:.0} % of the observations (kept {} points)",
            100.0 * fraction,
            rec.points.len()
        )
    })
}

/// A record of `rec` before its adjustment.
pub(crate) fn record_before(source: &str, rec: &MetricReconstruction) -> CandidateRecord {
    CandidateRecord {
        source: source.to_string(),
        focal_before_px: focal_lengths(rec),
        observations: observation_count(rec),
        in_front_fraction: in_front_fraction(rec),
        ..Default::default()
    }
}

/// Judges an adjusted candidate: fills in what the adjustment did and returns why it must be
/// rejected, if it must. `projective_rms_px` is the projective model's final RMS.
pub(crate) fn judge(
    record: &mut CandidateRecord,
    rec: &MetricReconstruction,
    adjustments: &[MetricBaRecord],
    projective_rms_px: Option<f64>,
) -> Option<String> {
    let removed: usize = adjustments.iter().map(|r| r.observations_removed).sum();
    let removed_fraction = removed as f64 / record.observations.max(1) as f64;
    let rms = adjustments.last().map(|r| r.final_rms_px);
    record.removed_fraction = Some(removed_fraction);
    record.final_rms_px = rms;
    record.score = rms.map(|r| (record.observations.saturating_sub(removed)) as f64 / (1.0 + r));
    record.focal_after_px = focal_lengths(rec);
    let behind = (record.in_front_fraction < MIN_IN_FRONT).then(|| {
        format!(
            "only {:.0} % of the observations were in front of their camera",
            100.0 * record.in_front_fraction
        )
    });
    let removals = (removed_fraction > MAX_REMOVED_FRACTION).then(|| {
        format!(
            "the metric adjustment removed {:.0} % of the observations (kept {} points)",
            100.0 * removed_fraction,
            rec.points.len()
        )
    });
    let focal = rec
        .cameras
        .values()
        .find(|c| {
            let s = f64::from(c.width + c.height);
            let f = c.intrinsics.f;
            !(f.is_finite() && f > RANGE.0 * s && f < RANGE.1 * s)
        })
        .map(|c| {
            format!(
                "implausible focal length {:.1} px for a {}×{} image (outside {}–{} × (w + h))",
                c.intrinsics.f, c.width, c.height, RANGE.0, RANGE.1
            )
        });
    let fit = match (rms, projective_rms_px) {
        (Some(m), Some(p)) if m.is_nan() || m > MAX_RMS_RATIO * p + RMS_SLACK_PX => Some(format!(
            "reprojection error {m:.2} px, against {p:.2} px for the projective model"
        )),
        (None, _) => Some("no adjustment ran".into()),
        _ => None,
    };
    record.removals_only =
        removals.is_some() && behind.is_none() && focal.is_none() && fit.is_none();
    let why = behind.or(removals).or(focal).or(fit);
    record.accepted = why.is_none();
    record.rejected = why.clone();
    why
}

/// Adjusts the candidates in the order given and returns the first one [`judge`] accepts, with its
/// adjusted model and adjustments; every candidate tried is recorded in `tried`. `adjust` is the
/// full metric bundle adjustment. A candidate of a large model is first adjusted on a subsample
/// ([`screen`]), which rejects it when it collapses there, and otherwise gives its full adjustment
/// a start from the subsample's cameras.
pub(crate) fn first_sound<'a, C>(
    candidates: impl IntoIterator<Item = (&'a C, &'a str, &'a MetricReconstruction)>,
    projective_rms_px: Option<f64>,
    mut adjust: impl FnMut(
        &mut MetricReconstruction,
        Option<f64>,
    ) -> Result<Vec<MetricBaRecord>, String>,
    tried: &mut Vec<CandidateRecord>,
) -> Option<(&'a C, MetricReconstruction, Vec<MetricBaRecord>)> {
    for (c, source, rec) in candidates {
        let clock = Instant::now();
        let start = match screen::screen(source, rec, projective_rms_px, &mut adjust, tried, false)
        {
            Screened::Decided(r) => {
                tracing::warn!(
                    "metric frame from {source} rejected: {}",
                    r.rejected.as_deref().unwrap_or("decided on a subsample")
                );
                tried.push(r);
                stamp(tried, clock);
                continue;
            }
            s => s.start(),
        };
        let found = adjust_in_full(
            source,
            rec,
            start,
            projective_rms_px,
            &mut adjust,
            None,
            tried,
        );
        stamp(tried, clock);
        if let Some((adjusted, adjustments)) = found {
            return Some((c, adjusted, adjustments));
        }
    }
    None
}

/// The full adjustment of one candidate `rec`, from `start` when given (its warm start, with the
/// same observations, and the subsample's points), judged; its record goes to `tried`. The
/// adjusted model when it is sound.
fn adjust_in_full(
    source: &str,
    rec: &MetricReconstruction,
    start: Option<(MetricReconstruction, usize)>,
    projective_rms_px: Option<f64>,
    adjust: &mut impl FnMut(
        &mut MetricReconstruction,
        Option<f64>,
    ) -> Result<Vec<MetricBaRecord>, String>,
    bar: Option<f64>,
    tried: &mut Vec<CandidateRecord>,
) -> Option<(MetricReconstruction, Vec<MetricBaRecord>)> {
    let mut record = record_before(source, rec);
    record.tried = true;
    record.warm_start_points = start.as_ref().map(|s| s.1);
    record.subsample_focal_px = start.as_ref().map(|s| focal_lengths(&s.0));
    let mut adjusted = start.map_or_else(|| rec.clone(), |s| s.0);
    let why = match adjust(&mut adjusted, bar) {
        Ok(adjustments) => match judge(&mut record, &adjusted, &adjustments, projective_rms_px) {
            None => {
                record.sound = true;
                tried.push(record);
                return Some((adjusted, adjustments));
            }
            Some(why) => why,
        },
        Err(e) => {
            record.rejected = Some(e.clone());
            e
        }
    };
    tracing::warn!("metric frame from {source} rejected: {why}");
    tried.push(record);
    None
}

/// Adjusts every candidate and returns the accepted one with the best score after its full
/// adjustment (ties: the earlier), the paper's "let the full adjustment decide" among the frames
/// that critical motion leaves open. Every candidate is recorded in `tried`. A candidate of a large
/// model is first adjusted on a subsample ([`screen`]), which rejects it when it collapses there,
/// passes over it when it comes to the calibration of a frame already adjusted, and otherwise
/// gives its full adjustment a start from the subsample's cameras.
pub(crate) fn best_sound<'a, C>(
    candidates: impl IntoIterator<Item = (&'a C, &'a str, &'a MetricReconstruction)>,
    projective_rms_px: Option<f64>,
    mut adjust: impl FnMut(
        &mut MetricReconstruction,
        Option<f64>,
    ) -> Result<Vec<MetricBaRecord>, String>,
    tried: &mut Vec<CandidateRecord>,
) -> Option<(&'a C, MetricReconstruction, Vec<MetricBaRecord>)> {
    let mut best: Option<(f64, usize, &'a C, MetricReconstruction, Vec<MetricBaRecord>)> = None;
    for (c, source, rec) in candidates {
        let clock = Instant::now();
        let start = match screen::screen(source, rec, projective_rms_px, &mut adjust, tried, true) {
            Screened::Decided(r) => {
                tried.push(r);
                stamp(tried, clock);
                continue;
            }
            s => s.start(),
        };
        // A candidate that cannot come within `CLOSE_SCORE` of the best sound one so far may stop
        // early (`metric::ba::adjust_candidate`).
        let bar = best.as_ref().map(|b| CLOSE_SCORE * b.0);
        let found = adjust_in_full(
            source,
            rec,
            start,
            projective_rms_px,
            &mut adjust,
            bar,
            tried,
        );
        stamp(tried, clock);
        let Some((adjusted, adjustments)) = found else {
            continue;
        };
        let full = tried
            .last()
            .and_then(|r| r.score)
            .unwrap_or(f64::NEG_INFINITY);
        if best.as_ref().is_none_or(|b| full > b.0) {
            best = Some((full, tried.len() - 1, c, adjusted, adjustments));
        }
    }
    let (_, index, c, rec, adjustments) = best?;
    for (k, r) in tried.iter_mut().enumerate() {
        if r.accepted && k != index {
            r.accepted = false;
            r.rejected = Some("a better-scoring candidate was kept".into());
        }
    }
    Some((c, rec, adjustments))
}

/// [`best_sound`] when `all`, else [`first_sound`].
pub(crate) fn choose<'a, C>(
    all: bool,
    candidates: impl IntoIterator<Item = (&'a C, &'a str, &'a MetricReconstruction)>,
    projective_rms_px: Option<f64>,
    adjust: impl FnMut(&mut MetricReconstruction, Option<f64>) -> Result<Vec<MetricBaRecord>, String>,
    tried: &mut Vec<CandidateRecord>,
) -> Option<(&'a C, MetricReconstruction, Vec<MetricBaRecord>)> {
    if all {
        best_sound(candidates, projective_rms_px, adjust, tried)
    } else {
        first_sound(candidates, projective_rms_px, adjust, tried)
    }
}

/// One line per rejected candidate, for the error a user sees when none survives.
pub(crate) fn describe_rejections(records: &[CandidateRecord]) -> String {
    records
        .iter()
        .map(|r| {
            let f: Vec<String> = r
                .focal_before_px
                .iter()
                .map(|f| format!("{f:.0} px"))
                .collect();
            format!(
                "{} (f = {}): {}",
                r.source,
                f.join(", "),
                r.rejected.as_deref().unwrap_or("rejected")
            )
        })
        .collect::<Vec<_>>()
        .join("; ")
}

/// One more frame against the kept one, after the candidate loop (a probe of a camera that only
/// translates, a frame found along the focal profile): it is screened on a subsample ([`screen`];
/// whether it comes to the kept calibration is asked of a probe only), then gets the full adjustment and [`judge`]'s checks, and it replaces the kept frame when it is sound and scores better (the
/// rule of [`best_sound`]). Its records go to `tried`, marked `probe` when asked; a sound frame
/// that scores lower is rejected with `lost`, and a kept frame it replaces with `won`. Returns the
/// adjusted frame only when it replaces the kept one.
#[allow(clippy::too_many_arguments)]
pub(crate) fn challenge<'a, C>(
    candidate: (&'a C, &'a str, &'a MetricReconstruction),
    projective_rms_px: Option<f64>,
    mut adjust: impl FnMut(
        &mut MetricReconstruction,
        Option<f64>,
    ) -> Result<Vec<MetricBaRecord>, String>,
    tried: &mut Vec<CandidateRecord>,
    probe: bool,
    lost: &str,
    won: &str,
) -> Option<(&'a C, MetricReconstruction, Vec<MetricBaRecord>)> {
    let clock = Instant::now();
    let start = match screen::screen(
        candidate.1,
        candidate.2,
        projective_rms_px,
        &mut adjust,
        tried,
        probe,
    ) {
        Screened::Decided(mut r) => {
            r.probe |= probe;
            tried.push(r);
            stamp(tried, clock);
            return None;
        }
        s => s.start(),
    };
    let kept_score = tried
        .iter()
        .find(|r| r.accepted)
        .and_then(|r| r.score)
        .unwrap_or(f64::NEG_INFINITY);
    let mut records = Vec::new();
    let found = adjust_in_full(
        candidate.1,
        candidate.2,
        start,
        projective_rms_px,
        &mut adjust,
        kept_score.is_finite().then_some(CLOSE_SCORE * kept_score),
        &mut records,
    )
    .map(|(r, a)| (candidate.0, r, a));
    stamp(&mut records, clock);
    let better = records
        .last()
        .filter(|r| r.accepted)
        .and_then(|r| r.score)
        .is_some_and(|s| s > kept_score);
    for mut r in records {
        r.probe |= probe;
        if r.accepted && !better {
            r.accepted = false;
            r.rejected = Some(lost.to_string());
        }
        if r.accepted {
            for k in tried.iter_mut().filter(|k| k.accepted) {
                k.accepted = false;
                k.rejected = Some(won.to_string());
            }
        }
        tried.push(r);
    }
    found.filter(|_| better)
}

/// Whether two frames' focal lengths (one per intrinsics group) are all within
/// [`screen::SAME_FOCAL`] of each other: one calibration, reached from two starts.
pub(crate) fn same_focal(a: &[f64], b: &[f64]) -> bool {
    !a.is_empty()
        && a.len() == b.len()
        && a.iter()
            .zip(b)
            .all(|(x, y)| (y / x - 1.0).abs() <= screen::SAME_FOCAL)
}

mod screen;
mod undetermined;
use screen::Screened;
pub use undetermined::{
    aspect_undetermined, flat_profile, focal_ambiguity, translation_only, CLOSE_SCORE,
    DISTINCT_FOCAL, MAX_UNDETERMINED_ASPECT, MIN_AXIS_SPREAD_DEG, MIN_PROFILE_INCREASE,
};
#[cfg(test)]
mod tests;
