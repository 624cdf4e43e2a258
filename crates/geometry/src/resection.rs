//! Projective resection of §3.2 ("Updating the Structure and Motion"): the camera `P` from 2D–3D
//! correspondences by the direct linear transform (H&Z alg. 7.1), six points being the minimal case
//! (11 degrees of freedom, two equations per point), and the iterated weighted refinement that
//! approximates the reprojection error the same way eq. 20 does for points.
//!
//! Both point sets are conditioned first (Hartley normalisation): the image points isotropically to
//! mean distance √2, the finite 3D points isotropically to mean distance √3 (H&Z §7.1).

use nalgebra::{Matrix3, Matrix3x4, Matrix4, SMatrix, SymmetricEigen, Vector2, Vector3, Vector4};

use crate::error::{GeometryError, Result};
use crate::normalize::hartley_normalization;

/// `U` with `U M` centred at the origin and at mean distance √3 (finite points only; points with
/// `|w|` below `1e-9 ‖M‖` do not count). The identity when fewer than 4 points are finite.
fn normalize_3d(points: &[Vector4<f64>]) -> Matrix4<f64> {
    let finite: Vec<Vector3<f64>> = points
        .iter()
        .filter(|m| m.w.abs() > 1e-9 * m.norm())
        .map(|m| m.xyz() / m.w)
        .collect();
    if finite.len() < 4 {
        return Matrix4::identity();
    }
    let n = finite.len() as f64;
    let c = finite.iter().sum::<Vector3<f64>>() / n;
    let d = finite.iter().map(|x| (x - c).norm()).sum::<f64>() / n;
    if !(d > 0.0 && d.is_finite()) {
        return Matrix4::identity();
    }
    let s = 3f64.sqrt() / d;
    let mut u = Matrix4::identity() * s;
    u[(3, 3)] = 1.0;
    u.fixed_view_mut::<3, 1>(0, 3).copy_from(&(-s * c));
    u
}

/// Accumulates the weighted DLT normal matrix `AᵀA` (12×12, `p` row-major) and returns its
/// eigenvector of the smallest eigenvalue as a camera, plus the ratio of the two smallest
/// eigenvalues (a rank check).
fn solve_dlt(
    points: &[Vector4<f64>],
    image: &[Vector2<f64>],
    weights: Option<&[f64]>,
) -> Option<(Matrix3x4<f64>, f64, f64)> {
    let row = |k: usize, r: usize| -> SMatrix<f64, 1, 12> {
        let (m, x) = (&points[k], &image[k]);
        let w = weights.map_or(1.0, |w| w[k]);
        let mt = m.transpose();
        let coord = if r == 0 { x.x } else { x.y };
        // x·(p3·M) − p1·M = 0 and y·(p3·M) − p2·M = 0.
        let mut a = SMatrix::<f64, 1, 12>::zeros();
        a.fixed_view_mut::<1, 4>(0, 4 * r).copy_from(&(-mt));
        a.fixed_view_mut::<1, 4>(0, 8).copy_from(&(mt * coord));
        a * w
    };
    if points.len() <= 32 {
        // Small systems (the minimal 6-point case above all): SVD of A itself, which does not square
        // the condition number as AᵀA would.
        let mut a = nalgebra::DMatrix::<f64>::zeros((2 * points.len()).max(12), 12);
        for k in 0..points.len() {
            for r in 0..2 {
                a.row_mut(2 * k + r).copy_from(&row(k, r));
            }
        }
        let (sv, v_t) = crate::linalg::full_right_svd(a)?;
        let ratio = sv[11] / sv[10].max(1e-300);
        let rel = sv[10] / sv[0].max(1e-300);
        return Some((
            Matrix3x4::from_fn(|r, c| v_t[(11, 4 * r + c)]),
            ratio * ratio,
            rel,
        ));
    }
    // Each row has 8 non-zero entries (the other camera row's 4 are zero) and `AᵀA` is symmetric:
    // the upper triangle of the non-zero products, summed in the same order as the full outer
    // products (adding an exact zero changes no sum), then mirrored.
    let mut ata = SMatrix::<f64, 12, 12>::zeros();
    for k in 0..points.len() {
        for r in 0..2 {
            let a = row(k, r);
            let nz = [4 * r, 4 * r + 1, 4 * r + 2, 4 * r + 3, 8, 9, 10, 11];
            for (q, &i) in nz.iter().enumerate() {
                let ai = a[i];
                for &j in &nz[q..] {
                    ata[(i, j)] += ai * a[j];
                }
            }
        }
    }
    for i in 0..12 {
        for j in 0..i {
            ata[(i, j)] = ata[(j, i)];
        }
    }
    if ata.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let eig = SymmetricEigen::new(ata);
    let mut idx: Vec<usize> = (0..12).collect();
    idx.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    let v = eig.eigenvectors.column(idx[0]);
    let ratio = eig.eigenvalues[idx[0]].abs() / eig.eigenvalues[idx[1]].abs().max(1e-300);
    let rel = (eig.eigenvalues[idx[1]].abs() / eig.eigenvalues[idx[11]].abs().max(1e-300)).sqrt();
    Some((Matrix3x4::from_fn(|r, c| v[4 * r + c]), ratio, rel))
}

