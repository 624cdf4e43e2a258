//! The steps that build one metric model (Table 2, then §3.4 and the metric adjustments), each a
//! small function, and [`StepError`], which says which of them failed and why.
//!
//! 1. [`projective_step`]: Table 2 steps 2–4 on the views still free (`projective.rs`);
//! 2. [`metric_frame`]: the upgrade of eq. 27 from the linear self-calibration (§3.4, eqs. 24–27),
//!    or from a known calibration (eq. 26 with `K` given), with the fall-backs on the priors and the
//!    focal hypotheses when the motion is critical, the best-explaining candidate kept;
//! 3. metric bundle adjustment (`metric_ba.rs`);
//! 4. [`calibrated_registration_step`]: views the projective stage could not add, by calibrated
//!    resection (`register.rs`), then adjusted again;
//! 5. [`predicted_matches_step`]: more observations at the predicted projections (§3.2,
//!    `predict.rs`), then a final adjustment;
//! 6. `consistency::take_out`: views whose pose disagrees with their verified pairs are taken out
//!    (`consistency.rs`), and the model adjusted again;
//! 7. [`video_frames_step`]: a video's in-between frames from their tracks (`video.rs`);
//! 8. [`uncertainty_step`]: per-point and intrinsics uncertainty (`uncertainty.rs`).

use std::collections::BTreeMap;
use std::time::Instant;

use handheld_core::{MetricReconstruction, Progress};

use crate::consistency;
use crate::context::Context;
use crate::model::ProjectiveModel;
use crate::{
    frame, guard, metric, metric_ba, predict, projective, register, uncertainty, video,
    MetricBaRecord, SfmModel, UncertaintyReport,
};

/// The step that stopped one model, with the reason it gave.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum StepError {
    /// Table 2 steps 2–4: no initial pair could start a model, or a projective bundle adjustment
    /// failed. The views left cannot start another model, so the search ends.
    #[error("projective reconstruction: {0}")]
    Projective(String),
    /// §3.4: the metric upgrade (linear self-calibration, eq. 27) failed.
    #[error("metric upgrade: {0}")]
    MetricUpgrade(String),
    /// The first metric bundle adjustment of the upgraded model failed.
    #[error("metric adjustment of the upgraded model: {0}")]
    MetricAdjustment(String),
    /// The adjustment after `added` views were registered by calibrated resection failed.
    #[error("adjustment after the calibrated registration of {added} more views: {reason}")]
    CalibratedRegistration { added: usize, reason: String },
    /// The final adjustment after `added` observations were found at their predicted projections
    /// failed.
    #[error("final adjustment after {added} observations at predicted projections: {reason}")]
    PredictedMatches { added: usize, reason: String },
    /// The adjustment after `added` in-between video frames were registered failed.
    #[error("adjustment after registering {added} in-between video frames: {reason}")]
    VideoFrames { added: usize, reason: String },
}

impl StepError {
    /// Whether no further model should be attempted after this failure (the others only discard
    /// the current model).
    pub fn ends_search(&self) -> bool {
        matches!(self, Self::Projective(_))
    }
}

/// What the successive models share: the views still free to start or join one, and why views
/// could not be registered.
pub(crate) struct Search {
    /// Views that may start or join the next projective model.
    pub allowed: Vec<bool>,
    pub failures: BTreeMap<usize, String>,
}

impl Search {
    /// Images without any verified pair (a video's in-between frames) cannot start or join the
    /// projective model; video frames are registered from their tracks afterwards.
    pub fn new(ctx: &Context) -> Self {
        let allowed = ctx
            .input
            .images
            .iter()
            .enumerate()
            .map(|(i, im)| !im.keypoints.is_empty() && !ctx.graph.neighbours(i).is_empty())
            .collect();
        Self {
            allowed,
            failures: BTreeMap::new(),
        }
    }

    /// Views still free to start a model.
    pub fn free(&self) -> usize {
        self.allowed.iter().filter(|a| **a).count()
    }

    /// Marks views as taken by a model: they no longer start or join another one.
    fn take(&mut self, images: &[usize]) {
        for &i in images {
            self.allowed[i] = false;
        }
    }
}

/// Seconds per step, as reported in the summary.
type Timings = BTreeMap<String, f64>;

fn record(timings: &mut Timings, step: &str, since: Instant) {
    timings.insert(step.to_string(), since.elapsed().as_secs_f64());
}

