//! Metric bundle adjustment (§3.4, eq. 21) of the upgraded model: the schedule of adjustments
//! (focal and k1 first, then every intrinsic the options allow, then a final pass), each followed by
//! outlier removal; and the soft priors (principal point near the centre, EXIF focal lengths, a known
//! calibration). Split from
//! `upgrade::transform`, which builds the metric model from the projective one.

use std::collections::{BTreeMap, BTreeSet};

use handheld_bundle::{
    bundle_adjust_metric_rolling, BundleOptions, GaussianPrior, IntrinsicParam, IntrinsicsMask,
    MetricBundleConfig, RobustLoss, RollingShutter,
};
use handheld_core::{CameraId, ImageId, MetricReconstruction, PointId, TrackElement};
use serde::Serialize;

use crate::common::image_centre;
use crate::context::Context;
use crate::metric::noise::{noise_scaled_loss, scaled_priors, Noise, HUBER_95};
use crate::options::Distortion;
use crate::upgrade::guard::MAX_REMOVED_FRACTION;

/// One metric bundle adjustment, for the summary.
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct MetricBaRecord {
    pub step: String,
    pub iterations: usize,
    pub initial_rms_px: f64,
    pub final_rms_px: f64,
    pub seconds: f64,
    /// Observations removed by the filtering that followed.
    pub observations_removed: usize,
    pub points_removed: usize,
    /// The Huber scale of this adjustment (pixels of a median-σ keypoint).
    pub loss_scale_px: f64,
    /// The observations' noise σ̂ measured before this adjustment ([`Noise::observation`]), when
    /// the loss and the priors were scaled by it.
    pub noise_px: Option<f64>,
    /// The robust cost `½ Σ ρ(‖r‖²)` (plus the priors') before and after the adjustment, squared
    /// pixels of a median-σ keypoint.
    #[serde(default)]
    pub initial_cost: f64,
    #[serde(default)]
    pub final_cost: f64,
}

impl MetricBaRecord {
    fn of(
        step: &str,
        s: &handheld_bundle::BundleSummary,
        loss: RobustLoss,
        noise: Option<Noise>,
        removed: usize,
        points: usize,
    ) -> Self {
        let loss_scale_px = match loss {
            RobustLoss::Huber(a) | RobustLoss::Cauchy(a) => a,
            RobustLoss::None => f64::INFINITY,
        };
        Self {
            loss_scale_px,
            noise_px: noise.map(|n| n.observation),
            step: step.to_string(),
            iterations: s.iterations,
            initial_rms_px: s.initial_rms_px,
            final_rms_px: s.final_rms_px,
            seconds: s.total_seconds,
            observations_removed: removed,
            points_removed: points,
            initial_cost: s.initial_cost,
            final_cost: s.final_cost,
        }
    }
}

/// Removes observations whose reprojection error exceeds `max_px` (or that lie behind their
/// camera) and points left with fewer than `min_track` views. Returns (observations, points) removed.
pub(crate) fn filter_metric(
    rec: &mut MetricReconstruction,
    max_px: f64,
    min_track: usize,
) -> (usize, usize) {
    filter_metric_rolling(rec, max_px, min_track, None)
}

/// [`filter_metric`], each observation projected from its row's pose under a rolling shutter
/// (`metric/rolling.rs`) when one is given.
pub(crate) fn filter_metric_rolling(
    rec: &mut MetricReconstruction,
    max_px: f64,
    min_track: usize,
    rolling: Option<&RollingShutter>,
) -> (usize, usize) {
    let bad_obs: Vec<(PointId, TrackElement)> = crate::metric::rolling::residuals(rec, rolling)
        .filter(|(_, _, e)| !e.is_some_and(|e| e <= max_px))
        .map(|(pid, el, _)| (pid, *el))
        .collect();
    let n_obs = bad_obs.len();
    for (pid, el) in bad_obs {
        if let Some(pt) = rec.points.get_mut(&pid) {
            pt.track.elements.retain(|e| e != &el);
        }
        if let Some(v) = rec.views.get_mut(&el.image_id) {
            v.observations[el.point2d_idx as usize].point_id = None;
        }
    }
    let short: Vec<PointId> = rec
        .points
        .iter()
        .filter(|(_, p)| p.track.len() < min_track)
        .map(|(id, _)| *id)
        .collect();
    for id in &short {
        if let Some(p) = rec.points.remove(id) {
            for el in p.track.elements {
                if let Some(v) = rec.views.get_mut(&el.image_id) {
                    v.observations[el.point2d_idx as usize].point_id = None;
                }
            }
        }
    }
    (n_obs, short.len())
}

