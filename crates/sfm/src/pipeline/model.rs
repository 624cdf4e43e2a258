//! One model, step by step (the list in `pipeline/mod.rs`): [`build_model`] builds the core of the
//! model ([`core_model`]: the projective model, its metric frame, started again from the next
//! initial pair when none survives, calibrated registration and the predicted matches), builds it
//! again without the views the consistency check flags, then runs the steps on the finished model.

use std::collections::{BTreeMap, BTreeSet};
use std::time::Instant;

use handheld_core::{MetricReconstruction, Progress};

use crate::context::Context;
use crate::error::StepError;
use crate::metric::ba::MetricBaRecord;
use crate::metric::consistency::{self, Judged, ViewDisagreement};
use crate::metric::depthless::take_out_depthless;
use crate::metric::principal_point::principal_point_test;
use crate::metric::rolling::rolling_shutter_step;
use crate::metric::uncertainty::uncertainty_step;
use crate::projective::model::ProjectiveModel;
use crate::summary::{summarize, SfmModel};
use crate::upgrade::transform::{self, RejectedStart, SelfCalibrationReport};
use crate::upgrade::{frame, guard};

use super::calibrated_net::{calibrated_challenge, calibrated_core, needs_challenge};
use super::steps::{
    add, calibrated_registration_step, predicted_matches_step, projective_step, record,
    video_frames_step, Search, Timings,
};

/// The error of a model none of whose starts gave a sound metric frame: the last failure, with
/// the initial pairs tried.
fn abandoned(rejected: &[RejectedStart], last: StepError) -> StepError {
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
/// (`metric/consistency.rs`): a misplaced view bends the model around it (templeSparseRing without one
/// view: focal length 4 % off, rotations 2° off even after the view is taken out), while the same
/// views built without it from the start are sound.
pub const MAX_REBUILDS: usize = 1;

/// A model through its predicted matches (steps 1–5), before the consistency check.
struct Core {
    model: ProjectiveModel,
    rec: MetricReconstruction,
    is_prior: bool,
    report: SelfCalibrationReport,
    metric_ba: Vec<MetricBaRecord>,
    timings: Timings,
    /// Seconds spent in the metric frame's adjustment.
    metric_frame_s: f64,
}

/// Builds the next model from the free views of `search`: the steps of `pipeline/mod.rs` in order.
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
    let Some(mut core) = core_model(ctx, search, true, progress)? else {
        return Ok(None);
    };
    // Views misplaced in the model: build it again without them, then try to register them into
    // the sound model by calibrated resection (they are judged again below).
    let mut banned: Vec<(usize, ViewDisagreement)> = Vec::new();
    // The verdict on the model as it stands, when nothing changed it since.
    let judged = rebuild_without_flagged(ctx, search, progress, &entry, &mut core, &mut banned);
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
        register_banned_again(
            ctx,
            &mut rec,
            search,
            &banned,
            estimate_aspect,
            &mut metric_ba,
            &mut timings,
        );
    }
    let t_con = Instant::now();
    let judged = judged.unwrap_or_else(|| consistency::inconsistent_views(ctx, &rec));
    let (mut consistency, records) =
        consistency::take_out(ctx, &mut rec, &mut search.failures, estimate_aspect, judged);
    consistency.rebuilt_without = banned.into_iter().map(|(_, d)| d).collect();
    let removed: BTreeSet<usize> = consistency
        .removed
        .iter()
        .filter_map(|d| ctx.input.images.iter().position(|im| im.name == d.image))
        .collect();
    let alone = consistency::unconfirmed(ctx, &rec, &removed);
    if !alone.is_empty() {
        consistency.unconfirmed = alone
            .iter()
            .map(|&i| ctx.input.images[i].name.clone())
            .collect();
        tracing::info!(
            "no verified pair confirms the poses of {}: their only checkable partners were taken out",
            consistency.unconfirmed.join(", ")
        );
    }
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
        principal_point_test(ctx, &mut rec, &mut metric_ba, estimate_aspect, &mut report);
        record(&mut timings, "principal_point_test", t_pp);
    }
    let t_rs = Instant::now();
    let rolling_shutter = rolling_shutter_step(ctx, &mut rec, estimate_aspect, &mut metric_ba);
    if rolling_shutter.is_some() {
        record(&mut timings, "rolling_shutter", t_rs);
    }
    focal_warnings(ctx, &rec, &mut report, estimate_aspect);
    if is_prior {
        report.used_prior_fallback = true;
    }
    timings.insert(
        "metric_ba".into(),
        metric_frame_s + t2.elapsed().as_secs_f64(),
    );
    let t3 = Instant::now();
    let points_without_depth = take_out_depthless(ctx, &mut rec);
    let (uncertainty, uncertainty_note) = uncertainty_step(ctx, &rec);
    record(&mut timings, "uncertainty", t3);
    record(&mut timings, "model", t_all);
    let mut summary = summarize(
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
    summary.points_without_depth = points_without_depth;
    summary.rolling_shutter = rolling_shutter;
    Ok(Some(SfmModel {
        reconstruction: rec,
        summary,
    }))
}

