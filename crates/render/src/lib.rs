//! Rasterisation and image-based rendering of the reconstructed models.
//!
//! Today: [`render_mesh`], a z-buffered, perspective-correct software rasteriser that renders a
//! (textured or vertex-coloured) mesh through a calibrated camera, radial distortion included,
//! so a model can be compared with an input photo pixel by pixel (issue #7's held-out view).
//! Image-based rendering and augmented video come with their own issues.

pub mod raster;

pub use raster::{mean_absolute_difference, render_mesh, Rendered};
