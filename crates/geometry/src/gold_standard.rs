//! The maximum-likelihood ("Gold Standard") fundamental matrix of eq. 13 (H&Z alg. 11.3):
//! minimise `Σ d(m, m̂)² + d(m′, m̂′)²` subject to `m̂′ᵀ F m̂ = 0`, over a camera pair
//! `P1 = [I | 0]`, `P2` and one 3D point per match. The problem is sparse (§3.3): each point touches
//! only its own 3 parameters and the 12 of `P2`, so every LM step eliminates the points through a
//! Schur complement and solves a 12×12 system.
//!
//! Points are parameterised as `X = (u, v, 1, ρ)`: `P1 X = (u, v, 1)` is the corrected point in image
//! 1 itself and `ρ` a projective inverse depth, finite for every point whose first image is finite.
//! Work happens in Hartley-normalised coordinates; costs are reported in pixels².

use nalgebra::{Matrix2x3, Matrix3, Matrix3x4, SMatrix, SVector, Vector2, Vector3, Vector4};

use crate::error::{check_pair_lengths, GeometryError, Result};
use crate::fundamental::fundamental_from_cameras;
use crate::normalize::hartley_normalization;
use crate::skew::canonical_cameras;
use handheld_core::ProjectiveCamera;

/// Options of the Gold Standard refinement.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GoldStandardOptions {
    /// Maximum LM iterations (default 30).
    pub max_iterations: usize,
    /// Stop when the relative cost decrease falls below this (default 1e-10).
    pub cost_tolerance: f64,
}

impl Default for GoldStandardOptions {
    fn default() -> Self {
        Self {
            max_iterations: 30,
            cost_tolerance: 1e-10,
        }
    }
}

/// The refined F (pixels, unit norm), the corrected matches `m̂ ↔ m̂′`, and the cost of eq. 13
/// (`½ Σ` squared pixel distances) before and after.
#[derive(Clone, Debug, PartialEq)]
pub struct GoldStandardReport {
    pub f: Matrix3<f64>,
    pub x1_hat: Vec<Vector2<f64>>,
    pub x2_hat: Vec<Vector2<f64>>,
    pub initial_cost: f64,
    pub final_cost: f64,
    pub iterations: usize,
}

struct State {
    p2: Matrix3x4<f64>,
    pts: Vec<Vector3<f64>>,
}

fn project2(p2: &Matrix3x4<f64>, x: &Vector3<f64>) -> (Vector3<f64>, Vector2<f64>) {
    let q = p2 * Vector4::new(x[0], x[1], 1.0, x[2]);
    (q, Vector2::new(q.x / q.z, q.y / q.z))
}

fn cost(s: &State, y1: &[Vector2<f64>], y2: &[Vector2<f64>], w1: f64, w2: f64) -> f64 {
    let mut c = 0.0;
    for ((x, a), b) in s.pts.iter().zip(y1).zip(y2) {
        let (_, p) = project2(&s.p2, x);
        c += w1 * (Vector2::new(x[0], x[1]) - a).norm_squared() + w2 * (p - b).norm_squared();
    }
    0.5 * c
}

/// The first-order correction of a match onto `x2ᵀ F x1 = 0` (H&Z §12.4, eq. 12.6 and §4.2.6):
/// `δ = −Jᵀ ε / (J Jᵀ)` with `ε = x2ᵀ F x1` and `J` its derivative in the four coordinates. The
/// match itself when the derivative vanishes (at both epipoles).
fn sampson_correction(
    f: &Matrix3<f64>,
    a: &Vector2<f64>,
    b: &Vector2<f64>,
) -> (Vector2<f64>, Vector2<f64>) {
    let (ha, hb) = (Vector3::new(a.x, a.y, 1.0), Vector3::new(b.x, b.y, 1.0));
    let (fa, ftb) = (f * ha, f.transpose() * hb);
    let e = hb.dot(&fa);
    let jj = ftb.x * ftb.x + ftb.y * ftb.y + fa.x * fa.x + fa.y * fa.y;
    if !(jj > 1e-300 && e.is_finite()) {
        return (*a, *b);
    }
    let k = e / jj;
    (
        Vector2::new(a.x - k * ftb.x, a.y - k * ftb.y),
        Vector2::new(b.x - k * fa.x, b.y - k * fa.y),
    )
}

