//! The fundamental matrix of §2.2: `m2ᵀ F m1 = 0` (eq. 11) from 7 or ≥ 8 correspondences, the two
//! error measures used to score it (eq. 12 and Sampson's first-order geometric error), and the
//! epipoles. The solvers follow H&Z §11.1–11.2 on Hartley-normalised points; `F` is returned with
//! unit Frobenius norm, sign unspecified.

use handheld_core::ProjectiveCamera;
use nalgebra::{DMatrix, Matrix3, Matrix3x4, Vector2, Vector3, Vector4};

use crate::error::{check_pair_lengths, GeometryError, Result};
use crate::linalg::{
    full_right_svd, normal_equations_null_vector, null_space_short, row_to_matrix3,
};
use crate::normalize::hartley_normalization;
use crate::poly::real_roots_cubic;
use crate::skew::skew;

/// Relative size below which a singular value counts as zero when checking for degeneracy.
const RANK_TOL: f64 = 1e-10;

/// One row of the design matrix below.
fn design_row(a: &Vector2<f64>, b: &Vector2<f64>) -> [f64; 9] {
    [
        b.x * a.x,
        b.x * a.y,
        b.x,
        b.y * a.x,
        b.y * a.y,
        b.y,
        a.x,
        a.y,
        1.0,
    ]
}

/// Design matrix of `x2ᵀ F x1 = 0` with `f` read row-major (H&Z eq. 11.3).
fn design_matrix(x1: &[Vector2<f64>], x2: &[Vector2<f64>]) -> DMatrix<f64> {
    DMatrix::from_fn(x1.len(), 9, |r, c| {
        let (a, b) = (x1[r], x2[r]);
        let u = [b.x, b.y, 1.0][c / 3];
        let v = [a.x, a.y, 1.0][c % 3];
        u * v
    })
}

/// The least-squares null vector of the 8-point design matrix, read row-major as `F̂`, from the
/// normal equations ([`normal_equations_null_vector`]): 45 multiply-adds a match instead of a
/// Householder bidiagonalisation of the `n × 9` matrix, which was 5 % of kitti-seq1's matching
/// stage (issue #34). `None` where the SVD must decide.
fn normal_equations_fit(x1: &[Vector2<f64>], x2: &[Vector2<f64>]) -> Option<Matrix3<f64>> {
    let v = normal_equations_null_vector(x1.iter().zip(x2).map(|(a, b)| design_row(a, b)))?;
    Some(Matrix3::from_fn(|i, j| v[3 * i + j]))
}

/// Projects `F` onto the rank-2 matrices closest in Frobenius norm (H&Z §11.1.1).
pub fn enforce_rank2(f: &Matrix3<f64>) -> Matrix3<f64> {
    let svd = f.svd(true, true);
    match (svd.u, svd.v_t) {
        (Some(u), Some(v_t)) => {
            let mut s = svd.singular_values;
            s[2] = 0.0;
            u * Matrix3::from_diagonal(&s) * v_t
        }
        _ => *f,
    }
}

fn unit(f: Matrix3<f64>) -> Result<Matrix3<f64>> {
    let n = f.norm();
    if !(n.is_finite() && n > 0.0) {
        return Err(GeometryError::Degenerate {
            reason: "fundamental matrix vanished",
        });
    }
    Ok(f / n)
}

/// The normalised 8-point algorithm (H&Z alg. 11.1): Hartley normalisation, the least-squares null
/// vector of the `n × 9` design matrix for `n ≥ 8`, rank-2 enforcement, denormalisation
/// `F = T2ᵀ F̂ T1`.
///
/// Errors: fewer than 8 matches, mismatched lengths, non-finite input, or a design matrix whose
/// null space is more than one-dimensional (e.g. a planar scene, collinear points).
pub fn fundamental_8point(x1: &[Vector2<f64>], x2: &[Vector2<f64>]) -> Result<Matrix3<f64>> {
    check_pair_lengths(x1, x2, 8)?;
    let (n1, n2) = (hartley_normalization(x1)?, hartley_normalization(x2)?);
    if let Some(f_hat) = normal_equations_fit(&n1.points, &n2.points) {
        return unit(n2.t.transpose() * enforce_rank2(&f_hat) * n1.t);
    }
    let (sv, v_t) =
        full_right_svd(design_matrix(&n1.points, &n2.points)).ok_or(GeometryError::NonFinite)?;
    if sv[7] <= RANK_TOL * sv[0] {
        return Err(GeometryError::Degenerate {
            reason: "8-point design matrix has rank < 8",
        });
    }
    let f_hat = enforce_rank2(&row_to_matrix3(&v_t, 8));
    unit(n2.t.transpose() * f_hat * n1.t)
}

