//! Rigid and similarity transforms, named by the frames they map between (`cam_from_world`:
//! `p_in_cam = cam_from_world · p_in_world`). The paper's `R, t` of eq. 2 are the camera orientation and
//! position in the world, so `cam_from_world = (Rᵀ, −Rᵀ t)`.

use nalgebra::{
    Isometry3, Matrix3, Matrix3x4, Point3, Rotation3, Translation3, UnitQuaternion, Vector3,
};
use serde::{Deserialize, Serialize};

/// A rigid transform `b_from_a`; a thin alias of nalgebra's isometry.
pub type Rigid3 = Isometry3<f64>;

/// Builds `cam_from_world` from the paper's camera orientation `R` (camera to world) and centre `t`.
pub fn cam_from_world_from_center(
    r_world_from_cam: &Rotation3<f64>,
    center: &Point3<f64>,
) -> Rigid3 {
    let r = r_world_from_cam.inverse();
    let t = -(r * center.coords);
    Isometry3::from_parts(
        Translation3::from(t),
        UnitQuaternion::from_rotation_matrix(&r),
    )
}

/// The camera centre in world coordinates.
pub fn center_of(cam_from_world: &Rigid3) -> Point3<f64> {
    cam_from_world.inverse().translation.vector.into()
}

/// `[R | t]` as a 3×4 matrix.
pub fn to_matrix3x4(cam_from_world: &Rigid3) -> Matrix3x4<f64> {
    let mut m = Matrix3x4::zeros();
    m.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(cam_from_world.rotation.to_rotation_matrix().matrix());
    m.fixed_view_mut::<3, 1>(0, 3)
        .copy_from(&cam_from_world.translation.vector);
    m
}

/// A similarity `b_from_a`: `p_b = scale · R · p_a + t`. Used to align a reconstruction with ground truth.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Sim3 {
    pub scale: f64,
    pub rotation: UnitQuaternion<f64>,
    pub translation: Vector3<f64>,
}

impl Sim3 {
    pub fn identity() -> Self {
        Self {
            scale: 1.0,
            rotation: UnitQuaternion::identity(),
            translation: Vector3::zeros(),
        }
    }

    pub fn transform_point(&self, p: &Point3<f64>) -> Point3<f64> {
        Point3::from(self.scale * (self.rotation * p.coords) + self.translation)
    }

    /// The inverse similarity `a_from_b` of this `b_from_a`.
    pub fn inverse(&self) -> Self {
        let rotation = self.rotation.inverse();
        Self {
            scale: 1.0 / self.scale,
            rotation,
            translation: -(rotation * self.translation) / self.scale,
        }
    }

    /// Maps a pose `cam_from_a` to `cam_from_b` for this `b_from_a` (the scale goes into the translation).
    pub fn transform_pose(&self, cam_from_a: &Rigid3) -> Rigid3 {
        let r = cam_from_a.rotation * self.rotation.inverse();
        let t = self.scale * cam_from_a.translation.vector - r * self.translation;
        Isometry3::from_parts(Translation3::from(t), r)
    }

    /// Least-squares similarity `dst ≈ s R src + t` (Umeyama 1991).
    pub fn align(src: &[Point3<f64>], dst: &[Point3<f64>]) -> Option<Self> {
        let n = src.len();
        if n < 3 || dst.len() != n {
            return None;
        }
        let mu_s = src.iter().map(|p| p.coords).sum::<Vector3<f64>>() / n as f64;
        let mu_d = dst.iter().map(|p| p.coords).sum::<Vector3<f64>>() / n as f64;
        let mut cov = Matrix3::zeros();
        let mut var = 0.0;
        for (s, d) in src.iter().zip(dst) {
            let xs = s.coords - mu_s;
            cov += (d.coords - mu_d) * xs.transpose();
            var += xs.norm_squared();
        }
        cov /= n as f64;
        var /= n as f64;
        if var <= 0.0 {
            return None;
        }
        let svd = cov.svd(true, true);
        let (u, vt) = (svd.u?, svd.v_t?);
        let mut sgn = Matrix3::identity();
        if u.determinant() * vt.determinant() < 0.0 {
            sgn[(2, 2)] = -1.0;
        }
        let r = u * sgn * vt;
        let d = svd.singular_values;
        let trace = d[0] * sgn[(0, 0)] + d[1] * sgn[(1, 1)] + d[2] * sgn[(2, 2)];
        let scale = trace / var;
        let rotation = UnitQuaternion::from_matrix(&r);
        let translation = mu_d - scale * (rotation * mu_s);
        Some(Self {
            scale,
            rotation,
            translation,
        })
    }
}

/// The angle of a rotation, in degrees.
pub fn rotation_angle_deg(q: &UnitQuaternion<f64>) -> f64 {
    q.angle().to_degrees()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_similarity_and_its_inverse_cancel() {
        let s = Sim3 {
            scale: 0.3,
            rotation: UnitQuaternion::from_scaled_axis(Vector3::new(0.4, -0.2, 1.1)),
            translation: Vector3::new(1.0, -5.0, 2.5),
        };
        let p = Point3::new(0.7, 2.0, -3.0);
        let back = s.inverse().transform_point(&s.transform_point(&p));
        assert!((back - p).norm() < 1e-12, "{back}");
    }

    #[test]
    fn center_round_trip() {
        let r = Rotation3::from_euler_angles(0.1, -0.4, 0.7);
        let c = Point3::new(1.0, -2.0, 3.5);
        let pose = cam_from_world_from_center(&r, &c);
        assert!((center_of(&pose) - c).norm() < 1e-12);
        assert!(pose.transform_point(&c).coords.norm() < 1e-12);
    }

    #[test]
    fn umeyama_recovers_similarity() {
        let truth = Sim3 {
            scale: 2.5,
            rotation: UnitQuaternion::from_euler_angles(0.3, 0.2, -1.0),
            translation: Vector3::new(1.0, 2.0, -3.0),
        };
        let src: Vec<_> = (0..10)
            .map(|i| Point3::new(i as f64, (i * i) as f64 * 0.1, (i as f64).sin()))
            .collect();
        let dst: Vec<_> = src.iter().map(|p| truth.transform_point(p)).collect();
        let est = Sim3::align(&src, &dst).expect("well-posed");
        assert!((est.scale - 2.5).abs() < 1e-10);
        assert!(est.rotation.angle_to(&truth.rotation) < 1e-10);
        assert!((est.translation - truth.translation).norm() < 1e-9);
    }

    #[test]
    fn sim3_pose_transform_keeps_projection() {
        let s = Sim3 {
            scale: 3.0,
            rotation: UnitQuaternion::from_euler_angles(0.5, 0.1, 0.2),
            translation: Vector3::new(0.0, 1.0, 2.0),
        };
        let pose = cam_from_world_from_center(
            &Rotation3::from_euler_angles(0.2, 0.3, 0.1),
            &Point3::new(0.5, 0.0, -4.0),
        );
        let p = Point3::new(0.3, 0.2, 1.0);
        let a = pose.transform_point(&p);
        let b = s
            .transform_pose(&pose)
            .transform_point(&s.transform_point(&p));
        assert!(((a.coords / a.z) - (b.coords / b.z)).norm() < 1e-12);
    }
}
