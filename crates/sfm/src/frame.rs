//! The metric frame of one start (§3.4): the candidate frames (the self-calibration's, a known
//! calibration's, the priors', the focal hypotheses', the two-view focal length's), each given the
//! full adjustment and judged by [`crate::guard`]; the probes of a camera that only translates;
//! and the focal profile of the kept frame, which may lead to a better one or show that the focal
//! length is undetermined. Split from `pipeline.rs`, which builds the whole model.

use std::time::Instant;

use handheld_core::MetricReconstruction;

use crate::context::Context;
use crate::metric::Upgraded;
use crate::model::ProjectiveModel;
use crate::pipeline::StepError;
use crate::{guard, hypotheses, metric, metric_ba};

/// How many times the kept frame may be replaced by a better one found along its focal profile.
const MAX_PROFILE_DESCENTS: usize = 2;

/// A metric frame to adjust: where it came from, and whether it is the priors' (or a focal
/// hypothesis') rather than the self-calibration's.
struct Candidate {
    rec: MetricReconstruction,
    source: &'static str,
    is_prior: bool,
}

/// The frames from the priors alone and from the focal hypotheses (see `hypotheses`), which
/// critical motion (eq. 26 leaves the focal length free) or a rejected self-calibration calls for.
fn fallback_candidates(
    ctx: &Context,
    model: &ProjectiveModel,
    report: &metric::SelfCalibrationReport,
    estimate_aspect: bool,
) -> Vec<Candidate> {
    let mut out = Vec::new();
    if !report.used_prior_fallback {
        if let Ok(rec) = metric::prior_frame(ctx, model, estimate_aspect) {
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
        if let Ok(rec) = metric::from_transform(ctx, model, &h.t, estimate_aspect) {
            out.push(Candidate {
                rec,
                source: "two-view focal length",
                is_prior: true,
            });
        }
    }
    for h in hypotheses::focal_hypotheses(model, 3) {
        tracing::debug!(focal = h.focal, residual = h.residual, "focal hypothesis");
        if let Ok(rec) = metric::from_transform(ctx, model, &h.t, estimate_aspect) {
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
///
/// A known calibration gives the upgrade itself (eq. 26 with `K` given), whatever the motion; the
/// self-calibrated candidates are built only without one, or if it is inconsistent with the
/// cameras. When the linear self-calibration is doubtful (critical motion, or an `Ω*` that is not
/// semi-definite), the frame from the priors alone and the focal hypotheses are candidates too:
/// the paper's "fall back on the priors" without trusting either blindly. Every candidate gets the
/// full adjustment, [`crate::guard`] judges what that did, and the sound one with the best score
/// is kept; a rejected self-calibration gives way to the fallbacks. When none survives, the step fails with what was tried, and no model is reported.
pub(crate) fn adjust_metric_frame(
    ctx: &Context,
    model: &ProjectiveModel,
    up: Upgraded,
    estimate_aspect: bool,
) -> Result<
    (
        MetricReconstruction,
        bool,
        metric::SelfCalibrationReport,
        Vec<metric_ba::MetricBaRecord>,
    ),
    StepError,
> {
    let mut report = up.report;
    // A new model: its principal point is free until its own test says otherwise.
    ctx.hold_principal_point(false);
    let known = ctx.opts.known_intrinsics.and_then(|k| {
        let focal = 0.5 * (k.fx + k.fy) * ctx.scale.first().copied().unwrap_or(f64::NAN);
        let h = hypotheses::known_focal_upgrade(model, focal).filter(|h| !h.clamped)?;
        metric::from_transform(ctx, model, &h.t, estimate_aspect).ok()
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
            |rec| metric_ba::refine_metric(ctx, rec, estimate_aspect),
            &mut tried,
        );
        if let Some((c, rec, adjustments)) = found {
            let (mut rec, mut adjustments, mut is_prior) = (rec, adjustments, c.is_prior);
            let mut ambiguity = guard::focal_ambiguity(&tried);
            if ambiguity.is_none() && !expanded && ctx.opts.known_intrinsics.is_none() {
                if let Some(why) = guard::translation_only(&rec) {
                    // Nearly pure translation is nearly critical: the other frames are adjusted
                    // too, as probes. They decide whether the focal length is determined, and a
                    // sound probe that explains the images better than the kept frame replaces
                    // it: every frame has had the full adjustment, which decides (the rule of
                    // `guard::best_sound`).
                    tracing::info!("{why}; probing the focal length with the other frames");
                    for p in &fallback_candidates(ctx, model, &report, estimate_aspect) {
                        if let Some((p, r, a)) = guard::challenge(
                            (p, p.source, &p.rec),
                            projective_rms,
                            |r| metric_ba::refine_metric(ctx, r, estimate_aspect),
                            &mut tried,
                            true,
                            &format!("a probe of the focal length only ({why})"),
                            "a probe of the focal length explained the images better",
                        ) {
                            (rec, adjustments, is_prior) = (r, a, p.is_prior);
                        }
                    }
                    ambiguity = guard::focal_ambiguity(&tried);
                }
            }
            let mut flat = None;
            if ctx.opts.known_intrinsics.is_none() {
                // The fit along the focal length. Where holding it 20 % away fits clearly better,
                // the adjustment stopped on a slope, not at a minimum (a near-critical motion's
                // long valley): that held model, with its focal length freed again, is one more
                // candidate, kept when its full adjustment scores better. Then the profile of
                // what is kept decides whether the focal length is determined.
                for descents in 0..=MAX_PROFILE_DESCENTS {
                    let t_profile = Instant::now();
                    let ratios = match metric_ba::focal_profile(ctx, &rec, estimate_aspect) {
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
                    flat = guard::flat_profile(&rec, ratios);
                    let k = usize::from(ratios[1] < ratios[0]);
                    if descents == MAX_PROFILE_DESCENTS
                        || ratios[k] >= 1.0 - guard::MIN_PROFILE_INCREASE
                    {
                        break;
                    }
                    let scale = if k == 0 {
                        1.0 - metric_ba::PROFILE_STEP
                    } else {
                        1.0 + metric_ba::PROFILE_STEP
                    };
                    let start =
                        match metric_ba::held_adjustment(ctx, &rec, estimate_aspect, Some(scale)) {
                            Ok((_, r)) => r,
                            Err(e) => {
                                tracing::debug!("{e}");
                                break;
                            }
                        };
                    match guard::challenge(
                        (&(), "focal profile", &start),
                        projective_rms,
                        |r| metric_ba::refine_metric(ctx, r, estimate_aspect),
                        &mut tried,
                        false,
                        "scored below the kept frame",
                        "the frame found along the focal profile explained the images better",
                    ) {
                        Some((_, r, a)) => (rec, adjustments, is_prior) = (r, a, true),
                        None => break,
                    }
                }
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
            return Ok((rec, is_prior, report, adjustments));
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

/// Views whose orientations all lie within this angle of their mean hardly rotate: a camera that
/// only translates is a critical motion for the principal point (Sturm, *Critical motion
/// sequences for monocular self-calibration and uncalibrated Euclidean reconstruction*, CVPR
/// 1997, §4: under pure translation a shift of the principal point is a common rotation of all
/// views, to first order). The jackknife over views cannot see this, since every subset of such a
/// sequence shares the ambiguity: on kitti-seq1 (orientations within 0.7°) the freely adjusted
/// principal point is 15 px from the truth in y, while its jackknife σ reads 2 px. The other sets
/// turn by far more (fountain-P11: 59°, herzjesu-P8: 22°, templeSparseRing: 161°, iclnuim-5:
/// 59°), and for them the jackknife decides.
const MIN_ORIENTATION_SPREAD_DEG: f64 = 2.0;

/// Largest angle between a view's orientation and the views' chordal L2 mean orientation
/// (Hartley et al., *Rotation averaging*, IJCV 2013, §5.3: the SO(3) projection of Σ Rᵢ), degrees.
fn orientation_spread_deg(rec: &MetricReconstruction) -> f64 {
    let sum: nalgebra::Matrix3<f64> = rec
        .views
        .values()
        .map(|v| *v.cam_from_world.rotation.to_rotation_matrix().matrix())
        .sum();
    let mean = nalgebra::Rotation3::from_matrix(&sum);
    rec.views
        .values()
        .map(|v| {
            v.cam_from_world
                .rotation
                .to_rotation_matrix()
                .angle_to(&mean)
                .to_degrees()
        })
        .fold(0.0, f64::max)
}

/// Whether the images determine the principal point (`metric_ba::principal_point_spread`), asked
/// of the finished model (every registered view). The free principal point errs by about its
/// jackknife spread σ; holding it at the image centre errs by its true offset `o`, whose square
/// `o_est² − σ²` estimates without bias (E[o_est²] = o² + σ²). So it is held, and the model
/// adjusted again with it held (for this model's every later adjustment), when that is expected
/// to err less: `Σ (o_est² − σ²) < Σ σ²` over the two coordinates, i.e. `Σ o_est² < 2 Σ σ²`
/// ([`metric_ba::PrincipalPointSpread::held_is_closer`]). A significance test (χ²₂ at 95 %, used
/// before) protects the centre instead: on templeSparseRing without one view it held a principal
/// point estimated 10–13 px from the centre (σ 4–6 px; the truth is 19 px off) in 3 of 16 subsets,
/// and the rotations then erred by 0.5–1°.
pub(crate) fn principal_point_test(
    ctx: &Context,
    rec: &mut MetricReconstruction,
    adjustments: &mut Vec<metric_ba::MetricBaRecord>,
    estimate_aspect: bool,
    report: &mut metric::SelfCalibrationReport,
) {
    let t = Instant::now();
    let spread = match metric_ba::principal_point_spread(ctx, rec, estimate_aspect) {
        Ok(s) if !s.is_empty() => s,
        Ok(_) => return,
        Err(e) => {
            tracing::debug!("{e}");
            return;
        }
    };
    tracing::debug!(
        ?spread,
        seconds = t.elapsed().as_secs_f64(),
        "principal point spread"
    );
    let turning = orientation_spread_deg(rec);
    report.orientation_spread_deg = Some(turning);
    let translating = turning < MIN_ORIENTATION_SPREAD_DEG;
    let determined = !translating && spread.iter().any(|s| !s.held_is_closer());
    report.principal_point_spread = spread;
    if determined {
        return;
    }
    if translating {
        tracing::info!(
            "the views hardly rotate (all within {turning:.2}° of their mean orientation), so the \
             principal point cannot be told from a rotation of all of them: it is held at the centre"
        );
    }
    ctx.hold_principal_point(true);
    let mut held = rec.clone();
    for cam in held.cameras.values_mut() {
        cam.intrinsics.pp = metric_ba::image_centre(cam.width, cam.height);
    }
    let adjusted = metric_ba::refine_metric(ctx, &mut held, estimate_aspect).and_then(|a| {
        match guard::collapsed(&held, &a) {
            Some(why) => Err(why),
            None => Ok(a),
        }
    });
    match adjusted {
        Ok(a) => {
            tracing::info!(
                "the images do not determine the principal point (its offset from the image \
                 centre is within its spread over the views, so the centre is the better guess): it \
                 is held at the centre"
            );
            *rec = held;
            adjustments.extend(a);
            report.principal_point_held = true;
        }
        Err(e) => {
            tracing::debug!("adjustment with the principal point held: {e}");
            ctx.hold_principal_point(false);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use handheld_core::{CameraId, ImageId, Rigid3, View};
    use nalgebra::Vector3;

    fn views(rotations: &[Vector3<f64>]) -> MetricReconstruction {
        let mut rec = MetricReconstruction::default();
        for (k, r) in rotations.iter().enumerate() {
            let id = ImageId(k as u32 + 1);
            rec.views.insert(
                id,
                View {
                    id,
                    camera_id: CameraId(1),
                    name: format!("{k}.png"),
                    cam_from_world: Rigid3::new(Vector3::new(0.0, 0.0, k as f64), *r),
                    observations: Vec::new(),
                    frame: None,
                },
            );
        }
        rec
    }

    #[test]
    fn the_centre_is_kept_when_it_is_expected_to_be_closer_than_the_estimate() {
        let spread = |offset_px: [f64; 2], sigma_px: [f64; 2]| metric_ba::PrincipalPointSpread {
            camera_id: 1,
            offset_px,
            sigma_px,
        };
        // Within its noise: the centre is the better guess.
        assert!(spread([2.0, -1.0], [3.0, 2.0]).held_is_closer());
        // templeSparseRing without view 0 (byte matcher): 13 px off with σ (6.0, 3.9). Not
        // significant at 95 % (χ² 5.4), but the estimate's error (≈ σ) is expected to be smaller
        // than the offset's (≈ 13 px): it is freed.
        let temple = spread([-12.6, 3.9], [6.0, 3.9]);
        assert!(temple.chi2() < 5.991);
        assert!(!temple.held_is_closer());
        // fountain-P11: far off with a small spread.
        assert!(!spread([-19.1, -15.9], [1.6, 3.0]).held_is_closer());
    }

    #[test]
    fn orientation_spread_is_the_largest_angle_from_the_mean_orientation() {
        let d = 1f64.to_radians();
        // A car that drives straight, yawing ±0.5°: translating, whatever its heading.
        let straight = views(&[
            Vector3::new(0.3, 1.0, 0.0),
            Vector3::new(0.3, 1.0 + 0.5 * d, 0.0),
            Vector3::new(0.3, 1.0 - 0.5 * d, 0.0),
        ]);
        let s = orientation_spread_deg(&straight);
        assert!((s - 0.5).abs() < 0.01, "spread {s}");
        assert!(s < MIN_ORIENTATION_SPREAD_DEG);
        // Views on an arc, 30° apart: they turn.
        let arc = views(&[
            Vector3::new(0.0, -30.0 * d, 0.0),
            Vector3::zeros(),
            Vector3::new(0.0, 30.0 * d, 0.0),
        ]);
        let s = orientation_spread_deg(&arc);
        assert!((s - 30.0).abs() < 0.01, "spread {s}");
    }
}
