//! `handheld bench …` and `handheld stereo`: the arguments of each benchmark, mapped onto
//! `handheld_eval::bench`'s options; the library runs them and the report is printed.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use handheld_dense::StereoMethod;
use handheld_eval::bench::{self, BenchLoss, BenchSolver, BundleProblem};

use crate::common::{choice, choice_name, GlobalArgs};
use crate::ui::{print_result, Bars};

/// Prints a report: `human` gets the report's JSON.
fn print<T: serde::Serialize>(
    g: &GlobalArgs,
    report: &T,
    human: impl FnOnce(&serde_json::Value) -> String,
) -> Result<()> {
    let value = serde_json::to_value(report)?;
    print_result(g, &value, &human(&value));
    Ok(())
}

fn pretty(v: &serde_json::Value) -> String {
    serde_json::to_string_pretty(v).unwrap_or_default()
}

fn bundle_defaults() -> bench::BundleBenchOptions {
    bench::BundleBenchOptions::default()
}

#[derive(Debug, Args)]
pub struct BenchBundleArgs {
    /// A BAL problem file (`problem-49-7776-pre.txt`).
    #[arg(
        long,
        required_unless_present = "synthetic",
        conflicts_with = "synthetic"
    )]
    pub bal: Option<PathBuf>,
    /// A synthetic problem `CAMERASxPOINTS` instead, e.g. `1000x200000`.
    #[arg(long)]
    pub synthetic: Option<String>,
    /// Maximum Levenberg–Marquardt iterations.
    #[arg(long, default_value_t = bundle_defaults().iterations)]
    pub iterations: usize,
    /// Robust loss.
    #[arg(long, default_value = choice_name(&bundle_defaults().robust), value_parser = choice::<BenchLoss>)]
    pub robust: BenchLoss,
    /// Scale of the robust loss in pixels.
    #[arg(long, default_value_t = bundle_defaults().robust_scale)]
    pub robust_scale: f64,
    /// Worker threads (0: all cores).
    #[arg(long, default_value_t = bundle_defaults().threads)]
    pub threads: usize,
    /// Linear solver for the reduced camera system.
    #[arg(long, default_value = choice_name(&bundle_defaults().linear_solver), value_parser = choice::<BenchSolver>)]
    pub linear_solver: BenchSolver,
    /// Seed of the synthetic problem.
    #[arg(long, default_value_t = bundle_defaults().seed)]
    pub seed: u64,
}

pub fn bundle(a: &BenchBundleArgs, g: &GlobalArgs, bars: &Bars) -> Result<()> {
    let problem = match &a.bal {
        Some(path) => BundleProblem::Bal(path.clone()),
        None => a.synthetic.as_deref().unwrap_or_default().parse()?,
    };
    let o = bench::BundleBenchOptions {
        problem,
        iterations: a.iterations,
        robust: a.robust,
        robust_scale: a.robust_scale,
        threads: a.threads,
        linear_solver: a.linear_solver,
        seed: a.seed,
    };
    let s = bench::bench_bundle(&o, bars)?;
    print(g, &s, |_| {
        format!(
            "{}: {} cameras, {} points, {} observations\ncost {:.6e} -> {:.6e} (rms {:.3} -> {:.3} px) in {} iterations ({}), \
             {:.3} s ({:.4} s/iteration, {} solver)",
            s.problem, s.cameras, s.points, s.observations,
            s.initial_cost, s.final_cost, s.initial_rms_px, s.final_rms_px, s.iterations,
            s.termination, s.total_seconds, s.seconds_per_iteration, s.linear_solver
        )
    })
}

