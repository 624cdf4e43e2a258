//! Surface models from calibrated views and depth maps (paper §5.1).
//!
//! * [`single`]: the §5.1 mesh of one depth map (triangle grid over the image, depth smoothing,
//!   discontinuity test) and [`enhance`]: its texture's robust median over the linked views
//!   (Ofek et al. 1997);
//! * [`tsdf`]: Curless–Levoy volumetric fusion in sparse voxel blocks; [`marching_cubes`] with the
//!   derived case table of [`mc_tables`]: the fused surface as one welded, oriented mesh;
//! * [`simplify`]: Garland–Heckbert quadric decimation (meshoptimizer), borders locked;
//! * [`texture`]: a view per face, charts, an atlas (`atlas`) with seam levelling (`seams`);
//! * [`fusion`]: [`fuse_depth_maps`], the volumetric stage in one call (TSDF → marching cubes →
//!   speck removal → simplification), with its summary; [`topology`]: connectivity helpers;
//! * [`eval`]: Middlebury multi-view accuracy and completeness against a ground-truth mesh.
//!
//! World frame = the sparse model's frame; poses are `cam_from_world`; depth maps are camera-frame
//! `z` of the original (distorted) images. Nothing here touches a file (`handheld-io` writes OBJ,
//! glTF and PLY).

mod atlas;
mod bvh;
pub mod enhance;
pub mod error;
pub mod eval;
pub mod fusion;
pub mod marching_cubes;
pub mod mc_tables;
mod seams;
pub mod simplify;
pub mod single;
pub mod texture;
pub mod topology;
pub mod tsdf;
pub mod view;

pub use bvh::MeshIndex;
pub use enhance::{enhance_texture, EnhanceOptions, EnhanceSummary};
pub use error::{MeshError, Result};
pub use eval::{evaluate, EvalOptions, MultiViewScores};
pub use fusion::{fuse_depth_maps, FusionOptions, FusionSummary};
pub use marching_cubes::{extract_mesh, ExtractOptions};
pub use simplify::{simplify, SimplifyOptions, SimplifySummary};
pub use single::{mesh_from_depth_map, SingleMeshOptions, SingleMeshSummary};
pub use texture::{texture_mesh, TextureOptions, TextureSummary, TexturedMesh};
pub use tsdf::{TsdfOptions, TsdfVolume, VoxelSize};
pub use view::{DepthView, ImageView};