/// The 7-point algorithm (H&Z §11.1.2; the minimal solver of Table 1, step 2.2): the two-dimensional
/// null space `{F1, F2}` of the 7 × 9 design matrix and the real roots of the cubic
/// `det(F1 + λ F2) = 0`, so 1 or 3 solutions, each of rank 2.
///
/// The pencil is parametrised from whichever basis matrix has the larger determinant, so the cubic's
/// leading coefficient never vanishes by accident; when both determinants vanish, both basis
/// matrices are returned as solutions. With 7 matches (every RANSAC sample) the null space is
/// exact and found by Gauss–Jordan elimination with complete pivoting (Golub & Van Loan §3.4.8,
/// as for the 4-point homography), a few hundred multiply-adds where the SVD of the padded 9 × 9
/// matrix cost half of a low-texture set's matching stage; with more, it is taken in the
/// least-squares sense by the SVD.
///
/// Errors: fewer than 7 matches, mismatched lengths, non-finite input, or a design matrix of rank
/// below 7 (coincident or collinear points).
pub fn fundamental_7point(x1: &[Vector2<f64>], x2: &[Vector2<f64>]) -> Result<Vec<Matrix3<f64>>> {
    check_pair_lengths(x1, x2, 7)?;
    let (n1, n2) = (hartley_normalization(x1)?, hartley_normalization(x2)?);
    let (mut g1, mut g2) = if x1.len() == 7 {
        // The minimal case (every RANSAC sample), on the stack, by elimination.
        let rows: Vec<[f64; 9]> = n1
            .points
            .iter()
            .zip(&n2.points)
            .map(|(a, b)| design_row(a, b))
            .collect();
        let (null, ratio) = null_space_short(&rows).ok_or(GeometryError::NonFinite)?;
        if ratio <= RANK_TOL || null.len() != 2 {
            return Err(GeometryError::Degenerate {
                reason: "7-point design matrix has rank < 7",
            });
        }
        let g = |v: &nalgebra::SVector<f64, 9>| Matrix3::from_fn(|i, j| v[3 * i + j]);
        (g(&null[0]), g(&null[1]))
    } else {
        let (sv, v_t) = full_right_svd(design_matrix(&n1.points, &n2.points))
            .ok_or(GeometryError::NonFinite)?;
        if sv[6] <= RANK_TOL * sv[0] {
            return Err(GeometryError::Degenerate {
                reason: "7-point design matrix has rank < 7",
            });
        }
        (row_to_matrix3(&v_t, 7), row_to_matrix3(&v_t, 8))
    };
    if g2.determinant().abs() < g1.determinant().abs() {
        std::mem::swap(&mut g1, &mut g2);
    }
    // det(G1 + λ G2) = a0 + a1 λ + a2 λ² + a3 λ³, interpolated from four evaluations.
    let d = |l: f64| (g1 + g2 * l).determinant();
    let (d0, d1, dm1, d2) = (d(0.0), d(1.0), d(-1.0), d(2.0));
    let a0 = d0;
    let a2 = 0.5 * (d1 + dm1) - a0;
    let s = 0.5 * (d1 - dm1); // a1 + a3
    let u = 0.5 * (d2 - a0 - 4.0 * a2); // a1 + 4 a3
    let a3 = (u - s) / 3.0;
    let a1 = s - a3;
    let coeffs = [a0, a1, a2, a3];
    let scale = coeffs.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
    let mut candidates: Vec<Matrix3<f64>> = real_roots_cubic(coeffs)
        .into_iter()
        .map(|l| g1 + g2 * l)
        .collect();
    if a3.abs() <= 1e-14 * scale {
        candidates.push(g2);
    }
    // Each candidate is singular already: a polished root of det(G1 + λ G2) = 0 (and G2 when the
    // cubic's leading coefficient vanishes), so no SVD projection per candidate.
    let back = |g: &Matrix3<f64>| unit(n2.t.transpose() * g * n1.t);
    Ok(candidates.iter().filter_map(|g| back(g).ok()).collect())
}