/// The metric bundle adjustment schedule: (1) poses, points, f, k1 (and the aspect ratio for
/// video) with the principal point at the image centre; filter; (2) everything the options allow
/// (principal point, k2); filter at the final threshold; (3) a last adjustment and filter, and
/// when that removed observations, one more adjustment of the survivors.
pub(crate) fn refine_metric(
    ctx: &Context,
    rec: &mut MetricReconstruction,
    estimate_aspect: bool,
) -> Result<Vec<MetricBaRecord>, String> {
    adjust_metric_schedule(ctx, rec, estimate_aspect, Schedule::Full, None, None)
}

/// Removed fraction at which a candidate frame's schedule stops after a step ([`adjust_candidate`]).
/// Such a frame is rejected whatever follows (it is far beyond the guard's
/// `MAX_REMOVED_FRACTION`, and the removals only grow), and it cannot explain the images about as
/// well as a sound frame (`guard::focal_ambiguity` needs 95 % of the kept score, which at most
/// 10 % of the observations reach only when the kept frame's RMS exceeds 7 px).
pub const COLLAPSED_FRACTION: f64 = 0.9;

/// [`refine_metric`] for a candidate frame: the schedule stops after a step that has removed
/// [`COLLAPSED_FRACTION`] of the observations (a wrong upgrade collapses in its first step: a
/// phone's distorted projective model lost 93–100 % there for every candidate, and the two further
/// steps cost more than half of the time).
///
/// `bar`, when given, is the score below which the candidate can matter to nothing: it then also
/// stops after a step once it has removed more than the guard's `MAX_REMOVED_FRACTION` (it is
/// rejected whatever follows) and keeps fewer observations than `bar`. Its score (what it keeps,
/// divided by `1 + RMS`) can only fall below that, so it can neither be kept nor come close enough
/// to the kept frame for `guard::focal_ambiguity` (the guard passes `CLOSE_SCORE ×` the best sound
/// score so far). templeSparseRing's last focal hypothesis ran three more steps of 100 iterations
/// to its rejection.
pub(crate) fn adjust_candidate(
    ctx: &Context,
    rec: &mut MetricReconstruction,
    estimate_aspect: bool,
    bar: Option<f64>,
) -> Result<Vec<MetricBaRecord>, String> {
    adjust_metric_schedule(ctx, rec, estimate_aspect, Schedule::Candidate, bar, None)
}

/// Only the last step of [`refine_metric`]: for a model that was adjusted and then extended (new
/// observations of existing points).
pub(crate) fn final_adjustment(
    ctx: &Context,
    rec: &mut MetricReconstruction,
    estimate_aspect: bool,
) -> Result<Vec<MetricBaRecord>, String> {
    adjust_metric_schedule(ctx, rec, estimate_aspect, Schedule::FinalOnly, None, None)
}

/// [`final_adjustment`] with a rolling-shutter camera (`metric/rolling.rs`): the frames'
/// velocities held, the read-out refined from `rolling.readout` and written back there.
pub(crate) fn final_adjustment_rolling(
    ctx: &Context,
    rec: &mut MetricReconstruction,
    estimate_aspect: bool,
    rolling: &mut RollingShutter,
) -> Result<Vec<MetricBaRecord>, String> {
    adjust_metric_schedule(
        ctx,
        rec,
        estimate_aspect,
        Schedule::FinalOnly,
        None,
        Some(rolling),
    )
}

/// Which part of the schedule runs.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Schedule {
    /// Every step ([`refine_metric`]).
    Full,
    /// Every step, stopping after one that collapsed the frame ([`adjust_candidate`]).
    Candidate,
    /// The last step only ([`final_adjustment`]).
    FinalOnly,
}

