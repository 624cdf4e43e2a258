//! [`PosedView`]: one view of a sequence with everything the dense, surface and rendering stages
//! share: its camera, pose and image, and the optional per-pixel maps the dense stage adds (depth,
//! its variance, a fusion confidence and the multi-view visibility count).
//!
//! The image is an 8-bit [`RgbImage`] (grey images are stored with three equal channels): every
//! consumer samples it directly, and it is a quarter of the memory of a float copy. Maps are
//! one-channel [`FloatMap`]s at the camera's size, row-major, camera-frame `z` for depth; a
//! missing value is `NaN` (depth, variance) or `0` (confidence, visibility).

use image::RgbImage;
use nalgebra::Point3;
use thiserror::Error;

use crate::camera::Camera;
use crate::maps::FloatMap;
use crate::pose::Rigid3;
use crate::posed_camera::PosedCamera;

/// A posed view: camera and pose ([`PosedCamera`], `p_in_cam = cam_from_world · p_in_world`),
/// image, and the optional maps of the dense stage. All images and maps have the camera's size
/// ([`PosedView::validate`]).
///
/// Stages read only what they need: dense matching and linking the image, camera and pose; fusion
/// and evaluation the depth (and confidence); texturing the image (and depth for occlusions). A
/// view used only for its depth may carry an empty image (`RgbImage::default()`).
#[derive(Clone, Debug, PartialEq)]
pub struct PosedView {
    /// The image's name (file name relative to the image folder), used in messages and file names.
    pub name: String,
    /// The camera that took the image (its size is the image's size) and its pose, world →
    /// camera; [`PosedView::camera`] and [`PosedView::cam_from_world`] read its parts.
    pub posed: PosedCamera,
    /// The original (distorted) image, 0..=255, at the camera's size.
    pub image: RgbImage,
    /// Camera-frame `z` of the surface through each pixel centre; `NaN` or ≤ 0 where missing.
    pub depth: Option<FloatMap>,
    /// Variance of `depth` (model units²); `NaN` where missing.
    pub variance: Option<FloatMap>,
    /// Fusion weight of each depth pixel (0 = ignore), e.g. `1 / (1 + σ/(0.005·z))`.
    pub confidence: Option<FloatMap>,
    /// Number of views a depth pixel was linked through (reference included); 0 where missing.
    pub visibility: Option<FloatMap>,
}

/// A map or image of a [`PosedView`] that does not fit its camera.
#[derive(Clone, Debug, Error, PartialEq, Eq)]
pub enum ViewError {
    /// The map or image does not have the camera's size.
    #[error("{name}: the {what} is {got_w}x{got_h} but its camera is {cam_w}x{cam_h}; images and maps must be at the camera's resolution")]
    SizeMismatch {
        name: String,
        what: &'static str,
        got_w: usize,
        got_h: usize,
        cam_w: usize,
        cam_h: usize,
    },
    /// A map has several channels or a data length that does not match its size.
    #[error("{name}: malformed {what}: {reason}")]
    MalformedMap {
        name: String,
        what: &'static str,
        reason: String,
    },
}

impl PosedView {
    /// A view with its image and no maps.
    pub fn new(
        name: impl Into<String>,
        camera: Camera,
        cam_from_world: Rigid3,
        image: RgbImage,
    ) -> Self {
        Self::from_posed(name, PosedCamera::new(camera, cam_from_world), image)
    }

    /// A view of `posed` with its image and no maps.
    pub fn from_posed(name: impl Into<String>, posed: PosedCamera, image: RgbImage) -> Self {
        Self {
            name: name.into(),
            posed,
            image,
            depth: None,
            variance: None,
            confidence: None,
            visibility: None,
        }
    }

    /// The camera that took the image.
    pub fn camera(&self) -> &Camera {
        &self.posed.camera
    }

    /// World → camera.
    pub fn cam_from_world(&self) -> &Rigid3 {
        &self.posed.cam_from_world
    }

    /// The camera centre in world coordinates.
    pub fn center(&self) -> Point3<f64> {
        self.posed.center()
    }

    /// `(width, height)` of the camera, in pixels.
    pub fn size(&self) -> (usize, usize) {
        self.posed.size()
    }

