//! The plane-induced homography `x2 ~ H x1` (§3.1, eqs. 14–15 use it to measure the distance between
//! views; GRIC key-frame selection compares it with F). Normalised DLT of H&Z alg. 4.2 and the
//! transfer errors of H&Z §4.2.2.

use nalgebra::{DMatrix, Matrix3, Vector2, Vector3};

use crate::error::{check_pair_lengths, GeometryError, Result};
use crate::linalg::{
    full_right_svd, normal_equations_null_vector, null_space_short, row_to_matrix3,
};
use crate::normalize::hartley_normalization;

/// Relative size below which a singular value counts as zero.
const RANK_TOL: f64 = 1e-10;

/// The two rows of H&Z eq. 4.3 for one correspondence `p ↔ q`: `[0ᵀ, −xᵀ, y'·xᵀ]` and
/// `[xᵀ, 0ᵀ, −x'·xᵀ]`, `h` read row-major.
fn dlt_rows(p: &Vector2<f64>, q: &Vector2<f64>) -> ([f64; 9], [f64; 9]) {
    let xh = [p.x, p.y, 1.0];
    let mut r1 = [0.0; 9];
    let mut r2 = [0.0; 9];
    for k in 0..3 {
        r1[3 + k] = -xh[k];
        r1[6 + k] = q.y * xh[k];
        r2[k] = xh[k];
        r2[6 + k] = -q.x * xh[k];
    }
    (r1, r2)
}

/// The normalised DLT (H&Z alg. 4.2, the 2-row form of eq. 4.3): exact for 4 correspondences,
/// least squares (algebraic error) for more. Returned with unit Frobenius norm.
///
/// Errors: fewer than 4 matches, mismatched lengths, non-finite input, a rank-deficient design
/// matrix (three of four points collinear, all points collinear) or a singular result (points
/// collinear in one image only).
pub fn homography_dlt(x1: &[Vector2<f64>], x2: &[Vector2<f64>]) -> Result<Matrix3<f64>> {
    check_pair_lengths(x1, x2, 4)?;
    let (n1, n2) = (hartley_normalization(x1)?, hartley_normalization(x2)?);
    let n = x1.len();
    let rows = || {
        n1.points.iter().zip(&n2.points).flat_map(|(p, q)| {
            let (r1, r2) = dlt_rows(p, q);
            [r1, r2]
        })
    };
    let h_hat = if n == 4 {
        // The minimal case (every RANSAC sample): the exact null vector by elimination.
        let rows: Vec<[f64; 9]> = rows().collect();
        let (null, ratio) = null_space_short(&rows).ok_or(GeometryError::NonFinite)?;
        if ratio <= RANK_TOL || null.len() != 1 {
            return Err(GeometryError::Degenerate {
                reason: "homography design matrix has rank < 8",
            });
        }
        Matrix3::from_fn(|i, j| null[0][3 * i + j])
    } else if let Some(v) = normal_equations_null_vector(rows()) {
        // The normal equations (see `linalg`): an LO-RANSAC refit's DLT over hundreds of inliers
        // was a Householder bidiagonalisation of its `2n × 9` matrix.
        Matrix3::from_fn(|i, j| v[3 * i + j])
    } else {
        let a = DMatrix::from_row_iterator(2 * n, 9, rows().flatten());
        let (sv, v_t) = full_right_svd(a).ok_or(GeometryError::NonFinite)?;
        if sv[7] <= RANK_TOL * sv[0] {
            return Err(GeometryError::Degenerate {
                reason: "homography design matrix has rank < 8",
            });
        }
        row_to_matrix3(&v_t, 8)
    };
    let hs = h_hat.singular_values();
    if hs[2] <= 1e-8 * hs[0] {
        return Err(GeometryError::Degenerate {
            reason: "homography is singular",
        });
    }
    let t2_inv = n2.t.try_inverse().ok_or(GeometryError::Degenerate {
        reason: "normalisation not invertible",
    })?;
    let h = t2_inv * h_hat * n1.t;
    let norm = h.norm();
    if !(norm.is_finite() && norm > 0.0) {
        return Err(GeometryError::Degenerate {
            reason: "homography vanished",
        });
    }
    Ok(h / norm)
}

/// One-sided transfer error `d(x2, H x1)²` in pixels² (H&Z eq. 4.6); infinite when `H x1` is at
/// infinity.
pub fn transfer_error_sq(h: &Matrix3<f64>, x1: &Vector2<f64>, x2: &Vector2<f64>) -> f64 {
    let m = h * Vector3::new(x1.x, x1.y, 1.0);
    if m.z == 0.0 {
        return f64::INFINITY;
    }
    (m.xy() / m.z - x2).norm_squared()
}

