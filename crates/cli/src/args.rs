//! Command-line arguments (clap). Parsing only: every option maps onto a library `*Options` struct.

use std::path::PathBuf;

use clap::{Args, Parser, Subcommand, ValueEnum};

/// Handheld: 3D models from an uncalibrated hand-held camera (photos or video).
#[derive(Debug, Parser)]
#[command(name = "handheld", version, about, propagate_version = true)]
pub struct Cli {
    #[command(flatten)]
    pub global: GlobalArgs,
    #[command(subcommand)]
    pub command: Command,
}

/// Flags every command takes.
#[derive(Debug, Args, Clone, Copy)]
pub struct GlobalArgs {
    /// Print nothing but errors (no progress bars, no logs).
    #[arg(long, short, global = true)]
    pub quiet: bool,
    /// Print the result as one JSON object on stdout (logs stay on stderr).
    #[arg(long, global = true)]
    pub json: bool,
    /// More logging (-v debug, -vv trace).
    #[arg(long, short, global = true, action = clap::ArgAction::Count)]
    pub verbose: u8,
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
    Stereo(crate::stereo::StereoArgs),
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
    Bundle(crate::bench_bundle::BenchBundleArgs),
    /// Feature extraction and matching on a folder of images (compare with COLMAP).
    Matching(crate::bench_matching::BenchMatchingArgs),
    /// SGM and DP stereo on the Middlebury pairs, scored against GT (compare with OpenCV SGBM).
    Stereo(crate::stereo::BenchStereoArgs),
    /// Dense targets: multi-view linking curve, polar rectification, pair speed.
    Dense(crate::bench_dense::BenchDenseArgs),
}

/// Camera path of the synthetic sequence.
#[derive(Debug, Clone, Copy, ValueEnum, PartialEq, Eq)]
pub enum PathKind {
    /// Walk around the object.
    Orbit,
    /// Walk sideways past the scene.
    Walk,
    /// Move forwards into the scene.
    Forward,
}

#[derive(Debug, Args)]
pub struct DemoArgs {
    /// Output folder: input images, ground truth and the workspace go inside.
    #[arg(long, short, default_value = "handheld-demo")]
    pub output: PathBuf,
    /// Number of frames to render.
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u32).range(2..=1000))]
    pub frames: u32,
    /// Image width in pixels.
    #[arg(long, default_value_t = 640, value_parser = clap::value_parser!(u32).range(64..=8192))]
    pub width: u32,
    /// Image height in pixels.
    #[arg(long, default_value_t = 480, value_parser = clap::value_parser!(u32).range(48..=8192))]
    pub height: u32,
    /// Seed of the scene, the path and the noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Camera path.
    #[arg(long, value_enum, default_value_t = PathKind::Orbit)]
    pub path: PathKind,
    /// Redo every stage even when its outputs are up to date.
    #[arg(long)]
    pub force: bool,
    /// Pixel aspect ratio f_y / f_x of the synthetic camera (e.g. 1.09, the paper's camcorder; §3.4).
    #[arg(long, default_value_t = 1.0)]
    pub aspect_ratio: f64,
    /// Encode the frames as an H.264 video (needs ffmpeg) and reconstruct that in video mode: KLT
    /// tracks, GRIC key-frames, a pose for every frame.
    #[arg(long)]
    pub video: bool,
}

