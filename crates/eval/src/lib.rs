//! Evaluation as a library: everything that measures Handheld rather than runs it.
//!
//! - [`demo`]: renders a synthetic hand-held sequence with exact ground truth, runs the whole
//!   pipeline on it ([`handheld_pipeline::reconstruct`]) and scores matching, the sparse model, the
//!   depth maps and the mesh against the ground truth ([`demo::run_demo`]); the demo's augmented video is scored
//!   against the exact cameras (`demo/augment.rs`).
//! - [`bench`](mod@bench): the benchmarks against the field's references — bundle adjustment on BAL problems
//!   (Ceres), feature matching (COLMAP, run in the same process tree), the whole sparse run (COLMAP 4.2 through
//!   pycolmap), stereo on Middlebury (OpenCV's StereoSGBM), the dense targets, novel views with every N-th image held
//!   out (`bench/render.rs`), a glossy highlight on held-out views (`bench/specular.rs`), augmented-video compositing
//!   speed (`bench/augment.rs`) — and the one-pair stereo command.
//!
//! Each entry point takes a typed options struct (`Serialize`, `Deserialize`, `validate()`) and
//! returns a typed `Serialize` report; the command line only maps its flags and prints the report.
//! The figures these produce, with their commands and dates, are in `docs/benchmarks.md`.

pub mod bench;
pub mod demo;
pub mod error;

pub use demo::{run_demo, CameraPath, DemoOptions, DemoReport, DemoScene};
pub use error::{EvalError, Result};
pub use handheld_pipeline::Context;

/// An error and its causes on one line (`outer: inner: …`), as reports carry failed evaluations.
pub fn error_chain(e: &dyn std::error::Error) -> String {
    let mut text = e.to_string();
    let mut source = e.source();
    while let Some(s) = source {
        text.push_str(": ");
        text.push_str(&s.to_string());
        source = s.source();
    }
    text
}
