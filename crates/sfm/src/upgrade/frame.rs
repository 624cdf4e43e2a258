//! The metric frame of one start (§3.4): the candidate frames (the self-calibration's, a known
//! calibration's, the priors', the focal hypotheses', the two-view focal length's), each given the
//! full adjustment (`metric/ba.rs`) and judged by [`crate::upgrade::guard`]; the probes of a camera
//! that only translates; and the focal profile of the kept frame (`metric/profile.rs`), which may
//! lead to a better one or show that the focal length is undetermined. The pipeline calls
//! [`adjust_metric_frame`] once per start of a model.

use std::time::Instant;

use handheld_core::MetricReconstruction;

use crate::context::Context;
use crate::error::StepError;
use crate::metric::ba::{adjust_candidate, MetricBaRecord};
use crate::metric::profile::{focal_profile, held_adjustment, PROFILE_STEP};
use crate::projective::model::ProjectiveModel;
use crate::upgrade::transform::{from_transform, prior_frame, SelfCalibrationReport, Upgraded};
use crate::upgrade::{guard, hypotheses};

/// How many times the kept frame may be replaced by a better one found along its focal profile.
const MAX_PROFILE_DESCENTS: usize = 2;

/// A metric frame to adjust: where it came from, and whether it is the priors' (or a focal
/// hypothesis') rather than the self-calibration's.
struct Candidate {
    rec: MetricReconstruction,
    source: &'static str,
    is_prior: bool,
}

/// The frames from the priors alone and from the focal hypotheses (see `hypotheses.rs`), which
/// critical motion (eq. 26 leaves the focal length free) or a rejected self-calibration calls for.
fn fallback_candidates(
    ctx: &Context,
    model: &ProjectiveModel,
    report: &SelfCalibrationReport,
    estimate_aspect: bool,
) -> Vec<Candidate> {
    let mut out = Vec::new();
    if !report.used_prior_fallback {
        if let Ok(rec) = prior_frame(ctx, model, estimate_aspect) {
            out.push(Candidate {
                rec,
                source: "priors",
                is_prior: true,
            });
        }
    }
    // An independent source: the focal length the verified pairs give one by one (Bougnoux).
    if let Some(h) = hypotheses::two_view_focal(ctx, model)
        .and_then(|f| hypotheses::known_focal_upgrade(model, f))
        .filter(|h| !h.clamped)
    {
        tracing::debug!(focal = h.focal, "two-view focal hypothesis");
        if let Ok(rec) = from_transform(ctx, model, &h.t, estimate_aspect) {
            out.push(Candidate {
                rec,
                source: "two-view focal length",
                is_prior: true,
            });
        }
    }
    for h in hypotheses::focal_hypotheses(model, 3) {
        tracing::debug!(focal = h.focal, residual = h.residual, "focal hypothesis");
        if let Ok(rec) = from_transform(ctx, model, &h.t, estimate_aspect) {
            out.push(Candidate {
                rec,
                source: "focal hypothesis",
                is_prior: true,
            });
        }
    }
    out
}

/// The adjusted metric model, whether its frame came from the priors (or a focal hypothesis)
/// rather than from the self-calibration, the self-calibration report (with every candidate
/// tried) and the adjustments.
pub(crate) type AdjustedFrame = (
    MetricReconstruction,
    bool,
    SelfCalibrationReport,
    Vec<MetricBaRecord>,
);

/// The kept frame while the probes and the focal profile may still replace it.
struct Kept {
    rec: MetricReconstruction,
    adjustments: Vec<MetricBaRecord>,
    is_prior: bool,
}