fn adjust_metric_schedule(
    ctx: &Context,
    rec: &mut MetricReconstruction,
    estimate_aspect: bool,
    schedule: Schedule,
    bar: Option<f64>,
    mut rolling: Option<&mut RollingShutter>,
) -> Result<Vec<MetricBaRecord>, String> {
    let only_final = schedule == Schedule::FinalOnly;
    let o = ctx.opts;
    let mut records = Vec::new();
    let observations: usize = rec.points.values().map(|p| p.track.len()).sum();
    let mut removed = 0usize;
    // A known calibration is the starting point too: the upgrade assumed a centred principal point.
    if let (Some(k), false) = (o.known_intrinsics, only_final) {
        for cam in rec.cameras.values_mut() {
            let i = &mut cam.intrinsics;
            i.f = k.fx;
            i.aspect = k.fy / k.fx;
            i.pp = nalgebra::Vector2::new(k.cx, k.cy);
        }
    }
    let Setup { base, full, priors } = setup(ctx, rec, estimate_aspect);
    let steps: [(&str, IntrinsicsMask, f64, usize); 3] = [
        ("f+k1", base, o.metric_max_error_px, 100),
        ("all intrinsics", full, o.final_max_error_px, 100),
        ("final", full, o.final_max_error_px, 100),
    ];
    for (name, mask, thr, iters) in steps {
        if only_final && name != "final" {
            continue;
        }
        let (loss, prior_scale, noise) = if name == "f+k1" {
            (first_step_loss(rec, o.loss_scale_px), 1.0, None)
        } else {
            noise_scaled_loss(ctx, rec, rolling.as_deref())
        };
        let config = MetricBundleConfig {
            refine: mask,
            priors: scaled_priors(&priors, prior_scale),
            keypoint_sigma: ctx.keypoint_sigma.clone(),
            // The read-out's prior weighed against data of the measured noise, as the others.
            rolling_shutter: rolling.as_deref().map(|r| RollingShutter {
                refine_sigma: r.refine_sigma.map(|s| s * prior_scale),
                ..r.clone()
            }),
            ..Default::default()
        };
        let bopts = BundleOptions {
            max_iterations: iters,
            loss,
            // Tight tolerances only for the last adjustment; the earlier ones feed a filter.
            function_tolerance: if name == "final" { 1e-6 } else { 1e-5 },
            parameter_tolerance: if name == "final" { 1e-10 } else { 1e-8 },
            // Each point re-solved after every joint step (`BundleOptions::
            // embedded_point_iterations`), but not from the rough start of the first step, where
            // it changed which minimum a wrong frame reached (kitti-seq1's priors frame, 1 587 px
            // against 708, ended at 2 256 px with 78 % of its observations removed instead of
            // converging to the kept frame). Where the later steps crawl (a long walk's soft
            // modes), they stop sooner: 400 views 91.6 → 73.6 s.
            embedded_point_iterations: usize::from(name != "f+k1"),
            ..Default::default()
        };
        let (s, readout) = bundle_adjust_metric_rolling(rec, &config, &bopts)
            .map_err(|e| format!("metric bundle adjustment ({name}): {e}"))?;
        if let Some(r) = rolling.as_deref_mut() {
            r.readout = readout;
        }
        keep_scale(rec);
        let (ro, rp) = filter_metric_rolling(rec, thr, o.min_track_length, rolling.as_deref());
        records.push(MetricBaRecord::of(name, &s, loss, noise, ro, rp));
        removed += ro;
        if schedule == Schedule::Candidate
            && removed as f64 >= COLLAPSED_FRACTION * observations.max(1) as f64
        {
            tracing::debug!(
                "the {name} step removed {removed} of {observations} observations: the schedule stops"
            );
            break;
        }
        if schedule == Schedule::Candidate
            && removed as f64 > MAX_REMOVED_FRACTION * observations as f64
            && bar.is_some_and(|b| (observations.saturating_sub(removed) as f64) < b)
        {
            tracing::debug!(
                "the {name} step removed {removed} of {observations} observations, and what is left \
                 scores below the best frame's: the schedule stops"
            );
            break;
        }
        // The model reported is the optimum of the observations it keeps: the ones the last
        // filter removed had pulled on it, and on the weakly determined parameters (the
        // principal point against the rotations) that pull is worth pixels (herzjesu-P8: 12 px
        // of principal point from 0.9 % of the observations).
        if name == "final" && ro > 0 {
            let (s, readout) = bundle_adjust_metric_rolling(rec, &config, &bopts)
                .map_err(|e| format!("metric bundle adjustment (survivors): {e}"))?;
            if let Some(r) = rolling.as_deref_mut() {
                r.readout = readout;
            }
            keep_scale(rec);
            records.push(MetricBaRecord::of("survivors", &s, loss, noise, 0, 0));
        }
    }
    Ok(records)
}

/// Sizes (the camera centres' RMS distance from their mean, model units) outside which
/// [`keep_scale`] brings a model back to unit size.
pub const SCALE_RANGE: (f64, f64) = (1e-3, 1e3);

