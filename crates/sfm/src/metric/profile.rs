//! Probes of an adjusted metric model that adjust it again on a sample of its points: the profile
//! of the fit along the focal length ([`focal_profile`]) and the principal point's jackknife over
//! the views ([`principal_point_spread`]).

use std::collections::BTreeSet;

use handheld_bundle::{bundle_adjust_metric, BundleOptions, IntrinsicsMask, MetricBundleConfig};
use handheld_core::{ImageId, MetricReconstruction, PointId};
use rayon::prelude::*;
use serde::Serialize;

use crate::common::image_centre;
use crate::context::Context;
use crate::metric::ba::{remove_points, setup, without_views, Setup};
use crate::metric::noise::{noise_scaled_loss, scaled_priors};

/// Relative change of the focal length at which [`focal_profile`] probes the fit: far enough to
/// leave a determined focal length's valley by a wide margin (a sound frame's focal length is
/// within a few per cent), near enough to stay in the basin of the kept frame.
pub const PROFILE_STEP: f64 = 0.2;

/// The profile of the fit along the focal length (a likelihood-ratio test in the spirit of
/// Hartley & Zisserman §A6.4's parameter profiling): the adjusted model `rec` is adjusted again on
/// the same observations (no filtering), once with every parameter free and once each with the
/// focal length held at `(1 ∓ PROFILE_STEP) ×` its value, everything else (poses, points, the
/// other intrinsics) free. Returns the robust cost of the two held adjustments relative to the
/// free one's. A determined focal length makes them large (the metric constraints break); a
/// critical motion (pure translation, a turntable's single axis) leaves them near 1, whatever
/// the covariance says: the formal σ of the focal length is a local, linear statement, and it
/// reads a few pixels on data where two focal lengths 20 % apart fit equally well.
pub(crate) fn focal_profile(
    ctx: &Context,
    rec: &MetricReconstruction,
    estimate_aspect: bool,
) -> Result<[f64; 2], String> {
    let sample = subsample_points(rec, PROFILE_MAX_POINTS, 0);
    let free = held_adjustment(ctx, &sample, estimate_aspect, None)?
        .0
        .max(f64::MIN_POSITIVE);
    let (low, high) = rayon::join(
        || held_adjustment(ctx, &sample, estimate_aspect, Some(1.0 - PROFILE_STEP)),
        || held_adjustment(ctx, &sample, estimate_aspect, Some(1.0 + PROFILE_STEP)),
    );
    Ok([low?.0 / free, high?.0 / free])
}

/// `rec` adjusted on its observations as they are (no filtering) with its focal lengths scaled by
/// `scale` and held there, or free (`None`); every other parameter the schedule refines is free.
/// Returns the robust cost and the adjusted model.
pub(crate) fn held_adjustment(
    ctx: &Context,
    rec: &MetricReconstruction,
    estimate_aspect: bool,
    scale: Option<f64>,
) -> Result<(f64, MetricReconstruction), String> {
    let Setup { full, priors, .. } = setup(ctx, rec, estimate_aspect);
    // The same loss and priors as the schedule's last adjustments.
    let (loss, prior_scale, _) = noise_scaled_loss(ctx, rec, None);
    let priors = scaled_priors(&priors, prior_scale);
    // The ratios need about a per cent: the schedule's first-step tolerances do.
    let bopts = BundleOptions {
        max_iterations: 100,
        loss,
        function_tolerance: 1e-5,
        parameter_tolerance: 1e-8,
        ..Default::default()
    };
    let mut r = rec.clone();
    if let Some(sc) = scale {
        for cam in r.cameras.values_mut() {
            cam.intrinsics.f *= sc;
        }
    }
    let config = MetricBundleConfig {
        refine: IntrinsicsMask {
            f: scale.is_none(),
            ..full
        },
        priors,
        keypoint_sigma: ctx.keypoint_sigma.clone(),
        ..Default::default()
    };
    bundle_adjust_metric(&mut r, &config, &bopts)
        .map(|s| (s.final_cost, r))
        .map_err(|e| format!("focal profile: {e}"))
}

/// Groups of views the principal point's jackknife leaves out in turn.
const JACKKNIFE_GROUPS: usize = 8;

