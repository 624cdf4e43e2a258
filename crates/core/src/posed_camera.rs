//! [`PosedCamera`]: a camera in a pose, the one shape every stage passes around when it needs to
//! see the world through a view (projection, rendering, rectification, texturing). A
//! [`crate::PosedView`] holds one next to its image and maps.

use nalgebra::{Point3, Vector2};
use serde::{Deserialize, Serialize};

use crate::camera::Camera;
use crate::pose::{center_of, Rigid3};

/// A camera and its pose (`p_in_cam = cam_from_world · p_in_world`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PosedCamera {
    /// The camera (intrinsics and image size).
    pub camera: Camera,
    /// World → camera.
    pub cam_from_world: Rigid3,
}

impl PosedCamera {
    /// A camera at `cam_from_world`.
    pub fn new(camera: Camera, cam_from_world: Rigid3) -> Self {
        Self {
            camera,
            cam_from_world,
        }
    }

    /// Checks that the camera can project: valid intrinsics ([`crate::Intrinsics::validate`]), a
    /// non-zero image size and a finite pose. The error says what is wrong.
    pub fn validate(&self) -> Result<(), String> {
        let camera = &self.camera;
        camera.intrinsics.validate()?;
        if camera.width == 0 || camera.height == 0 {
            return Err(format!("image size {}x{}", camera.width, camera.height));
        }
        let pose = &self.cam_from_world;
        let finite = pose.translation.vector.iter().all(|v| v.is_finite())
            && pose.rotation.coords.iter().all(|v| v.is_finite());
        if !finite {
            return Err("the pose contains a non-finite value".into());
        }
        Ok(())
    }

    /// The camera centre in world coordinates.
    pub fn center(&self) -> Point3<f64> {
        center_of(&self.cam_from_world)
    }

    /// `(width, height)` of the camera, in pixels.
    pub fn size(&self) -> (usize, usize) {
        (self.camera.width as usize, self.camera.height as usize)
    }

    /// Projects a world point to a (distorted) pixel; `None` when it lies behind the camera.
    pub fn project(&self, p_in_world: &Point3<f64>) -> Option<Vector2<f64>> {
        self.camera.project(&self.cam_from_world, p_in_world)
    }

    /// A world point in the camera frame.
    pub fn to_cam(&self, p_in_world: &Point3<f64>) -> Point3<f64> {
        self.cam_from_world.transform_point(p_in_world)
    }

    /// The same pose with the camera scaled for an image resized by `(sx, sy)`
    /// ([`Camera::scaled`]).
    pub fn scaled(&self, sx: f64, sy: f64) -> Self {
        Self::new(self.camera.scaled(sx, sy), self.cam_from_world)
    }

    /// The same pose with the camera shrunk so its longer side is at most `max_size`
    /// ([`Camera::scaled_to`]).
    pub fn scaled_to(&self, max_size: u32) -> Self {
        Self::new(self.camera.scaled_to(max_size), self.cam_from_world)
    }
}

impl From<(Camera, Rigid3)> for PosedCamera {
    fn from((camera, cam_from_world): (Camera, Rigid3)) -> Self {
        Self::new(camera, cam_from_world)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Intrinsics;
    use crate::ids::CameraId;
    use nalgebra::Vector3;

    fn posed() -> PosedCamera {
        let mut intrinsics = Intrinsics::pinhole(100.0, 31.5, 23.5);
        intrinsics.skew = 0.25;
        intrinsics.aspect = 1.1;
        let camera = Camera {
            id: CameraId(3),
            width: 64,
            height: 48,
            intrinsics,
        };
        PosedCamera::new(
            camera,
            Rigid3::new(Vector3::new(0.1, -0.2, 2.0), Vector3::new(0.05, 0.0, 0.1)),
        )
    }

    #[test]
    fn projects_through_its_pose_and_scales_like_the_image() {
        let p = posed();
        let x = Point3::new(0.3, 0.2, 1.0);
        assert_eq!(p.project(&x), p.camera.project(&p.cam_from_world, &x));
        assert!((p.to_cam(&p.center()).coords).norm() < 1e-12);
        let half = p.scaled(0.5, 0.5);
        assert_eq!(half.size(), (32, 24));
        assert_eq!(half.cam_from_world, p.cam_from_world);
        // Pixel centres at integer positions: the pixel (x, y) of the full image is
        // ((x + ½)·s − ½, (y + ½)·s − ½) in the half one.
        let (a, b) = (p.project(&x).unwrap(), half.project(&x).unwrap());
        assert!(((a.add_scalar(0.5)) * 0.5 - b.add_scalar(0.5)).norm() < 1e-9);
        assert_eq!(p.scaled_to(64), p);
        assert_eq!(p.scaled_to(0), p);
        assert_eq!(p.scaled_to(32).size(), (32, 24));
        let json = serde_json::to_string(&p).unwrap();
        let back: PosedCamera = serde_json::from_str(&json).unwrap();
        assert_eq!(back.size(), p.size());
        assert!((back.center() - p.center()).norm() < 1e-12);
    }
}