/// `(x2ᵀ F x1, F x1, Fᵀ x2)` for pixel points.
fn epipolar_terms(
    f: &Matrix3<f64>,
    x1: &Vector2<f64>,
    x2: &Vector2<f64>,
) -> (f64, Vector3<f64>, Vector3<f64>) {
    let h1 = Vector3::new(x1.x, x1.y, 1.0);
    let h2 = Vector3::new(x2.x, x2.y, 1.0);
    let fx1 = f * h1;
    let ftx2 = f.tr_mul(&h2);
    (h2.dot(&fx1), fx1, ftx2)
}

/// Squared Sampson distance (H&Z eq. 11.9), the first-order approximation of the squared geometric
/// error of eq. 13: `(x2ᵀFx1)² / ((Fx1)₁² + (Fx1)₂² + (Fᵀx2)₁² + (Fᵀx2)₂²)`, in pixels².
pub fn sampson_distance_sq(f: &Matrix3<f64>, x1: &Vector2<f64>, x2: &Vector2<f64>) -> f64 {
    let (e, fx1, ftx2) = epipolar_terms(f, x1, x2);
    let den = fx1.x * fx1.x + fx1.y * fx1.y + ftx2.x * ftx2.x + ftx2.y * ftx2.y;
    if den > 0.0 {
        e * e / den
    } else if e == 0.0 {
        0.0
    } else {
        f64::INFINITY
    }
}

/// Sampson distance in pixels (square root of [`sampson_distance_sq`]).
pub fn sampson_distance(f: &Matrix3<f64>, x1: &Vector2<f64>, x2: &Vector2<f64>) -> f64 {
    sampson_distance_sq(f, x1, x2).sqrt()
}

/// The summand of eq. 12, `d(x2, F x1)² + d(x1, Fᵀ x2)²`: squared distances of each point to the
/// epipolar line of the other (H&Z eq. 11.10), in pixels².
pub fn symmetric_epipolar_distance_sq(
    f: &Matrix3<f64>,
    x1: &Vector2<f64>,
    x2: &Vector2<f64>,
) -> f64 {
    let (e, fx1, ftx2) = epipolar_terms(f, x1, x2);
    let l2 = fx1.x * fx1.x + fx1.y * fx1.y;
    let l1 = ftx2.x * ftx2.x + ftx2.y * ftx2.y;
    if e == 0.0 {
        return 0.0;
    }
    if l1 <= 0.0 || l2 <= 0.0 {
        return f64::INFINITY;
    }
    e * e * (1.0 / l1 + 1.0 / l2)
}

/// The epipoles `(e1, e2)` with `F e1 = 0` and `Fᵀ e2 = 0` (H&Z result 9.13), unit-norm homogeneous
/// 3-vectors; `e2` is the paper's `e12` of eq. 16. Errors when `F` has rank below 2.
pub fn epipoles(f: &Matrix3<f64>) -> Result<(Vector3<f64>, Vector3<f64>)> {
    if f.iter().any(|v| !v.is_finite()) {
        return Err(GeometryError::NonFinite);
    }
    let svd = f.svd(true, true);
    let (u, v_t) = match (svd.u, svd.v_t) {
        (Some(u), Some(v_t)) => (u, v_t),
        _ => {
            return Err(GeometryError::Degenerate {
                reason: "SVD of F failed",
            })
        }
    };
    let s = svd.singular_values;
    if s[1] <= RANK_TOL * s[0] {
        return Err(GeometryError::Degenerate {
            reason: "F has rank below 2",
        });
    }
    let e1 = v_t.row(2).transpose();
    let e2 = u.column(2).into_owned();
    Ok((e1, e2))
}

