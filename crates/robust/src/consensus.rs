//! How a hypothesis is scored from its residuals, separate from the loop so that plain RANSAC and
//! MSAC share it. Scores are additive over samples and larger is better; an outlier contributes 0.

/// Scores one residual against the inlier threshold.
pub trait Consensus {
    /// Contribution of a sample with residual `r` under threshold `t` (`r ≤ t` is an inlier).
    /// Must be 0 for outliers (`r > t`, or `r` NaN) and non-negative for inliers.
    fn score(&self, r: f64, t: f64) -> f64;
}

/// Plain RANSAC (Fischler & Bolles 1981): the score is the number of inliers.
#[derive(Clone, Copy, Debug, Default)]
pub struct InlierCount;

impl Consensus for InlierCount {
    fn score(&self, r: f64, t: f64) -> f64 {
        if r <= t {
            1.0
        } else {
            0.0
        }
    }
}

/// MSAC (Torr & Zisserman 2000): the truncated quadratic cost `ρ(r) = min(r², t²)`, expressed as the
/// score `1 − ρ(r)/t²` so that a perfect inlier counts 1 and an outlier 0. Maximising it minimises
/// `Σ ρ`, which prefers models that fit their inliers closely.
#[derive(Clone, Copy, Debug, Default)]
pub struct Msac;

impl Consensus for Msac {
    fn score(&self, r: f64, t: f64) -> f64 {
        if r <= t {
            1.0 - (r * r) / (t * t)
        } else {
            0.0
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scores() {
        assert_eq!(InlierCount.score(0.9, 1.0), 1.0);
        assert_eq!(InlierCount.score(1.1, 1.0), 0.0);
        assert_eq!(Msac.score(0.0, 2.0), 1.0);
        assert!((Msac.score(1.0, 2.0) - 0.75).abs() < 1e-15);
        assert_eq!(Msac.score(3.0, 2.0), 0.0);
        assert_eq!(Msac.score(f64::INFINITY, 2.0), 0.0);
        assert_eq!(InlierCount.score(f64::NAN, 2.0), 0.0);
    }
}
