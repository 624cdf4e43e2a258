//! Triangulation of §3.1 ("Initializing Structure"): the linear DLT from any number of views
//! (H&Z §12.2), and the optimal two-view method of Hartley & Sturm (1997) that minimises the image
//! reprojection error of eq. 17 through the one-parameter family of epipolar planes of eq. 18
//! (H&Z alg. 12.1). Both work in a projective frame: cameras are [`ProjectiveCamera`]s.

use handheld_core::{ProjectiveCamera, ProjectivePoint};
use nalgebra::{DMatrix, Matrix3, Matrix3x4, Matrix4, SymmetricEigen, Vector2, Vector3, Vector4};

use crate::error::{GeometryError, Result};
use crate::fundamental::{epipoles, fundamental_from_cameras};
use crate::linalg::full_right_svd;
use crate::poly;

/// Relative size below which a singular value counts as zero.
const RANK_TOL: f64 = 1e-10;

/// Linear triangulation (H&Z §12.2, the homogeneous DLT): each view adds the rows
/// `x·p3ᵀ − p1ᵀ` and `y·p3ᵀ − p2ᵀ`, each scaled to unit norm so that no view dominates by the size of
/// its matrix; the point is the least-squares null vector. Returned with unit norm and `w ≥ 0`.
///
/// Errors: fewer than 2 views, mismatched lengths, non-finite input, or rank below 3 (coincident
/// centres, a point on the baseline).
pub fn triangulate_linear(
    cameras: &[ProjectiveCamera],
    points: &[Vector2<f64>],
) -> Result<ProjectivePoint> {
    if cameras.len() != points.len() {
        return Err(GeometryError::LengthMismatch {
            left: cameras.len(),
            right: points.len(),
        });
    }
    if cameras.len() < 2 {
        return Err(GeometryError::InsufficientCorrespondences {
            required: 2,
            actual: cameras.len(),
        });
    }
    let mut a = DMatrix::<f64>::zeros(2 * cameras.len(), 4);
    for (i, (cam, x)) in cameras.iter().zip(points).enumerate() {
        let p = &cam.P;
        for (k, coord) in [x.x, x.y].into_iter().enumerate() {
            let row = p.row(2) * coord - p.row(k);
            let n = row.norm();
            if !n.is_finite() {
                return Err(GeometryError::NonFinite);
            }
            if n > 0.0 {
                a.row_mut(2 * i + k).copy_from(&(row / n));
            }
        }
    }
    let (sv, v_t) = full_right_svd(a).ok_or(GeometryError::NonFinite)?;
    if sv[2] <= RANK_TOL * sv[0] {
        return Err(GeometryError::Degenerate {
            reason: "rays do not determine a point",
        });
    }
    let mut x = Vector4::new(v_t[(3, 0)], v_t[(3, 1)], v_t[(3, 2)], v_t[(3, 3)]);
    if x.w < 0.0 {
        x = -x;
    }
    Ok(ProjectivePoint { X: x })
}

