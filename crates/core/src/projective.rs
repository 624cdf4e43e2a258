//! The projective world of §3.1–3.3: cameras are 3×4 matrices `P` and points homogeneous 4-vectors,
//! defined only up to a common projective transformation `T` (`P → P T⁻¹`, `M → T M`). Self-calibration
//! (§3.4, eq. 27) is the one bridge to [`crate::MetricReconstruction`].

use std::collections::BTreeMap;

use nalgebra::{Matrix3x4, Matrix4, Vector2, Vector3, Vector4};
use serde::{Deserialize, Serialize};

use crate::ids::{ImageId, PointId};
use crate::reconstruction::Track;

/// A projective camera `m ~ P M` (eq. 1).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[allow(non_snake_case)]
pub struct ProjectiveCamera {
    pub P: Matrix3x4<f64>,
}

impl ProjectiveCamera {
    /// The canonical first camera `[I | 0]` (eq. 16).
    pub fn canonical() -> Self {
        Self {
            P: Matrix3x4::identity(),
        }
    }

    /// Projects a homogeneous point to pixel coordinates; `None` at infinity in the image.
    pub fn project(&self, x: &ProjectivePoint) -> Option<Vector2<f64>> {
        let m: Vector3<f64> = self.P * x.X;
        if m.z.abs() < 1e-300 {
            return None;
        }
        Some(Vector2::new(m.x / m.z, m.y / m.z))
    }

    /// Applies `P → P T⁻¹` for a world transformation `M → T M`.
    pub fn transformed(&self, t_inv: &Matrix4<f64>) -> Self {
        Self { P: self.P * t_inv }
    }

    /// Scales `P` to unit Frobenius norm (the gauge used by projective bundle adjustment).
    pub fn normalized(&self) -> Self {
        Self {
            P: self.P / self.P.norm(),
        }
    }
}

/// A homogeneous 3D point.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[allow(non_snake_case)]
pub struct ProjectivePoint {
    pub X: Vector4<f64>,
}

impl ProjectivePoint {
    pub fn new(x: f64, y: f64, z: f64, w: f64) -> Self {
        Self {
            X: Vector4::new(x, y, z, w),
        }
    }

    /// Unit-norm representative (the point's local parameterisation on the sphere).
    pub fn normalized(&self) -> Self {
        Self {
            X: self.X / self.X.norm(),
        }
    }

    /// Euclidean coordinates, `None` for points at infinity.
    pub fn to_euclidean(&self) -> Option<Vector3<f64>> {
        if self.X.w.abs() < 1e-12 * self.X.norm() {
            return None;
        }
        Some(self.X.xyz() / self.X.w)
    }
}

/// A reconstruction up to a projective transformation: cameras for the registered views plus points
/// with their tracks. Observations are pixel coordinates, as in the metric reconstruction.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct ProjectiveReconstruction {
    pub cameras: BTreeMap<ImageId, ProjectiveCamera>,
    pub points: BTreeMap<PointId, (ProjectivePoint, Track)>,
}

impl ProjectiveReconstruction {
    /// Applies the world transformation `M → T M` to every camera and point.
    pub fn transform(&mut self, t: &Matrix4<f64>) -> Option<()> {
        let t_inv = t.try_inverse()?;
        for cam in self.cameras.values_mut() {
            *cam = cam.transformed(&t_inv);
        }
        for (p, _) in self.points.values_mut() {
            p.X = t * p.X;
        }
        Some(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn projective_transform_keeps_projections() {
        let cam = ProjectiveCamera {
            P: Matrix3x4::new(
                500.0, 0.0, 320.0, 10.0, 0.0, 500.0, 240.0, -3.0, 0.0, 0.0, 1.0, 4.0,
            ),
        };
        let x = ProjectivePoint::new(0.2, -0.1, 3.0, 1.0);
        let t = Matrix4::new(
            1.0, 0.2, 0.0, 0.5, 0.0, 1.3, 0.1, 0.0, 0.05, 0.0, 0.9, 0.0, 0.01, 0.02, 0.0, 1.0,
        );
        let mut rec = ProjectiveReconstruction::default();
        rec.cameras.insert(ImageId(0), cam);
        rec.points.insert(PointId(0), (x, Track::default()));
        let before = cam.project(&x).unwrap();
        rec.transform(&t).unwrap();
        let after = rec.cameras[&ImageId(0)]
            .project(&rec.points[&PointId(0)].0)
            .unwrap();
        assert!((before - after).norm() < 1e-9);
    }
}
