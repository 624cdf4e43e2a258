//! How well a fundamental matrix fixes each epipolar line: first-order covariance propagation
//! (H&Z §5.2, "Transformation of covariance matrix", applied to `F` as in §11.4's covariance of the
//! epipolar lines), from `F`'s covariance under the Sampson residuals of its inliers.
//!
//! `F` is estimated from the matches it explains, so it is known well where they are and poorly
//! where they are not (far from them, or across a part of the scene they do not sample). A guided
//! search along an epipolar line that is itself a few pixels off accepts whatever lies on the
//! wrong line. [`EpipolarUncertainty::line_sigma`] says, for a point and a candidate match, how far
//! the true line may be from the estimated one there.
//!
//! Everything is computed on Hartley-normalised points (`normalize.rs`): `F` scaled to unit
//! Frobenius norm has 7 degrees of freedom, the 9 entries less its scale and the `det F = 0`
//! constraint, so its covariance is the pseudo-inverse of the normal matrix on the 7-dimensional
//! tangent space orthogonal to `vec F` and to `vec cof F` (the gradient of `det F`).

use nalgebra::{Matrix3, SMatrix, SVector, Vector2, Vector3};

use crate::error::{GeometryError, Result};
use crate::normalize::hartley_normalization;

type Mat9 = SMatrix<f64, 9, 9>;
type Vec9 = SVector<f64, 9>;

/// `F`'s covariance and what is needed to evaluate the spread of its epipolar lines.
#[derive(Clone, Debug)]
pub struct EpipolarUncertainty {
    t1: Matrix3<f64>,
    t2: Matrix3<f64>,
    /// `F` in normalised coordinates, unit Frobenius norm.
    f: Matrix3<f64>,
    /// Covariance of `vec F` (row-major), normalised coordinates.
    cov: Mat9,
}

/// `∂(x₂ᵀ F x₁)/∂F`, row-major.
fn outer(p1: &Vector3<f64>, p2: &Vector3<f64>) -> Vec9 {
    Vec9::from_fn(|k, _| p2[k / 3] * p1[k % 3])
}

fn vec9(m: &Matrix3<f64>) -> Vec9 {
    Vec9::from_fn(|k, _| m[(k / 3, k % 3)])
}

impl EpipolarUncertainty {
    /// From `F` (`x₂ᵀ F x₁ = 0`, pixels) and the matches it was estimated from. The residual
    /// variance is estimated from the matches (`N − 7` degrees of freedom).
    ///
    /// Errors: fewer than 9 matches, or degenerate points.
    pub fn new(f: &Matrix3<f64>, x1: &[Vector2<f64>], x2: &[Vector2<f64>]) -> Result<Self> {
        let n = x1.len().min(x2.len());
        if n < 9 {
            return Err(GeometryError::InsufficientCorrespondences {
                required: 9,
                actual: n,
            });
        }
        let (n1, n2) = (
            hartley_normalization(&x1[..n])?,
            hartley_normalization(&x2[..n])?,
        );
        let (t1, t2) = (n1.t, n2.t);
        let (Some(t1i), Some(t2i)) = (t1.try_inverse(), t2.try_inverse()) else {
            return Err(GeometryError::Degenerate {
                reason: "singular normalisation",
            });
        };
        let mut fnorm = t2i.transpose() * f * t1i;
        let scale = fnorm.norm();
        if !(scale.is_finite() && scale > 0.0) {
            return Err(GeometryError::NonFinite);
        }
        fnorm /= scale;
        let mut normal = Mat9::zeros();
        let mut rss = 0.0;
        for (a, b) in n1.points.iter().zip(&n2.points) {
            let (p1, p2) = (Vector3::new(a.x, a.y, 1.0), Vector3::new(b.x, b.y, 1.0));
            let (l2, l1) = (fnorm * p1, fnorm.transpose() * p2);
            let d = (l2.x * l2.x + l2.y * l2.y + l1.x * l1.x + l1.y * l1.y).sqrt();
            if d.is_nan() || d <= 0.0 {
                continue;
            }
            let g = outer(&p1, &p2) / d;
            rss += (p2.dot(&l2) / d).powi(2);
            normal += g * g.transpose();
        }
        let sigma2 = rss / (n - 7) as f64;
        // The tangent space: orthogonal to F's scale and to the gradient of det F.
        let r = |i: usize| -> Vector3<f64> { fnorm.row(i).transpose() };
        let cof = Matrix3::from_rows(&[
            r(1).cross(&r(2)).transpose(),
            r(2).cross(&r(0)).transpose(),
            r(0).cross(&r(1)).transpose(),
        ]);
        let mut basis = [vec9(&fnorm), vec9(&cof)];
        basis[0].normalize_mut();
        let c = basis[1] - basis[0] * basis[0].dot(&basis[1]);
        let cn = c.norm();
        let mut projector = Mat9::identity() - basis[0] * basis[0].transpose();
        if cn > 1e-12 {
            basis[1] = c / cn;
            projector -= basis[1] * basis[1].transpose();
        }
        let m = projector * normal * projector;
        let svd = m.symmetric_eigen();
        let top = svd.eigenvalues.max();
        if !(top.is_finite() && top > 0.0) {
            return Err(GeometryError::Degenerate {
                reason: "no information on F",
            });
        }
        // The 7 largest eigenvalues carry the information; the 2 constrained directions are ~0.
        let mut order: Vec<usize> = (0..9).collect();
        order.sort_by(|&i, &j| svd.eigenvalues[j].total_cmp(&svd.eigenvalues[i]));
        let mut cov = Mat9::zeros();
        for &k in &order[..7] {
            let e = svd.eigenvalues[k];
            if e > top * 1e-14 {
                let v = svd.eigenvectors.column(k);
                cov += v * v.transpose() * (sigma2 / e);
            }
        }
        Ok(Self {
            t1,
            t2,
            f: fnorm,
            cov,
        })
    }

