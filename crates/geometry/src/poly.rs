//! Real roots of small polynomials, kept apart because two solvers need them: the cubic
//! `det(F1 + λF2) = 0` of the 7-point method (H&Z §11.1.2) and the sextic of Hartley–Sturm
//! triangulation (paper eq. 18, H&Z alg. 12.1). Coefficients are given in ascending order,
//! `c[0] + c[1]·x + c[2]·x² + …`.

use nalgebra::{Complex, DMatrix};

/// Evaluates the polynomial with ascending coefficients `c` at `x` (Horner).
pub fn eval(c: &[f64], x: f64) -> f64 {
    c.iter().rev().fold(0.0, |acc, &ci| acc * x + ci)
}

fn eval_with_derivative(c: &[f64], x: f64) -> (f64, f64) {
    let mut p = 0.0;
    let mut dp = 0.0;
    for &ci in c.iter().rev() {
        dp = dp * x + p;
        p = p * x + ci;
    }
    (p, dp)
}

/// A few Newton steps on `c` from `x`, each kept only if it lowers `|p(x)|`.
pub fn polish_root(c: &[f64], mut x: f64) -> f64 {
    for _ in 0..4 {
        let (p, dp) = eval_with_derivative(c, x);
        if p == 0.0 || dp == 0.0 || !dp.is_finite() {
            break;
        }
        let next = x - p / dp;
        if !next.is_finite() || eval(c, next).abs() >= p.abs() {
            break;
        }
        x = next;
    }
    x
}

/// Length of `c` after dropping leading coefficients that are negligible (`≤ 1e-14·max|cᵢ|`);
/// 0 when every coefficient vanishes.
fn effective_len(c: &[f64]) -> usize {
    let scale = c.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
    let mut len = c.len();
    while len > 0 && c[len - 1].abs() <= 1e-14 * scale {
        len -= 1;
    }
    len
}

/// Real roots of `c0 + c1 x + c2 x² + c3 x³` (closed form, then Newton polishing).
///
/// A negligible leading coefficient lowers the degree; the caller decides what a root at infinity
/// means. An identically zero polynomial has no roots reported. Double roots may be reported
/// twice or, when rounding makes the discriminant slightly positive, not at all.
pub fn real_roots_cubic(c: [f64; 4]) -> Vec<f64> {
    if c.iter().any(|v| !v.is_finite()) {
        return Vec::new();
    }
    let len = effective_len(&c);
    let mut roots = match len {
        0 | 1 => Vec::new(),
        2 => vec![-c[0] / c[1]],
        3 => real_roots_quadratic(c[0], c[1], c[2]),
        _ => {
            let (b, cc, d) = (c[2] / c[3], c[1] / c[3], c[0] / c[3]);
            // Depressed cubic t³ + p t + q with x = t − b/3.
            let p = cc - b * b / 3.0;
            let q = 2.0 * b * b * b / 27.0 - b * cc / 3.0 + d;
            let shift = -b / 3.0;
            let disc = (q / 2.0).powi(2) + (p / 3.0).powi(3);
            if disc > 0.0 {
                let sq = disc.sqrt();
                // Pick the sign that avoids cancellation, then use u·v = −p/3.
                let u = (-q / 2.0 - q.signum() * sq).cbrt();
                let t = if u != 0.0 { u - p / (3.0 * u) } else { 0.0 };
                vec![t + shift]
            } else if p == 0.0 {
                vec![shift]
            } else {
                let m = 2.0 * (-p / 3.0).sqrt();
                let arg = (3.0 * q / (p * m)).clamp(-1.0, 1.0);
                let theta = arg.acos() / 3.0;
                (0..3)
                    .map(|k| {
                        m * (theta - 2.0 * std::f64::consts::PI * k as f64 / 3.0).cos() + shift
                    })
                    .collect()
            }
        }
    };
    for r in &mut roots {
        *r = polish_root(&c[..len.max(1)], *r);
    }
    roots.retain(|r| r.is_finite());
    roots
}

/// Real roots of `c0 + c1 x + c2 x²` with the cancellation-free formula.
pub fn real_roots_quadratic(c0: f64, c1: f64, c2: f64) -> Vec<f64> {
    if c2 == 0.0 {
        return if c1 != 0.0 {
            vec![-c0 / c1]
        } else {
            Vec::new()
        };
    }
    let disc = c1 * c1 - 4.0 * c2 * c0;
    if disc < 0.0 {
        return Vec::new();
    }
    let q = -0.5 * (c1 + c1.signum() * disc.sqrt());
    if q == 0.0 {
        return vec![0.0, 0.0];
    }
    vec![q / c2, c0 / q]
}

