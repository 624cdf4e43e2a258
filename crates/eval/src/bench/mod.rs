//! The benchmarks: each takes a typed options struct and returns a typed report, the reference
//! programs (COLMAP, pycolmap, OpenCV) run in the same process tree so the timings compare.

pub mod augment;
pub mod bundle;
pub mod colmap;
pub mod dense;
pub mod matching;
pub mod mesh;
pub mod pycolmap;
pub mod render;
pub mod scale;
pub mod sparse;
pub mod specular;
pub mod stereo;

pub use augment::{bench_augment, AugmentBenchOptions, AugmentBenchReport};
pub use bundle::{
    bench_bundle, BenchLoss, BenchSolver, BundleBenchOptions, BundleBenchReport, BundleProblem,
};
pub use colmap::{run_colmap, ColmapReport};
pub use dense::{bench_dense, DenseBenchOptions, DenseBenchReport};
pub use matching::{bench_matching, MatchingBenchOptions, MatchingBenchReport};
pub use mesh::{bench_mesh, MeshBenchOptions, MeshBenchReport, StreetRun};
pub use pycolmap::{pycolmap_version, run_pycolmap_sparse, PycolmapSparseRun};
pub use render::{bench_render, RenderBenchOptions, RenderBenchReport};
pub use scale::{bench_scale, ScaleBenchOptions, ScaleBenchReport, ScaleRun};
pub use sparse::{
    bench_sparse, ColmapSparseRun, HandheldSparseRun, SparseBenchOptions, SparseBenchReport,
    SparseRatios, SparseRound, TARGET_TOTAL_RATIO,
};
pub use specular::{bench_specular, SpecularBenchOptions, SpecularReport};
pub use stereo::{
    bench_stereo, stereo_pair, StereoBenchOptions, StereoBenchReport, StereoPairOptions,
    StereoPairReport,
};