/// `F = [e2]× P2 P1⁺` for two projective cameras, with `e2 = P2 C1` and `C1` the centre of the first
/// camera (H&Z eq. 9.1). Unit Frobenius norm. Errors when `P1` has rank below 3 or the centres
/// coincide.
pub fn fundamental_from_cameras(
    p1: &ProjectiveCamera,
    p2: &ProjectiveCamera,
) -> Result<Matrix3<f64>> {
    let (p1, p2): (Matrix3x4<f64>, Matrix3x4<f64>) = (p1.P, p2.P);
    if p1.iter().chain(p2.iter()).any(|v| !v.is_finite()) {
        return Err(GeometryError::NonFinite);
    }
    let (sv, v_t) = full_right_svd(DMatrix::from_fn(3, 4, |r, c| p1[(r, c)]))
        .ok_or(GeometryError::NonFinite)?;
    if sv[2] <= RANK_TOL * sv[0] {
        return Err(GeometryError::Degenerate {
            reason: "camera matrix has rank below 3",
        });
    }
    let c1 = Vector4::new(v_t[(3, 0)], v_t[(3, 1)], v_t[(3, 2)], v_t[(3, 3)]);
    let gram = (p1 * p1.transpose())
        .try_inverse()
        .ok_or(GeometryError::Degenerate {
            reason: "camera matrix has rank below 3",
        })?;
    let p1_pinv = p1.transpose() * gram;
    let e2 = p2 * c1;
    let f = skew(&e2) * p2 * p1_pinv;
    if f.norm() <= RANK_TOL * p2.norm() * p1_pinv.norm() {
        return Err(GeometryError::Degenerate {
            reason: "camera centres coincide",
        });
    }
    unit(f)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::*;

    fn truth(tv: &TwoView) -> Matrix3<f64> {
        fundamental_from_cameras(
            &ProjectiveCamera { P: tv.p1 },
            &ProjectiveCamera { P: tv.p2 },
        )
        .expect("distinct centres")
    }

    #[test]
    fn true_f_satisfies_epipolar_constraint() {
        let tv = two_view(1, 50);
        let f = truth(&tv);
        for (a, b) in tv.x1.iter().zip(&tv.x2) {
            assert!(sampson_distance(&f, a, b) < 1e-9);
            assert!(symmetric_epipolar_distance_sq(&f, a, b) < 1e-18);
        }
        let (e1, e2) = epipoles(&f).expect("rank 2");
        assert!((f * e1).norm() < 1e-12 && (f.transpose() * e2).norm() < 1e-12);
        // e1 is the image of the second centre in the first view.
        let m2 = tv.p2.fixed_view::<3, 3>(0, 0).into_owned();
        let c2 = -(m2.try_inverse().expect("finite camera") * tv.p2.column(3));
        let img = tv.p1 * c2.push(1.0);
        assert!(img.normalize().cross(&e1).norm() < 1e-9);
    }

    #[test]
    fn eight_point_recovers_f_exactly() {
        for seed in 0..5 {
            for n in [8, 9, 30, 200] {
                let tv = two_view(seed, n);
                let f = fundamental_8point(&tv.x1, &tv.x2).expect("general position");
                let err = equal_up_to_scale(&f, &truth(&tv));
                assert!(err < 1e-8, "seed {seed} n {n}: {err:e}");
                assert!(f.determinant().abs() < 1e-12);
                for (a, b) in tv.x1.iter().zip(&tv.x2) {
                    assert!(hom(b).dot(&(f * hom(a))).abs() < 1e-8);
                }
            }
        }
    }

    /// The normal equations' eigenvector is the design matrix's last right singular vector: on
    /// noisy matches (σ 0.5 and 3 px, 8 to 2 000 of them) the two fits agree to 10⁻⁹.
    #[test]
    fn eight_point_by_normal_equations_equals_the_svd_fit() {
        let mut r = rng(5);
        for (seed, n, sigma) in [(0, 8, 0.5), (1, 9, 0.5), (2, 60, 3.0), (3, 2000, 0.5)] {
            let tv = two_view(seed, n);
            let x1 = add_noise(&mut r, &tv.x1, sigma);
            let x2 = add_noise(&mut r, &tv.x2, sigma);
            let (n1, n2) = (
                hartley_normalization(&x1).expect("spread"),
                hartley_normalization(&x2).expect("spread"),
            );
            let (_, v_t) = full_right_svd(design_matrix(&n1.points, &n2.points)).expect("finite");
            let by_svd =
                unit(n2.t.transpose() * enforce_rank2(&row_to_matrix3(&v_t, 8)) * n1.t).expect("F");
            let f = fundamental_8point(&x1, &x2).expect("general position");
            let err = equal_up_to_scale(&f, &by_svd);
            assert!(err < 1e-9, "seed {seed} n {n}: {err:e}");
        }
    }

    #[test]
    fn eight_point_with_noise_has_sampson_rms_near_noise() {
        let tv = two_view(3, 300);
        let mut r = rng(77);
        let sigma = 0.5;
        let x1 = add_noise(&mut r, &tv.x1, sigma);
        let x2 = add_noise(&mut r, &tv.x2, sigma);
        let f = fundamental_8point(&x1, &x2).expect("general position");
        let rms = (x1
            .iter()
            .zip(&x2)
            .map(|(a, b)| sampson_distance_sq(&f, a, b))
            .sum::<f64>()
            / 300.0)
            .sqrt();
        // The residual of a fitted model is slightly below σ; the algebraic fit slightly above.
        assert!(rms > 0.35 && rms < 0.65, "Sampson RMS {rms}");
        let rms_true = (x1
            .iter()
            .zip(&x2)
            .map(|(a, b)| sampson_distance_sq(&truth(&tv), a, b))
            .sum::<f64>()
            / 300.0)
            .sqrt();
        assert!(rms <= rms_true * 1.05, "fit {rms} vs truth {rms_true}");
        eprintln!(
            "8-point, σ = 0.5 px, 300 matches: Sampson RMS {rms:.4} px (true F: {rms_true:.4} px)"
        );
    }

    #[test]
    fn seven_point_contains_the_truth() {
        for seed in 0..20 {
            let tv = two_view(100 + seed, 7);
            let sols = fundamental_7point(&tv.x1, &tv.x2).expect("general position");
            assert!(
                sols.len() == 1 || sols.len() == 3,
                "{} solutions",
                sols.len()
            );
            let best = sols
                .iter()
                .map(|f| equal_up_to_scale(f, &truth(&tv)))
                .fold(f64::INFINITY, f64::min);
            assert!(best < 1e-8, "seed {seed}: {best:e}");
            for f in &sols {
                assert!(f.determinant().abs() < 1e-10);
                for (a, b) in tv.x1.iter().zip(&tv.x2) {
                    assert!(sampson_distance(f, a, b) < 1e-6);
                }
            }
        }
    }

    #[test]
    fn degenerate_inputs_are_errors() {
        let tv = two_view(5, 20);
        assert!(matches!(
            fundamental_8point(&tv.x1[..7], &tv.x2[..7]),
            Err(GeometryError::InsufficientCorrespondences {
                required: 8,
                actual: 7
            })
        ));
        assert!(matches!(
            fundamental_7point(&tv.x1[..6], &tv.x2[..6]),
            Err(GeometryError::InsufficientCorrespondences { .. })
        ));
        assert!(matches!(
            fundamental_8point(&tv.x1[..9], &tv.x2[..8]),
            Err(GeometryError::LengthMismatch { .. })
        ));
        // Collinear points in both images.
        let line1: Vec<_> = (0..10)
            .map(|i| Vector2::new(10.0 * i as f64, 5.0 * i as f64 + 3.0))
            .collect();
        let line2: Vec<_> = (0..10)
            .map(|i| Vector2::new(7.0 * i as f64 + 1.0, -2.0 * i as f64 + 90.0))
            .collect();
        assert!(fundamental_8point(&line1, &line2).is_err());
        assert!(fundamental_7point(&line1[..7], &line2[..7]).is_err());
        // Coincident points.
        let same = vec![Vector2::new(1.0, 2.0); 8];
        assert!(fundamental_8point(&same, &tv.x2[..8]).is_err());
        let mut nan = tv.x1[..8].to_vec();
        nan[3].x = f64::NAN;
        assert!(fundamental_8point(&nan, &tv.x2[..8]).is_err());
        assert!(epipoles(&Matrix3::zeros()).is_err());
    }

    #[test]
    fn planar_scene_is_degenerate_for_eight_point() {
        // Points on a plane induce a homography: the F null space is 3-dimensional (H&Z §11.9).
        let tv = two_view(9, 4);
        let mut r = rng(9);
        let mut x1 = Vec::new();
        let mut x2 = Vec::new();
        for _ in 0..20 {
            use rand::Rng;
            let p =
                nalgebra::Point3::new(r.random_range(-1.0..1.0), r.random_range(-1.0..1.0), 5.0);
            x1.push(project(&tv.p1, &p));
            x2.push(project(&tv.p2, &p));
        }
        assert!(matches!(
            fundamental_8point(&x1, &x2),
            Err(GeometryError::Degenerate { .. })
        ));
    }
}