/// All complex roots of a polynomial of any degree, as the eigenvalues of its balanced companion
/// matrix (the method of Matlab's `roots`). `None` when the coefficients are not finite or the
/// eigenvalue iteration does not converge; an empty vector for a constant polynomial.
pub fn roots(c: &[f64]) -> Option<Vec<Complex<f64>>> {
    if c.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let len = effective_len(c);
    if len <= 1 {
        return Some(Vec::new());
    }
    let n = len - 1;
    let lead = c[n];
    let mut m = DMatrix::<f64>::zeros(n, n);
    for i in 1..n {
        m[(i, i - 1)] = 1.0;
    }
    for i in 0..n {
        m[(i, n - 1)] = -c[i] / lead;
    }
    balance(&mut m);
    let schur = nalgebra::linalg::Schur::try_new(m, f64::EPSILON, 10_000)?;
    Some(schur.complex_eigenvalues().iter().copied().collect())
}

/// Parlett–Reinsch balancing by powers of two (similarity, so eigenvalues are unchanged).
fn balance(m: &mut DMatrix<f64>) {
    let n = m.nrows();
    for _ in 0..20 {
        let mut converged = true;
        for i in 0..n {
            let mut r = 0.0;
            let mut cn = 0.0;
            for j in 0..n {
                if j != i {
                    cn += m[(j, i)].abs();
                    r += m[(i, j)].abs();
                }
            }
            if cn == 0.0 || r == 0.0 {
                continue;
            }
            let s = cn + r;
            let mut f = 1.0;
            let (mut c2, r2) = (cn, r);
            while c2 < r2 / 2.0 {
                c2 *= 4.0;
                f *= 2.0;
            }
            while c2 > r2 * 2.0 {
                c2 /= 4.0;
                f /= 2.0;
            }
            if (cn * f + r / f) < 0.95 * s {
                converged = false;
                for j in 0..n {
                    m[(i, j)] /= f;
                    m[(j, i)] *= f;
                }
            }
        }
        if converged {
            break;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn from_roots(r: &[f64], lead: f64) -> Vec<f64> {
        let mut c = vec![lead];
        for &x in r {
            let mut next = vec![0.0; c.len() + 1];
            for (i, &ci) in c.iter().enumerate() {
                next[i + 1] += ci;
                next[i] -= x * ci;
            }
            c = next;
        }
        c
    }

    fn sorted(mut v: Vec<f64>) -> Vec<f64> {
        v.sort_by(|a, b| a.total_cmp(b));
        v
    }

    #[test]
    fn cubic_three_real_roots() {
        let c = from_roots(&[-2.0, 0.5, 3.0], 1.7);
        let r = sorted(real_roots_cubic([c[0], c[1], c[2], c[3]]));
        assert_eq!(r.len(), 3);
        for (a, b) in r.iter().zip([-2.0, 0.5, 3.0]) {
            assert!((a - b).abs() < 1e-12, "{r:?}");
        }
    }

    #[test]
    fn cubic_one_real_root_and_degree_drop() {
        // (x − 1.5)(x² + 1)
        let c = [-1.5, 1.0, -1.5, 1.0];
        let r = real_roots_cubic(c);
        assert_eq!(r.len(), 1);
        assert!((r[0] - 1.5).abs() < 1e-12);
        // Leading coefficient zero: a quadratic with roots 1 and 2.
        let r = sorted(real_roots_cubic([2.0, -3.0, 1.0, 0.0]));
        assert_eq!(r.len(), 2);
        assert!((r[0] - 1.0).abs() < 1e-12 && (r[1] - 2.0).abs() < 1e-12);
        assert!(real_roots_cubic([0.0; 4]).is_empty());
        assert!(real_roots_cubic([f64::NAN, 1.0, 0.0, 1.0]).is_empty());
    }

    #[test]
    fn cubic_wide_dynamic_range() {
        let c = from_roots(&[1e-4, 1.0, 1e4], 1.0);
        let r = sorted(real_roots_cubic([c[0], c[1], c[2], c[3]]));
        assert_eq!(r.len(), 3);
        for (a, b) in r.iter().zip([1e-4, 1.0, 1e4]) {
            assert!(((a - b) / b).abs() < 1e-9, "{r:?}");
        }
    }

    #[test]
    fn sextic_roots_by_companion_matrix() {
        let truth = [-3.0, -1.0, 0.25, 2.0, 5.0, 40.0];
        let c = from_roots(&truth, -0.3);
        let r = roots(&c).expect("converges");
        assert_eq!(r.len(), 6);
        let re = sorted(r.iter().map(|z| polish_root(&c, z.re)).collect());
        for (a, b) in re.iter().zip(truth) {
            assert!((a - b).abs() < 1e-9 * b.abs().max(1.0), "{re:?}");
        }
        assert!(roots(&[1.0]).expect("constant").is_empty());
        assert!(roots(&[f64::INFINITY, 1.0]).is_none());
    }
}
