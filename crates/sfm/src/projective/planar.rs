//! Resection where the 3D points a view sees lie on one plane (the paper, end of §3.1, defers
//! this case to Pollefeys, Verbiest & Van Gool 2002, *Surviving dominant planes in uncalibrated
//! structure and motion recovery*, ECCV).
//!
//! When the 2D–3D matches of a new view lie on a plane `π`, the 6-point DLT is degenerate: every
//! camera `P + a πᵀ` (`a ∈ ℝ³`) projects the plane's points alike, so the camera RANSAC keeps is
//! one member of a three-parameter family, fitted to the plane and wrong everywhere off it.
//!
//! - [`PlaneTest`] decides it by GRIC (Torr 1998), as Pollefeys et al. decide between F and H: the
//!   camera (11 parameters) against a homography from the plane's coordinates to the image (8),
//!   on the same inliers, with the noise σ measured on the camera's residuals. Data dimension
//!   r = 2 (an image point per match; the 3D point is given), model dimension d = 0, so
//!   `GRIC = Σ min(e²/σ², 2λ₃) + λ₂ k`, λ₂ = ln(2n), λ₃ = 2.
//! - [`recover_parallax`] looks for the member of the family that the off-plane matches support
//!   (the plane-and-parallax idea of DEGENSAC, Chum, Werner & Matas 2005: a degenerate sample is
//!   completed by the points off its plane): `a` from two matches the plane's camera does not
//!   explain (two linear equations each), scored by support over every candidate.
//!
//! A view whose matches stay planar after that is not resected: it fails with a reason and is tried
//! again when the model has grown, and after the upgrade calibrated resection (P3P,
//! `metric/register.rs`), which has no such degeneracy, registers it.

use nalgebra::{Matrix3, Matrix3x4, Matrix4, SMatrix, SymmetricEigen, Vector2, Vector3, Vector4};

use handheld_geometry::reprojection_distance;

/// Torr's λ₃: the cap of a residual's cost is λ₃ (r − d) = 4 for r = 2, d = 0.
const CAP: f64 = 4.0;
/// Samples of [`recover_parallax`].
const PARALLAX_TRIALS: usize = 300;

/// The GRIC scores of a resection's inliers.
#[derive(Clone, Copy, Debug)]
pub(crate) struct PlaneTest {
    pub gric_camera: f64,
    pub gric_plane: f64,
    /// The plane through the points (projective 4-vector).
    pub plane: Vector4<f64>,
}

impl PlaneTest {
    /// Whether one homography explains the matches as well as the camera, given the camera's three
    /// extra parameters.
    pub fn planar(&self) -> bool {
        self.gric_plane <= self.gric_camera
    }

    /// GRIC of `p` against the plane's homography on the inlier matches `(m, x)` (3D, normalised
    /// image point). `None` with fewer than 12 matches (too few for either).
    pub fn of(p: &Matrix3x4<f64>, m: &[Vector4<f64>], x: &[Vector2<f64>]) -> Option<Self> {
        let n = m.len();
        if n < 12 || x.len() != n {
            return None;
        }
        let e_cam: Vec<f64> = m
            .iter()
            .zip(x)
            .map(|(m, x)| reprojection_distance(p, m, x))
            .collect();
        // The 2D residual of an isotropic Gaussian has median σ √(2 ln 2).
        let mut sorted = e_cam.clone();
        sorted.sort_by(f64::total_cmp);
        let sigma = (sorted[n / 2] / (2.0 * std::f64::consts::LN_2).sqrt()).max(1e-9);
        let (plane, basis) = fit_plane(m);
        let h = plane_homography(&basis, m, x)?;
        let e_plane: Vec<f64> = m
            .iter()
            .zip(x)
            .map(|(m, x)| transfer(&h, &(basis.transpose() * m), x))
            .collect();
        let lambda2 = (2.0 * n as f64).ln();
        let cost = |e: &[f64]| -> f64 {
            e.iter()
                .map(|e| (e * e / (sigma * sigma)).min(CAP))
                .sum::<f64>()
        };
        Some(Self {
            gric_camera: cost(&e_cam) + 11.0 * lambda2,
            gric_plane: cost(&e_plane) + 8.0 * lambda2,
            plane,
        })
    }
}

