//! Tracks and the metric reconstruction: id-keyed maps of intrinsics groups ([`Camera`]), registered
//! views ([`View`], one per photo or video frame, each with its own `cam_from_world`) and 3D points
//! with their tracks. This mirrors COLMAP's scene model so the sparse model can be exported losslessly.

use std::collections::BTreeMap;

use nalgebra::{Point3, Vector2};
use serde::{Deserialize, Serialize};

use crate::camera::Camera;
use crate::ids::{CameraId, ImageId, PointId};
use crate::pose::{center_of, Rigid3, Sim3};

/// One observation of a track: keypoint `point2d_idx` of image `image_id`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct TrackElement {
    pub image_id: ImageId,
    pub point2d_idx: u32,
}

/// The views that see one 3D point.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Track {
    pub elements: Vec<TrackElement>,
}

impl Track {
    pub fn len(&self) -> usize {
        self.elements.len()
    }

    pub fn is_empty(&self) -> bool {
        self.elements.is_empty()
    }
}

/// A 2D keypoint of a view and the 3D point it was triangulated into, if any.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Observation {
    /// Pixel position (pixel-centre convention of [`crate::PIXEL_CENTER_OFFSET_COLMAP`]).
    pub xy: Vector2<f64>,
    pub point_id: Option<PointId>,
}

/// Where a view came from in a video; `None` for photos.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameInfo {
    /// Index of the frame in the decoded stream (before any stride).
    pub index: u64,
    /// Presentation time in seconds from the start of the video.
    pub time_s: f64,
    /// True for key-frames selected by §3.1; in-between frames get a pose by resection.
    pub keyframe: bool,
}

/// A registered view.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct View {
    pub id: ImageId,
    /// File name relative to the image folder (COLMAP's `NAME`).
    pub name: String,
    pub camera_id: CameraId,
    pub cam_from_world: Rigid3,
    pub observations: Vec<Observation>,
    pub frame: Option<FrameInfo>,
}

impl View {
    pub fn center(&self) -> Point3<f64> {
        center_of(&self.cam_from_world)
    }
}

/// A triangulated 3D point.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Point3D {
    pub xyz: Point3<f64>,
    pub color: [u8; 3],
    /// Mean reprojection error in pixels (COLMAP's `ERROR`); negative when unknown.
    pub error: f64,
    pub track: Track,
}

/// A reconstruction in a metric frame (up to a similarity), as produced by self-calibration and metric BA.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MetricReconstruction {
    pub cameras: BTreeMap<CameraId, Camera>,
    pub views: BTreeMap<ImageId, View>,
    pub points: BTreeMap<PointId, Point3D>,
}

impl MetricReconstruction {
    /// Projects a world point into a view; `None` when the view is unknown or the point is behind it.
    pub fn project(&self, image_id: ImageId, p: &Point3<f64>) -> Option<Vector2<f64>> {
        let view = self.views.get(&image_id)?;
        self.cameras
            .get(&view.camera_id)?
            .project(&view.cam_from_world, p)
    }

    /// Every track element whose point and view exist, with its reprojection error in pixels
    /// (`None` when the point is behind the view).
    pub fn residuals(&self) -> impl Iterator<Item = (&TrackElement, Option<f64>)> + '_ {
        self.points.values().flat_map(move |p| {
            p.track.elements.iter().filter_map(move |el| {
                let obs = self
                    .views
                    .get(&el.image_id)?
                    .observations
                    .get(el.point2d_idx as usize)?;
                Some((
                    el,
                    self.project(el.image_id, &p.xyz)
                        .map(|px| (px - obs.xy).norm()),
                ))
            })
        })
    }

    /// Reprojection errors (pixels) of every track element whose point and view exist; infinite
    /// for a point behind its view.
    pub fn reprojection_errors(&self) -> Vec<f64> {
        self.residuals()
            .map(|(_, e)| e.unwrap_or(f64::INFINITY))
            .collect()
    }

    /// Mean reprojection error in pixels over all observations (NaN when there are none).
    pub fn mean_reprojection_error(&self) -> f64 {
        let e = self.reprojection_errors();
        e.iter().sum::<f64>() / e.len() as f64
    }

    /// Applies a similarity `new_from_old` to every pose and point.
    pub fn transform(&mut self, new_from_old: &Sim3) {
        for v in self.views.values_mut() {
            v.cam_from_world = new_from_old.transform_pose(&v.cam_from_world);
        }
        for p in self.points.values_mut() {
            p.xyz = new_from_old.transform_point(&p.xyz);
        }
    }

    /// Checks internal references: every view's camera exists, every track element points at an
    /// existing observation that refers back to the point.
    pub fn validate(&self) -> Result<(), String> {
        for v in self.views.values() {
            if !self.cameras.contains_key(&v.camera_id) {
                return Err(format!(
                    "view {} ({}) uses unknown camera {}",
                    v.id, v.name, v.camera_id
                ));
            }
        }
        for (id, p) in &self.points {
            for el in &p.track.elements {
                let view = self
                    .views
                    .get(&el.image_id)
                    .ok_or(format!("point {id} seen by unknown view {}", el.image_id))?;
                let obs = view
                    .observations
                    .get(el.point2d_idx as usize)
                    .ok_or(format!(
                        "point {id}: view {} has no keypoint {}",
                        el.image_id, el.point2d_idx
                    ))?;
                if obs.point_id != Some(*id) {
                    return Err(format!(
                        "point {id}: keypoint {} of view {} does not refer back",
                        el.point2d_idx, el.image_id
                    ));
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Intrinsics;
    use crate::pose::cam_from_world_from_center;
    use nalgebra::{Rotation3, UnitQuaternion, Vector3};

    fn tiny() -> MetricReconstruction {
        let mut rec = MetricReconstruction::default();
        rec.cameras.insert(
            CameraId(1),
            Camera {
                id: CameraId(1),
                width: 640,
                height: 480,
                intrinsics: Intrinsics::pinhole(500.0, 319.5, 239.5),
            },
        );
        let pose = cam_from_world_from_center(&Rotation3::identity(), &Point3::new(0.0, 0.0, -5.0));
        let x = Point3::new(0.1, 0.2, 0.0);
        let px = rec.cameras[&CameraId(1)].project(&pose, &x).unwrap();
        rec.views.insert(
            ImageId(1),
            View {
                id: ImageId(1),
                name: "a.png".into(),
                camera_id: CameraId(1),
                cam_from_world: pose,
                observations: vec![Observation {
                    xy: px,
                    point_id: Some(PointId(9)),
                }],
                frame: None,
            },
        );
        rec.points.insert(
            PointId(9),
            Point3D {
                xyz: x,
                color: [1, 2, 3],
                error: 0.0,
                track: Track {
                    elements: vec![TrackElement {
                        image_id: ImageId(1),
                        point2d_idx: 0,
                    }],
                },
            },
        );
        rec
    }

    #[test]
    fn exact_projection_has_zero_error_and_survives_similarity() {
        let mut rec = tiny();
        rec.validate().unwrap();
        assert!(rec.mean_reprojection_error() < 1e-12);
        rec.transform(&Sim3 {
            scale: 4.0,
            rotation: UnitQuaternion::from_euler_angles(0.1, 0.2, 0.3),
            translation: Vector3::new(1.0, 2.0, 3.0),
        });
        assert!(rec.mean_reprojection_error() < 1e-9);
    }

    #[test]
    fn validate_catches_dangling_track() {
        let mut rec = tiny();
        rec.points.get_mut(&PointId(9)).unwrap().track.elements[0].point2d_idx = 5;
        assert!(rec.validate().is_err());
    }
}