/// Adds to a step's time (a step run once per start).
fn add(timings: &mut Timings, step: &str, since: Instant) {
    *timings.entry(step.to_string()).or_default() += since.elapsed().as_secs_f64();
}

/// The error of a model none of whose starts gave a sound metric frame: the last failure, with
/// the initial pairs tried.
fn abandoned(rejected: &[metric::RejectedStart], last: StepError) -> StepError {
    let pairs: Vec<String> = rejected
        .iter()
        .map(|r| format!("{} + {}", r.initial_pair[0], r.initial_pair[1]))
        .collect();
    let tried = format!(
        "started from {} initial pairs ({})",
        pairs.len(),
        pairs.join(", ")
    );
    match last {
        StepError::MetricUpgrade(m) => StepError::MetricUpgrade(format!("{m}; {tried}")),
        StepError::MetricAdjustment(m) => StepError::MetricAdjustment(format!("{m}; {tried}")),
        other => other,
    }
}

/// How many initial pairs one model may start from. A start whose metric frame no candidate
/// survives (or whose self-calibration fails outright) is abandoned and the model is built again
/// from the next best initial pair among the same views: a projective frame from a short or
/// ill-conditioned baseline can poison the self-calibration while another start of the same views
/// upgrades cleanly, as COLMAP retries its initial pairs.
pub const MAX_STARTS: usize = 3;

/// How many times one model is built again without the views the consistency check flagged
/// (`consistency.rs`): a misplaced view bends the model around it (templeSparseRing without one
/// view: focal length 4 % off, rotations 2° off even after the view is taken out), while the same
/// views built without it from the start are sound.
pub const MAX_REBUILDS: usize = 1;

/// A model through its predicted matches (steps 1–5), before the consistency check.
struct Core {
    model: ProjectiveModel,
    rec: MetricReconstruction,
    is_prior: bool,
    report: metric::SelfCalibrationReport,
    metric_ba: Vec<MetricBaRecord>,
    timings: Timings,
    /// Seconds spent in the metric frame's adjustment.
    metric_frame_s: f64,
}