#[derive(Debug, Args)]
pub struct BenchMatchingArgs {
    /// Folder of images.
    #[arg(long)]
    pub images: PathBuf,
    /// Data set folder with ground-truth cameras in `gt/` (Strecha `.camera` or Middlebury `*_par.txt`).
    #[arg(long)]
    pub gt_cameras: Option<PathBuf>,
    /// Match every pair (as COLMAP's exhaustive_matcher) instead of only adjacent ones.
    #[arg(long)]
    pub exhaustive: bool,
    /// Also run COLMAP (feature_extractor + exhaustive_matcher, CPU) on the same images.
    #[arg(long)]
    pub colmap: bool,
    /// Threads for Handheld and COLMAP (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Downscale images whose longer side exceeds this (pixels).
    #[arg(long)]
    pub max_image_size: Option<u32>,
    /// SIFT contrast threshold (OpenCV convention; default: the library default).
    #[arg(long)]
    pub contrast_threshold: Option<f32>,
    /// SIFT: keep at most this many features per image. Default 13 312, COLMAP's budget here (its
    /// extractor gives 10.5–13.2 k per fountain-P11 image); `reconstruct` keeps 8192.
    #[arg(long, default_value_t = bench::MatchingBenchOptions::default().max_features)]
    pub max_features: usize,
    /// SIFT: upsample the image first (octave −1), as COLMAP does by default.
    #[arg(long)]
    pub upsample: bool,
    /// Brute force only over this many strongest keypoints per image, then guided matching over
    /// all (0: brute force over all; default: the library default).
    #[arg(long)]
    pub seed_features: Option<usize>,
}

pub fn matching(a: &BenchMatchingArgs, g: &GlobalArgs, bars: &Bars) -> Result<()> {
    let o = bench::MatchingBenchOptions {
        images: a.images.clone(),
        gt_cameras: a.gt_cameras.clone(),
        exhaustive: a.exhaustive,
        colmap: a.colmap,
        threads: a.threads,
        max_image_size: a.max_image_size,
        contrast_threshold: a.contrast_threshold,
        max_features: a.max_features,
        upsample: a.upsample,
        seed_features: a.seed_features,
    };
    print(g, &bench::bench_matching(&o, bars)?, pretty)
}

#[derive(Debug, Args)]
pub struct BenchSparseArgs {
    /// Folder of images.
    #[arg(long)]
    pub images: PathBuf,
    /// Data set folder with ground-truth cameras: both models are scored with --eval-script.
    #[arg(long)]
    pub gt: Option<PathBuf>,
    /// Threads for Handheld and COLMAP (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Also run COLMAP 4.2 (`pip install pycolmap`, CPU): extraction, exhaustive matching,
    /// incremental mapping.
    #[arg(long)]
    pub colmap: bool,
    /// The script that scores a COLMAP text model against --gt (`python3 SCRIPT MODEL DATASET`).
    #[arg(long, default_value_os_t = bench::SparseBenchOptions::default().eval_script)]
    pub eval_script: PathBuf,
    /// Keep both runs in this folder (empty or absent); default: a temporary folder.
    #[arg(long)]
    pub work: Option<PathBuf>,
    /// Rounds of Handheld then COLMAP, interleaved; the ratios are each stage's median over the
    /// rounds' ratios.
    #[arg(long, default_value_t = bench::SparseBenchOptions::default().rounds)]
    pub rounds: usize,
}

pub fn sparse(a: &BenchSparseArgs, g: &GlobalArgs, bars: &Bars) -> Result<()> {
    let o = bench::SparseBenchOptions {
        images: a.images.clone(),
        gt: a.gt.clone(),
        threads: a.threads,
        colmap: a.colmap,
        eval_script: a.eval_script.clone(),
        work: a.work.clone(),
        rounds: a.rounds,
        ..Default::default()
    };
    let r = bench::bench_sparse(&o, bars)?;
    print(g, &r, |_| r.summary_text())
}