/// Brings the model back to unit size, centred on its cameras, when an adjustment has drifted
/// along the scale gauge. Metric bundle adjustment holds the first view (6 of the 7 gauge
/// freedoms), not the scale: the cost does not change along it, and the adjustments of a weakly
/// determined model can drift along it. The 8-frame 320×240 demo orbit shrank by 10⁴ in one
/// adjustment and to 10⁻⁹ of its first size over the schedule, every camera and point within
/// 10⁻⁹ of one spot 0.45 units from the origin: the projections were unchanged, but the dense
/// stage's f32 volume then had a voxel of 3·10⁻¹¹ and the texturing found no face any view sees.
/// A similarity changes no projection, so this changes nothing else.
pub(crate) fn keep_scale(rec: &mut MetricReconstruction) {
    let c: Vec<nalgebra::Vector3<f64>> = rec.views.values().map(|v| v.center().coords).collect();
    if c.len() < 2 {
        return;
    }
    let mean = c.iter().sum::<nalgebra::Vector3<f64>>() / c.len() as f64;
    let size = (c.iter().map(|p| (p - mean).norm_squared()).sum::<f64>() / c.len() as f64).sqrt();
    if !(size.is_finite() && size > 0.0 && mean.iter().all(|v| v.is_finite())) {
        return;
    }
    let (lo, hi) = SCALE_RANGE;
    if size < lo || size > hi || mean.norm() > hi * size {
        tracing::debug!(
            size,
            offset = mean.norm(),
            "model brought back to unit size"
        );
        rec.transform(&handheld_core::Sim3 {
            scale: 1.0 / size,
            rotation: nalgebra::UnitQuaternion::identity(),
            translation: -mean / size,
        });
    }
}

/// The loss of the schedule's first adjustment. A new metric frame starts far from its optimum
/// (tens of pixels RMS): with the final Huber scale almost every residual is then in the loss's
/// linear part, the adjustment is close to an L1 fit and stalls in a poor minimum (iclnuim-5:
/// 13.9 px RMS after 117 iterations, and the 4 px filter then removed 5 % of the observations).
/// So the scale starts from the residuals' own spread, σ̂ = median ‖r‖ / 1.1774 (the median of a
/// 2D Gaussian error's norm, a Rayleigh variable, is 1.1774 σ), as Huber's proposal 2 estimates
/// it, and is never below the final one.
pub(crate) fn first_step_loss(rec: &MetricReconstruction, final_scale_px: f64) -> RobustLoss {
    let mut e = rec.reprojection_errors();
    e.retain(|v| v.is_finite());
    if e.is_empty() {
        return RobustLoss::Huber(final_scale_px);
    }
    let mid = e.len() / 2;
    let median = *e.select_nth_unstable_by(mid, f64::total_cmp).1;
    RobustLoss::Huber((HUBER_95 * median / 1.1774).max(final_scale_px))
}

/// `rec` without the views `out`: their observations are detached, and points left with fewer
/// than two observations removed.
pub(crate) fn without_views(
    rec: &MetricReconstruction,
    out: &BTreeSet<ImageId>,
) -> MetricReconstruction {
    let mut r = rec.clone();
    for id in out {
        r.views.remove(id);
    }
    let mut dead = Vec::new();
    for (pid, p) in r.points.iter_mut() {
        p.track.elements.retain(|e| !out.contains(&e.image_id));
        if p.track.elements.len() < 2 {
            dead.push(*pid);
        }
    }
    remove_points(&mut r, dead);
    r
}

/// Removes the points `ids` and detaches their observations from the views.
pub(crate) fn remove_points(
    rec: &mut MetricReconstruction,
    ids: impl IntoIterator<Item = PointId>,
) {
    for id in ids {
        if let Some(p) = rec.points.remove(&id) {
            for el in p.track.elements {
                if let Some(v) = rec.views.get_mut(&el.image_id) {
                    v.observations[el.point2d_idx as usize].point_id = None;
                }
            }
        }
    }
}

/// What every adjustment of the schedule shares: the intrinsics refined in the first step
/// (`base`) and in the later ones (`full`), and the soft priors.
pub(crate) struct Setup {
    pub base: IntrinsicsMask,
    pub full: IntrinsicsMask,
    pub priors: BTreeMap<CameraId, Vec<(IntrinsicParam, GaussianPrior)>>,
}

