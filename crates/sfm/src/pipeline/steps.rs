//! The steps of one model that run one phase each, and the bookkeeping the successive models
//! share ([`Search`]: the views still free, and why views could not be registered): Table 2 steps
//! 2–4 on the free views (`projective/`), calibrated registration of the views the projective
//! stage could not add (`metric/register.rs`), the matches at predicted projections (§3.2,
//! `metric/predict.rs`) and a video's in-between frames (`video.rs`), each followed by the metric
//! adjustment it needs (`metric/ba.rs`) and failing with the [`StepError`] that names it.

use std::collections::BTreeMap;
use std::time::Instant;

use handheld_core::{MetricReconstruction, Progress};

use crate::context::Context;
use crate::error::StepError;
use crate::metric::ba::{self as metric_ba, MetricBaRecord};
use crate::metric::{predict, register};
use crate::projective::grow::reconstruct_projective;
use crate::projective::model::ProjectiveModel;
use crate::upgrade::guard;
use crate::video;

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
        Self {
            allowed: ctx.linked.clone(),
            failures: BTreeMap::new(),
        }
    }

    /// Views still free to start a model.
    pub fn free(&self) -> usize {
        self.allowed.iter().filter(|a| **a).count()
    }

    /// Marks views as taken by a model: they no longer start or join another one.
    pub(crate) fn take(&mut self, images: &[usize]) {
        for &i in images {
            self.allowed[i] = false;
        }
    }
}

/// Seconds per step, as reported in the summary.
pub(crate) type Timings = BTreeMap<String, f64>;

pub(crate) fn record(timings: &mut Timings, step: &str, since: Instant) {
    timings.insert(step.to_string(), since.elapsed().as_secs_f64());
}

/// Adds to a step's time (a step run once per start).
pub(crate) fn add(timings: &mut Timings, step: &str, since: Instant) {
    *timings.entry(step.to_string()).or_default() += since.elapsed().as_secs_f64();
}

/// Table 2 steps 2–4 on the free views; the views it registers are taken from `search` and the
/// reasons of those it could not register recorded.
pub(crate) fn projective_step(
    ctx: &Context,
    search: &mut Search,
    excluded: &[(usize, usize)],
    progress: &dyn Progress,
) -> Result<ProjectiveModel, StepError> {
    let model = reconstruct_projective(ctx, &search.allowed, excluded, progress)
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
pub(crate) fn calibrated_registration_step(
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
pub(crate) fn predicted_matches_step(
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
pub(crate) fn video_frames_step(
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