/// Refines a fundamental matrix by eq. 13 on (inlier) matches `x1 ↔ x2` (pixels).
pub fn gold_standard_fundamental(
    f: &Matrix3<f64>,
    x1: &[Vector2<f64>],
    x2: &[Vector2<f64>],
    opts: &GoldStandardOptions,
) -> Result<GoldStandardReport> {
    check_pair_lengths(x1, x2, 8)?;
    let n1 = hartley_normalization(x1)?;
    let n2 = hartley_normalization(x2)?;
    let (y1, y2) = (&n1.points, &n2.points);
    let t1_inv = n1.t.try_inverse().ok_or(GeometryError::Degenerate {
        reason: "normalisation",
    })?;
    let t2_inv = n2.t.try_inverse().ok_or(GeometryError::Degenerate {
        reason: "normalisation",
    })?;
    // Pixel distance = normalised distance / scale, so weights 1/s² make the cost pixels².
    let (w1, w2) = (1.0 / n1.scale().powi(2), 1.0 / n2.scale().powi(2));
    let fnorm = t2_inv.transpose() * f * t1_inv;
    let (_, cam2) = canonical_cameras(&fnorm, &Vector3::zeros(), 1.0)?;
    let mut s = State {
        p2: cam2.P / cam2.P.norm(),
        pts: Vec::with_capacity(y1.len()),
    };
    // Initial points: the first-order (Sampson) correction onto F, then the depth that fits the
    // second view. The adjustment below reaches the same minimum from it as from the optimal
    // correction (H&Z alg. 12.1), which costs a degree-6 polynomial's roots per match.
    for (a, b) in y1.iter().zip(y2) {
        let (a_hat, b_hat) = sampson_correction(&fnorm, a, b);
        let m = s.p2.fixed_view::<3, 3>(0, 0) * Vector3::new(a_hat.x, a_hat.y, 1.0);
        let e = s.p2.column(3).into_owned();
        // Solve b_hat × (m + ρ e) = 0 for ρ in least squares.
        let bh = Vector3::new(b_hat.x, b_hat.y, 1.0);
        let (c1, c2) = (bh.cross(&m), bh.cross(&e));
        let rho = if c2.norm_squared() > 1e-300 {
            -c1.dot(&c2) / c2.norm_squared()
        } else {
            0.0
        };
        s.pts.push(Vector3::new(a_hat.x, a_hat.y, rho));
    }
    let initial_cost = cost(&s, y1, y2, w1, w2);
    let mut current = initial_cost;
    let mut lambda = 1e-3;
    let mut iterations = 0;
    let n = y1.len();
    let mut v_blocks = vec![SMatrix::<f64, 3, 3>::zeros(); n];
    let mut w_blocks = vec![SMatrix::<f64, 12, 3>::zeros(); n];
    let mut g_pts = vec![SVector::<f64, 3>::zeros(); n];
    while iterations < opts.max_iterations {
        iterations += 1;
        let mut u = SMatrix::<f64, 12, 12>::zeros();
        let mut g_cam = SVector::<f64, 12>::zeros();
        for i in 0..n {
            let x = s.pts[i];
            let (q, p) = project2(&s.p2, &x);
            let r1 = Vector2::new(x[0], x[1]) - y1[i];
            let r2 = p - y2[i];
            // dπ/dq
            let dpi = Matrix2x3::new(
                1.0 / q.z,
                0.0,
                -q.x / (q.z * q.z),
                0.0,
                1.0 / q.z,
                -q.y / (q.z * q.z),
            );
            let xh = Vector4::new(x[0], x[1], 1.0, x[2]);
            // dq/dP2 (row-major p_rc): dq_r/dp_rc = X_c.
            let mut jc = SMatrix::<f64, 2, 12>::zeros();
            for rr in 0..3 {
                for cc in 0..4 {
                    jc[(0, rr * 4 + cc)] = dpi[(0, rr)] * xh[cc];
                    jc[(1, rr * 4 + cc)] = dpi[(1, rr)] * xh[cc];
                }
            }
            let dq_dx = Matrix3::from_columns(&[
                s.p2.column(0).into_owned(),
                s.p2.column(1).into_owned(),
                s.p2.column(3).into_owned(),
            ]);
            let jp2 = dpi * dq_dx;
            let jp1 = Matrix2x3::new(1.0, 0.0, 0.0, 0.0, 1.0, 0.0);
            u += w2 * jc.transpose() * jc;
            g_cam += w2 * jc.transpose() * r2;
            v_blocks[i] = w1 * jp1.transpose() * jp1 + w2 * jp2.transpose() * jp2;
            w_blocks[i] = w2 * jc.transpose() * jp2;
            g_pts[i] = w1 * jp1.transpose() * r1 + w2 * jp2.transpose() * r2;
        }
        let mut improved = false;
        for _ in 0..10 {
            // Schur complement: S = U* − Σ W V*⁻¹ Wᵀ, rhs = −g_c + Σ W V*⁻¹ g_p.
            let mut sm = u;
            for k in 0..12 {
                sm[(k, k)] += lambda * (u[(k, k)] + 1e-12);
            }
            let mut rhs = -g_cam;
            let mut vinv = Vec::with_capacity(n);
            let mut ok = true;
            for i in 0..n {
                let mut v = v_blocks[i];
                for k in 0..3 {
                    v[(k, k)] += lambda * (v_blocks[i][(k, k)] + 1e-12);
                }
                let Some(vi) = v.try_inverse() else {
                    ok = false;
                    break;
                };
                let wv = w_blocks[i] * vi;
                sm -= wv * w_blocks[i].transpose();
                rhs += wv * g_pts[i];
                vinv.push(vi);
            }
            let dc = if ok {
                sm.cholesky().map(|c| c.solve(&rhs))
            } else {
                None
            };
            let Some(dc) = dc else {
                lambda *= 10.0;
                continue;
            };
            let mut cand = State {
                p2: s.p2,
                pts: s.pts.clone(),
            };
            for rr in 0..3 {
                for cc in 0..4 {
                    cand.p2[(rr, cc)] += dc[rr * 4 + cc];
                }
            }
            for i in 0..n {
                let dp = vinv[i] * (-g_pts[i] - w_blocks[i].transpose() * dc);
                cand.pts[i] += dp;
            }
            // Gauge: keep P2 at unit norm (rescaling P2 and ρ together changes nothing in the images).
            let norm = cand.p2.norm();
            cand.p2 /= norm;
            let c = cost(&cand, y1, y2, w1, w2);
            if c.is_finite() && c < current {
                let rel = (current - c) / current.max(1e-300);
                s = cand;
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
    let fn_ref = fundamental_from_cameras(
        &ProjectiveCamera::canonical(),
        &ProjectiveCamera { P: s.p2 },
    )?;
    let fp = n2.t.transpose() * fn_ref * n1.t;
    let back = |t_inv: &Matrix3<f64>, v: Vector2<f64>| {
        let h = t_inv * Vector3::new(v.x, v.y, 1.0);
        Vector2::new(h.x / h.z, h.y / h.z)
    };
    let x1_hat = s
        .pts
        .iter()
        .map(|x| back(&t1_inv, Vector2::new(x[0], x[1])))
        .collect();
    let x2_hat = s
        .pts
        .iter()
        .map(|x| back(&t2_inv, project2(&s.p2, x).1))
        .collect();
    Ok(GoldStandardReport {
        f: fp / fp.norm(),
        x1_hat,
        x2_hat,
        initial_cost,
        final_cost: current,
        iterations,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fundamental::fundamental_8point;
    use crate::refine_f::epipolar_residuals;
    use crate::test_util::*;

    #[test]
    fn gold_standard_reaches_noise_level_and_beats_linear() {
        let tv = two_view(21, 200);
        let mut r = rng(8);
        let sigma = 1.0;
        let x1 = add_noise(&mut r, &tv.x1, sigma);
        let x2 = add_noise(&mut r, &tv.x2, sigma);
        let f0 = fundamental_8point(&x1, &x2).unwrap();
        let rep =
            gold_standard_fundamental(&f0, &x1, &x2, &GoldStandardOptions::default()).unwrap();
        assert!(rep.final_cost <= rep.initial_cost);
        // ML residual: E[2·cost] = σ² (4n − (3n + 7)) = σ² (n − 7).
        let n = x1.len() as f64;
        let expected = sigma * sigma * (n - 7.0);
        assert!(
            (2.0 * rep.final_cost / expected - 1.0).abs() < 0.25,
            "2·cost {} vs {}",
            2.0 * rep.final_cost,
            expected
        );
        // Corrected points satisfy the refined epipolar geometry exactly.
        for (a, b) in rep.x1_hat.iter().zip(&rep.x2_hat) {
            assert!(epipolar_residuals(&rep.f, a, b)[0].abs() < 1e-6);
        }
        // Closer to the truth (error on exact points) than the linear estimate.
        let err = |f: &Matrix3<f64>| {
            tv.x1
                .iter()
                .zip(&tv.x2)
                .map(|(a, b)| epipolar_residuals(f, a, b)[0].powi(2))
                .sum::<f64>()
        };
        assert!(
            err(&rep.f) < err(&f0),
            "gold {} linear {}",
            err(&rep.f),
            err(&f0)
        );
    }
}