fn check(points: &[Vector4<f64>], image: &[Vector2<f64>]) -> Result<()> {
    if points.len() != image.len() {
        return Err(GeometryError::LengthMismatch {
            left: points.len(),
            right: image.len(),
        });
    }
    if points.len() < 6 {
        return Err(GeometryError::InsufficientCorrespondences {
            required: 6,
            actual: points.len(),
        });
    }
    if points.iter().any(|m| m.iter().any(|v| !v.is_finite()))
        || image.iter().any(|x| !x.x.is_finite() || !x.y.is_finite())
    {
        return Err(GeometryError::NonFinite);
    }
    Ok(())
}

/// Normalised DLT resection (H&Z alg. 7.1): `P` with `x ~ P M` from ≥ 6 correspondences, unit
/// Frobenius norm. Errors for fewer than 6 points, non-finite input or a rank-deficient design
/// (e.g. coplanar or collinear 3D points).
pub fn resection_dlt(points: &[Vector4<f64>], image: &[Vector2<f64>]) -> Result<Matrix3x4<f64>> {
    check(points, image)?;
    resection_weighted_impl(points, image, 0)
}

/// The DLT followed by `iterations` re-solves in which each point's two equations are weighted by
/// `1 / (p3·M)` of the previous estimate, so that the algebraic residual approaches the image
/// distance: the resection counterpart of eq. 20.
pub fn resection_iterative(
    points: &[Vector4<f64>],
    image: &[Vector2<f64>],
    iterations: usize,
) -> Result<Matrix3x4<f64>> {
    check(points, image)?;
    resection_weighted_impl(points, image, iterations)
}

fn resection_weighted_impl(
    points: &[Vector4<f64>],
    image: &[Vector2<f64>],
    iterations: usize,
) -> Result<Matrix3x4<f64>> {
    let n2 = hartley_normalization(image)?;
    let t2: Matrix3<f64> = n2.t;
    let u = normalize_3d(points);
    let pts: Vec<Vector4<f64>> = points
        .iter()
        .map(|m| {
            let v = u * m;
            v / v.norm()
        })
        .collect();
    let degenerate = GeometryError::Degenerate {
        reason: "the 2D–3D correspondences do not determine a camera",
    };
    let (mut p, ratio, rel) = solve_dlt(&pts, &n2.points, None).ok_or(GeometryError::NonFinite)?;
    // With exactly 6 points the system is square and the smallest eigenvalue is ~0 for any data;
    // a second tiny eigenvalue means a one-parameter family of cameras (degenerate sample).
    // A second (near-)null direction relative to the largest singular value: e.g. coplanar points.
    if pts.len() > 6 && (ratio > 0.5 || rel < 1e-8) {
        return Err(degenerate);
    }
    let mut weights = vec![1.0; pts.len()];
    for _ in 0..iterations {
        for (w, m) in weights.iter_mut().zip(&pts) {
            let d = (p.row(2) * m)[0].abs();
            *w = if d > 1e-12 { 1.0 / d } else { 1e12 };
        }
        let mean = weights.iter().sum::<f64>() / weights.len() as f64;
        weights.iter_mut().for_each(|w| *w /= mean);
        p = solve_dlt(&pts, &n2.points, Some(&weights))
            .ok_or(GeometryError::NonFinite)?
            .0;
    }
    let t2_inv = t2.try_inverse().ok_or(degenerate.clone())?;
    let p = t2_inv * p * u;
    let n = p.norm();
    if !(n > 0.0 && n.is_finite()) {
        return Err(degenerate);
    }
    // A rank-deficient left block cannot be a finite camera.
    Ok(p / n)
}