/// The plane through unit-norm projective points (the right singular vector of their stack with
/// the smallest singular value) and a basis of it (the other three, as columns).
fn fit_plane(m: &[Vector4<f64>]) -> (Vector4<f64>, SMatrix<f64, 4, 3>) {
    let mut s = Matrix4::zeros();
    for p in m {
        let q = p.normalize();
        s += q * q.transpose();
    }
    let eig = SymmetricEigen::new(s);
    let mut order = [0usize, 1, 2, 3];
    order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    let col = |k: usize| eig.eigenvectors.column(order[k]).into_owned();
    let basis = SMatrix::<f64, 4, 3>::from_columns(&[col(0), col(1), col(2)]);
    (col(3), basis)
}

/// The homography from the plane coordinates `basisᵀ m` to the image points: the DLT on
/// coordinates scaled to unit RMS per component (Hartley normalisation), solved by the 9×9 normal
/// equations' smallest eigenvector.
fn plane_homography(
    basis: &SMatrix<f64, 4, 3>,
    m: &[Vector4<f64>],
    x: &[Vector2<f64>],
) -> Option<Matrix3<f64>> {
    let u: Vec<Vector3<f64>> = m
        .iter()
        .map(|m| basis.transpose() * m.normalize())
        .collect();
    let mut rms = Vector3::zeros();
    for u in &u {
        rms += u.component_mul(u);
    }
    let d = rms.map(|v| 1.0 / (v / u.len() as f64).sqrt().max(1e-12));
    let dm = Matrix3::from_diagonal(&d);
    let mut ata = SMatrix::<f64, 9, 9>::zeros();
    for (u, x) in u.iter().zip(x) {
        let u = dm * u;
        let mut r1 = SMatrix::<f64, 1, 9>::zeros();
        let mut r2 = SMatrix::<f64, 1, 9>::zeros();
        for k in 0..3 {
            r1[3 + k] = -u[k];
            r1[6 + k] = x.y * u[k];
            r2[k] = u[k];
            r2[6 + k] = -x.x * u[k];
        }
        ata += r1.transpose() * r1 + r2.transpose() * r2;
    }
    let eig = SymmetricEigen::new(ata);
    let k = eig.eigenvalues.imin();
    let h = eig.eigenvectors.column(k);
    let h = Matrix3::new(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], h[8]) * dm;
    h.iter().all(|v| v.is_finite()).then_some(h)
}

fn transfer(h: &Matrix3<f64>, u: &Vector3<f64>, x: &Vector2<f64>) -> f64 {
    let q = h * u;
    if q.z.abs() <= 1e-14 * q.norm().max(1e-300) {
        return f64::INFINITY;
    }
    ((q.x / q.z - x.x).powi(2) + (q.y / q.z - x.y).powi(2)).sqrt()
}

/// The member `p + a πᵀ` of the degenerate family that most candidates `(m, x)` support within
/// `thr`, from samples of two candidates that `p` does not explain; `None` when no sample beats
/// `p`'s own support. Deterministic for a seed.
pub(crate) fn recover_parallax(
    p: &Matrix3x4<f64>,
    plane: &Vector4<f64>,
    m: &[Vector4<f64>],
    x: &[Vector2<f64>],
    thr: f64,
    seed: u64,
) -> Option<Matrix3x4<f64>> {
    let support = |q: &Matrix3x4<f64>| {
        m.iter()
            .zip(x)
            .filter(|(m, x)| reprojection_distance(q, m, x) < thr)
            .count()
    };
    let off: Vec<usize> = (0..m.len())
        .filter(|&k| reprojection_distance(p, &m[k], &x[k]) >= thr)
        .collect();
    if off.len() < 2 {
        return None;
    }
    let mut best = (support(p), None);
    let mut state = seed | 1;
    let mut next = |n: usize| {
        // xorshift64*: a fixed, seeded sequence.
        state ^= state >> 12;
        state ^= state << 25;
        state ^= state >> 27;
        (state.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 33) as usize % n
    };
    for _ in 0..PARALLAX_TRIALS {
        let (i, j) = (off[next(off.len())], off[next(off.len())]);
        if i == j {
            continue;
        }
        let Some(a) = solve_offset(p, plane, &[(m[i], x[i]), (m[j], x[j])]) else {
            continue;
        };
        let q = p + a * plane.transpose();
        let s = support(&q);
        if s > best.0 {
            best = (s, Some(q));
        }
    }
    best.1
}

