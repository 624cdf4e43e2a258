//! Calibrated resection (the metric counterpart of §3.2's projective resection): the pose of a
//! camera with known intrinsics from 2D–3D matches.
//!
//! - [`p3p`]: Grunert's minimal solution (Haralick et al., "Review and analysis of solutions of the
//!   three point perspective pose estimation problem", IJCV 1994): the laws of cosines for the
//!   three ray lengths give a quartic in their ratio; each real root gives the points in the
//!   camera frame, and the absolute orientation between the two triplets gives `[R | t]`.
//! - [`absolute_orientation`]: the rotation and translation between two point sets (Kabsch /
//!   Umeyama without scale, SVD of the cross-covariance).
//! - [`refine_pose`]: Gauss–Newton on the normalized reprojection error over all inliers.
//!
//! Used after the metric upgrade, when projective resection is degenerate (all 3D points on a
//! plane) or for frames added to a calibrated model (video in-between frames).

use nalgebra::{Matrix3, Matrix6, Rotation3, UnitQuaternion, Vector2, Vector3, Vector6};

use crate::poly;

/// `Y = R X + t`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    pub rotation: UnitQuaternion<f64>,
    pub translation: Vector3<f64>,
}

impl Pose {
    pub fn transform(&self, x: &Vector3<f64>) -> Vector3<f64> {
        self.rotation * x + self.translation
    }

    /// Normalized projection error `‖π(R X + t) − x‖`; infinite behind the camera.
    pub fn reprojection_error(&self, x: &Vector2<f64>, world: &Vector3<f64>) -> f64 {
        let y = self.transform(world);
        if y.z <= 1e-12 {
            return f64::INFINITY;
        }
        (Vector2::new(y.x / y.z, y.y / y.z) - x).norm()
    }
}

/// Polynomial product of coefficient vectors (lowest degree first).
fn mul(a: &[f64], b: &[f64]) -> Vec<f64> {
    let mut out = vec![0.0; a.len() + b.len() - 1];
    for (i, x) in a.iter().enumerate() {
        for (j, y) in b.iter().enumerate() {
            out[i + j] += x * y;
        }
    }
    out
}

fn add_scaled(acc: &mut Vec<f64>, p: &[f64], s: f64) {
    if acc.len() < p.len() {
        acc.resize(p.len(), 0.0);
    }
    for (a, x) in acc.iter_mut().zip(p) {
        *a += s * x;
    }
}

/// The rotation and translation with `Y ≈ R X + t` in the least-squares sense (no scale); `None`
/// for fewer than three points or a degenerate (collinear) configuration.
pub fn absolute_orientation(x: &[Vector3<f64>], y: &[Vector3<f64>]) -> Option<Pose> {
    if x.len() < 3 || x.len() != y.len() {
        return None;
    }
    let n = x.len() as f64;
    let cx = x.iter().sum::<Vector3<f64>>() / n;
    let cy = y.iter().sum::<Vector3<f64>>() / n;
    let mut h = Matrix3::zeros();
    for (a, b) in x.iter().zip(y) {
        h += (b - cy) * (a - cx).transpose();
    }
    let svd = h.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    if svd.singular_values[1] <= 1e-12 * svd.singular_values[0].max(1e-300) {
        return None;
    }
    let d = (u * v_t).determinant().signum();
    let r = u * Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, d)) * v_t;
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
    Some(Pose {
        rotation,
        translation: cy - rotation * cx,
    })
}

/// Grunert's P3P: all poses (up to four) placing the three world points on the three rays.
/// `rays` are the (not necessarily unit) viewing directions `(x, y, 1)` of normalized image points.
pub fn p3p(rays: &[Vector3<f64>; 3], world: &[Vector3<f64>; 3]) -> Vec<Pose> {
    let f: [Vector3<f64>; 3] = std::array::from_fn(|i| rays[i].normalize());
    let a2 = (world[1] - world[2]).norm_squared();
    let b2 = (world[0] - world[2]).norm_squared();
    let c2 = (world[0] - world[1]).norm_squared();
    if a2 < 1e-18 || b2 < 1e-18 || c2 < 1e-18 {
        return Vec::new();
    }
    let (ca, cb, cg) = (f[1].dot(&f[2]), f[0].dot(&f[2]), f[0].dot(&f[1]));
    // With s₂ = u s₁, s₃ = v s₁ (distances along the rays), the laws of cosines give
    //   (i)  u² + v² − 2uv cα = (a²/b²)(1 + v² − 2v cβ)
    //   (ii) 1 + u² − 2u cγ   = (c²/b²)(1 + v² − 2v cβ).
    // (i) − (ii) is linear in u: u = N(v) / D(v); substituted into (ii) it is a quartic in v.
    let q = [1.0, -2.0 * cb, 1.0]; // 1 + v² − 2v cβ
    let k = (c2 - a2) / b2;
    // N(v) = −[k q(v) − 1 + v²]
    let mut nv = Vec::new();
    add_scaled(&mut nv, &q, -k);
    add_scaled(&mut nv, &[1.0, 0.0, -1.0], 1.0);
    let dv = [2.0 * cg, -2.0 * ca]; // D(v) = 2(cγ − v cα)
                                    // N² + D² − 2cγ N D − (c²/b²) q D² = 0
    let d2 = mul(&dv, &dv);
    let mut quartic = mul(&nv, &nv);
    add_scaled(&mut quartic, &d2, 1.0);
    add_scaled(&mut quartic, &mul(&nv, &dv), -2.0 * cg);
    add_scaled(&mut quartic, &mul(&q, &d2), -c2 / b2);
    let Some(roots) = poly::roots(&quartic) else {
        return Vec::new();
    };
    let mut out = Vec::new();
    for z in roots {
        if z.im.abs() > 1e-6 * (1.0 + z.re.abs()) {
            continue;
        }
        let v = poly::polish_root(&quartic, z.re);
        let d = poly::eval(&dv, v);
        if v <= 0.0 || d.abs() < 1e-12 {
            continue;
        }
        let u = poly::eval(&nv, v) / d;
        let den = 1.0 + u * u - 2.0 * u * cg;
        if u <= 0.0 || den <= 1e-12 {
            continue;
        }
        let s1 = (c2 / den).sqrt();
        let cam = [f[0] * s1, f[1] * (u * s1), f[2] * (v * s1)];
        if let Some(p) = absolute_orientation(world, &cam) {
            out.push(p);
        }
    }
    out
}