#[derive(Debug, Args)]
pub struct BenchDenseArgs {
    /// Width of the synthetic images (height is 3/4 of it).
    #[arg(long, default_value_t = bench::DenseBenchOptions::default().width)]
    pub width: u32,
    /// A COLMAP model and its images for the full-resolution timing (first two views).
    #[arg(long, requires = "images")]
    pub model: Option<PathBuf>,
    #[arg(long)]
    pub images: Option<PathBuf>,
    /// Timed runs (median reported).
    #[arg(long, default_value_t = bench::DenseBenchOptions::default().runs)]
    pub runs: u32,
    /// With --model: also run the whole dense stage on it (defaults: full size up to 24 MP), and
    /// report failed pairs, fill per view, seconds per megapixel and peak memory.
    #[arg(long, requires = "model")]
    pub stage: bool,
    /// With --stage: the longer-side limit of the stage run (0: the default).
    #[arg(long, default_value_t = 0)]
    pub stage_max_size: u32,
}

pub fn dense(a: &BenchDenseArgs, g: &GlobalArgs) -> Result<()> {
    let o = bench::DenseBenchOptions {
        width: a.width,
        model: a.model.clone(),
        images: a.images.clone(),
        runs: a.runs,
        stage_max_size: a.stage.then_some(a.stage_max_size),
    };
    print(g, &bench::bench_dense(&o)?, pretty)
}

#[derive(Debug, Args)]
pub struct StereoArgs {
    /// Left image of a rectified pair.
    #[arg(long)]
    pub left: PathBuf,
    /// Right image (left x matches right x − d).
    #[arg(long)]
    pub right: PathBuf,
    /// Largest disparity searched (inclusive).
    #[arg(long, allow_negative_numbers = true)]
    pub max_disparity: i32,
    /// Smallest disparity searched.
    #[arg(long, default_value_t = 0, allow_negative_numbers = true)]
    pub min_disparity: i32,
    /// `sgm` (semi-global matching, census cost) or `dp` (dynamic programming along each
    /// scanline, §4.2).
    #[arg(long, default_value = choice_name(&handheld_dense::StereoOptions::default().method), value_parser = choice::<StereoMethod>)]
    pub method: StereoMethod,
    /// Output PFM (left view's disparity; missing = NaN).
    #[arg(long, short)]
    pub output: PathBuf,
    /// Write only measured pixels (no hole filling of occlusions and mismatches).
    #[arg(long)]
    pub valid_only: bool,
}

pub fn stereo(a: &StereoArgs, g: &GlobalArgs) -> Result<()> {
    let o = bench::StereoPairOptions {
        left: a.left.clone(),
        right: a.right.clone(),
        min_disparity: a.min_disparity,
        max_disparity: a.max_disparity,
        method: a.method,
        output: a.output.clone(),
        valid_only: a.valid_only,
    };
    let r = bench::stereo_pair(&o)?;
    print(g, &r, |_| {
        format!(
            "{}: {}×{} in {:.3} s, density {:.1} % ({:.1} % measured, the rest filled)",
            r.output.display(),
            r.width,
            r.height,
            r.seconds,
            100.0 * r.density,
            100.0 * r.measured_fraction
        )
    })
}

#[derive(Debug, Args)]
pub struct BenchStereoArgs {
    /// Middlebury pair folders (`im2.png`, `im6.png`, `disp2.pgm` at GT scale 4).
    #[arg(long, num_args = 1.., default_values = ["../shared/datasets/stereo-teddy", "../shared/datasets/stereo-cones"])]
    pub pairs: Vec<PathBuf>,
    /// Largest disparity (inclusive); 63 gives OpenCV's 64 disparities.
    #[arg(long, default_value_t = bench::StereoBenchOptions::default().max_disparity)]
    pub max_disparity: i32,
    /// Timed runs per method (the median is reported; one matcher is reused, as OpenCV reuses its
    /// StereoSGBM object).
    #[arg(long, default_value_t = bench::StereoBenchOptions::default().runs, value_parser = clap::value_parser!(u32).range(1..=100))]
    pub runs: u32,
    /// Also run OpenCV's StereoSGBM (python3 with opencv-python-headless) in the same run.
    #[arg(long)]
    pub opencv: bool,
}

