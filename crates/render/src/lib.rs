//! Rendering of the reconstructed models: the software rasteriser, image-based rendering (§5.2) and the augmented video
//! (§5.3). The pipeline only loads a workspace and calls in here; every step of rendering and augmenting lives in this
//! crate.
//!
//! - [`render_mesh`] (`raster.rs`): a z-buffered, perspective-correct software rasteriser that renders a
//!   (textured or vertex-coloured) mesh through a calibrated camera, radial distortion applied at the vertices, so a
//!   model can be compared with an input photo pixel by pixel. `raster.rs` also exposes the generic `rasterise`
//!   (sub-sample grid, window, z-buffer, fragment callback) that the mesh renderer, the compositor and the occlusion
//!   depth share;
//! - [`ibr`]: combined image- and geometry-based rendering (§5.2) from the recorded images and their depth maps:
//!   - `source.rs`: a recorded view ready for look-ups (matrices, f32 colours, depth holes filled by pull-push
//!     diffusion);
//!   - `support.rs`: the virtual view's support mesh (projected camera centres + image corners, `spade` Delaunay), eq. 29
//!     corner points, the depth search along a virtual ray (iterated, with a ray march as fallback), adaptive
//!     subdivision, the least-squares fixed plane;
//!   - `scene.rs` (`IbrScene`): the prepared views, the fixed plane, the scene box;
//!   - `ulr.rs`: unstructured-lumigraph weights (Buehler et al. 2001);
//!   - `shade.rs`: the leaf-id raster over ideal pixels and the per-pixel loop (plane intersection or proxy depth,
//!     barycentric or grid-interpolated weights merged per view, occlusion-checked bilinear samples in the distorted
//!     images);
//!   - `mod.rs`: the methods, the options and the `Renderer` with reused buffers, rows in parallel;
//! - `scene`: the scene a workspace is rendered from (its depth maps, or the sparse views with the fixed plane when
//!   there are none, and the textured mesh) and the render methods; cameras in a pose are `core::PosedCamera`;
//! - [`path`]: camera paths for fly-throughs (Catmull–Rom through poses, orbit);
//! - [`metrics`]: PSNR and SSIM against a photo over a mask (the novel-view protocol);
//! - [`augment`] (§5.3): the placement similarity, automatic placement on the dominant near-horizontal plane by RANSAC
//!   with `robust::run` (`place.rs`), the supersampled, shaded, occlusion-tested compositor (`composite.rs`), the
//!   shipped box and axes (`objects.rs`), and the frame loop (occlusion depth in the object's window, per-frame RMS,
//!   anchor jitter).
//!
//! Files, video encoding and the camera-track exports stay in `handheld-io`; the pipeline only orchestrates.

pub mod augment;
pub mod ibr;
pub mod metrics;
pub mod path;
pub mod raster;
pub mod scene;

pub use ibr::{FrameStats, IbrError, IbrMethod, IbrOptions, IbrScene, Plane, Renderer};
pub use metrics::{quality, Quality};
pub use raster::{mean_absolute_difference, render_mesh, Rendered};
