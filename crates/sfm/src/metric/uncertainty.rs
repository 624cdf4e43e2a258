//! Per-point uncertainty of the metric model (§3.3): the BA engine's covariance of every point,
//! summarised as the median and 90th percentile of each point's largest standard deviation, absolute
//! and relative to its distance from the nearest observing camera.

use handheld_bundle::{
    metric_uncertainty, BundleOptions, IntrinsicParam, IntrinsicsMask, MetricBundleConfig,
};
use handheld_core::MetricReconstruction;
use serde::Serialize;

use crate::common::median;
use crate::context::Context;
use crate::options::Distortion;

/// Per-point uncertainty statistics from the BA engine's covariance (§3.3).
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct UncertaintyReport {
    pub points: usize,
    /// Median and 90th percentile of the largest standard deviation of each point (model units).
    pub median_sigma: f64,
    pub p90_sigma: f64,
    /// The same relative to the point's distance from the nearest camera centre observing it.
    pub median_relative_sigma: f64,
    pub variance_factor: f64,
    /// Standard deviation (pixels; k1 unitless) of each refined intrinsic of each group, from the
    /// data alone (no priors): how well the views determine the calibration.
    pub intrinsics_sigma: Vec<IntrinsicsSigma>,
}

impl UncertaintyReport {
    /// Standard deviation of group `camera_id`'s focal length divided by `focal`, when known.
    pub fn relative_focal_sigma(&self, camera_id: u32, focal: f64) -> Option<f64> {
        self.intrinsics_sigma
            .iter()
            .find(|s| s.camera_id == camera_id)
            .and_then(|s| s.f)
            .map(|sf| sf / focal)
            .filter(|r| r.is_finite())
    }
}

/// [`UncertaintyReport::intrinsics_sigma`] of one intrinsics group.
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct IntrinsicsSigma {
    pub camera_id: u32,
    pub f: Option<f64>,
    pub principal_point: Option<[f64; 2]>,
    pub k1: Option<f64>,
}

pub(crate) fn uncertainty(
    ctx: &Context,
    rec: &MetricReconstruction,
) -> Result<UncertaintyReport, String> {
    let o = ctx.opts;
    let full = IntrinsicsMask {
        f: true,
        aspect: false,
        skew: false,
        principal_point: ctx.refines_principal_point(),
        k1: o.distortion != Distortion::None,
        k2: o.distortion == Distortion::K1K2,
    };
    let config = MetricBundleConfig {
        refine: full,
        ..Default::default()
    };
    let u =
        metric_uncertainty(rec, &config, &BundleOptions::default()).map_err(|e| e.to_string())?;
    let mut sig: Vec<f64> = Vec::new();
    let mut rel: Vec<f64> = Vec::new();
    for (id, p) in &u.points {
        let s = p.sigma_xyz().iter().fold(0.0f64, |a, b| a.max(*b));
        sig.push(s);
        if let Some(pt) = rec.points.get(id) {
            let d = pt
                .track
                .elements
                .iter()
                .filter_map(|e| rec.views.get(&e.image_id))
                .map(|v| (v.center() - pt.xyz).norm())
                .fold(f64::INFINITY, f64::min);
            if d.is_finite() && d > 0.0 {
                rel.push(s / d);
            }
        }
    }
    let n = sig.len();
    sig.sort_by(f64::total_cmp);
    Ok(UncertaintyReport {
        points: n,
        median_sigma: if n > 0 { sig[n / 2] } else { f64::NAN },
        p90_sigma: if n > 0 {
            sig[(n * 9 / 10).min(n - 1)]
        } else {
            f64::NAN
        },
        median_relative_sigma: median(&mut rel),
        variance_factor: u.variance_factor,
        intrinsics_sigma: u
            .intrinsics
            .iter()
            .map(|(id, sd)| IntrinsicsSigma {
                camera_id: id.0,
                f: sd[IntrinsicParam::F.index()],
                principal_point: sd[IntrinsicParam::Ppx.index()]
                    .zip(sd[IntrinsicParam::Ppy.index()])
                    .map(|(x, y)| [x, y]),
                k1: sd[IntrinsicParam::K1.index()],
            })
            .collect(),
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
    match uncertainty(ctx, rec) {
        Ok(u) => (Some(u), None),
        Err(e) => (None, Some(e)),
    }
}