/// Builds the next model from the free views of `search`: the steps of the module docs in order.
/// `Ok(None)` when the projective model holds fewer than 2 views (nothing more can be built); an
/// error names the step that failed. The views of the projective model are taken from `search`
/// whatever happens after.
pub(crate) fn build_model(
    ctx: &Context,
    search: &mut Search,
    progress: &dyn Progress,
) -> Result<Option<SfmModel>, StepError> {
    let estimate_aspect = ctx.opts.estimate_aspect.unwrap_or(ctx.input.video);
    let t_all = Instant::now();
    let entry = (search.allowed.clone(), search.failures.clone());
    let Some(mut core) = core_model(ctx, search, progress)? else {
        return Ok(None);
    };
    // Views misplaced in the model: build it again without them, then try to register them into
    // the sound model by calibrated resection (they are judged again below).
    let mut banned: Vec<(usize, consistency::ViewDisagreement)> = Vec::new();
    // The verdict on the model as it stands, when nothing changed it since.
    let mut judged = None;
    for _ in 0..MAX_REBUILDS {
        let (flagged, max_kept) = consistency::inconsistent_views(ctx, &core.rec);
        if flagged.is_empty() {
            judged = Some((flagged, max_kept));
            break;
        }
        let kept = (search.allowed.clone(), search.failures.clone());
        search.allowed = entry.0.clone();
        search.failures = entry.1.clone();
        for &i in banned.iter().chain(&flagged).map(|(i, _)| i) {
            search.allowed[i] = false;
        }
        let names = flagged
            .iter()
            .map(|(_, d)| format!("{} ({:.1}°)", d.image, d.median_deg))
            .collect::<Vec<_>>()
            .join(", ");
        match core_model(ctx, search, progress) {
            Ok(Some(rebuilt))
                if rebuilt.rec.views.len() + flagged.len() >= core.rec.views.len() =>
            {
                tracing::info!(
                    "the model was built again without the views whose poses disagreed with their verified image pairs: {names}"
                );
                banned.extend(flagged);
                core = rebuilt;
            }
            // The views cannot be spared: keep the model; the check below takes them out.
            _ => {
                search.allowed = kept.0;
                search.failures = kept.1;
                break;
            }
        }
    }
    let Core {
        model,
        mut rec,
        is_prior,
        mut report,
        mut metric_ba,
        mut timings,
        metric_frame_s,
    } = core;
    let t2 = Instant::now();
    if !banned.is_empty() {
        let t_reg = Instant::now();
        let mut allowed = vec![false; ctx.input.images.len()];
        for (i, _) in &banned {
            allowed[*i] = true;
        }
        let mut again = Search {
            allowed,
            failures: std::mem::take(&mut search.failures),
        };
        let before = rec.clone();
        match calibrated_registration_step(ctx, &mut rec, &mut again, estimate_aspect) {
            Ok(records) => metric_ba.extend(records),
            Err(e) => {
                tracing::warn!("{e}; the model is kept without those views");
                rec = before;
            }
        }
        search.failures = again.failures;
        for (i, d) in &banned {
            let id = ctx.input.images[*i].id;
            if rec.views.contains_key(&id) {
                continue;
            }
            let why = search.failures.remove(i).unwrap_or_default();
            search.failures.insert(
                *i,
                format!(
                    "registered first with a pose that disagreed with its verified image pairs by {:.1}° (median over {} partners); the model was built again without it, and it could not join that model: {why}",
                    d.median_deg, d.partners
                ),
            );
        }
        record(&mut timings, "calibrated_registration_again", t_reg);
    }
    let t_con = Instant::now();
    let judged = judged.unwrap_or_else(|| consistency::inconsistent_views(ctx, &rec));
    let (mut consistency, records) =
        consistency::take_out(ctx, &mut rec, search, estimate_aspect, judged);
    consistency.rebuilt_without = banned.into_iter().map(|(_, d)| d).collect();
    metric_ba.extend(records);
    record(&mut timings, "view_consistency", t_con);
    let t_frames = Instant::now();
    if let Some(records) = video_frames_step(ctx, &mut rec, search, estimate_aspect)? {
        metric_ba.extend(records);
        record(&mut timings, "video_frames", t_frames);
    }
    // Whether the images determine the principal point, judged on the final model: the metric
    // frame may hold only some of the views (templeSparseRing without one view: 11 of 15, whose
    // principal point is 3 px off-centre, within its spread, while all 15 put it 17 px off, as
    // the ground truth has it).
    if ctx.opts.known_intrinsics.is_none() && ctx.refines_principal_point() {
        let t_pp = Instant::now();
        frame::principal_point_test(ctx, &mut rec, &mut metric_ba, estimate_aspect, &mut report);
        record(&mut timings, "principal_point_test", t_pp);
    }
    // A warning about the focal length names the frame it judged; the adjustments after it (the
    // views registered later, the predicted matches, the principal point's test) move it
    // (dinoSparseRing: 3051 px then, 3169 px reported).
    if let (Some(w), Some(f)) = (
        report.focal_ambiguity.as_mut(),
        guard::focal_lengths(&rec).first(),
    ) {
        w.push_str(&format!("; the reported model's focal length is {f:.0} px"));
    }
    // The aspect ratio a camera that only translates cannot determine, judged on the final model
    // (a video's in-between frames are adjusted with it last).
    if estimate_aspect && report.focal_ambiguity.is_none() && ctx.opts.known_intrinsics.is_none() {
        if let Some(why) = guard::translation_only(&rec) {
            report.focal_ambiguity = guard::aspect_undetermined(&rec, &why);
            if let Some(w) = &report.focal_ambiguity {
                tracing::warn!("{w}");
            }
        }
    }
    if is_prior {
        report.used_prior_fallback = true;
    }
    timings.insert(
        "metric_ba".into(),
        metric_frame_s + t2.elapsed().as_secs_f64(),
    );
    let t3 = Instant::now();
    let (uncertainty, uncertainty_note) = uncertainty_step(ctx, &rec);
    record(&mut timings, "uncertainty", t3);
    record(&mut timings, "model", t_all);
    let mut summary = crate::summarize(
        ctx,
        &model,
        &rec,
        report,
        metric_ba,
        uncertainty,
        uncertainty_note,
        timings,
    );
    summary.view_consistency = consistency;
    Ok(Some(SfmModel {
        reconstruction: rec,
        summary,
    }))
}

