//! Core types shared by every Handheld stage.
//!
//! The notation follows Pollefeys et al., *Visual Modeling with a Hand-Held Camera* (IJCV 2004), §1.1:
//! a projective camera is a 3×4 matrix `P` with `m ~ P M` (eq. 1); in a metric frame
//! `P = K Rᵀ [I | −t]` (eq. 2) and radial distortion is applied to normalised coordinates (eq. 3).
//!
//! The crate is split by concept: [`ids`] (newtype identifiers), [`camera`] (intrinsics, distortion and
//! the metric camera), [`pose`] (rigid and similarity transforms named by their frames),
//! [`posed_camera`] (a camera in a pose, what every stage passes to project, render or rectify),
//! [`projective`] (the projective world of §3.1–3.3), [`reconstruction`] (tracks and the metric
//! reconstruction),
//! [`maps`] (dense float maps such as depth), [`posed_view`] (a posed view with its image and
//! optional depth maps, the vocabulary of the dense, surface and rendering stages), [`geometry3d`] (point clouds and triangle meshes).
//! Nothing here touches a file: input and output live in `handheld-io`.
//!
//! Where each piece lives:
//! - `ids.rs`: newtype ids;
//! - `camera.rs`: `Intrinsics` (eq. 2's K: focal length f, aspect ratio r, skew s, principal point u, v; eq. 3's radial
//!   k1 + k2) and `Camera` (an intrinsics group);
//! - `pose.rs`: `Rigid3` poses named `cam_from_world` (`p_in_cam = cam_from_world · p_in_world`), `Sim3` and Umeyama
//!   alignment; a camera in a pose is one type, `PosedCamera { camera, cam_from_world }`;
//! - `projective.rs`: `ProjectiveCamera {P}`, `ProjectivePoint {X}`, `ProjectiveReconstruction`;
//! - `reconstruction.rs`: `Track`, `View` (with optional video `FrameInfo`), `Point3D`, `MetricReconstruction` (many
//!   views sharing intrinsics groups);
//! - `maps.rs`: `FloatMap` (depth, variance, confidence, visibility);
//! - `posed_view.rs`: `PosedView`, a view's name, camera, pose and RGB image, with optional depth, variance, confidence
//!   and visibility: the one posed-view type of dense, mesh and render;
//! - `geometry3d.rs`: `PointCloud`, `TriMesh`; `closest.rs`: point-to-triangle distance;
//! - `progress.rs`: the `Progress` trait every stage reports through.

pub mod camera;
pub mod closest;
pub mod geometry3d;
pub mod ids;
pub mod maps;
pub mod pose;
pub mod posed_camera;
pub mod posed_view;
pub mod progress;
pub mod projective;
pub mod reconstruction;

pub use camera::{Camera, Intrinsics};
pub use geometry3d::{PointCloud, TriMesh};
pub use ids::{CameraId, ImageId, PointId};
pub use maps::FloatMap;
pub use pose::{Rigid3, Sim3};
pub use posed_camera::PosedCamera;
pub use posed_view::{PosedView, ViewError};
pub use progress::{NoProgress, Progress};
pub use projective::{ProjectiveCamera, ProjectivePoint, ProjectiveReconstruction};
pub use reconstruction::{
    FrameInfo, MetricReconstruction, Observation, Point3D, Track, TrackElement, View,
};

/// Pixel convention used everywhere inside Handheld: the centre of the top-left pixel is `(0, 0)`,
/// `x` grows to the right and `y` downwards (Hartley & Zisserman, OpenCV). COLMAP puts that centre at
/// `(0.5, 0.5)`; `handheld-io` converts at the boundary.
pub const PIXEL_CENTER_OFFSET_COLMAP: f64 = 0.5;