/// How far the data put the principal point from the image centre, against how well they
/// determine it: per intrinsics group, the offset of the freely adjusted principal point from the
/// centre, and its standard deviation from a grouped delete-a-group jackknife over the views
/// (Efron & Stein 1981; Shao & Tu, *The Jackknife and Bootstrap* §2.3: σ² = (g−1)/g Σ (θ_i − θ̄)²),
/// each replicate adjusted (everything the schedule refines, free) on the profile's sample of
/// points with one group of views left out.
///
/// Why not the covariance: the principal point trades off against the cameras' rotations to
/// first order (a shift δ is a rotation by δ/f but for terms in δ·x² that k1 and the structure
/// partly absorb), so what decides it are small, view-dependent effects, and errors that are
/// correlated within a view (unmodelled distortion, localisation biases) move it by pixels while
/// the formal σ, which assumes independent errors, reads a fraction of a pixel (fountain-P11:
/// σ 0.2 px, error 4 px). Leaving views out measures the spread those view-dependent errors cause.
pub(crate) fn principal_point_spread(
    ctx: &Context,
    rec: &MetricReconstruction,
    estimate_aspect: bool,
) -> Result<Vec<PrincipalPointSpread>, String> {
    let sample = subsample_points(rec, PROFILE_MAX_POINTS, 0);
    let free = held_adjustment(ctx, &sample, estimate_aspect, None)?.1;
    let ids: Vec<ImageId> = sample.views.keys().copied().collect();
    let g = ids.len().min(JACKKNIFE_GROUPS);
    if g < 3 {
        return Err("too few views for the principal point's jackknife".into());
    }
    let replicates: Vec<Option<MetricReconstruction>> = (0..g)
        .into_par_iter()
        .map(|k| {
            let out: BTreeSet<ImageId> = ids.iter().copied().skip(k).step_by(g).collect();
            let part = without_views(&sample, &out);
            held_adjustment(ctx, &part, estimate_aspect, None)
                .ok()
                .map(|(_, r)| r)
        })
        .collect();
    let mut out = Vec::new();
    for (id, cam) in &free.cameras {
        let pps: Vec<nalgebra::Vector2<f64>> = replicates
            .iter()
            .flatten()
            .filter_map(|r| r.cameras.get(id).map(|c| c.intrinsics.pp))
            .collect();
        if pps.len() < 3 {
            continue;
        }
        let n = pps.len() as f64;
        let mean = pps.iter().sum::<nalgebra::Vector2<f64>>() / n;
        let var = pps
            .iter()
            .map(|p| (p - mean).component_mul(&(p - mean)))
            .sum::<nalgebra::Vector2<f64>>()
            * ((n - 1.0) / n);
        out.push(PrincipalPointSpread {
            camera_id: id.0,
            offset_px: (cam.intrinsics.pp - image_centre(cam.width, cam.height)).into(),
            sigma_px: var.map(f64::sqrt).into(),
        });
    }
    Ok(out)
}

/// One intrinsics group's principal point against its spread ([`principal_point_spread`]).
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct PrincipalPointSpread {
    pub camera_id: u32,
    /// The freely adjusted principal point minus the image centre, pixels.
    pub offset_px: [f64; 2],
    /// Its jackknife standard deviation, pixels.
    pub sigma_px: [f64; 2],
}

impl PrincipalPointSpread {
    /// Σ (offset / σ)²: χ² with 2 degrees of freedom when the principal point is at the centre.
    pub fn chi2(&self) -> f64 {
        (0..2)
            .map(|k| (self.offset_px[k] / self.sigma_px[k].max(1e-9)).powi(2))
            .sum()
    }

    /// Whether the image centre is expected to be closer to the true principal point than the
    /// free estimate: `Σ offset² < 2 Σ σ²` (see `frame::principal_point_test`).
    pub fn held_is_closer(&self) -> bool {
        let o2: f64 = self.offset_px.iter().map(|o| o * o).sum();
        let s2: f64 = self.sigma_px.iter().map(|s| s * s).sum();
        o2 < 2.0 * s2
    }
}

/// Points the profile adjusts at most: a costs ratio needs a sample, not every point (fountain-P11
/// has 18 000), and the profile then costs a fraction of the schedule (0.1 s there).
const PROFILE_MAX_POINTS: usize = 1000;

/// `rec` with every k-th point only (by id, so the same model gives the same sample), at most
/// `max` of them, and each view topped up from its own observations to `min_view_obs` (0: none)
/// so that no camera is left loose; the observations of the others are detached.
pub(crate) fn subsample_points(
    rec: &MetricReconstruction,
    max: usize,
    min_view_obs: usize,
) -> MetricReconstruction {
    let mut out = rec.clone();
    let n = out.points.len();
    if n <= max {
        return out;
    }
    let step = n.div_ceil(max);
    let mut keep: BTreeSet<PointId> = rec.points.keys().step_by(step).copied().collect();
    if min_view_obs > 0 {
        let mut per_view = std::collections::BTreeMap::new();
        for id in &keep {
            for el in &rec.points[id].track.elements {
                *per_view.entry(el.image_id).or_insert(0usize) += 1;
            }
        }
        for (image, view) in &rec.views {
            let mut have = per_view.get(image).copied().unwrap_or(0);
            for pid in view.observations.iter().filter_map(|o| o.point_id) {
                if have >= min_view_obs {
                    break;
                }
                if rec.points.contains_key(&pid) && keep.insert(pid) {
                    have += 1;
                }
            }
        }
    }
    let dropped: Vec<PointId> = rec
        .points
        .keys()
        .filter(|id| !keep.contains(id))
        .copied()
        .collect();
    remove_points(&mut out, dropped);
    out
}