/// Steps 1–5 on the free views of `search`: the projective model, its metric frame (started again
/// from the next initial pair when none survives, up to [`MAX_STARTS`]), calibrated registration
/// and the predicted matches. `Ok(None)` when the projective model holds fewer than 2 views.
fn core_model(
    ctx: &Context,
    search: &mut Search,
    progress: &dyn Progress,
) -> Result<Option<Core>, StepError> {
    let estimate_aspect = ctx.opts.estimate_aspect.unwrap_or(ctx.input.video);
    let mut timings = Timings::new();
    let mut excluded: Vec<(usize, usize)> = Vec::new();
    let mut rejected: Vec<metric::RejectedStart> = Vec::new();
    let (model, (mut rec, is_prior, mut report, mut metric_ba)) = loop {
        let saved = (search.allowed.clone(), search.failures.clone());
        let t0 = Instant::now();
        let model = match projective_step(ctx, search, &excluded, progress) {
            Ok(m) => m,
            // No other start: the last start's failure is the one to report.
            Err(e) if !rejected.is_empty() => return Err(abandoned(&rejected, e)),
            Err(e) => return Err(e),
        };
        add(&mut timings, "projective", t0);
        if model.order.len() < 2 {
            return Ok(None);
        }
        let t1 = Instant::now();
        let up = metric::upgrade(ctx, &model, estimate_aspect).map_err(StepError::MetricUpgrade);
        add(&mut timings, "self_calibration", t1);
        let t2 = Instant::now();
        let metric = up.and_then(|up| frame::adjust_metric_frame(ctx, &model, up, estimate_aspect));
        add(&mut timings, "metric_ba", t2);
        match metric {
            Ok(m) => break (model, m),
            Err(e) => {
                let names = &ctx.input.images;
                let (a, b) = model.init_pair;
                tracing::warn!(
                    "the model started from {} and {} has no sound metric frame ({e}); starting again from the next initial pair",
                    names[a].name,
                    names[b].name
                );
                rejected.push(metric::RejectedStart {
                    initial_pair: [names[a].name.clone(), names[b].name.clone()],
                    reason: e.to_string(),
                });
                excluded.push((a.min(b), a.max(b)));
                if rejected.len() >= MAX_STARTS {
                    return Err(abandoned(&rejected, e));
                }
                search.allowed = saved.0;
                search.failures = saved.1;
            }
        }
    };
    report.rejected_starts = rejected;
    let metric_frame_s = timings.get("metric_ba").copied().unwrap_or(0.0);
    let t_reg = Instant::now();
    metric_ba.extend(calibrated_registration_step(
        ctx,
        &mut rec,
        search,
        estimate_aspect,
    )?);
    record(&mut timings, "calibrated_registration", t_reg);
    let t_pred = Instant::now();
    metric_ba.extend(predicted_matches_step(ctx, &mut rec, estimate_aspect)?);
    record(&mut timings, "predicted_matches", t_pred);
    Ok(Some(Core {
        model,
        rec,
        is_prior,
        report,
        metric_ba,
        timings,
        metric_frame_s,
    }))
}

/// Table 2 steps 2–4 on the free views; the views it registers are taken from `search` and the
/// reasons of those it could not register recorded.
fn projective_step(
    ctx: &Context,
    search: &mut Search,
    excluded: &[(usize, usize)],
    progress: &dyn Progress,
) -> Result<ProjectiveModel, StepError> {
    let model = projective::reconstruct_projective(ctx, &search.allowed, excluded, progress)
        .map_err(StepError::Projective)?;
    search.take(&model.order);
    for (i, e) in &model.failures {
        search.failures.insert(*i, e.clone());
    }
    Ok(model)
}

/// Views the projective stage could not add (planar 2D–3D matches, late links) are tried again
/// with calibrated resection, then everything is adjusted once more. The views added are taken
/// from `search` (even when that adjustment fails).
fn calibrated_registration_step(
    ctx: &Context,
    rec: &mut MetricReconstruction,
    search: &mut Search,
    estimate_aspect: bool,
) -> Result<Vec<MetricBaRecord>, StepError> {
    let added = register::register_calibrated(ctx, rec, &search.allowed, &mut search.failures);
    if added.is_empty() {
        return Ok(Vec::new());
    }
    search.take(&added);
    for i in &added {
        search.failures.remove(i);
    }
    metric_ba::refine_metric(ctx, rec, estimate_aspect).map_err(|reason| {
        StepError::CalibratedRegistration {
            added: added.len(),
            reason,
        }
    })
}

