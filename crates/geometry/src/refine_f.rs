//! Non-linear refinement of the fundamental matrix (§2.2, Table 1 steps 3 and 5).
//!
//! [`refine_fundamental`] minimises eq. 12, `C(F) = Σ d(m′, F m)² + d(m, Fᵀ m′)²` (Zhang et al. 1995),
//! by Levenberg–Marquardt over the orthonormal representation `F = U diag(1, s, 0) Vᵀ` of Bartoli &
//! Sturm (2004), which has exactly the 7 degrees of freedom of F and keeps it rank 2 at every step.
//! The parameterisation lives in Hartley-normalised coordinates for conditioning; residuals are pixel
//! distances. The Gold Standard of eq. 13 is in [`crate::gold_standard`].

use nalgebra::{Matrix3, Rotation3, SMatrix, SVector, Vector2, Vector3};

use crate::error::{check_pair_lengths, GeometryError, Result};
use crate::normalize::hartley_normalization;

/// Options of the eq. 12 refinement.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RefineFOptions {
    /// Maximum LM iterations (default 20).
    pub max_iterations: usize,
    /// Stop when the relative cost decrease falls below this (default 1e-10).
    pub cost_tolerance: f64,
}

impl Default for RefineFOptions {
    fn default() -> Self {
        Self {
            max_iterations: 20,
            cost_tolerance: 1e-10,
        }
    }
}

/// Result of a refinement: the refined F (pixels, unit Frobenius norm) and the cost of eq. 12 before
/// and after, in px².
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RefineFReport {
    pub f: Matrix3<f64>,
    pub initial_cost: f64,
    pub final_cost: f64,
    pub iterations: usize,
}

/// The two residuals of eq. 12 for one match: `d(m′, F m)` and `d(m, Fᵀ m′)` (signed, pixels).
pub fn epipolar_residuals(f: &Matrix3<f64>, x1: &Vector2<f64>, x2: &Vector2<f64>) -> [f64; 2] {
    let m = Vector3::new(x1.x, x1.y, 1.0);
    let mp = Vector3::new(x2.x, x2.y, 1.0);
    let l2 = f * m;
    let l1 = f.transpose() * mp;
    let alg = mp.dot(&l2);
    let n2 = (l2.x * l2.x + l2.y * l2.y).sqrt();
    let n1 = (l1.x * l1.x + l1.y * l1.y).sqrt();
    if n1 < 1e-300 || n2 < 1e-300 {
        return [f64::INFINITY, f64::INFINITY];
    }
    [alg / n2, alg / n1]
}

struct Orthonormal {
    u: Matrix3<f64>,
    v: Matrix3<f64>,
    s: f64,
}

impl Orthonormal {
    fn from_f(f: &Matrix3<f64>) -> Option<Self> {
        let svd = f.svd(true, true);
        let (mut u, mut vt) = (svd.u?, svd.v_t?);
        let sv = svd.singular_values;
        // nalgebra does not sort: order the singular values descending.
        let mut idx = [0usize, 1, 2];
        idx.sort_by(|&a, &b| sv[b].total_cmp(&sv[a]));
        let u0 = u;
        let vt0 = vt;
        for (k, &i) in idx.iter().enumerate() {
            u.set_column(k, &u0.column(i));
            vt.set_row(k, &vt0.row(i));
        }
        if sv[idx[0]] <= 0.0 {
            return None;
        }
        if u.determinant() < 0.0 {
            u = -u;
        }
        let mut v = vt.transpose();
        if v.determinant() < 0.0 {
            v = -v;
        }
        Some(Self {
            u,
            v,
            s: sv[idx[1]] / sv[idx[0]],
        })
    }

    fn to_f(&self) -> Matrix3<f64> {
        self.u * Matrix3::from_diagonal(&Vector3::new(1.0, self.s, 0.0)) * self.v.transpose()
    }

    fn updated(&self, d: &SVector<f64, 7>) -> Self {
        let ru = Rotation3::new(Vector3::new(d[0], d[1], d[2]));
        let rv = Rotation3::new(Vector3::new(d[3], d[4], d[5]));
        Self {
            u: self.u * ru.matrix(),
            v: self.v * rv.matrix(),
            s: (self.s + d[6]).clamp(0.0, 1.0),
        }
    }
}

