//! Rendering a workspace's new views (§5.2): the workspace's recorded views, depth maps and mesh
//! loaded as a [`RenderScene`] (`handheld_render::scene`, where the rendering itself is), one view
//! rendered to a PNG, a camera path streamed to an H.264 video.
//!
//! A workspace without dense depth maps falls back to the fixed plane, with a warning.

mod flight;
mod load;
mod view;

pub use flight::{render_flight, FlightSummary};
pub use handheld_render::scene::{
    virtual_camera, FlightOptions, PathKind, RenderMethod, RenderScene, SceneError, DEFAULT_METHOD,
};
pub(crate) use load::scene_error;
pub use load::{load_scene, scene_from_folders, write_png};
pub use view::{render_view, PoseFile, ViewSpec, ViewSummary};
