//! Estimators for two-view relations (§2.2, Table 1): the fundamental matrix and the homography,
//! wrapping the solvers of `handheld-geometry`. Only the glue lives here; the algorithms stay there.

use handheld_geometry::{
    fundamental_7point, fundamental_8point, homography_dlt, sampson_distance,
    symmetric_transfer_error_sq,
};
use nalgebra::{Matrix3, Vector2};

use crate::estimator::Estimator;

/// A putative correspondence between two images, in pixels (top-left pixel centre at `(0, 0)`,
/// see [`handheld_core::PIXEL_CENTER_OFFSET_COLMAP`]): `x1` in the first image, `x2` in the second.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Match2d2d {
    pub x1: Vector2<f64>,
    pub x2: Vector2<f64>,
}

impl Match2d2d {
    pub fn new(x1: Vector2<f64>, x2: Vector2<f64>) -> Self {
        Self { x1, x2 }
    }
}

fn split(samples: &[Match2d2d]) -> (Vec<Vector2<f64>>, Vec<Vector2<f64>>) {
    samples.iter().map(|m| (m.x1, m.x2)).unzip()
}

/// The fundamental matrix `x2ᵀ F x1 = 0` (Table 1): 7-point minimal solver (H&Z §11.1.2, 1 or 3
/// solutions), normalised 8-point refit on inliers (H&Z alg. 11.1), Sampson distance residual in
/// pixels (H&Z eq. 11.9, the first-order geometric error of eq. 13).
#[derive(Clone, Copy, Debug, Default)]
pub struct FundamentalEstimator;

impl Estimator for FundamentalEstimator {
    type Model = Matrix3<f64>;
    type Sample = Match2d2d;
    const SAMPLE_SIZE: usize = 7;

    fn fit(&self, samples: &[Match2d2d], out: &mut Vec<Matrix3<f64>>) {
        let (x1, x2) = split(samples);
        if let Ok(sols) = fundamental_7point(&x1, &x2) {
            out.extend(sols);
        }
    }

    fn residual(&self, model: &Matrix3<f64>, s: &Match2d2d) -> f64 {
        sampson_distance(model, &s.x1, &s.x2)
    }

    fn refit(&self, samples: &[Match2d2d], _model: &Matrix3<f64>) -> Option<Matrix3<f64>> {
        let (x1, x2) = split(samples);
        fundamental_8point(&x1, &x2).ok()
    }
}

/// The homography `x2 ~ H x1`: 4-point normalised DLT (H&Z alg. 4.2), the same DLT in least squares
/// as refit, and the residual `√(d(x2, H x1)² + d(x1, H⁻¹ x2)²)` in pixels (symmetric transfer
/// error, H&Z eq. 4.7). A singular `H` gives infinite residuals.
#[derive(Clone, Copy, Debug, Default)]
pub struct HomographyEstimator;

impl Estimator for HomographyEstimator {
    type Model = Matrix3<f64>;
    type Sample = Match2d2d;
    const SAMPLE_SIZE: usize = 4;

    fn fit(&self, samples: &[Match2d2d], out: &mut Vec<Matrix3<f64>>) {
        let (x1, x2) = split(samples);
        if let Ok(h) = homography_dlt(&x1, &x2) {
            out.push(h);
        }
    }

    fn residual(&self, model: &Matrix3<f64>, s: &Match2d2d) -> f64 {
        match model.try_inverse() {
            Some(h_inv) => symmetric_transfer_error_sq(model, &h_inv, &s.x1, &s.x2).sqrt(),
            None => f64::INFINITY,
        }
    }

    fn refit(&self, samples: &[Match2d2d], _model: &Matrix3<f64>) -> Option<Matrix3<f64>> {
        let (x1, x2) = split(samples);
        homography_dlt(&x1, &x2).ok()
    }
}