/// Refines `f` on the matches by minimising eq. 12 (Levenberg–Marquardt, numeric Jacobian over the
/// 7 orthonormal parameters). The result never costs more than the input.
pub fn refine_fundamental(
    f: &Matrix3<f64>,
    x1: &[Vector2<f64>],
    x2: &[Vector2<f64>],
    opts: &RefineFOptions,
) -> Result<RefineFReport> {
    check_pair_lengths(x1, x2, 8)?;
    let n1 = hartley_normalization(x1)?;
    let n2 = hartley_normalization(x2)?;
    // F_pix = T2ᵀ F_n T1  ⇔  F_n = T2⁻ᵀ F_pix T1⁻¹.
    let t1_inv = n1.t.try_inverse().ok_or(GeometryError::Degenerate {
        reason: "normalisation",
    })?;
    let t2_inv = n2.t.try_inverse().ok_or(GeometryError::Degenerate {
        reason: "normalisation",
    })?;
    let to_pix = |fnorm: &Matrix3<f64>| n2.t.transpose() * fnorm * n1.t;
    let fn0 = t2_inv.transpose() * f * t1_inv;
    let mut param = Orthonormal::from_f(&fn0).ok_or(GeometryError::Degenerate {
        reason: "F is zero",
    })?;
    let residuals = |p: &Orthonormal, out: &mut Vec<f64>| {
        out.clear();
        let fp = to_pix(&p.to_f());
        for (a, b) in x1.iter().zip(x2) {
            out.extend_from_slice(&epipolar_residuals(&fp, a, b));
        }
    };
    let cost = |r: &[f64]| 0.5 * r.iter().map(|v| v * v).sum::<f64>();
    let mut r = Vec::with_capacity(2 * x1.len());
    let mut r_try = Vec::with_capacity(2 * x1.len());
    residuals(&param, &mut r);
    let initial_cost = cost(&r);
    let mut current = initial_cost;
    let mut lambda = 1e-3;
    let mut iterations = 0;
    let mut jac: Vec<SVector<f64, 7>> = vec![SVector::zeros(); r.len()];
    while iterations < opts.max_iterations && current.is_finite() {
        iterations += 1;
        // Central-difference Jacobian: 14 residual evaluations per iteration, each O(n).
        let h = 1e-6;
        for k in 0..7 {
            let mut d = SVector::<f64, 7>::zeros();
            d[k] = h;
            residuals(&param.updated(&d), &mut r_try);
            let plus = r_try.clone();
            d[k] = -h;
            residuals(&param.updated(&d), &mut r_try);
            for (i, j) in jac.iter_mut().enumerate() {
                j[k] = (plus[i] - r_try[i]) / (2.0 * h);
            }
        }
        let mut jtj = SMatrix::<f64, 7, 7>::zeros();
        let mut jtr = SVector::<f64, 7>::zeros();
        for (j, ri) in jac.iter().zip(&r) {
            if ri.is_finite() {
                jtj += j * j.transpose();
                jtr += j * *ri;
            }
        }
        let mut improved = false;
        for _ in 0..10 {
            let mut a = jtj;
            for k in 0..7 {
                a[(k, k)] += lambda * (jtj[(k, k)] + 1e-12);
            }
            let Some(step) = a.cholesky().map(|c| c.solve(&(-jtr))) else {
                lambda *= 10.0;
                continue;
            };
            let cand = param.updated(&step);
            residuals(&cand, &mut r_try);
            let c = cost(&r_try);
            if c < current {
                let rel = (current - c) / current.max(1e-300);
                param = cand;
                std::mem::swap(&mut r, &mut r_try);
                current = c;
                lambda = (lambda / 10.0).max(1e-12);
                improved = rel > opts.cost_tolerance;
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    let fp = to_pix(&param.to_f());
    Ok(RefineFReport {
        f: fp / fp.norm(),
        initial_cost,
        final_cost: current,
        iterations,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fundamental::{fundamental_8point, fundamental_from_cameras};
    use crate::test_util::*;
    use handheld_core::ProjectiveCamera;

    #[test]
    fn refinement_lowers_eq12_cost_and_keeps_rank2() {
        let tv = two_view(11, 150);
        let mut r = rng(5);
        let x1 = add_noise(&mut r, &tv.x1, 1.0);
        let x2 = add_noise(&mut r, &tv.x2, 1.0);
        let f0 = fundamental_8point(&x1, &x2).unwrap();
        let rep = refine_fundamental(&f0, &x1, &x2, &RefineFOptions::default()).unwrap();
        assert!(rep.final_cost < rep.initial_cost, "{rep:?}");
        assert!(rep.f.determinant().abs() < 1e-12);
        // Closer to the truth than the linear estimate.
        let ft = fundamental_from_cameras(
            &ProjectiveCamera { P: tv.p1 },
            &ProjectiveCamera { P: tv.p2 },
        )
        .unwrap();
        let err = |f: &Matrix3<f64>| {
            tv.x1
                .iter()
                .zip(&tv.x2)
                .map(|(a, b)| epipolar_residuals(f, a, b)[0].powi(2))
                .sum::<f64>()
                / tv.x1.len() as f64
        };
        assert!(
            err(&rep.f) <= err(&f0) * 1.05,
            "refined {} vs linear {}",
            err(&rep.f),
            err(&f0)
        );
        assert!(equal_up_to_scale(&rep.f, &ft) < 0.05);
    }

    #[test]
    fn exact_data_stays_exact() {
        let tv = two_view(2, 40);
        let f0 = fundamental_8point(&tv.x1, &tv.x2).unwrap();
        let rep = refine_fundamental(&f0, &tv.x1, &tv.x2, &RefineFOptions::default()).unwrap();
        assert!(rep.final_cost < 1e-16, "{rep:?}");
    }
}