    /// The image as a 3-channel float map, 0..=255 (a copy).
    pub fn image_map(&self) -> FloatMap {
        FloatMap::from_u8(
            self.image.width() as usize,
            self.image.height() as usize,
            3,
            self.image.as_raw(),
        )
    }

    /// Colour of pixel `(x, y)` (no bounds check beyond the image's own).
    pub fn rgb(&self, x: u32, y: u32) -> [u8; 3] {
        self.image.get_pixel(x, y).0
    }

    /// The maps that are present, with their names: depth, variance, confidence, visibility.
    pub fn maps(&self) -> impl Iterator<Item = (&'static str, &FloatMap)> {
        [
            ("depth", &self.depth),
            ("variance", &self.variance),
            ("confidence", &self.confidence),
            ("visibility", &self.visibility),
        ]
        .into_iter()
        .filter_map(|(n, m)| m.as_ref().map(|m| (n, m)))
    }

    /// Fraction of pixels with a depth (0 without a depth map).
    pub fn fill(&self) -> f64 {
        self.depth.as_ref().map_or(0.0, FloatMap::fill_ratio)
    }

    /// Checks that the image has the camera's size.
    pub fn check_image(&self) -> Result<(), ViewError> {
        let (cw, ch) = self.size();
        let (w, h) = (self.image.width() as usize, self.image.height() as usize);
        if (w, h) != (cw, ch) {
            return Err(self.mismatch("image", w, h));
        }
        Ok(())
    }

    /// Checks that `map` (named `what` in the error) has one channel and the camera's size.
    pub fn check_map(&self, what: &'static str, map: &FloatMap) -> Result<(), ViewError> {
        if map.channels != 1 || map.data.len() != map.width * map.height {
            return Err(ViewError::MalformedMap {
                name: self.name.clone(),
                what,
                reason: format!(
                    "{} channels and {} values for {}x{} pixels, expected 1 channel",
                    map.channels,
                    map.data.len(),
                    map.width,
                    map.height
                ),
            });
        }
        if (map.width, map.height) != self.size() {
            return Err(self.mismatch(what, map.width, map.height));
        }
        Ok(())
    }

    /// Checks the image and every present map against the camera's size.
    pub fn validate(&self) -> Result<(), ViewError> {
        self.check_image()?;
        self.maps()
            .try_for_each(|(what, m)| self.check_map(what, m))
    }

    fn mismatch(&self, what: &'static str, got_w: usize, got_h: usize) -> ViewError {
        let (cam_w, cam_h) = self.size();
        ViewError::SizeMismatch {
            name: self.name.clone(),
            what,
            got_w,
            got_h,
            cam_w,
            cam_h,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Intrinsics;
    use crate::ids::CameraId;
    use nalgebra::Vector3;

    fn view() -> PosedView {
        let camera = Camera {
            id: CameraId(0),
            width: 4,
            height: 3,
            intrinsics: Intrinsics::pinhole(5.0, 1.5, 1.0),
        };
        let pose = Rigid3::new(Vector3::new(1.0, 2.0, 3.0), Vector3::zeros());
        PosedView::new("a.png", camera, pose, RgbImage::new(4, 3))
    }

    #[test]
    fn validates_sizes_and_centre() {
        let mut v = view();
        assert!(v.validate().is_ok());
        assert!((v.center() - Point3::new(-1.0, -2.0, -3.0)).norm() < 1e-12);
        v.depth = Some(FloatMap::filled(4, 3, 1, 2.0));
        assert_eq!(v.fill(), 1.0);
        assert!(v.validate().is_ok());
        v.confidence = Some(FloatMap::filled(3, 3, 1, 1.0));
        let e = v.validate().unwrap_err();
        assert!(e.to_string().contains("confidence is 3x3"), "{e}");
        v.confidence = Some(FloatMap::filled(4, 3, 3, 1.0));
        assert!(matches!(v.validate(), Err(ViewError::MalformedMap { .. })));
        v.confidence = None;
        v.image = RgbImage::new(2, 2);
        assert!(v.check_image().is_err());
    }
}