/// Options shared by the commands that ingest input.
#[derive(Debug, Args, Clone)]
pub struct InputArgs {
    /// A folder of photos (JPEG, PNG, TIFF) or a video file (mp4, mov, avi, mkv).
    pub input: PathBuf,
    /// The workspace folder (one sub-folder per stage).
    #[arg(long, short)]
    pub output: PathBuf,
    /// Video: keep every N-th frame.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..))]
    pub stride: u32,
    /// Video: start time in seconds.
    #[arg(long, default_value_t = 0.0)]
    pub start: f64,
    /// Video: end time in seconds.
    #[arg(long)]
    pub end: Option<f64>,
    /// Video: keep at most this many frames.
    #[arg(long)]
    pub max_frames: Option<usize>,
    /// Photos: skip unreadable or corrupt images with a warning instead of stopping.
    #[arg(long)]
    pub skip_bad_images: bool,
    /// Redo the stages even when their outputs are up to date.
    #[arg(long)]
    pub force: bool,
    /// Features: keep at most this many per image (strongest first).
    #[arg(long, default_value_t = 8192, value_parser = clap::builder::TypedValueParser::map(clap::value_parser!(u64).range(16..=1_000_000), |v| v as usize))]
    pub max_features: usize,
    /// Features: downscale images whose longer side is larger than this (pixels).
    #[arg(long, value_parser = clap::value_parser!(u32).range(64..))]
    pub max_image_size: Option<u32>,
    /// Features: KLT tracking and GRIC key-frames (video, §3.1) or SIFT matching (photos).
    #[arg(long, value_enum, default_value_t = TrackingMode::Auto)]
    pub tracking: TrackingMode,
    /// Features (KLT): live tracks kept per frame by re-detection.
    #[arg(long, default_value_t = 1000, value_parser = clap::builder::TypedValueParser::map(clap::value_parser!(u64).range(16..=100_000), |v| v as usize))]
    pub klt_features: usize,
    /// Matching: which pairs to match.
    #[arg(long, value_enum, default_value_t = PairMode::Auto)]
    pub pairs: PairMode,
    /// Matching: neighbours on each side for sequential matching.
    #[arg(long, default_value_t = 8, value_parser = clap::builder::TypedValueParser::map(clap::value_parser!(u64).range(1..=1000), |v| v as usize))]
    pub window: usize,
    /// Matching: Lowe's ratio test threshold, in (0, 1].
    #[arg(long, default_value_t = 0.8)]
    pub ratio: f32,
    /// Matching: skip guided matching along epipolar lines (Table 1 step 4).
    #[arg(long)]
    pub no_guided: bool,
    /// Matching: brute force only over this many strongest features per image, then guided
    /// matching over all of them (0: brute force over all features).
    #[arg(long, default_value_t = 2048)]
    pub seed_features: usize,
    /// Matching: with sequential pairs, do not look for close views outside the window (§3.2).
    #[arg(long)]
    pub no_close_views: bool,
    /// Sparse: seed of every random choice (the same seed gives the same model).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Sparse: radial distortion estimated by metric BA (eq. 3).
    #[arg(long, value_enum, default_value_t = DistortionArg::K1)]
    pub distortion: DistortionArg,
    /// Sparse: the pixel aspect ratio: estimated for video, 1 for photos (auto), or forced.
    #[arg(long, value_enum, default_value_t = AspectArg::Auto)]
    pub aspect: AspectArg,
    /// Sparse: keep the principal point at the image centre instead of estimating it.
    #[arg(long)]
    pub fixed_principal_point: bool,
    /// Sparse (photos): register every keypoint of a track to the track's reference keypoint by
    /// affine patch alignment before SfM. It makes the observations more consistent (herzjesu-P8:
    /// median error against the ground-truth cameras 0.32 → 0.27 px) but did not make the cameras
    /// reliably more accurate, so it is off by default.
    #[arg(long)]
    pub refine_keypoints: bool,
    /// Sparse: weight metric BA observations by their keypoint's detection scale (σ ∝ √scale).
    #[arg(long)]
    pub scale_weights: bool,
    /// Sparse: a known calibration `FX,FY,CX,CY` in pixels, COLMAP's convention (the top-left
    /// pixel's centre at 0.5, 0.5, as in a COLMAP `cameras.txt`). It pins the focal lengths and the
    /// principal point of every camera in metric BA; without it the cameras are self-calibrated.
    #[arg(long, value_name = "FX,FY,CX,CY")]
    pub intrinsics: Option<String>,
    /// Sparse: standard deviation of the principal point's prior at the image centre, as a fraction
    /// of width + height (eq. 25's u ≈ v ≈ 0 in K_N units).
    #[arg(long, default_value_t = 0.005)]
    pub principal_point_prior: f64,
    #[command(flatten)]
    pub dense: DenseArgs,
    #[command(flatten)]
    pub mesh: MeshArgs,
}

/// Options of the dense stage (§4).
#[derive(Debug, Clone, Args)]
pub struct DenseArgs {
    /// Dense: images are downscaled so their longer side is at most this (0 = full resolution).
    #[arg(long, default_value_t = 1600)]
    pub dense_max_size: u32,
    /// Dense: stereo method of each rectified pair (§4.2).
    #[arg(long, value_enum, default_value_t = StereoMethodArg::Sgm)]
    pub stereo_method: StereoMethodArg,
    /// Dense: N, the views linked per reference view (the reference and (N−1)/2 on each side, §4.3).
    #[arg(long, default_value_t = 11)]
    pub link_views: usize,
    /// Dense: V_min, the fewest views a kept depth must be linked through (reference included).
    #[arg(long, default_value_t = 2)]
    pub min_visibility: usize,
    /// Dense: the V a view keeps when at least half its depths reach it; views whose neighbours
    /// are too far apart to link further (an object ring) keep --min-visibility.
    #[arg(long, default_value_t = 3)]
    pub preferred_visibility: usize,
}

