//! Options of the SfM stage, plain data with documented units and a `validate()`.

use serde::{Deserialize, Serialize};

use crate::error::SfmError;
use crate::split::SplitOptions;
use crate::upgrade::selfcal::{SelfCalibrationError, SelfCalibrationOptions};

/// Which radial distortion coefficients metric BA estimates (eq. 3).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Distortion {
    None,
    K1,
    K1K2,
}

/// A calibration the user already knows, in pixels (Handheld convention: the top-left pixel's centre
/// at (0, 0)). It pins every intrinsics group by tight priors in metric BA; self-calibration still
/// initialises the metric frame.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct KnownIntrinsics {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
}

/// Options of [`crate::reconstruct`].
#[derive(Clone, Debug, PartialEq, Serialize, serde::Deserialize)]
pub struct SfmOptions {
    /// Inlier threshold of the projective stage in pixels (resection, triangulation, filtering). It
    /// absorbs the not-yet-modelled radial distortion. Default 4.
    pub projective_max_error_px: f64,
    /// Observations further than this from their reprojection are removed after the first metric
    /// bundle adjustment. Default 4.
    pub metric_max_error_px: f64,
    /// Threshold of the final filtering, after distortion and principal point are estimated. Default 2.
    pub final_max_error_px: f64,
    /// Huber scale of every bundle adjustment in pixels; with `noise_scaled_loss`, the largest
    /// scale of the metric adjustments after the first. Default 1.5.
    pub loss_scale_px: f64,
    /// Metric adjustments after the first take their Huber scale (1.345 σ̂) and the weight of
    /// their priors from the observations' measured noise σ̂, instead of `loss_scale_px` and
    /// priors stated against 1 px of noise. Default true.
    pub noise_scaled_loss: bool,
    /// Points an initial pair must triangulate. Default 50.
    pub init_min_points: usize,
    /// Initial pairs tried before giving up on a model. Default 10.
    pub max_initial_pairs: usize,
    /// Resection inliers needed to register a view. Default 20.
    pub min_resection_inliers: usize,
    /// Registration attempts per view (each after the structure grew). Default 3.
    pub max_resection_attempts: usize,
    /// Projective BA runs whenever the number of views grew by this factor (and for the first 5). Default 1.25.
    pub ba_growth_factor: f64,
    /// Weighted re-solves of eq. 20. Default 3.
    pub triangulation_iterations: usize,
    /// Points seen in fewer views are dropped from the final model (2-view points stay only while
    /// reprojection-consistent, §3.2). Default 2.
    pub min_track_length: usize,
    /// Estimate the principal point in the final metric BA. Default true.
    pub refine_principal_point: bool,
    /// Standard deviation of the principal point's prior at the image centre, as a fraction of
    /// `w + h` (only with `refine_principal_point`). Default 0.005.
    pub principal_point_prior: f64,
    /// Weight metric BA observations by their keypoint's detection scale `s`: σ ∝ √s, normalised so
    /// the median keypoint has σ = 1 px (measured on herzjesu-P8 against the ground-truth cameras:
    /// the reprojection error grows as 0.17 √s). With the adjustment's gradient right for the
    /// held view it helps on every set with ground truth (AUC@1: fountain-P11 88.3 → 90.0,
    /// herzjesu-P8 85.6 → 87.7, templeSparseRing 70.5 → 73.2, iclnuim-5 30.9 → 33.7). Default true.
    pub scale_weighted_observations: bool,
    /// Known intrinsics (`None`: uncalibrated, the default). Default None.
    pub known_intrinsics: Option<KnownIntrinsics>,
    /// Radial distortion model. Default k1.
    pub distortion: Distortion,
    /// Estimate a constant aspect ratio; `None` = automatic (true for video, §3.4). Default None.
    pub estimate_aspect: Option<bool>,
    /// Independent models (pieces of a broken sequence) to attempt at most. Default 5.
    pub max_models: usize,
    /// Seed of every random choice. Default 0.
    pub seed: u64,
    /// Compute per-point uncertainty (covariance) statistics. Default true.
    pub uncertainty: bool,
    pub self_calibration: SelfCalibrationOptions,
    /// Split-and-merge for large sets (`split/`).
    #[serde(default)]
    pub split: SplitOptions,
}

impl Default for SfmOptions {
    fn default() -> Self {
        Self {
            projective_max_error_px: 4.0,
            metric_max_error_px: 4.0,
            final_max_error_px: 2.0,
            loss_scale_px: 1.5,
            noise_scaled_loss: true,
            init_min_points: 50,
            max_initial_pairs: 10,
            min_resection_inliers: 20,
            max_resection_attempts: 3,
            ba_growth_factor: 1.25,
            triangulation_iterations: 3,
            min_track_length: 2,
            refine_principal_point: true,
            principal_point_prior: 0.005,
            scale_weighted_observations: true,
            known_intrinsics: None,
            distortion: Distortion::K1,
            estimate_aspect: None,
            max_models: 5,
            seed: 0,
            uncertainty: true,
            self_calibration: SelfCalibrationOptions::default(),
            split: SplitOptions::default(),
        }
    }
}