/// Multi-view triangulation by the iterated weighted linear method of §3.2 ("Refining and Extending
/// Structure"): solve eq. 19, `(x p3 − p1) M = 0`, `(y p3 − p2) M = 0` over all views, then re-solve
/// `iterations` times with each view's rows divided by `p3 M̃` of the previous solution (eq. 20), which
/// makes the algebraic residual approach the image distance `d(P M, m)`. Cameras are raw 3×4
/// matrices (any scale; each is used at unit norm). Returns the unit-norm point, its sign chosen so
/// that the first camera's `p3·M` is positive.
///
/// Errors: fewer than 2 views, mismatched lengths, non-finite input, or rays that do not determine
/// a point (the two smallest eigenvalues of the normal matrix too close).
pub fn triangulate_iterative(
    cameras: &[Matrix3x4<f64>],
    points: &[Vector2<f64>],
    iterations: usize,
) -> Result<Vector4<f64>> {
    if cameras.len() != points.len() {
        return Err(GeometryError::LengthMismatch {
            left: cameras.len(),
            right: points.len(),
        });
    }
    if cameras.len() < 2 {
        return Err(GeometryError::InsufficientCorrespondences {
            required: 2,
            actual: cameras.len(),
        });
    }
    let solve = |weights: &[f64]| -> Result<(Vector4<f64>, f64)> {
        let mut ata = Matrix4::<f64>::zeros();
        for ((p, x), w) in cameras.iter().zip(points).zip(weights) {
            for (k, coord) in [x.x, x.y].into_iter().enumerate() {
                let row = (p.row(2) * coord - p.row(k)) * *w;
                ata += row.transpose() * row;
            }
        }
        if ata.iter().any(|v| !v.is_finite()) {
            return Err(GeometryError::NonFinite);
        }
        let eig = SymmetricEigen::new(ata);
        let mut idx = [0usize, 1, 2, 3];
        idx.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
        let ratio = eig.eigenvalues[idx[0]].abs() / eig.eigenvalues[idx[1]].abs().max(1e-300);
        Ok((eig.eigenvectors.column(idx[0]).into_owned(), ratio))
    };
    let mut weights: Vec<f64> = cameras.iter().map(|p| 1.0 / p.norm().max(1e-300)).collect();
    let (mut m, ratio) = solve(&weights)?;
    if ratio > 1e-2 && cameras.len() == 2 {
        // Two views: the rays always nearly meet, so only an exactly rank-deficient system fails.
    } else if ratio > 0.25 {
        return Err(GeometryError::Degenerate {
            reason: "rays do not determine a point",
        });
    }
    for _ in 0..iterations {
        for (w, p) in weights.iter_mut().zip(cameras) {
            let pn = p / p.norm().max(1e-300);
            let d = (pn.row(2) * m)[0].abs();
            *w = 1.0 / (p.norm().max(1e-300) * d.max(1e-12));
        }
        m = solve(&weights)?.0;
    }
    if (cameras[0].row(2) * m)[0] < 0.0 {
        m = -m;
    }
    Ok(m / m.norm())
}

/// Optimal two-view triangulation: [`optimal_correction`] with the `F` of the two cameras, then
/// [`triangulate_linear`] on the corrected points, whose rays meet exactly. The result minimises
/// eq. 17 over all 3D points. When many points share a camera pair, compute `F` once with
/// [`crate::fundamental_from_cameras`] and call the two steps directly.
pub fn triangulate_optimal(
    p1: &ProjectiveCamera,
    p2: &ProjectiveCamera,
    x1: &Vector2<f64>,
    x2: &Vector2<f64>,
) -> Result<ProjectivePoint> {
    let f = fundamental_from_cameras(p1, p2)?;
    let (c1, c2) = optimal_correction(&f, x1, x2)?;
    triangulate_linear(&[*p1, *p2], &[c1, c2])
}

fn translation(x: &Vector2<f64>) -> Matrix3<f64> {
    Matrix3::new(1.0, 0.0, x.x, 0.0, 1.0, x.y, 0.0, 0.0, 1.0)
}

fn rotation_from_epipole(e: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(e.x, e.y, 0.0, -e.y, e.x, 0.0, 0.0, 0.0, 1.0)
}

/// Scales a homogeneous epipole so that `e₁² + e₂² = 1`; `None` when it lies at the origin.
fn unit_xy(e: Vector3<f64>) -> Option<Vector3<f64>> {
    let n = e.xy().norm();
    (n > 1e-12 * e.norm()).then(|| e / n)
}

/// Closest point to the origin on the line `(λ, μ, ν)` (H&Z alg. 12.1, step (ix)).
fn foot_of_origin(l: &Vector3<f64>) -> Vector3<f64> {
    Vector3::new(-l.x * l.z, -l.y * l.z, l.x * l.x + l.y * l.y)
}

fn poly_mul(a: &[f64], b: &[f64]) -> Vec<f64> {
    let mut out = vec![0.0; a.len() + b.len() - 1];
    for (i, &ai) in a.iter().enumerate() {
        for (j, &bj) in b.iter().enumerate() {
            out[i + j] += ai * bj;
        }
    }
    out
}

fn poly_add(a: &[f64], b: &[f64], scale_b: f64) -> Vec<f64> {
    let mut out = vec![0.0; a.len().max(b.len())];
    for (i, &v) in a.iter().enumerate() {
        out[i] += v;
    }
    for (i, &v) in b.iter().enumerate() {
        out[i] += scale_b * v;
    }
    out
}