/// The least-squares `a` with `x × ((p + a πᵀ) m) = 0` for each match: two linear equations each,
/// `s a₁ − u s a₃ = u (pm)₃ − (pm)₁` and `s a₂ − v s a₃ = v (pm)₃ − (pm)₂` with `s = πᵀm`.
fn solve_offset(
    p: &Matrix3x4<f64>,
    plane: &Vector4<f64>,
    matches: &[(Vector4<f64>, Vector2<f64>)],
) -> Option<Vector3<f64>> {
    let mut ata = Matrix3::zeros();
    let mut atb = Vector3::zeros();
    for (m, x) in matches {
        let q = p * m;
        let s = plane.dot(m);
        let rows = [
            (Vector3::new(s, 0.0, -x.x * s), x.x * q.z - q.x),
            (Vector3::new(0.0, s, -x.y * s), x.y * q.z - q.y),
        ];
        for (r, b) in rows {
            ata += r * r.transpose();
            atb += r * b;
        }
    }
    ata.try_inverse().map(|inv| inv * atb)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Point3, Rotation3};

    fn camera(yaw: f64, c: Vector3<f64>) -> Matrix3x4<f64> {
        let r = Rotation3::from_euler_angles(0.1, yaw, 0.05).into_inner();
        let mut p = Matrix3x4::zeros();
        p.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
        p.set_column(3, &(-r * c));
        p
    }

    /// Points on the plane z = 4 (a wall) and, when `off > 0`, that many in front of it.
    fn scene(off: usize) -> Vec<Vector4<f64>> {
        let mut pts = Vec::new();
        for i in 0..15 {
            for j in 0..15 {
                let (a, b) = (i as f64 / 7.0 - 1.0, j as f64 / 7.0 - 1.0);
                pts.push(Point3::new(a * 2.0, b * 2.0, 4.0));
            }
        }
        for k in 0..off {
            let t = k as f64 / off as f64;
            pts.push(Point3::new(t - 0.5, 0.6 * (t * 7.0).sin(), 2.5 + t));
        }
        pts.iter()
            .map(|p| Vector4::new(p.x, p.y, p.z, 1.0).normalize())
            .collect()
    }

    fn project(p: &Matrix3x4<f64>, m: &[Vector4<f64>], noise: f64) -> Vec<Vector2<f64>> {
        m.iter()
            .enumerate()
            .map(|(k, m)| {
                let q = p * m;
                let wiggle = Vector2::new(
                    ((k * 7919) % 13) as f64 - 6.0,
                    ((k * 104729) % 11) as f64 - 5.0,
                );
                Vector2::new(q.x / q.z, q.y / q.z) + wiggle * noise / 6.0
            })
            .collect()
    }

    #[test]
    fn a_wall_alone_is_planar_and_a_wall_with_an_object_is_not() {
        let p = camera(0.3, Vector3::new(-1.0, 0.2, 0.0));
        let wall = scene(0);
        let x = project(&p, &wall, 1e-3);
        let t = PlaneTest::of(&p, &wall, &x).unwrap();
        assert!(t.planar(), "{t:?}");
        let both = scene(60);
        let x = project(&p, &both, 1e-3);
        let t = PlaneTest::of(&p, &both, &x).unwrap();
        assert!(!t.planar(), "{t:?}");
    }

    #[test]
    fn the_family_member_the_off_plane_points_support_is_the_true_camera() {
        let p = camera(0.3, Vector3::new(-1.0, 0.2, 0.0));
        let pts = scene(40);
        let x = project(&p, &pts, 1e-4);
        // A wrong member of the family: exact on the wall, wrong off it.
        let wall = Vector4::new(0.0, 0.0, 1.0, -4.0).normalize();
        let wrong = p + Vector3::new(0.05, -0.03, 0.02) * wall.transpose();
        let on_wall = (0..225).filter(|&k| reprojection_distance(&wrong, &pts[k], &x[k]) < 1e-3);
        assert_eq!(on_wall.count(), 225);
        let q = recover_parallax(&wrong, &wall, &pts, &x, 1e-3, 7).unwrap();
        let worst = pts
            .iter()
            .zip(&x)
            .map(|(m, x)| reprojection_distance(&q, m, x))
            .fold(0.0, f64::max);
        assert!(worst < 1e-3, "worst residual {worst}");
    }
}
