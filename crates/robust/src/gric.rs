//! Model selection between F and H by GRIC, the Geometric Robust Information Criterion of Torr
//! (1998; Torr, Fitzgibbon & Zisserman 1999):
//! `GRIC = Σᵢ ρ(eᵢ²/σ²) + λ₁ d n + λ₂ k`, `ρ(x) = min(x, λ₃ (r − d))`,
//! with data dimension `r = 4` (two image points), model manifold dimension `d` (3 for F, 2 for H),
//! `k` model parameters (7 for F, 8 for H), `λ₁ = ln r`, `λ₂ = ln(r n)`, `λ₃ = 2`. The lower score wins.
//! The paper uses it for key-frame selection (§3.1, footnote 1) and to detect planar or purely
//! rotational configurations.

use handheld_geometry::{sampson_distance_sq, symmetric_transfer_error_sq};
use nalgebra::Matrix3;

use crate::two_view::Match2d2d;

/// Which relation a GRIC score is for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GricModel {
    Fundamental,
    Homography,
}

impl GricModel {
    fn dims(self) -> (f64, f64) {
        match self {
            GricModel::Fundamental => (3.0, 7.0),
            GricModel::Homography => (2.0, 8.0),
        }
    }
}

/// GRIC of a model given the squared residuals `e²` (px²) of all matches and the noise `σ` (px).
pub fn gric(model: GricModel, residuals_sq: &[f64], sigma: f64) -> f64 {
    let r: f64 = 4.0;
    let (d, k) = model.dims();
    let n = residuals_sq.len() as f64;
    let (l1, l2, l3) = (r.ln(), (r * n).ln(), 2.0);
    let s2 = (sigma * sigma).max(1e-12);
    let cap = l3 * (r - d);
    residuals_sq
        .iter()
        .map(|e2| {
            if e2.is_finite() {
                (e2 / s2).min(cap)
            } else {
                cap
            }
        })
        .sum::<f64>()
        + l1 * d * n
        + l2 * k
}

/// Squared residuals of F for GRIC: the Sampson distance, the first-order distance of the match to
/// the F variety in the 4D joint image space.
pub fn f_residuals_sq(f: &Matrix3<f64>, matches: &[Match2d2d]) -> Vec<f64> {
    matches
        .iter()
        .map(|m| sampson_distance_sq(f, &m.x1, &m.x2))
        .collect()
}

/// Squared residuals of H for GRIC: a quarter of the symmetric transfer error, which approximates
/// the 4D distance to the H variety when the noise is split between the two images.
pub fn h_residuals_sq(h: &Matrix3<f64>, matches: &[Match2d2d]) -> Vec<f64> {
    let Some(h_inv) = h.try_inverse() else {
        return vec![f64::INFINITY; matches.len()];
    };
    matches
        .iter()
        .map(|m| 0.25 * symmetric_transfer_error_sq(h, &h_inv, &m.x1, &m.x2))
        .collect()
}

/// Robust noise estimate from squared residuals of the inliers of the more general model:
/// `σ = √(median(e²) / 0.455)` (0.455 is the median of χ²₁), clamped to at least `min_sigma`.
pub fn estimate_sigma(residuals_sq: &[f64], min_sigma: f64) -> f64 {
    let mut v: Vec<f64> = residuals_sq
        .iter()
        .copied()
        .filter(|e| e.is_finite())
        .collect();
    if v.is_empty() {
        return min_sigma;
    }
    v.sort_by(|a, b| a.total_cmp(b));
    (v[v.len() / 2] / 0.455).sqrt().max(min_sigma)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn perfect_fit_prefers_fewer_parameters_per_match() {
        // Zero residuals: F pays λ₁·3 per match, H λ₁·2, so H wins when both explain everything.
        let e = vec![0.0; 100];
        assert!(gric(GricModel::Homography, &e, 1.0) < gric(GricModel::Fundamental, &e, 1.0));
        // Large H residuals: F wins.
        let big = vec![50.0; 100];
        assert!(gric(GricModel::Fundamental, &e, 1.0) < gric(GricModel::Homography, &big, 1.0));
    }

    #[test]
    fn sigma_of_gaussian_residuals() {
        // Residuals e = σ·z for a deterministic normal-like sample with median |z| ≈ 0.6745.
        let e2: Vec<f64> = (1..1000)
            .map(|i| {
                let p = i as f64 / 1000.0;
                let z = (2.0f64).sqrt() * erfinv(2.0 * p - 1.0);
                (2.0 * z).powi(2)
            })
            .collect();
        let s = estimate_sigma(&e2, 0.1);
        assert!((s - 2.0).abs() < 0.05, "{s}");
    }

    fn erfinv(x: f64) -> f64 {
        // Winitzki's approximation, accurate to ~1e-3: enough for this check.
        let a = 0.147;
        let ln = (1.0 - x * x).ln();
        let t = 2.0 / (std::f64::consts::PI * a) + ln / 2.0;
        x.signum() * ((t * t - ln / a).sqrt() - t).sqrt()
    }
}
