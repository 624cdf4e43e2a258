//! Command-line arguments (clap). Parsing only: every option maps onto a library `*Options` struct.

use std::path::PathBuf;

use clap::{Args, Parser, Subcommand};

pub use crate::common::{choice, choice_name, DenseArgs, GlobalArgs, InputArgs, MeshArgs};

/// Handheld: 3D models from an uncalibrated hand-held camera (photos or video).
#[derive(Debug, Parser)]
#[command(name = "handheld", version, about, propagate_version = true)]
pub struct Cli {
    #[command(flatten)]
    pub global: GlobalArgs,
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Render a synthetic hand-held sequence with exact ground truth, reconstruct it, print the accuracy.
    Demo(DemoArgs),
    /// Run the whole pipeline on a folder of photos or a video file, resuming finished stages.
    Reconstruct(ReconstructArgs),
    /// Run only the ingest stage: validate the images (or decode the video) into the workspace.
    Ingest(IngestArgs),
    /// Run the pipeline up to the features stage (RootSIFT per image).
    Features(IngestArgs),
    /// Run the pipeline up to the matches stage (verified pairs in COLMAP's database.db).
    Match(IngestArgs),
    /// The dense stage alone (§4) on a COLMAP model and its images: depth maps and fused.ply.
    Dense(DenseModelArgs),
    /// The mesh stage alone (§5.1) on a dense folder: fused textured model and per-view meshes.
    Mesh(MeshStageArgs),
    /// Dense matching of one already-rectified pair (§4.2): the left view's disparity as PFM.
    Stereo(crate::bench::StereoArgs),
    /// New views rendered from the images and depth maps (§5.2): one view to PNG, a path to mp4.
    Render(crate::render::RenderArgs),
    /// A virtual object composited into a video (§5.3), and the camera track (glTF, .chan).
    Augment(crate::augment::AugmentArgs),
    /// Rebuild WORKSPACE/report.html (verdict, images, plots, 3D viewer) from what exists.
    Report(crate::report::ReportArgs),
    /// Benchmarks; each prints one JSON object (use with --json).
    Bench(BenchArgs),
}

#[derive(Debug, Args)]
pub struct BenchArgs {
    #[command(subcommand)]
    pub which: BenchCommand,
}

#[derive(Debug, Subcommand)]
pub enum BenchCommand {
    /// Bundle adjustment on a BAL problem (compare with Ceres' bundle_adjuster).
    Bundle(crate::bench::BenchBundleArgs),
    /// Feature extraction and matching on a folder of images (compare with COLMAP).
    Matching(crate::bench::BenchMatchingArgs),
    /// The whole sparse run (images → metric model), stage by stage, against COLMAP 4.2 (pycolmap).
    Sparse(crate::bench::BenchSparseArgs),
    /// SGM and DP stereo on the Middlebury pairs, scored against GT (compare with OpenCV SGBM).
    Stereo(crate::bench::BenchStereoArgs),
    /// Dense targets: multi-view linking curve, polar rectification, pair speed.
    Dense(crate::bench::BenchDenseArgs),
    /// Novel views: every N-th image held out, each method scored by PSNR/SSIM; speed.
    Render(crate::bench::BenchRenderArgs),
    /// View-dependent highlights: a glossy sphere, held-out views, PSNR over the highlight.
    Specular(crate::bench::BenchSpecularArgs),
    /// Augmented video: compositing + encoding speed at 1280×720 (SfM not counted).
    Augment(crate::bench::BenchAugmentArgs),
    /// SfM on large synthetic walks (250–2000 views): monolithic against split-and-merge.
    Scale(crate::bench::BenchScaleArgs),
    /// Dense depth and the fused mesh of a synthetic street (1.5–150 m) against exact truth.
    Mesh(crate::bench::BenchMeshArgs),
}

/// The demo's defaults, from the library.
fn demo_defaults() -> handheld_eval::DemoOptions {
    handheld_eval::DemoOptions::default()
}