/// Symmetric transfer error `d(x2, H x1)² + d(x1, H⁻¹ x2)²` in pixels² (H&Z eq. 4.7). The caller
/// passes `H⁻¹` so that it is inverted once per model rather than once per point.
pub fn symmetric_transfer_error_sq(
    h: &Matrix3<f64>,
    h_inv: &Matrix3<f64>,
    x1: &Vector2<f64>,
    x2: &Vector2<f64>,
) -> f64 {
    transfer_error_sq(h, x1, x2) + transfer_error_sq(h_inv, x2, x1)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::*;
    use rand::Rng;

    fn true_h() -> Matrix3<f64> {
        Matrix3::new(0.9, 0.05, 30.0, -0.08, 1.1, -12.0, 2e-4, -1e-4, 1.0)
    }

    fn planar_matches(seed: u64, n: usize) -> (Vec<Vector2<f64>>, Vec<Vector2<f64>>) {
        let mut r = rng(seed);
        let h = true_h();
        let x1: Vec<_> = (0..n)
            .map(|_| Vector2::new(r.random_range(0.0..640.0), r.random_range(0.0..480.0)))
            .collect();
        let x2 = x1.iter().map(|p| {
            let m = h * hom(p);
            m.xy() / m.z
        });
        let x2 = x2.collect();
        (x1, x2)
    }

    #[test]
    fn dlt_by_normal_equations_equals_the_svd_fit() {
        let mut r = rng(11);
        for (seed, n, sigma) in [(0, 5, 0.5), (1, 9, 3.0), (2, 60, 1.0), (3, 2000, 0.5)] {
            let (x1, x2) = planar_matches(100 + seed, n);
            let x2 = add_noise(&mut r, &x2, sigma);
            let (n1, n2) = (
                hartley_normalization(&x1).expect("spread"),
                hartley_normalization(&x2).expect("spread"),
            );
            let rows = n1.points.iter().zip(&n2.points).flat_map(|(p, q)| {
                let (r1, r2) = dlt_rows(p, q);
                r1.into_iter().chain(r2)
            });
            let a = DMatrix::from_row_iterator(2 * n, 9, rows);
            let (_, v_t) = full_right_svd(a).expect("finite");
            let t2_inv = n2.t.try_inverse().expect("invertible");
            let by_svd = t2_inv * row_to_matrix3(&v_t, 8) * n1.t;
            let h = homography_dlt(&x1, &x2).expect("general position");
            let err = equal_up_to_scale(&h, &by_svd);
            assert!(err < 1e-9, "seed {seed} n {n}: {err:e}");
        }
    }

    #[test]
    fn dlt_recovers_true_h() {
        for n in [4, 5, 50] {
            let (x1, x2) = planar_matches(n as u64, n);
            let h = homography_dlt(&x1, &x2).expect("general position");
            assert!(equal_up_to_scale(&h, &true_h()) < 1e-10, "n = {n}");
            let h_inv = h.try_inverse().expect("invertible");
            for (a, b) in x1.iter().zip(&x2) {
                assert!(symmetric_transfer_error_sq(&h, &h_inv, a, b) < 1e-16);
            }
        }
    }

    #[test]
    fn dlt_recovers_plane_induced_h_of_two_cameras() {
        // H = K2 (R − t nᵀ/d) K1⁻¹ for the plane z = 5: build it from projections instead.
        let tv = two_view(4, 4);
        let mut r = rng(4);
        let pts: Vec<_> = (0..30)
            .map(|_| {
                nalgebra::Point3::new(r.random_range(-1.0..1.0), r.random_range(-1.0..1.0), 5.0)
            })
            .collect();
        let x1: Vec<_> = pts.iter().map(|p| project(&tv.p1, p)).collect();
        let x2: Vec<_> = pts.iter().map(|p| project(&tv.p2, p)).collect();
        let h4 = homography_dlt(&x1[..4], &x2[..4]).expect("4 points");
        let hn = homography_dlt(&x1, &x2).expect("30 points");
        assert!(equal_up_to_scale(&h4, &hn) < 1e-9);
        for (a, b) in x1.iter().zip(&x2) {
            assert!(transfer_error_sq(&h4, a, b) < 1e-14);
        }
    }

    #[test]
    fn noisy_least_squares_is_close() {
        let (x1, x2) = planar_matches(8, 200);
        let mut r = rng(80);
        let x2n = add_noise(&mut r, &x2, 0.5);
        let h = homography_dlt(&x1, &x2n).expect("general position");
        let rms = (x1
            .iter()
            .zip(&x2)
            .map(|(a, b)| transfer_error_sq(&h, a, b))
            .sum::<f64>()
            / 200.0)
            .sqrt();
        assert!(rms < 0.2, "transfer RMS to the noise-free points {rms}");
    }

    #[test]
    fn degenerate_inputs_are_errors() {
        let (x1, x2) = planar_matches(3, 10);
        assert!(matches!(
            homography_dlt(&x1[..3], &x2[..3]),
            Err(GeometryError::InsufficientCorrespondences { .. })
        ));
        assert!(matches!(
            homography_dlt(&x1[..5], &x2[..4]),
            Err(GeometryError::LengthMismatch { .. })
        ));
        // Three of the four points collinear in both images.
        let mut c1 = x1[..4].to_vec();
        c1[2] = (c1[0] + c1[1]) * 0.5;
        let c2: Vec<_> = c1
            .iter()
            .map(|p| {
                let m = true_h() * hom(p);
                m.xy() / m.z
            })
            .collect();
        assert!(homography_dlt(&c1, &c2).is_err());
        // Collinear in the first image only.
        assert!(homography_dlt(&c1, &x2[..4]).is_err());
        let line: Vec<_> = (0..8)
            .map(|i| Vector2::new(i as f64, 2.0 * i as f64))
            .collect();
        assert!(homography_dlt(&line, &x2[..8]).is_err());
        let same = vec![Vector2::new(1.0, 1.0); 4];
        assert!(homography_dlt(&same, &x2[..4]).is_err());
    }
}