pub fn bench_stereo(a: &BenchStereoArgs, g: &GlobalArgs) -> Result<()> {
    let o = bench::StereoBenchOptions {
        pairs: a.pairs.clone(),
        max_disparity: a.max_disparity,
        runs: a.runs,
        opencv: a.opencv,
    };
    print(g, &bench::bench_stereo(&o)?, |v| {
        let pairs = v["pairs"].as_array().map(Vec::as_slice).unwrap_or_default();
        let lines: Vec<String> = pairs
            .iter()
            .map(|p| format!("{}: {p}", p["pair"].as_str().unwrap_or_default()))
            .collect();
        lines.join("\n")
    })
}

#[derive(Debug, Args)]
pub struct BenchRenderArgs {
    /// A workspace reconstructed through the sparse stage (the benchmark reruns dense and mesh
    /// without the held-out images, in WORKSPACE/bench/render-every-N/).
    pub workspace: PathBuf,
    /// Hold out every N-th registered image (by name, starting with the first).
    #[arg(long, default_value_t = bench::RenderBenchOptions::default().every)]
    pub every: usize,
    /// Frames of the speed run along the fly-through.
    #[arg(long, default_value_t = bench::RenderBenchOptions::default().speed_frames)]
    pub speed_frames: usize,
    /// Redo the benchmark's dense and mesh stages.
    #[arg(long)]
    pub force: bool,
    /// The k best views of the unstructured-lumigraph weights.
    #[arg(long, default_value_t = handheld_render::IbrOptions::default().ulr_k)]
    pub ulr_k: usize,
    /// Split a triangle when its plane is off the scene by more than this (source pixels).
    #[arg(long, default_value_t = handheld_render::IbrOptions::default().subdivision_px)]
    pub subdivision_px: f64,
    /// Triangles are not split below this edge length (pixels).
    #[arg(long, default_value_t = handheld_render::IbrOptions::default().min_triangle_px)]
    pub min_triangle_px: f64,
}

pub fn render(a: &BenchRenderArgs, g: &GlobalArgs, bars: &crate::ui::Bars) -> Result<()> {
    let o = bench::RenderBenchOptions {
        workspace: a.workspace.clone(),
        every: a.every,
        speed_frames: a.speed_frames,
        force: a.force,
        ibr: handheld_render::IbrOptions {
            ulr_k: a.ulr_k,
            subdivision_px: a.subdivision_px,
            min_triangle_px: a.min_triangle_px,
            ..Default::default()
        },
        ..Default::default()
    };
    print(g, &bench::bench_render(&o, bars)?, pretty)
}

#[derive(Debug, Args)]
pub struct BenchSpecularArgs {
    /// Image width (height 3/4 of it).
    #[arg(long, default_value_t = bench::SpecularBenchOptions::default().width)]
    pub width: u32,
    /// Frames of the orbit.
    #[arg(long, default_value_t = bench::SpecularBenchOptions::default().frames)]
    pub frames: usize,
    /// Seed of the scene.
    #[arg(long, default_value_t = bench::SpecularBenchOptions::default().seed)]
    pub seed: u64,
    /// Write each held-out view (photo | subdivided | ulr | ulr_mesh | mesh) to this folder.
    #[arg(long)]
    pub images: Option<PathBuf>,
}

pub fn specular(a: &BenchSpecularArgs, g: &GlobalArgs) -> Result<()> {
    let o = bench::SpecularBenchOptions {
        width: a.width,
        frames: a.frames,
        seed: a.seed,
        images: a.images.clone(),
        ..Default::default()
    };
    print(g, &bench::bench_specular(&o)?, pretty)
}

#[derive(Debug, Args)]
pub struct BenchAugmentArgs {
    #[arg(long, default_value_t = bench::AugmentBenchOptions::default().width)]
    pub width: u32,
    #[arg(long, default_value_t = bench::AugmentBenchOptions::default().height)]
    pub height: u32,
    #[arg(long, default_value_t = bench::AugmentBenchOptions::default().frames)]
    pub frames: usize,
}