pub(crate) fn setup(ctx: &Context, rec: &MetricReconstruction, estimate_aspect: bool) -> Setup {
    let o = ctx.opts;
    let distortion = o.distortion != Distortion::None && !long_lens(rec);
    let base = IntrinsicsMask {
        f: true,
        aspect: estimate_aspect,
        skew: false,
        principal_point: false,
        k1: distortion,
        k2: false,
    };
    let full = IntrinsicsMask {
        principal_point: ctx.refines_principal_point(),
        k2: distortion && o.distortion == Distortion::K1K2,
        ..base
    };
    let mut priors = focal_priors(ctx, rec);
    // A soft prior keeps the principal point near the image centre (σ = principal_point_prior ·
    // (w + h), eq. 25's u ≈ v ≈ 0 in K_N units): free where the views determine it (wide-angle,
    // deep scenes), held where it would trade off against rotation (narrow field, shallow scenes).
    if ctx.refines_principal_point() {
        for cam in rec.cameras.values() {
            let s = o.principal_point_prior * (cam.width + cam.height) as f64;
            let e = priors.entry(cam.id).or_default();
            e.push((
                IntrinsicParam::Ppx,
                GaussianPrior {
                    mean: image_centre(cam.width, cam.height).x,
                    sigma: s,
                },
            ));
            e.push((
                IntrinsicParam::Ppy,
                GaussianPrior {
                    mean: image_centre(cam.width, cam.height).y,
                    sigma: s,
                },
            ));
        }
    }
    // A known calibration pins f, the aspect ratio and the principal point of every group.
    let full = match o.known_intrinsics {
        Some(k) => {
            for cam in rec.cameras.values() {
                let e = priors.entry(cam.id).or_default();
                e.retain(|(p, _)| {
                    !matches!(
                        p,
                        IntrinsicParam::F
                            | IntrinsicParam::Aspect
                            | IntrinsicParam::Ppx
                            | IntrinsicParam::Ppy
                    )
                });
                let pin = |mean: f64, sigma: f64| GaussianPrior { mean, sigma };
                e.push((IntrinsicParam::F, pin(k.fx, 1e-6 * k.fx)));
                e.push((IntrinsicParam::Aspect, pin(k.fy / k.fx, 1e-9)));
                e.push((IntrinsicParam::Ppx, pin(k.cx, 1e-3)));
                e.push((IntrinsicParam::Ppy, pin(k.cy, 1e-3)));
            }
            IntrinsicsMask {
                aspect: true,
                principal_point: true,
                ..full
            }
        }
        None => full,
    };
    Setup { base, full, priors }
}

/// Normalized radius `r = ½ diagonal / f` below which radial distortion is not estimated.
///
/// Eq. 3's displacement `k₁ r²` is unobservable at small `r`: it trades off against the focal length
/// and the principal point (on templeSparseRing, `r ≈ 0.26`, a spurious `k₁ ≈ −0.25` costs half the
/// rotation accuracy), and long lenses hardly distort. 0.3 is a diagonal field of view of ~33°, a
/// 70 mm-equivalent lens.
const MIN_DISTORTION_RADIUS: f64 = 0.3;

/// True when every intrinsics group has a narrow field of view (see [`MIN_DISTORTION_RADIUS`]).
fn long_lens(rec: &MetricReconstruction) -> bool {
    !rec.cameras.is_empty()
        && rec.cameras.values().all(|c| {
            let half_diag = 0.5 * f64::from(c.width).hypot(f64::from(c.height));
            half_diag / c.intrinsics.f.abs().max(1e-9) < MIN_DISTORTION_RADIUS
        })
}

/// EXIF focal lengths are only priors (σ = 10 %), per group, when every member agrees.
fn focal_priors(
    ctx: &Context,
    rec: &MetricReconstruction,
) -> BTreeMap<CameraId, Vec<(IntrinsicParam, GaussianPrior)>> {
    let mut out = BTreeMap::new();
    let by_id: BTreeMap<ImageId, usize> = ctx
        .input
        .images
        .iter()
        .enumerate()
        .map(|(k, im)| (im.id, k))
        .collect();
    for cam in rec.cameras.values() {
        let priors: Vec<f64> = rec
            .views
            .values()
            .filter(|v| v.camera_id == cam.id)
            .filter_map(|v| {
                by_id
                    .get(&v.id)
                    .and_then(|&k| ctx.input.images[k].focal_prior_px)
            })
            .collect();
        if let Some(&f) = priors.first() {
            if priors.iter().all(|p| (p - f).abs() < 1e-6 * f) {
                out.insert(
                    cam.id,
                    vec![(
                        IntrinsicParam::F,
                        GaussianPrior {
                            mean: f,
                            sigma: 0.1 * f,
                        },
                    )],
                );
            }
        }
    }
    out
}