    /// Standard deviation, in pixels of image 2, of the distance of `x2` from the epipolar line of
    /// `x1` (first order, for `x2` near the line).
    pub fn line_sigma(&self, x1: &Vector2<f64>, x2: &Vector2<f64>) -> f64 {
        self.line(x1).sigma(x2)
    }

    /// The epipolar line of `x1` with its uncertainty, for evaluating [`LineUncertainty::sigma`]
    /// at many points of image 2 cheaply.
    pub fn line(&self, x1: &Vector2<f64>) -> LineUncertainty {
        let p1 = self.t1 * Vector3::new(x1.x, x1.y, 1.0);
        let l = self.f * p1;
        let n2 = l.x * l.x + l.y * l.y;
        // var(p₂) = Σ_{ikjl} cov[(i,k),(j,l)] p₁ₖ p₁ₗ p₂ᵢ p₂ⱼ / n²: a quadratic form in p₂.
        let mut m = Matrix3::zeros();
        for i in 0..3 {
            for j in 0..3 {
                let mut acc = 0.0;
                for k in 0..3 {
                    for q in 0..3 {
                        acc += self.cov[(3 * i + k, 3 * j + q)] * p1[k] * p1[q];
                    }
                }
                m[(i, j)] = acc;
            }
        }
        LineUncertainty {
            m: if n2 > 0.0 { m / n2 } else { m * f64::INFINITY },
            t2: self.t2,
        }
    }
}

/// One epipolar line's positional uncertainty as a quadratic form over image 2 (see
/// [`EpipolarUncertainty::line`]).
#[derive(Clone, Copy, Debug)]
pub struct LineUncertainty {
    m: Matrix3<f64>,
    t2: Matrix3<f64>,
}