impl SfmOptions {
    /// Rejects out-of-range values with [`SfmError::InvalidOption`], naming the field
    /// (`self_calibration.<field>` for the nested self-calibration options).
    pub fn validate(&self) -> Result<(), SfmError> {
        let bad =
            |option: &'static str, reason: String| Err(SfmError::InvalidOption { option, reason });
        let pos = [
            ("projective_max_error_px", self.projective_max_error_px),
            ("metric_max_error_px", self.metric_max_error_px),
            ("final_max_error_px", self.final_max_error_px),
            ("loss_scale_px", self.loss_scale_px),
            ("principal_point_prior", self.principal_point_prior),
        ];
        for (option, v) in pos {
            if !(v.is_finite() && v > 0.0) {
                return bad(option, format!("must be positive and finite, got {v}"));
            }
        }
        if self.init_min_points < 8 {
            return bad(
                "init_min_points",
                format!("must be at least 8, got {}", self.init_min_points),
            );
        }
        if self.min_resection_inliers < 6 {
            return bad(
                "min_resection_inliers",
                format!("must be at least 6, got {}", self.min_resection_inliers),
            );
        }
        for (option, v) in [
            ("max_initial_pairs", self.max_initial_pairs),
            ("max_resection_attempts", self.max_resection_attempts),
            ("max_models", self.max_models),
        ] {
            if v == 0 {
                return bad(option, "must be at least 1, got 0".into());
            }
        }
        if !(self.ba_growth_factor.is_finite() && self.ba_growth_factor > 1.0) {
            return bad(
                "ba_growth_factor",
                format!("must be > 1, got {}", self.ba_growth_factor),
            );
        }
        if self.min_track_length < 2 {
            return bad(
                "min_track_length",
                format!("must be at least 2, got {}", self.min_track_length),
            );
        }
        if let Some(k) = self.known_intrinsics {
            let positive = |v: f64| v.is_finite() && v > 0.0;
            let finite = k.cx.is_finite() && k.cy.is_finite();
            if !(positive(k.fx) && positive(k.fy) && finite) {
                return bad(
                    "known_intrinsics",
                    format!("need positive focal lengths and a finite principal point, got {k:?}"),
                );
            }
        }
        if let Some((option, reason)) = self.split.invalid() {
            return bad(option, reason);
        }
        self.self_calibration.validate().map_err(|e| match e {
            SelfCalibrationError::InvalidOption { option, reason } => SfmError::InvalidOption {
                option: self_calibration_option(option),
                reason,
            },
            other => SfmError::InvalidOption {
                option: "self_calibration",
                reason: other.to_string(),
            },
        })
    }
}

/// The path of a [`SelfCalibrationOptions`] field inside [`SfmOptions`], as the user writes it.
fn self_calibration_option(field: &'static str) -> &'static str {
    match field {
        "iterations" => "self_calibration.iterations",
        "sigma_focal_sq" => "self_calibration.sigma_focal_sq",
        "sigma_aspect" => "self_calibration.sigma_aspect",
        "sigma_principal_point" => "self_calibration.sigma_principal_point",
        "sigma_skew" => "self_calibration.sigma_skew",
        "estimated_aspect_weight" => "self_calibration.estimated_aspect_weight",
        "prior_mean_weight" => "self_calibration.prior_mean_weight",
        "degenerate_singular_ratio" => "self_calibration.degenerate_singular_ratio",
        _ => "self_calibration",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rejected(o: SfmOptions) -> &'static str {
        match o.validate() {
            Err(SfmError::InvalidOption { option, .. }) => option,
            other => panic!("expected an option error, got {other:?}"),
        }
    }

    #[test]
    fn validate_names_the_offending_field() {
        assert!(SfmOptions::default().validate().is_ok());
        let err = SfmOptions {
            loss_scale_px: f64::NAN,
            ..Default::default()
        }
        .validate()
        .unwrap_err();
        assert_eq!(
            err.to_string(),
            "invalid SfM option `loss_scale_px`: must be positive and finite, got NaN"
        );
        let d = SfmOptions::default;
        assert_eq!(
            rejected(SfmOptions {
                max_models: 0,
                ..d()
            }),
            "max_models"
        );
        assert_eq!(
            rejected(SfmOptions {
                init_min_points: 3,
                ..d()
            }),
            "init_min_points"
        );
        assert_eq!(
            rejected(SfmOptions {
                known_intrinsics: Some(KnownIntrinsics {
                    fx: -1.0,
                    fy: 500.0,
                    cx: 0.0,
                    cy: 0.0
                }),
                ..d()
            }),
            "known_intrinsics"
        );
        let mut o = d();
        o.self_calibration.sigma_skew = 0.0;
        assert_eq!(rejected(o), "self_calibration.sigma_skew");
    }

    #[test]
    fn the_error_fits_anyhow_style_callers() {
        fn boxed(e: SfmError) -> Box<dyn std::error::Error + Send + Sync + 'static> {
            Box::new(e)
        }
        let e = SfmOptions {
            min_track_length: 1,
            ..Default::default()
        }
        .validate()
        .map_err(boxed)
        .unwrap_err();
        assert!(e.to_string().contains("min_track_length"), "{e}");
    }
}