/// The [`AdjustedFrame`] of one start.
///
/// A known calibration gives the upgrade itself (eq. 26 with `K` given), whatever the motion; the
/// self-calibrated candidates are built only without one, or if it is inconsistent with the
/// cameras. When the linear self-calibration is doubtful (critical motion, or an `Ω*` that is not
/// semi-definite), the frame from the priors alone and the focal hypotheses are candidates too:
/// the paper's "fall back on the priors" without trusting either blindly. Every candidate gets the
/// full adjustment, [`crate::upgrade::guard`] judges what that did, and the sound one with the
/// best score is kept; a rejected self-calibration gives way to the fallbacks. When none
/// survives, the step fails with what was tried, and no model is reported.
pub(crate) fn adjust_metric_frame(
    ctx: &Context,
    model: &ProjectiveModel,
    up: Upgraded,
    estimate_aspect: bool,
) -> Result<AdjustedFrame, StepError> {
    let report = up.report;
    // A new model: its principal point is free until its own test says otherwise.
    ctx.hold_principal_point(false);
    let known = ctx.opts.known_intrinsics.and_then(|k| {
        let focal = 0.5 * (k.fx + k.fy) * ctx.scale.first().copied().unwrap_or(f64::NAN);
        let h = hypotheses::known_focal_upgrade(model, focal).filter(|h| !h.clamped)?;
        from_transform(ctx, model, &h.t, estimate_aspect).ok()
    });
    let from_known = known.is_some();
    let source = match (from_known, report.used_prior_fallback) {
        (true, _) => "known calibration",
        (false, true) => "priors",
        (false, false) => "self-calibration",
    };
    let mut candidates = vec![Candidate {
        rec: known.unwrap_or(up.rec),
        source,
        is_prior: false,
    }];
    let mut expanded = report.degenerate.is_some() && !from_known;
    if expanded {
        candidates.extend(fallback_candidates(ctx, model, &report, estimate_aspect));
    }
    let projective_rms = model.ba.last().map(|r| r.final_rms_px);
    let mut tried = Vec::new();
    loop {
        // One candidate: adjust it. Several: all get the full adjustment, and the sound one that
        // it explains best is kept.
        let found = guard::choose(
            candidates.len() > 1,
            candidates.iter().map(|c| (c, c.source, &c.rec)),
            projective_rms,
            |rec, bar| adjust_candidate(ctx, rec, estimate_aspect, bar),
            &mut tried,
        );
        if let Some((c, rec, adjustments)) = found {
            let kept = Kept {
                rec,
                adjustments,
                is_prior: c.is_prior,
            };
            let judged = Judged {
                report,
                tried,
                expanded,
                projective_rms,
            };
            return Ok(settle(ctx, model, kept, judged, estimate_aspect));
        }
        if expanded || from_known {
            break;
        }
        // The self-calibrated frame was rejected: the priors and the focal hypotheses now.
        expanded = true;
        candidates = fallback_candidates(ctx, model, &report, estimate_aspect);
        if candidates.is_empty() {
            break;
        }
    }
    let advice = if ctx.opts.known_intrinsics.is_some() {
        "check the calibration given with --intrinsics (FX,FY,CX,CY in pixels, COLMAP's convention)"
    } else {
        "the focal length cannot be found from these images: give the calibration with --intrinsics FX,FY,CX,CY"
    };
    Err(StepError::MetricAdjustment(format!(
        "no metric frame survived its bundle adjustment ({}); {advice}",
        guard::describe_rejections(&tried)
    )))
}

/// What the candidate loop leaves for [`settle`]: the report, every candidate tried, whether the
/// fallback candidates were among them, and the projective model's final RMS.
struct Judged {
    report: SelfCalibrationReport,
    tried: Vec<guard::CandidateRecord>,
    expanded: bool,
    projective_rms: Option<f64>,
}

/// The kept frame after the probes of a camera that only translates and the descent along its
/// focal profile, with the focal length reported as undetermined when they show it is.
fn settle(
    ctx: &Context,
    model: &ProjectiveModel,
    mut kept: Kept,
    judged: Judged,
    estimate_aspect: bool,
) -> AdjustedFrame {
    let Judged {
        mut report,
        mut tried,
        expanded,
        projective_rms,
    } = judged;
    let mut ambiguity = guard::focal_ambiguity(&tried);
    if ambiguity.is_none() && !expanded && ctx.opts.known_intrinsics.is_none() {
        if let Some(why) = guard::translation_only(&kept.rec) {
            probe_translation(
                ctx,
                model,
                &report,
                &mut kept,
                &mut tried,
                projective_rms,
                estimate_aspect,
                &why,
            );
            ambiguity = guard::focal_ambiguity(&tried);
        }
    }
    let mut flat = None;
    if ctx.opts.known_intrinsics.is_none() {
        flat = descend_focal_profile(
            ctx,
            &mut kept,
            &mut report,
            &mut tried,
            projective_rms,
            estimate_aspect,
        );
    }
    // Judged again against what is kept now: other frames first, then the profile.
    if ambiguity.is_some() || flat.is_some() {
        ambiguity = guard::focal_ambiguity(&tried).or(flat);
    }
    report.focal_ambiguity = ambiguity;
    if let Some(w) = &report.focal_ambiguity {
        tracing::warn!("{w}");
    }
    report.candidates = tried;
    (kept.rec, kept.is_prior, report, kept.adjustments)
}