/// Builds the model again from the free views of `entry` without the views the consistency check
/// flags (up to [`MAX_REBUILDS`] times), adding them to `banned`, as long as the rebuilt model
/// loses no other view. Returns the check's verdict on `core` when it flagged nothing (the model
/// as it stands), `None` otherwise.
fn rebuild_without_flagged(
    ctx: &Context,
    search: &mut Search,
    progress: &dyn Progress,
    entry: &(Vec<bool>, BTreeMap<usize, String>),
    core: &mut Core,
    banned: &mut Vec<(usize, ViewDisagreement)>,
) -> Option<Judged> {
    for _ in 0..MAX_REBUILDS {
        let (flagged, max_kept) = consistency::inconsistent_views(ctx, &core.rec);
        if flagged.is_empty() {
            return Some((flagged, max_kept));
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
        // A model that the calibrated candidate built after a stratified start had failed is
        // built again by it alone: what sank the start (a dominant plane, critical motion,
        // distortion) belongs to the images, not to the views taken out (a corridor walk spent
        // its rebuild's first minutes on a projective model and candidates that failed again).
        let stratified =
            !core.report.calibrated_incremental || core.report.rejected_starts.is_empty();
        match core_model(ctx, search, stratified, progress) {
            Ok(Some(mut rebuilt))
                if rebuilt.rec.views.len() + flagged.len() >= core.rec.views.len() =>
            {
                tracing::info!(
                    "the model was built again without the views whose poses disagreed with their verified image pairs: {names}"
                );
                banned.extend(flagged);
                if !stratified {
                    rebuilt.report.rejected_starts = core.report.rejected_starts.clone();
                }
                *core = rebuilt;
            }
            // The views cannot be spared: keep the model; the check below takes them out.
            other => {
                let why = match other {
                    Ok(Some(rebuilt)) => format!(
                        "it held {} views, the model {} less the {} flagged",
                        rebuilt.rec.views.len(),
                        core.rec.views.len(),
                        flagged.len()
                    ),
                    Ok(None) => "no model".to_string(),
                    Err(e) => e.to_string(),
                };
                tracing::debug!("the model built again without {names} was not kept: {why}");
                search.allowed = kept.0;
                search.failures = kept.1;
                break;
            }
        }
    }
    None
}

/// The views the model was built again without (`banned`), registered into the sound model by
/// calibrated resection where they can be; the model is kept without them when the adjustment
/// after that fails. Those still out get a failure that says why.
fn register_banned_again(
    ctx: &Context,
    rec: &mut MetricReconstruction,
    search: &mut Search,
    banned: &[(usize, ViewDisagreement)],
    estimate_aspect: bool,
    metric_ba: &mut Vec<MetricBaRecord>,
    timings: &mut Timings,
) {
    let t_reg = Instant::now();
    let mut allowed = vec![false; ctx.input.images.len()];
    for (i, _) in banned {
        allowed[*i] = true;
    }
    let mut again = Search {
        allowed,
        failures: std::mem::take(&mut search.failures),
    };
    let before = rec.clone();
    match calibrated_registration_step(ctx, rec, &mut again, estimate_aspect) {
        Ok(records) => metric_ba.extend(records),
        Err(e) => {
            tracing::warn!("{e}; the model is kept without those views");
            *rec = before;
        }
    }
    search.failures = again.failures;
    for (i, d) in banned {
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
    record(timings, "calibrated_registration_again", t_reg);
}

/// The focal-length warnings, judged on the finished model.
fn focal_warnings(
    ctx: &Context,
    rec: &MetricReconstruction,
    report: &mut SelfCalibrationReport,
    estimate_aspect: bool,
) {
    // A warning about the focal length names the frame it judged; the adjustments after it (the
    // views registered later, the predicted matches, the principal point's test) move it
    // (dinoSparseRing: 3051 px then, 3169 px reported).
    if let (Some(w), Some(f)) = (
        report.focal_ambiguity.as_mut(),
        guard::focal_lengths(rec).first(),
    ) {
        w.push_str(&format!("; the reported model's focal length is {f:.0} px"));
    }
    // The aspect ratio a camera that only translates cannot determine, judged on the final model
    // (a video's in-between frames are adjusted with it last).
    if estimate_aspect && report.focal_ambiguity.is_none() && ctx.opts.known_intrinsics.is_none() {
        if let Some(why) = guard::translation_only(rec) {
            report.focal_ambiguity = guard::aspect_undetermined(rec, &why);
            if let Some(w) = &report.focal_ambiguity {
                tracing::warn!("{w}");
            }
        }
    }
}

/// Steps 1–5 on the free views of `search`: the projective model, its metric frame (started again
/// from the next initial pair when none survives, up to [`MAX_STARTS`]), calibrated registration
/// and the predicted matches. `Ok(None)` when the projective model holds fewer than 2 views.
/// Without `try_stratified`, the model is the calibrated incremental candidate's alone.
fn core_model(
    ctx: &Context,
    search: &mut Search,
    try_stratified: bool,
    progress: &dyn Progress,
) -> Result<Option<Core>, StepError> {
    let estimate_aspect = ctx.opts.estimate_aspect.unwrap_or(ctx.input.video);
    let mut timings = Timings::new();
    let mut excluded: Vec<(usize, usize)> = Vec::new();
    let mut rejected: Vec<RejectedStart> = Vec::new();
    let entry = (search.allowed.clone(), search.failures.clone());
    // The calibrated candidate tried after the first failed start, when it held fewer views.
    let mut early = None;
    // Its failure, when it found no sound model: it is not built again on the same views.
    let mut early_failed: Option<StepError> = None;
    let stratified = loop {
        if !try_stratified {
            break Err(StepError::MetricUpgrade(
                "no stratified start gave a sound metric frame on these images before".into(),
            ));
        }
        let saved = (search.allowed.clone(), search.failures.clone());
        let t0 = Instant::now();
        let model = match projective_step(ctx, search, &excluded, progress) {
            Ok(m) => m,
            // No other start: the last start's failure is the one to report.
            Err(e) if !rejected.is_empty() => break Err(abandoned(&rejected, e)),
            Err(e) => break Err(e),
        };
        add(&mut timings, "projective", t0);
        if model.order.len() < 2 {
            return Ok(None);
        }
        let t1 = Instant::now();
        let up = transform::upgrade(ctx, &model, estimate_aspect).map_err(StepError::MetricUpgrade);
        add(&mut timings, "self_calibration", t1);
        let t2 = Instant::now();
        let metric = up.and_then(|up| frame::adjust_metric_frame(ctx, &model, up, estimate_aspect));
        add(&mut timings, "metric_ba", t2);
        match metric {
            Ok(m) => break Ok((model, m)),
            Err(e) => {
                let names = &ctx.input.images;
                let (a, b) = model.init_pair;
                tracing::warn!(
                    "the model started from {} and {} has no sound metric frame ({e}); starting again from the next initial pair",
                    names[a].name,
                    names[b].name
                );
                rejected.push(RejectedStart {
                    initial_pair: [names[a].name.clone(), names[b].name.clone()],
                    reason: e.to_string(),
                });
                excluded.push((a.min(b), a.max(b)));
                // The causes that sink a start are mostly the images' own (lens distortion, a
                // dominant plane, critical motion), and the next initial pair meets them again:
                // on 50 portrait phone photos each further start cost minutes. The calibrated
                // candidate does not depend on the start; when it holds every view this start's
                // projective model did, it is the model and no further start is tried.
                if rejected.len() == 1 {
                    let mut trial = Search {
                        allowed: entry.0.clone(),
                        failures: entry.1.clone(),
                    };
                    let t = Instant::now();
                    let found =
                        calibrated_core(ctx, &mut trial, estimate_aspect, e.clone(), progress);
                    add(&mut timings, "calibrated_incremental", t);
                    match found {
                        Ok(found) => {
                            if found.0.order.len() >= model.order.len() {
                                *search = trial;
                                break Ok(found);
                            }
                            early = Some((found, trial));
                        }
                        Err(e) => early_failed = Some(e),
                    }
                }
                if rejected.len() >= MAX_STARTS {
                    break Err(abandoned(&rejected, e));
                }
                search.allowed = saved.0;
                search.failures = saved.1;
            }
        }
    };
    let (model, (mut rec, is_prior, mut report, mut metric_ba)) = match (stratified, early) {
        (Ok(found), _) => found,
        // No stratified start gave a sound metric frame: the calibrated incremental candidate
        // (already built after the first failed start, when it was sound).
        (Err(_), Some((found, trial))) => {
            *search = trial;
            found
        }
        (Err(e), None) => {
            search.allowed = entry.0;
            search.failures = entry.1;
            // Built from the same views after the first failed start: the same failure.
            if let Some(failed) = early_failed {
                return Err(failed);
            }
            let t = Instant::now();
            let found = calibrated_core(ctx, search, estimate_aspect, e, progress);
            add(&mut timings, "calibrated_incremental", t);
            found?
        }
    };
    report.rejected_starts = rejected;
    if !report.calibrated_incremental && needs_challenge(ctx, &report) {
        let t = Instant::now();
        calibrated_challenge(
            ctx,
            &model,
            &mut rec,
            &mut report,
            &mut metric_ba,
            estimate_aspect,
            progress,
        );
        add(&mut timings, "calibrated_incremental", t);
    }
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