impl LineUncertainty {
    /// Standard deviation, in pixels of image 2, of the line's distance from `x2`.
    pub fn sigma(&self, x2: &Vector2<f64>) -> f64 {
        let p2 = self.t2 * Vector3::new(x2.x, x2.y, 1.0);
        let var = p2.dot(&(self.m * p2)).max(0.0);
        let s = var.sqrt() / self.t2[(0, 0)];
        if s.is_nan() {
            f64::INFINITY
        } else {
            s
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Rotation3;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The estimated F, the matches, and the true F.
    type Pair = (
        Matrix3<f64>,
        Vec<Vector2<f64>>,
        Vec<Vector2<f64>>,
        Matrix3<f64>,
    );

    /// Two cameras 1000 px focal, 640×480, the second moved sideways and turned 5°; points in a
    /// box; matches with 0.3 px noise, only from the top-left corner of image 1 when `half`.
    fn setup(half: bool, seed: u64) -> Pair {
        let k = Matrix3::new(1000.0, 0.0, 320.0, 0.0, 1000.0, 240.0, 0.0, 0.0, 1.0);
        let r = Rotation3::from_euler_angles(0.02, 0.087, 0.01).into_inner();
        let t = Vector3::new(-1.0, 0.1, 0.05);
        let tx = crate::skew(&t);
        let ki = k.try_inverse().unwrap();
        let f_true = ki.transpose() * tx * r * ki;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let (mut x1, mut x2) = (Vec::new(), Vec::new());
        while x1.len() < 300 {
            let p = Vector3::new(
                rng.random_range(-3.0..3.0),
                rng.random_range(-2.0..2.0),
                rng.random_range(8.0..12.0),
            );
            let a = k * p;
            let b = k * (r * p + t);
            let (a, b) = (a.xy() / a.z, b.xy() / b.z);
            let inside = |q: &Vector2<f64>| q.x >= 0.0 && q.x < 640.0 && q.y >= 0.0 && q.y < 480.0;
            if !inside(&a) || !inside(&b) || (half && (a.x > 200.0 || a.y > 160.0)) {
                continue;
            }
            let mut noise =
                || Vector2::new(rng.random_range(-0.5..0.5), rng.random_range(-0.5..0.5));
            x1.push(a + noise());
            x2.push(b + noise());
        }
        let est = crate::fundamental_8point(&x1, &x2).unwrap();
        (est, x1, x2, f_true)
    }

    /// The estimated line's distance from a point on the true line (the one nearest the image
    /// same position in image 2), and that point.
    fn line_error(
        f: &Matrix3<f64>,
        truth: &Matrix3<f64>,
        x1: &Vector2<f64>,
    ) -> (f64, Vector2<f64>) {
        let p1 = Vector3::new(x1.x, x1.y, 1.0);
        let lt = truth * p1;
        let nt = Vector2::new(lt.x, lt.y).norm();
        let c = *x1;
        let foot = c - Vector2::new(lt.x, lt.y) / nt * ((lt.x * c.x + lt.y * c.y + lt.z) / nt);
        let le = f * p1;
        let d = (le.x * foot.x + le.y * foot.y + le.z) / (le.x * le.x + le.y * le.y).sqrt();
        (d, foot)
    }

    #[test]
    fn the_predicted_spread_of_the_lines_matches_their_actual_error() {
        // Over many seeds, the true line's distance from the estimated one, divided by the
        // predicted σ, has unit RMS, where the matches are and far from them.
        let mut mean_sigma = [0.0; 2];
        for (h, half) in [false, true].into_iter().enumerate() {
            let mut z2 = Vec::new();
            let mut sig = Vec::new();
            for seed in 0..40 {
                let (est, x1, x2, truth) = setup(half, seed);
                let u = EpipolarUncertainty::new(&est, &x1, &x2).unwrap();
                let q = Vector2::new(600.0, 400.0);
                let (d, foot) = line_error(&est, &truth, &q);
                let s = u.line_sigma(&q, &foot);
                z2.push((d / s).powi(2));
                sig.push(s);
            }
            let rms = (z2.iter().sum::<f64>() / z2.len() as f64).sqrt();
            assert!(
                (0.6..1.6).contains(&rms),
                "half {half}: normalised RMS {rms}"
            );
            mean_sigma[h] = sig.iter().sum::<f64>() / sig.len() as f64;
        }
        // Far from every match (they are all in the top-left corner of image 1) the line is known
        // several times worse than where matches are.
        assert!(
            mean_sigma[1] > 3.0 * mean_sigma[0],
            "σ with matches everywhere {}, with matches in a corner only {}",
            mean_sigma[0],
            mean_sigma[1]
        );
    }

    #[test]
    fn a_lines_sigma_is_largest_at_a_corner_of_a_box() {
        // Guided matching bounds every keypoint's σ by the largest at the corners of their
        // extent: σ is the norm of an affine function of the position, so convex.
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for (seed, half) in [(0, false), (1, true), (2, true)] {
            let (est, x1, x2, _) = setup(half, seed);
            let u = EpipolarUncertainty::new(&est, &x1, &x2).unwrap();
            for q in [Vector2::new(600.0, 400.0), Vector2::new(20.0, 30.0)] {
                let line = u.line(&q);
                let (lo, hi) = (Vector2::new(40.0, 10.0), Vector2::new(610.0, 470.0));
                let corners = [lo, Vector2::new(hi.x, lo.y), Vector2::new(lo.x, hi.y), hi];
                let top = corners.iter().map(|c| line.sigma(c)).fold(0.0, f64::max);
                for _ in 0..2000 {
                    let p =
                        Vector2::new(rng.random_range(lo.x..hi.x), rng.random_range(lo.y..hi.y));
                    assert!(
                        line.sigma(&p) <= top * (1.0 + 1e-9),
                        "{p:?}: {} > {top}",
                        line.sigma(&p)
                    );
                }
            }
        }
    }
}
