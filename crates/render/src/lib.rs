//! Rasterisation and image-based rendering of the reconstructed models.
//!
//! - [`render_mesh`]: a z-buffered, perspective-correct software rasteriser that renders a
//!   (textured or vertex-coloured) mesh through a calibrated camera, radial distortion included,
//!   so a model can be compared with an input photo pixel by pixel;
//! - [`ibr`]: combined image- and geometry-based rendering (§5.2) from the recorded images and
//!   their depth maps;
//! - [`metrics`]: PSNR and SSIM against a photo over a mask (the novel-view protocol);
//! - [`path`]: camera paths for fly-throughs.

pub mod augment;
pub mod ibr;
pub mod metrics;
pub mod path;
pub mod raster;
pub mod scene;

pub use ibr::{FrameStats, IbrError, IbrMethod, IbrOptions, IbrScene, Plane, Renderer};
pub use metrics::{quality, Quality};
pub use raster::{mean_absolute_difference, render_mesh, Rendered};
