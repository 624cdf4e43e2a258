//! Seeded synthetic ground truth for Handheld's tests.
//!
//! * [`scene`]: planes, boxes and spheres with exact ray casting and landmark feature points;
//!   [`default_scene`]: the standard seeded layout;
//! * [`texture`]: the procedural multi-scale block texture and the landmark disks;
//! * [`mesh`]: the scene as a triangle mesh, and point-to-mesh distance;
//! * [`path`]: hand-held orbit, walk-through and forward camera paths with jitter and zoom;
//! * [`render`]: ray-cast, anti-aliased, radially distorted images with depth maps and the
//!   ground-truth [`handheld_core::MetricReconstruction`];
//! * [`needs`]: what the real-data and tool-dependent tests need, probed by the build scripts of
//!   the crates that have such tests (a missing data set or program shows as an ignored test);
//! * [`correspondences`], [`multiview`]: cheap two-view, resection and multi-view correspondence sets
//!   (noise, outliers, degenerate configurations) for solver tests, without rendering.
//!
//! `examples/render_demo.rs` renders the default 20-frame 640×480 sequence and prints its timing.
//!
//! Everything is deterministic in its seed (`ChaCha8Rng`, integer hashing); nothing touches a file.
//!
//! Glossy materials: a Blinn–Phong highlight that moves with the viewpoint, with its per-pixel map (the specular
//! benchmark); `ring.rs`: the large sparse ring scene for bundle-adjustment scaling.

pub mod correspondences;
pub mod corridor;
pub mod default_scene;
pub mod finish;
pub mod mesh;
pub mod multiview;
pub mod needs;
pub mod path;
pub mod render;
pub mod ring;
pub mod scene;
pub mod sequence;
pub mod shutter;
pub mod street;
pub mod street_scene;
pub mod texture;
mod util;

pub use correspondences::{
    resection_set, two_view_set, ResectionOptions, ResectionSet, TwoViewKind, TwoViewOptions,
    TwoViewSet,
};
pub use mesh::{distance_to_mesh, point_triangle_distance};
pub use multiview::{multi_view_set, MultiViewOptions, MultiViewSet};
pub use path::{CameraPath, PathOptions, Trajectory};
pub use render::{
    ground_truth, landmark_projection, pixel_ray, render_frame, render_frame_with_rays,
    render_sequence, render_sequence_with_scene, RayTable, SequenceOptions, SyntheticSequence,
};
pub use ring::{ring_set, RingOptions, RingSet};
pub use scene::{FaceRect, Finish, Hit, Landmark, Primitive, Scene};
pub use shutter::{FrameMotion, Shutter};
pub use street::{street_set, StreetOptions, StreetPair, StreetSet};
pub use texture::{FaceTexture, LANDMARK_HALF_SQUARE, LANDMARK_RADIUS};