impl Default for DenseArgs {
    fn default() -> Self {
        Self {
            dense_max_size: 1600,
            stereo_method: StereoMethodArg::Sgm,
            link_views: 11,
            min_visibility: 2,
            preferred_visibility: 3,
        }
    }
}

/// Options of the mesh stage (§5.1).
#[derive(Debug, Clone, Args)]
pub struct MeshArgs {
    /// Mesh: `fused` (TSDF over all depth maps, plus per-view meshes) or `single` (per-view only).
    #[arg(long, value_enum, default_value_t = MeshMode::Fused)]
    pub mode: MeshMode,
    /// Mesh: face count after quadric simplification.
    #[arg(long, default_value_t = 500_000)]
    pub target_faces: usize,
    /// Mesh: TSDF voxel size in model units (default: three pixel footprints at the median depth).
    #[arg(long)]
    pub voxel_size: Option<f64>,
    /// Mesh: skip the per-view §5.1 meshes (mesh/views/).
    #[arg(long)]
    pub no_view_meshes: bool,
    /// Mesh: leave this image's depth map and colours out of the fused model, render the model
    /// from its camera and report the colour difference (`mesh/holdout.png`).
    #[arg(long)]
    pub hold_out: Option<String>,
    /// Mesh: close holes inside observed surface whose boundary is at most this many voxel
    /// lengths (0: leave every hole open). The outline where the views stop always stays open.
    #[arg(long, default_value_t = 1000.0)]
    pub max_hole_perimeter: f64,
}

impl Default for MeshArgs {
    fn default() -> Self {
        Self {
            mode: MeshMode::Fused,
            target_faces: 500_000,
            voxel_size: None,
            no_view_meshes: false,
            hold_out: None,
            max_hole_perimeter: 1000.0,
        }
    }
}

/// Which surface models the mesh stage builds.
#[derive(Debug, Clone, Copy, ValueEnum, PartialEq, Eq)]
pub enum MeshMode {
    /// One volumetric model from all depth maps, textured from all views; per-view meshes too.
    Fused,
    /// Only the per-view meshes of §5.1.
    Single,
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

/// Stereo matcher of the dense stage.
#[derive(Debug, Clone, Copy, ValueEnum, PartialEq, Eq)]
pub enum StereoMethodArg {
    /// Semi-global matching (census cost); the more accurate, measured on Middlebury.
    Sgm,
    /// The paper's scanline dynamic programming (§4.2).
    Dp,
}

/// Whether metric BA estimates the aspect ratio (§3.4).
#[derive(Debug, Clone, Copy, ValueEnum, PartialEq, Eq)]
pub enum AspectArg {
    /// Estimated for video, fixed to 1 for photos.
    Auto,
    /// Always fixed to 1 (square pixels).
    Fixed,
    /// Always estimated (one constant ratio per intrinsics group).
    Free,
}

/// Radial distortion model of the sparse stage.
#[derive(Debug, Clone, Copy, ValueEnum, PartialEq, Eq)]
pub enum DistortionArg {
    /// No distortion.
    None,
    /// k1 only.
    K1,
    /// k1 and k2.
    K1k2,
}

/// How correspondences are found.
#[derive(Debug, Clone, Copy, ValueEnum, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TrackingMode {
    /// KLT for a video file, SIFT for photos.
    Auto,
    /// KLT tracks and key-frames (also for a folder of consecutive frames).
    Klt,
    /// SIFT features and descriptor matching.
    Sift,
}

/// Which image pairs the matches stage matches.
#[derive(Debug, Clone, Copy, ValueEnum, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PairMode {
    /// Exhaustive up to 40 photos; a sequential window for video and longer photo sets.
    Auto,
    /// Every pair.
    Exhaustive,
    /// Each image with its `--window` successors.
    Sequential,
}

#[derive(Debug, Args)]
pub struct ReconstructArgs {
    #[command(flatten)]
    pub input: InputArgs,
    /// Stop after this stage.
    #[arg(long, value_enum, default_value_t = crate::pipeline::Stage::LAST)]
    pub until: crate::pipeline::Stage,
}

#[derive(Debug, Args)]
pub struct IngestArgs {
    #[command(flatten)]
    pub input: InputArgs,
}