/// Nearly pure translation (`why`) is nearly critical: the other frames are adjusted too, as
/// probes. They decide whether the focal length is determined, and a sound probe that explains
/// the images better than the kept frame replaces it: every frame has had the full adjustment,
/// which decides (the rule of `guard::best_sound`).
#[allow(clippy::too_many_arguments)]
fn probe_translation(
    ctx: &Context,
    model: &ProjectiveModel,
    report: &SelfCalibrationReport,
    kept: &mut Kept,
    tried: &mut Vec<guard::CandidateRecord>,
    projective_rms: Option<f64>,
    estimate_aspect: bool,
    why: &str,
) {
    tracing::info!("{why}; probing the focal length with the other frames");
    for p in &fallback_candidates(ctx, model, report, estimate_aspect) {
        if let Some((p, r, a)) = guard::challenge(
            (p, p.source, &p.rec),
            projective_rms,
            |r, bar| adjust_candidate(ctx, r, estimate_aspect, bar),
            tried,
            true,
            &format!("a probe of the focal length only ({why})"),
            "a probe of the focal length explained the images better",
        ) {
            *kept = Kept {
                rec: r,
                adjustments: a,
                is_prior: p.is_prior,
            };
        }
    }
}

/// The fit along the focal length. Where holding it 20 % away fits clearly better, the adjustment
/// stopped on a slope, not at a minimum (a near-critical motion's long valley): that held model,
/// with its focal length freed again, is one more candidate, kept when its full adjustment scores
/// better. Then the profile of what is kept decides whether the focal length is determined: the
/// reason it is not, when it is flat ([`guard::flat_profile`]).
fn descend_focal_profile(
    ctx: &Context,
    kept: &mut Kept,
    report: &mut SelfCalibrationReport,
    tried: &mut Vec<guard::CandidateRecord>,
    projective_rms: Option<f64>,
    estimate_aspect: bool,
) -> Option<String> {
    let mut flat = None;
    for descents in 0..=MAX_PROFILE_DESCENTS {
        let t_profile = Instant::now();
        let ratios = match focal_profile(ctx, &kept.rec, estimate_aspect) {
            Ok(p) => p,
            Err(e) => {
                tracing::debug!("{e}");
                break;
            }
        };
        tracing::debug!(
            ?ratios,
            seconds = t_profile.elapsed().as_secs_f64(),
            "focal profile"
        );
        report.focal_profile = Some(ratios);
        flat = guard::flat_profile(&kept.rec, ratios);
        let k = usize::from(ratios[1] < ratios[0]);
        if descents == MAX_PROFILE_DESCENTS || ratios[k] >= 1.0 - guard::MIN_PROFILE_INCREASE {
            break;
        }
        let scale = if k == 0 {
            1.0 - PROFILE_STEP
        } else {
            1.0 + PROFILE_STEP
        };
        let start = match held_adjustment(ctx, &kept.rec, estimate_aspect, Some(scale)) {
            Ok((_, r)) => r,
            Err(e) => {
                tracing::debug!("{e}");
                break;
            }
        };
        match guard::challenge(
            (&(), "focal profile", &start),
            projective_rms,
            |r, bar| adjust_candidate(ctx, r, estimate_aspect, bar),
            tried,
            false,
            "scored below the kept frame",
            "the frame found along the focal profile explained the images better",
        ) {
            Some((_, r, a)) => {
                *kept = Kept {
                    rec: r,
                    adjustments: a,
                    is_prior: true,
                }
            }
            None => break,
        }
    }
    flat
}