/// Reprojection distance of `M` under `P`; infinity when it projects to infinity.
pub fn reprojection_distance(p: &Matrix3x4<f64>, m: &Vector4<f64>, x: &Vector2<f64>) -> f64 {
    let q = p * m;
    if q.z.abs() <= 1e-14 * q.norm().max(1e-300) {
        return f64::INFINITY;
    }
    ((q.x / q.z - x.x).powi(2) + (q.y / q.z - x.y).powi(2)).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::*;
    use nalgebra::{Point3, Rotation3};
    use rand::Rng;

    fn scene(seed: u64, n: usize) -> (Matrix3x4<f64>, Vec<Vector4<f64>>, Vec<Vector2<f64>>) {
        let mut r = rng(seed);
        let k = Matrix3::new(800.0, 0.0, 320.0, 0.0, 810.0, 240.0, 0.0, 0.0, 1.0);
        let p = camera_matrix(
            &k,
            Rotation3::from_euler_angles(0.1, -0.2, 0.05),
            Point3::new(0.3, -0.2, -5.0),
        );
        let pts: Vec<Vector4<f64>> = (0..n)
            .map(|_| {
                Vector4::new(
                    r.random_range(-1.0..1.0),
                    r.random_range(-1.0..1.0),
                    r.random_range(-1.0..1.0),
                    1.0,
                )
            })
            .collect();
        let img = pts
            .iter()
            .map(|m| project(&p, &Point3::from(m.xyz())))
            .collect();
        (p, pts, img)
    }

    fn camera_error(a: &Matrix3x4<f64>, b: &Matrix3x4<f64>) -> f64 {
        let (a, b) = (a / a.norm(), b / b.norm());
        (a - b).norm().min((a + b).norm())
    }

    #[test]
    fn minimal_and_overdetermined_exact() {
        for seed in 0..5 {
            let (p, pts, img) = scene(seed, 6);
            let est = resection_dlt(&pts, &img).unwrap();
            assert!(
                camera_error(&est, &p) < 1e-8,
                "seed {seed}: {}",
                camera_error(&est, &p)
            );
            let (p, pts, img) = scene(seed, 50);
            let est = resection_iterative(&pts, &img, 3).unwrap();
            assert!(camera_error(&est, &p) < 1e-9);
        }
    }

    #[test]
    fn noisy_reprojection_close_to_noise() {
        let (p, pts, img) = scene(7, 200);
        let mut r = rng(70);
        let noisy = add_noise(&mut r, &img, 1.0);
        let est = resection_iterative(&pts, &noisy, 3).unwrap();
        // The fitted camera must reproject the exact points to within well under the noise level.
        let err: f64 = pts
            .iter()
            .zip(&img)
            .map(|(m, x)| reprojection_distance(&est, m, x))
            .sum::<f64>()
            / 200.0;
        assert!(err < 0.3, "mean error to the noise-free points {err}");
        let _ = p;
    }

    #[test]
    fn rejects_bad_input() {
        let (_, pts, img) = scene(1, 6);
        assert!(resection_dlt(&pts[..5], &img[..5]).is_err());
        let mut bad = pts.clone();
        bad[0].x = f64::NAN;
        assert!(resection_dlt(&bad, &img).is_err());
        // Coplanar points (z = 0) leave a family of cameras.
        let planar: Vec<Vector4<f64>> = (0..20)
            .map(|i| {
                Vector4::new(
                    (i % 5) as f64,
                    (i / 5) as f64 * 0.7 + (i % 3) as f64 * 0.1,
                    0.0,
                    1.0,
                )
            })
            .collect();
        let img: Vec<Vector2<f64>> = planar
            .iter()
            .map(|m| Vector2::new(m.x * 10.0 + 3.0, m.y * 9.0 - m.x))
            .collect();
        assert!(resection_dlt(&planar, &img).is_err());
    }
}