/// Gauss–Newton refinement of a pose on normalized image points (`iterations` steps, stopping
/// early when the update is negligible). Points behind the camera are skipped.
pub fn refine_pose(
    pose: &Pose,
    x: &[Vector2<f64>],
    world: &[Vector3<f64>],
    iterations: usize,
) -> Pose {
    let mut p = *pose;
    for _ in 0..iterations {
        let mut jtj = Matrix6::<f64>::zeros();
        let mut jtr = Vector6::<f64>::zeros();
        let mut cost = 0.0;
        for (xi, wi) in x.iter().zip(world) {
            let y = p.transform(wi);
            if y.z <= 1e-12 {
                continue;
            }
            let iz = 1.0 / y.z;
            let r = Vector2::new(y.x * iz, y.y * iz) - xi;
            cost += r.norm_squared();
            // d(proj)/dy, and dy/d(δω, δt) = [−[y]ₓ | I] for the left update
            // y ← exp(δω) y + δt, i.e. R ← exp(δω) R, t ← exp(δω) t + δt.
            let dp = nalgebra::Matrix2x3::new(iz, 0.0, -y.x * iz * iz, 0.0, iz, -y.y * iz * iz);
            let yr = y;
            let skew = Matrix3::new(0.0, -yr.z, yr.y, yr.z, 0.0, -yr.x, -yr.y, yr.x, 0.0);
            let mut j = nalgebra::Matrix2x6::zeros();
            j.fixed_view_mut::<2, 3>(0, 0).copy_from(&(dp * -skew));
            j.fixed_view_mut::<2, 3>(0, 3).copy_from(&dp);
            jtj += j.transpose() * j;
            jtr += j.transpose() * r;
        }
        let Some(step) = (jtj + Matrix6::identity() * 1e-12)
            .cholesky()
            .map(|c| c.solve(&-jtr))
        else {
            break;
        };
        let dr = UnitQuaternion::from_scaled_axis(Vector3::new(step[0], step[1], step[2]));
        let cand = Pose {
            rotation: dr * p.rotation,
            translation: dr * p.translation + Vector3::new(step[3], step[4], step[5]),
        };
        let new_cost: f64 = x
            .iter()
            .zip(world)
            .map(|(xi, wi)| {
                let e = cand.reprojection_error(xi, wi);
                if e.is_finite() {
                    e * e
                } else {
                    0.0
                }
            })
            .sum();
        if new_cost > cost {
            break;
        }
        p = cand;
        if step.norm() < 1e-12 {
            break;
        }
    }
    p
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scene() -> (Pose, Vec<Vector3<f64>>, Vec<Vector2<f64>>) {
        let pose = Pose {
            rotation: UnitQuaternion::from_euler_angles(0.2, -0.3, 0.5),
            translation: Vector3::new(0.3, -0.2, 4.0),
        };
        let world: Vec<Vector3<f64>> = (0..20)
            .map(|i| {
                let t = i as f64;
                Vector3::new((t * 0.7).sin(), (t * 1.3).cos(), (t * 0.37).sin() * 0.8)
            })
            .collect();
        let x = world
            .iter()
            .map(|w| {
                let y = pose.transform(w);
                Vector2::new(y.x / y.z, y.y / y.z)
            })
            .collect();
        (pose, world, x)
    }

    #[test]
    fn p3p_recovers_the_pose_among_its_solutions() {
        let (pose, world, x) = scene();
        for s in 0..6 {
            let idx = [s, s + 5, s + 11];
            let rays = idx.map(|i| Vector3::new(x[i].x, x[i].y, 1.0));
            let pts = idx.map(|i| world[i]);
            let sols = p3p(&rays, &pts);
            assert!(
                !sols.is_empty() && sols.len() <= 4,
                "{} solutions",
                sols.len()
            );
            let best = sols
                .iter()
                .map(|p| {
                    p.rotation.angle_to(&pose.rotation) + (p.translation - pose.translation).norm()
                })
                .fold(f64::INFINITY, f64::min);
            assert!(best < 1e-8, "sample {s}: best error {best}");
        }
    }

    #[test]
    fn refinement_converges_from_a_perturbed_pose() {
        let (pose, world, x) = scene();
        let start = Pose {
            rotation: UnitQuaternion::from_euler_angles(0.03, 0.02, -0.04) * pose.rotation,
            translation: pose.translation + Vector3::new(0.1, -0.05, 0.2),
        };
        let p = refine_pose(&start, &x, &world, 20);
        assert!(p.rotation.angle_to(&pose.rotation) < 1e-9);
        assert!((p.translation - pose.translation).norm() < 1e-8);
    }
}