pub fn augment(a: &BenchAugmentArgs, g: &GlobalArgs) -> Result<()> {
    let o = bench::AugmentBenchOptions {
        width: a.width,
        height: a.height,
        frames: a.frames,
    };
    print(g, &bench::bench_augment(&o)?, pretty)
}

fn scale_defaults() -> bench::ScaleBenchOptions {
    bench::ScaleBenchOptions::default()
}

#[derive(Debug, Args)]
pub struct BenchScaleArgs {
    /// The sizes, in views, comma-separated.
    #[arg(long, value_delimiter = ',', default_values_t = scale_defaults().views)]
    pub views: Vec<usize>,
    /// Skip the monolithic run above this many views.
    #[arg(long, default_value_t = scale_defaults().monolithic_max)]
    pub monolithic_max: usize,
    /// Split-and-merge's largest cluster, in views.
    #[arg(long, default_value_t = scale_defaults().cluster_views)]
    pub cluster_views: usize,
    /// Views a cluster borrows from its neighbours, as a fraction of its own.
    #[arg(long, default_value_t = scale_defaults().overlap)]
    pub overlap: f64,
    /// About how many points a view sees.
    #[arg(long, default_value_t = scale_defaults().points_per_view)]
    pub points_per_view: usize,
    /// Threads both modes run on.
    #[arg(long, default_value_t = scale_defaults().workers)]
    pub workers: usize,
    #[arg(long, default_value_t = scale_defaults().seed)]
    pub seed: u64,
}

pub fn scale(a: &BenchScaleArgs, g: &GlobalArgs, bars: &Bars) -> Result<()> {
    let o = bench::ScaleBenchOptions {
        views: a.views.clone(),
        monolithic_max: a.monolithic_max,
        cluster_views: a.cluster_views,
        overlap: a.overlap,
        points_per_view: a.points_per_view,
        workers: a.workers,
        seed: a.seed,
    };
    let r = bench::bench_scale(&o, bars)?;
    print(g, &r, |_| r.summary_text())
}

fn mesh_defaults() -> bench::MeshBenchOptions {
    bench::MeshBenchOptions::default()
}

#[derive(Debug, Args)]
pub struct BenchMeshArgs {
    /// Image width (height is 3/4 of it).
    #[arg(long, default_value_t = mesh_defaults().width)]
    pub width: u32,
    /// Frames per path (a drive down the street, a walk across it).
    #[arg(long, default_value_t = mesh_defaults().frames)]
    pub frames: usize,
    /// Metres the car drives.
    #[arg(long, default_value_t = mesh_defaults().drive_m)]
    pub drive_m: f64,
    /// Metres the walk crosses.
    #[arg(long, default_value_t = mesh_defaults().walk_m)]
    pub walk_m: f64,
    #[arg(long, default_value_t = mesh_defaults().seed)]
    pub seed: u64,
    /// Write each path's first and last frame and its fused mesh (PLY) here.
    #[arg(long)]
    pub out: Option<std::path::PathBuf>,
    /// Fusion: leave out depth samples whose standard deviation exceeds this many truncation
    /// bands (0 keeps every sample).
    #[arg(long, default_value_t = mesh_defaults().fusion.tsdf.max_depth_std)]
    pub max_depth_std: f64,
}

pub fn mesh(a: &BenchMeshArgs, g: &GlobalArgs) -> Result<()> {
    let o = bench::MeshBenchOptions {
        width: a.width,
        frames: a.frames,
        drive_m: a.drive_m,
        walk_m: a.walk_m,
        seed: a.seed,
        out: a.out.clone(),
        fusion: {
            let mut f = mesh_defaults().fusion;
            f.tsdf.max_depth_std = a.max_depth_std;
            f
        },
    };
    let r = bench::bench_mesh(&o)?;
    print(g, &r, |_| r.summary_text())
}
