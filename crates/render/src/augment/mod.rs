//! Augmented video (§5.3): a virtual object placed in the reconstructed scene and rendered into
//! every frame through that frame's camera, radial distortion included, so that it stays put in
//! the original (distorted) footage.
//!
//! - [`Placement`]: the similarity from the object's frame to the model's, automatic
//!   ([`auto_place`]: the dominant supporting plane of the sparse points by RANSAC on
//!   [`handheld_robust::run`], the object standing upright on it near the points most frames see,
//!   scaled to the scene) or given.
//! - [`Compositor`]: renders the object with `SUB × SUB` samples per pixel (anti-aliased edges),
//!   Lambert-shaded with a light whose colour is the frame's average colour, hidden where the
//!   real scene (a depth map in the frame's camera: the mesh or the dense depth) is nearer, and
//!   composites it over the frame.
//! - [`object_box`], [`object_axes`]: the two objects the project ships, made here.

mod composite;
mod frames;
mod objects;
mod place;
#[cfg(test)]
mod tests;

use handheld_core::{PosedCamera, TriMesh};
use nalgebra::{Matrix3, Point3, Rotation3, UnitQuaternion, Vector2, Vector3};
use serde::{Deserialize, Serialize};
use thiserror::Error;

pub use composite::{CompositeStats, Compositor, SUB};
pub use frames::{
    anchor_of, frame_rms, jitter, nearest_sources, placed_vertices, scene_depth, visible_somewhere,
    warped_depth, DepthSource, FrameFigures, FrameLoop, Occluder, TrackedFrame,
};
pub use objects::{object_axes, object_box};
pub use place::{auto_place, PlaceOptions, PlacementReport, SupportPlane};

/// What went wrong in augmenting.
#[derive(Debug, Error)]
pub enum AugmentError {
    #[error("no supporting plane: {0}")]
    NoPlane(String),
    #[error("the object has no triangles")]
    EmptyObject,
    #[error("the placement puts the object behind every camera (or outside every image); give another --transform")]
    Invisible,
    #[error("placement: {0}")]
    Placement(String),
}

/// `X_model = scale · R · X_object + translation`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Placement {
    pub scale: f64,
    /// Unit quaternion (w, x, y, z).
    pub rotation: [f64; 4],
    pub translation: [f64; 3],
}

impl Placement {
    pub fn new(scale: f64, r: &Rotation3<f64>, t: &Vector3<f64>) -> Self {
        let q = UnitQuaternion::from_rotation_matrix(r).into_inner();
        Self {
            scale,
            rotation: [q.w, q.i, q.j, q.k],
            translation: [t.x, t.y, t.z],
        }
    }

    /// Checks a placement read from a file: positive finite scale, unit quaternion, finite.
    pub fn validate(&self) -> Result<(), AugmentError> {
        let q = self.rotation;
        let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
        if !(self.scale.is_finite() && self.scale > 0.0) {
            return Err(AugmentError::Placement(format!(
                "scale must be positive, got {}",
                self.scale
            )));
        }
        if !(n.is_finite() && (n - 1.0).abs() < 1e-3) {
            return Err(AugmentError::Placement(format!(
                "rotation must be a unit quaternion [w, x, y, z], |q| = {n}"
            )));
        }
        if self.translation.iter().any(|v| !v.is_finite()) {
            return Err(AugmentError::Placement("translation must be finite".into()));
        }
        Ok(())
    }

    pub fn rotation_matrix(&self) -> Matrix3<f64> {
        let [w, x, y, z] = self.rotation;
        *UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z))
            .to_rotation_matrix()
            .matrix()
    }

    /// An object point in the model frame.
    pub fn apply(&self, p: &Point3<f64>) -> Point3<f64> {
        Point3::from(
            self.rotation_matrix() * p.coords * self.scale + Vector3::from(self.translation),
        )
    }

    /// The object mesh in the model frame (normals rotated).
    pub fn transform(&self, object: &TriMesh) -> TriMesh {
        let r = self.rotation_matrix();
        let mut m = object.clone();
        for p in &mut m.vertices.positions {
            let q = self.apply(&Point3::new(
                f64::from(p[0]),
                f64::from(p[1]),
                f64::from(p[2]),
            ));
            *p = [q.x as f32, q.y as f32, q.z as f32];
        }
        for n in &mut m.vertices.normals {
            let v = r * Vector3::new(f64::from(n[0]), f64::from(n[1]), f64::from(n[2]));
            *n = [v.x as f32, v.y as f32, v.z as f32];
        }
        m
    }
}

/// The object's axis-aligned bounds in its own frame.
pub fn bounds(object: &TriMesh) -> (Vector3<f64>, Vector3<f64>) {
    let mut lo = Vector3::repeat(f64::INFINITY);
    let mut hi = Vector3::repeat(f64::NEG_INFINITY);
    for p in &object.vertices.positions {
        let v = Vector3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
        lo = lo.inf(&v);
        hi = hi.sup(&v);
    }
    (lo, hi)
}

/// The pixel positions of model-frame points in a frame (distortion applied); `None` behind it.
pub fn project(view: &PosedCamera, points: &[Point3<f64>]) -> Vec<Option<Vector2<f64>>> {
    points.iter().map(|p| view.project(p)).collect()
}
