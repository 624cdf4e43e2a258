//! Robust losses `ρ(s)` on the squared residual norm `s = ‖r‖²`, with the scale `a` in pixels, and the
//! Triggs correction that folds `ρ` into the residual and Jacobian so the Gauss–Newton model matches
//! the robustified cost to second order (Triggs et al. 2000 §4.3; Ceres' `Corrector`).

use crate::options::BundleError;

/// A robust loss; the cost of one observation is `½ ρ(‖r‖²)`.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RobustLoss {
    /// `ρ(s) = s`.
    None,
    /// `ρ(s) = s` for `s ≤ a²`, else `2a√s − a²` (a in pixels).
    Huber(f64),
    /// `ρ(s) = a² log(1 + s/a²)` (a in pixels).
    Cauchy(f64),
}

impl RobustLoss {
    /// Checks the loss scale; the error names the option `loss`.
    pub fn validate(&self) -> Result<(), BundleError> {
        match self {
            RobustLoss::None => Ok(()),
            RobustLoss::Huber(a) | RobustLoss::Cauchy(a) if a.is_finite() && *a > 0.0 => Ok(()),
            _ => Err(BundleError::InvalidOption {
                option: "loss",
                reason: format!("the robust loss scale must be positive and finite: {self:?}"),
            }),
        }
    }

    /// `[ρ(s), ρ'(s), ρ''(s)]`.
    #[inline]
    pub fn evaluate(&self, s: f64) -> [f64; 3] {
        match *self {
            RobustLoss::None => [s, 1.0, 0.0],
            RobustLoss::Huber(a) => {
                let b = a * a;
                if s <= b {
                    [s, 1.0, 0.0]
                } else {
                    let r = s.sqrt();
                    [2.0 * a * r - b, a / r, -0.5 * a / (s * r)]
                }
            }
            RobustLoss::Cauchy(a) => {
                let b = a * a;
                let inv = 1.0 / (1.0 + s / b);
                [b * (s / b).ln_1p(), inv, -inv * inv / b]
            }
        }
    }
}

/// Scales a residual and its Jacobian rows so that `½‖r̃‖²` has the gradient and (Triggs-corrected)
/// Gauss–Newton Hessian of `½ρ(‖r‖²)`. Ceres' `Corrector`: `r̃ = (√ρ'/(1−α)) r`,
/// `J̃ = √ρ' (I − α rrᵀ/‖r‖²) J` with `α` the root of `½α² − α − (ρ''/ρ')‖r‖² = 0`.
#[derive(Clone, Copy, Debug)]
pub struct Corrector {
    sqrt_rho1: f64,
    residual_scaling: f64,
    alpha_sq_norm: f64,
}

impl Corrector {
    #[inline]
    pub fn new(loss: &RobustLoss, sq_norm: f64) -> Self {
        let rho = loss.evaluate(sq_norm);
        let sqrt_rho1 = rho[1].max(0.0).sqrt();
        if sq_norm == 0.0 || rho[2] <= 0.0 || rho[1] <= 0.0 {
            return Self {
                sqrt_rho1,
                residual_scaling: sqrt_rho1,
                alpha_sq_norm: 0.0,
            };
        }
        let d = 1.0 + 2.0 * sq_norm * rho[2] / rho[1];
        let alpha = 1.0 - d.sqrt();
        Self {
            sqrt_rho1,
            residual_scaling: sqrt_rho1 / (1.0 - alpha),
            alpha_sq_norm: alpha / sq_norm,
        }
    }

    /// True when nothing changes (no loss, or inside Huber's quadratic zone).
    #[inline]
    pub fn is_identity(&self) -> bool {
        self.sqrt_rho1 == 1.0 && self.alpha_sq_norm == 0.0
    }

    /// Corrects a 2-residual's Jacobian columns (each column `[j0, j1]`) given the *uncorrected* residual.
    #[inline]
    pub fn correct_jacobian(&self, r: [f64; 2], cols: &mut [[f64; 2]]) {
        if self.alpha_sq_norm == 0.0 {
            for c in cols {
                c[0] *= self.sqrt_rho1;
                c[1] *= self.sqrt_rho1;
            }
            return;
        }
        for c in cols {
            let rj = r[0] * c[0] + r[1] * c[1];
            c[0] = self.sqrt_rho1 * (c[0] - self.alpha_sq_norm * r[0] * rj);
            c[1] = self.sqrt_rho1 * (c[1] - self.alpha_sq_norm * r[1] * rj);
        }
    }

    #[inline]
    pub fn correct_residual(&self, r: [f64; 2]) -> [f64; 2] {
        [r[0] * self.residual_scaling, r[1] * self.residual_scaling]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn derivatives_match_finite_differences() {
        for loss in [RobustLoss::Huber(2.0), RobustLoss::Cauchy(1.5)] {
            for s in [0.5, 3.0, 10.0, 100.0] {
                let h = 1e-6 * s;
                let [_, d1, d2] = loss.evaluate(s);
                let fd1 = (loss.evaluate(s + h)[0] - loss.evaluate(s - h)[0]) / (2.0 * h);
                let fd2 = (loss.evaluate(s + h)[1] - loss.evaluate(s - h)[1]) / (2.0 * h);
                assert!((d1 - fd1).abs() < 1e-6 * (1.0 + d1.abs()), "{loss:?} {s}");
                assert!((d2 - fd2).abs() < 1e-6 * (1.0 + d2.abs()), "{loss:?} {s}");
            }
        }
        assert!(matches!(
            RobustLoss::Huber(0.0).validate(),
            Err(BundleError::InvalidOption { option: "loss", .. })
        ));
    }

    #[test]
    fn corrected_gradient_matches_robust_gradient() {
        // ∇(½ρ(‖r‖²)) = ρ' Jᵀr must equal J̃ᵀ r̃.
        let loss = RobustLoss::Cauchy(1.0);
        let r = [1.5, -2.0];
        let s = r[0] * r[0] + r[1] * r[1];
        let c = Corrector::new(&loss, s);
        let mut cols = [[0.3, -0.7], [1.1, 0.2]];
        let orig = cols;
        c.correct_jacobian(r, &mut cols);
        let rt = c.correct_residual(r);
        let rho1 = loss.evaluate(s)[1];
        for k in 0..2 {
            let want = rho1 * (orig[k][0] * r[0] + orig[k][1] * r[1]);
            let got = cols[k][0] * rt[0] + cols[k][1] * rt[1];
            assert!((want - got).abs() < 1e-12, "{want} {got}");
        }
    }
}
