//! The standard stages, one file each, and the standard graph:
//!
//! ```text
//! ingest ─▶ features ─▶ matches ─▶ sparse ─▶ dense ─▶ mesh ─▶ render
//!    └─────────┴───────────┴─────────┴─────────┴───────┴────────┘  (every stage also reads ingest's image list)
//! ```
//!
//! `dense` reads `sparse` (and `features` for a video's key-frames); `mesh` reads `dense` only
//! (plus the image list), so a stage that needs the sparse model never waits for a mesh;
//! `render` reads sparse, and dense and mesh when they are there; `augment` (only with an object)
//! reads sparse, and the mesh when it is there.
//!
//! A stage is one file here (its name, reads, options and their check, summary and body: see
//! [`crate::Stage`]; the sparse stage keeps what it reads in `sparse/input.rs`) and one
//! `register` line below; its options are checked when it is registered.

pub mod augment;
pub mod dense;
pub mod features;
pub mod ingest;
pub mod matches;
pub mod mesh;
pub mod render;
pub mod sparse;
pub mod tracks;

use std::path::Path;

use crate::error::Result;
use crate::options::PipelineOptions;
use crate::stage::Pipeline;

impl Pipeline {
    /// The standard graph on one input (a photo folder or a video file). The options are checked
    /// first; the error names the first option out of range.
    pub fn standard(input: &Path, o: &PipelineOptions) -> Result<Self> {
        let mut p = Pipeline::new();
        p.register(ingest::Ingest {
            input: input.to_path_buf(),
            options: o.ingest.clone(),
        })?
        .register(features::Features {
            options: o.features.clone(),
        })?
        .register(matches::Matches {
            options: o.matches.clone(),
        })?
        .register(sparse::Sparse {
            options: o.sparse.clone(),
        })?
        .register(dense::Dense {
            options: o.dense.clone(),
        })?
        .register(mesh::Mesh {
            options: o.mesh.clone(),
        })?
        .register(render::Render {
            options: o.render.clone(),
        })?;
        if let Some(a) = &o.augment {
            p.register(augment::Augment { options: a.clone() })?;
        }
        Ok(p)
    }
}

impl PipelineOptions {
    /// Checks every stage's options (each stage checks its own when the standard graph registers
    /// it); the error names the first option out of range.
    pub fn validate(&self) -> Result<()> {
        Pipeline::standard(Path::new(""), self).map(|_| ())
    }
}