#[derive(Debug, Args)]
pub struct DemoArgs {
    /// Output folder: input images, ground truth and the workspace go inside.
    #[arg(long, short, default_value_os_t = demo_defaults().output)]
    pub output: PathBuf,
    /// Number of frames to render.
    #[arg(long, default_value_t = demo_defaults().frames, value_parser = clap::value_parser!(u32).range(2..=1000))]
    pub frames: u32,
    /// Image width in pixels.
    #[arg(long, default_value_t = demo_defaults().width, value_parser = clap::value_parser!(u32).range(64..=8192))]
    pub width: u32,
    /// Image height in pixels.
    #[arg(long, default_value_t = demo_defaults().height, value_parser = clap::value_parser!(u32).range(48..=8192))]
    pub height: u32,
    /// Seed of the scene, the path and the noise.
    #[arg(long, default_value_t = demo_defaults().seed)]
    pub seed: u64,
    /// Camera path: orbit, walk, forward, ring (full turn, no back wall), hemisphere (three rings).
    #[arg(long, default_value = choice_name(&demo_defaults().path), value_parser = choice::<handheld_eval::CameraPath>)]
    pub path: handheld_eval::CameraPath,
    /// Redo every stage even when its outputs are up to date.
    #[arg(long)]
    pub force: bool,
    /// Pixel aspect ratio f_y / f_x of the synthetic camera (e.g. 1.09, the paper's camcorder; §3.4).
    #[arg(long, default_value_t = demo_defaults().aspect_ratio)]
    pub aspect_ratio: f64,
    /// Encode the frames as an H.264 video (needs ffmpeg) and reconstruct that in video mode: KLT
    /// tracks, GRIC key-frames, a pose for every frame.
    #[arg(long)]
    pub video: bool,
    /// Place the shipped box on the ground, composite it into every frame (§5.3) and score its
    /// projection against the exact cameras (use with --video).
    #[arg(long)]
    pub augment: bool,
    /// The scene: `objects` (boxes on a ground), `wall` (a phone orbiting an object on a wall),
    /// `wallpaper` (that wall with a repeated motif) or `corridor` (an indoor walk: plain walls, tiles).
    #[arg(long, default_value = choice_name(&demo_defaults().scene), value_parser = choice::<handheld_eval::DemoScene>)]
    pub scene: handheld_eval::DemoScene,
    /// Field of view across the longer image side, degrees (a phone: 65–70); default: the focal
    /// length is 0.9 × the width.
    #[arg(long)]
    pub fov: Option<f64>,
    /// First radial distortion coefficient of the synthetic camera (k2 is then 0); default −0.08
    /// with k2 = 0.01.
    #[arg(long, allow_hyphen_values = true)]
    pub k1: Option<f64>,
    /// x264 constant rate factor of the video (--video); default 12 (visually lossless), a
    /// phone's bit rate is about 23.
    #[arg(long)]
    pub crf: Option<u8>,
    /// Rolling shutter: first to last row's read-out, in frame intervals (a phone: 0.5–0.9 at 30 fps).
    #[arg(long, default_value_t = 0.0)]
    pub rolling_shutter: f64,
    /// Exposure time in frame intervals: motion blur.
    #[arg(long, default_value_t = 0.0)]
    pub exposure: f64,
    /// Stop after this stage and what it needs (e.g. `sparse`); the stages not run are not scored.
    #[arg(long)]
    pub until: Option<String>,
}

/// `handheld mesh`: the mesh stage alone, on a dense folder.
#[derive(Debug, Args)]
pub struct MeshStageArgs {
    /// A dense folder (WORKSPACE/dense or `handheld dense` output: cameras.json, depth/, confidence/).
    #[arg(long)]
    pub depth_maps: PathBuf,
    /// The folder holding the images named in cameras.json.
    #[arg(long)]
    pub images: PathBuf,
    /// Output folder (the layout of WORKSPACE/mesh).
    #[arg(long, short)]
    pub output: PathBuf,
    #[command(flatten)]
    pub mesh: MeshArgs,
}

/// `handheld dense`: the dense stage alone, on any COLMAP model and its images.
#[derive(Debug, Args)]
pub struct DenseModelArgs {
    /// A COLMAP sparse model (text or binary), e.g. WORKSPACE/sparse or COLMAP's sparse/0.
    #[arg(long)]
    pub model: PathBuf,
    /// The folder holding the model's images (by the names in images.txt).
    #[arg(long)]
    pub images: PathBuf,
    /// Output folder (the layout of WORKSPACE/dense).
    #[arg(long, short)]
    pub output: PathBuf,
    #[command(flatten)]
    pub dense: DenseArgs,
}

#[derive(Debug, Args)]
pub struct ReconstructArgs {
    #[command(flatten)]
    pub input: InputArgs,
    /// Run only what this stage needs (ingest, features, matches, sparse, dense, mesh or render);
    /// default: the whole graph.
    #[arg(long)]
    pub until: Option<String>,
}

#[derive(Debug, Args)]
pub struct IngestArgs {
    #[command(flatten)]
    pub input: InputArgs,
}