/// §3.2: more observations of the existing points, found at their predicted projections, then a
/// final adjustment.
fn predicted_matches_step(
    ctx: &Context,
    rec: &mut MetricReconstruction,
    estimate_aspect: bool,
) -> Result<Vec<MetricBaRecord>, StepError> {
    let before = rec.clone();
    let added = predict::extend_tracks(ctx, rec);
    if added == 0 {
        return Ok(Vec::new());
    }
    tracing::debug!(
        extended = added,
        "observations added by predicted projection"
    );
    let records = metric_ba::final_adjustment(ctx, rec, estimate_aspect)
        .map_err(|reason| StepError::PredictedMatches { added, reason })?;
    if let Some(why) = guard::collapsed(rec, &records) {
        tracing::warn!(
            "the adjustment with the {added} observations found at predicted projections {why}: \
             they are dropped and the model is kept as it was before them"
        );
        *rec = before;
        return Ok(Vec::new());
    }
    Ok(records)
}

/// Video: every in-between frame from its tracks, then all frames adjusted together. `None` when
/// no frame was added (nothing adjusted).
fn video_frames_step(
    ctx: &Context,
    rec: &mut MetricReconstruction,
    search: &mut Search,
    estimate_aspect: bool,
) -> Result<Option<Vec<MetricBaRecord>>, StepError> {
    let frames = video::register_frames(ctx, rec, &mut search.failures);
    if frames.is_empty() {
        return Ok(None);
    }
    tracing::info!("registered {} in-between video frames", frames.len());
    metric_ba::refine_metric(ctx, rec, estimate_aspect)
        .map(Some)
        .map_err(|reason| StepError::VideoFrames {
            added: frames.len(),
            reason,
        })
}

/// Per-point and intrinsics uncertainty when enabled; otherwise, or when it fails, the note saying
/// why it is missing (a model without it is still a model).
pub(crate) fn uncertainty_step(
    ctx: &Context,
    rec: &MetricReconstruction,
) -> (Option<UncertaintyReport>, Option<String>) {
    if !ctx.opts.uncertainty {
        return (None, Some("disabled".into()));
    }
    match uncertainty::uncertainty(ctx, rec) {
        Ok(u) => (Some(u), None),
        Err(e) => (None, Some(e)),
    }
}

#[cfg(test)]
mod tests {
    use handheld_core::{ImageId, NoProgress};
    use nalgebra::Vector2;

    use super::*;
    use crate::{reconstruct, SfmError, SfmImage, SfmInput, SfmOptions};

    fn image(i: u32) -> SfmImage {
        SfmImage {
            id: ImageId(i),
            name: format!("{i}.png"),
            width: 64,
            height: 48,
            keypoints: vec![Vector2::new(1.0, 2.0); 10],
            keypoint_scales: Vec::new(),
            camera_key: "cam".into(),
            focal_prior_px: None,
            frame: None,
            track_ids: Vec::new(),
            descriptors: Vec::new(),
            descriptor_dim: 0,
        }
    }

    #[test]
    fn images_without_pairs_give_the_no_overlap_error() {
        let input = SfmInput {
            images: (0..3).map(image).collect(),
            ..Default::default()
        };
        let err = reconstruct(&input, &SfmOptions::default(), &NoProgress).unwrap_err();
        assert!(
            matches!(
                err,
                SfmError::NoOverlap {
                    linked: 0,
                    total: 3
                }
            ),
            "{err:?}"
        );
        assert_eq!(
            err.to_string(),
            "no model could be built: only 0 of 3 images have verified matches with another image \
             (need 2): the images do not overlap, or the camera hardly moves (video: too few \
             key-frames)"
        );
    }

    #[test]
    fn step_errors_name_the_step_and_keep_the_reason() {
        let e = SfmError::NoModel(StepError::CalibratedRegistration {
            added: 2,
            reason: "metric bundle adjustment (final): diverged".into(),
        });
        assert_eq!(
            e.to_string(),
            "no model could be built: adjustment after the calibrated registration of 2 more \
             views: metric bundle adjustment (final): diverged"
        );
        assert!(StepError::Projective("x".into()).ends_search());
        assert!(!StepError::MetricUpgrade("x".into()).ends_search());
    }
}