/// Hartley–Sturm optimal correction (H&Z alg. 12.1; paper eq. 18): the points `(x̂1, x̂2)` with
/// `x̂2ᵀ F x̂1 = 0` that minimise `d(x1, x̂1)² + d(x2, x̂2)²`. Both points are moved to the origin
/// and the epipoles rotated onto the x-axis; the epipolar line pair is then parametrised by `t`, the
/// cost becomes `s(t) = t²/(1 + f²t²) + (ct + d)²/((at + b)² + f'²(ct + d)²)`, and its stationary
/// points are the real roots of a degree-6 polynomial. The global minimum over those roots and
/// `t = ∞` is taken; the corrected points are the feet of the perpendiculars on the two lines.
///
/// Errors: a non-finite input, `F` of rank below 2, or a measured point exactly at its epipole.
pub fn optimal_correction(
    f: &Matrix3<f64>,
    x1: &Vector2<f64>,
    x2: &Vector2<f64>,
) -> Result<(Vector2<f64>, Vector2<f64>)> {
    if !(x1.iter().chain(x2.iter()).all(|v| v.is_finite())) {
        return Err(GeometryError::NonFinite);
    }
    let (t1_inv, t2_inv) = (translation(x1), translation(x2));
    // Steps (i)–(ii): F ← T2⁻ᵀ F T1⁻¹, with T the translation taking the point to the origin.
    let ft = t2_inv.transpose() * f * t1_inv;
    let (e1, e2) = epipoles(&ft)?;
    let at_epipole = GeometryError::Degenerate {
        reason: "measured point coincides with its epipole",
    };
    let e1 = unit_xy(e1).ok_or(at_epipole.clone())?;
    let e2 = unit_xy(e2).ok_or(at_epipole)?;
    let (r1, r2) = (rotation_from_epipole(&e1), rotation_from_epipole(&e2));
    let fr = r2 * ft * r1.transpose();
    let fr = fr / fr.norm();
    let (f1, f2) = (e1.z, e2.z);
    let (a, b, c, d) = (fr[(1, 1)], fr[(1, 2)], fr[(2, 1)], fr[(2, 2)]);

    // Step (vii): g(t) = t((at+b)² + f'²(ct+d)²)² − (ad − bc)(1 + f²t²)²(at+b)(ct+d).
    let lin_a = [b, a];
    let lin_c = [d, c];
    let q = poly_add(
        &poly_mul(&lin_a, &lin_a),
        &poly_mul(&lin_c, &lin_c),
        f2 * f2,
    );
    let term1 = poly_mul(&[0.0, 1.0], &poly_mul(&q, &q));
    let one_f = [1.0, 0.0, f1 * f1];
    let term2 = poly_mul(&poly_mul(&one_f, &one_f), &poly_mul(&lin_a, &lin_c));
    let g = poly_add(&term1, &term2, -(a * d - b * c));

    // Step (viii): evaluate the cost at the real parts of every root and at t = ∞.
    let cost = |t: f64| {
        let (at_b, ct_d) = (a * t + b, c * t + d);
        let den = at_b * at_b + f2 * f2 * ct_d * ct_d;
        let second = if den > 0.0 {
            ct_d * ct_d / den
        } else {
            f64::INFINITY
        };
        t * t / (1.0 + f1 * f1 * t * t) + second
    };
    let mut best_t: Option<f64> = None;
    let mut best_cost = if f1 != 0.0 {
        1.0 / (f1 * f1) + c * c / (a * a + f2 * f2 * c * c)
    } else {
        f64::INFINITY
    };
    if !best_cost.is_finite() {
        best_cost = f64::INFINITY;
    }
    for root in poly::roots(&g).unwrap_or_default() {
        let t = poly::polish_root(&g, root.re);
        let s = cost(t);
        if s.is_finite() && (s < best_cost || (best_t.is_none() && !best_cost.is_finite())) {
            best_cost = s;
            best_t = Some(t);
        }
    }
    if best_t.is_none() && !best_cost.is_finite() {
        return Err(GeometryError::Degenerate {
            reason: "no finite minimum of the epipolar-plane cost",
        });
    }

    // Step (ix): the epipolar lines of the optimal plane and the closest points on them.
    let (l1, l2) = match best_t {
        Some(t) => (
            Vector3::new(t * f1, 1.0, -t),
            Vector3::new(-f2 * (c * t + d), a * t + b, c * t + d),
        ),
        None => (Vector3::new(f1, 0.0, -1.0), Vector3::new(-f2 * c, a, c)),
    };
    // Step (x): back to the original coordinates.
    let h1 = t1_inv * r1.transpose() * foot_of_origin(&l1);
    let h2 = t2_inv * r2.transpose() * foot_of_origin(&l2);
    if h1.z == 0.0 || h2.z == 0.0 {
        return Err(GeometryError::Degenerate {
            reason: "corrected point at infinity",
        });
    }
    Ok((h1.xy() / h1.z, h2.xy() / h2.z))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fundamental::sampson_distance_sq;
    use crate::test_util::*;
    use nalgebra::Matrix3x4;

    fn cams(tv: &TwoView) -> (ProjectiveCamera, ProjectiveCamera) {
        (ProjectiveCamera { P: tv.p1 }, ProjectiveCamera { P: tv.p2 })
    }

    fn reproj_sq(cams: &[ProjectiveCamera], obs: &[Vector2<f64>], x: &ProjectivePoint) -> f64 {
        cams.iter()
            .zip(obs)
            .map(|(c, o)| {
                c.project(x)
                    .map_or(f64::INFINITY, |p| (p - o).norm_squared())
            })
            .sum()
    }

    #[test]
    fn linear_is_exact_on_noise_free_data_with_many_views() {
        let tv = two_view(21, 30);
        let extra = camera_matrix(
            &handheld_core::Intrinsics::pinhole(700.0, 330.0, 230.0).k_matrix(),
            nalgebra::Rotation3::from_euler_angles(0.05, 0.2, 0.0),
            nalgebra::Point3::new(-0.7, 0.1, 0.3),
        );
        let cams3 = [
            ProjectiveCamera { P: tv.p1 },
            ProjectiveCamera { P: tv.p2 },
            ProjectiveCamera { P: extra },
        ];
        for p in &tv.points {
            let obs: Vec<_> = cams3.iter().map(|c| project(&c.P, p)).collect();
            let x = triangulate_linear(&cams3, &obs).expect("general position");
            let e = x.to_euclidean().expect("finite");
            assert!((e - p.coords).norm() < 1e-9, "{e:?} vs {p:?}");
        }
    }

    #[test]
    fn optimal_on_noise_free_data_is_exact() {
        let tv = two_view(22, 20);
        let (c1, c2) = cams(&tv);
        for (i, p) in tv.points.iter().enumerate() {
            let x = triangulate_optimal(&c1, &c2, &tv.x1[i], &tv.x2[i]).expect("general position");
            assert!((x.to_euclidean().expect("finite") - p.coords).norm() < 1e-8);
        }
    }

    #[test]
    fn optimal_corrects_onto_epipolar_geometry_and_beats_linear() {
        let mut total_opt = 0.0;
        let mut total_lin = 0.0;
        let mut total_sampson = 0.0;
        for seed in 0..5 {
            let tv = two_view(30 + seed, 100);
            let (c1, c2) = cams(&tv);
            let f = fundamental_from_cameras(&c1, &c2).expect("distinct centres");
            let mut r = rng(300 + seed);
            let x1 = add_noise(&mut r, &tv.x1, 1.0);
            let x2 = add_noise(&mut r, &tv.x2, 1.0);
            for (a, b) in x1.iter().zip(&x2) {
                let (ca, cb) = optimal_correction(&f, a, b).expect("general position");
                // The corrected points lie exactly on corresponding epipolar lines.
                assert!(
                    sampson_distance_sq(&f, &ca, &cb) < 1e-18,
                    "{}",
                    sampson_distance_sq(&f, &ca, &cb)
                );
                let moved = (ca - a).norm_squared() + (cb - b).norm_squared();
                let xo = triangulate_linear(&[c1, c2], &[ca, cb]).expect("rays meet");
                let e_opt = reproj_sq(&[c1, c2], &[*a, *b], &xo);
                assert!(
                    (e_opt - moved).abs() < 1e-6 * (1.0 + moved),
                    "{e_opt} vs {moved}"
                );
                let xl = triangulate_linear(&[c1, c2], &[*a, *b]).expect("general position");
                let e_lin = reproj_sq(&[c1, c2], &[*a, *b], &xl);
                assert!(e_opt <= e_lin + 1e-9, "optimal {e_opt} > linear {e_lin}");
                total_opt += e_opt;
                total_lin += e_lin;
                total_sampson += sampson_distance_sq(&f, a, b);
            }
        }
        eprintln!("500 points, σ = 1 px: Σ reprojection² optimal {total_opt:.2}, linear {total_lin:.2}, Σ Sampson² {total_sampson:.2}");
        assert!(total_opt < total_lin, "{total_opt} vs {total_lin}");
        // The Sampson distance is the first-order approximation of the optimal cost.
        assert!(
            (total_opt / total_sampson - 1.0).abs() < 0.01,
            "{total_opt} vs Sampson {total_sampson}"
        );
    }

    #[test]
    fn optimal_works_in_a_projective_frame() {
        let tv = two_view(40, 30);
        let (c1, c2) = cams(&tv);
        let f = fundamental_from_cameras(&c1, &c2).expect("distinct");
        let (q1, q2) =
            crate::skew::canonical_cameras(&f, &Vector3::new(0.1, 0.0, -0.2), 1.0).expect("rank 2");
        let mut r = rng(41);
        let x1 = add_noise(&mut r, &tv.x1, 0.7);
        let x2 = add_noise(&mut r, &tv.x2, 0.7);
        for (a, b) in x1.iter().zip(&x2) {
            let xm = triangulate_optimal(&c1, &c2, a, b).expect("metric");
            let xp = triangulate_optimal(&q1, &q2, a, b).expect("projective");
            let em = reproj_sq(&[c1, c2], &[*a, *b], &xm);
            let ep = reproj_sq(&[q1, q2], &[*a, *b], &xp);
            assert!(
                (em - ep).abs() < 1e-6 * (1.0 + em),
                "reprojection error depends on the frame: {em} vs {ep}"
            );
        }
    }

    #[test]
    fn degenerate_inputs_are_errors() {
        let tv = two_view(50, 5);
        let (c1, c2) = cams(&tv);
        assert!(matches!(
            triangulate_linear(&[c1], &[tv.x1[0]]),
            Err(GeometryError::InsufficientCorrespondences { .. })
        ));
        assert!(matches!(
            triangulate_linear(&[c1, c2], &[tv.x1[0]]),
            Err(GeometryError::LengthMismatch { .. })
        ));
        assert!(triangulate_linear(&[c1, c1], &[tv.x1[0], tv.x1[0]]).is_err());
        assert!(triangulate_linear(&[c1, c2], &[Vector2::new(f64::NAN, 0.0), tv.x2[0]]).is_err());
        assert!(triangulate_optimal(&c1, &c1, &tv.x1[0], &tv.x1[0]).is_err());
        let zero = ProjectiveCamera {
            P: Matrix3x4::zeros(),
        };
        assert!(triangulate_optimal(&zero, &c2, &tv.x1[0], &tv.x2[0]).is_err());
        assert!(optimal_correction(&Matrix3::zeros(), &tv.x1[0], &tv.x2[0]).is_err());
        assert!(optimal_correction(
            &Matrix3::identity(),
            &Vector2::new(f64::INFINITY, 0.0),
            &tv.x2[0]
        )
        .is_err());
    }

    #[test]
    fn iterative_multiview_is_close_to_truth() {
        let tv = two_view(11, 60);
        let mut r = rng(12);
        let x1 = add_noise(&mut r, &tv.x1, 0.5);
        let x2 = add_noise(&mut r, &tv.x2, 0.5);
        let mut err_lin = 0.0;
        let mut err_it = 0.0;
        for k in 0..60 {
            let cams = [tv.p1, tv.p2];
            let obs = [x1[k], x2[k]];
            let m0 = triangulate_iterative(&cams, &obs, 0).unwrap();
            let m = triangulate_iterative(&cams, &obs, 3).unwrap();
            let pc: Vec<ProjectiveCamera> =
                cams.iter().map(|p| ProjectiveCamera { P: *p }).collect();
            err_lin += reproj_sq(&pc, &obs, &ProjectivePoint { X: m0 });
            err_it += reproj_sq(&pc, &obs, &ProjectivePoint { X: m });
            let exact = triangulate_iterative(&cams, &[tv.x1[k], tv.x2[k]], 2).unwrap();
            let truth = tv.points[k];
            let e = exact.xyz() / exact.w;
            assert!((e - truth.coords).norm() < 1e-6 * truth.coords.norm().max(1.0));
        }
        // Eq. 20 never does worse than eq. 19 in reprojection error.
        assert!(err_it <= err_lin * 1.0001, "{err_it} vs {err_lin}");
        assert!(triangulate_iterative(&[tv.p1], &[x1[0]], 1).is_err());
    }
}
