//! The arguments and helpers several commands share: the global flags, the input and stage
//! options of the commands that run the pipeline, and the parsing of library enums. A leaf: it
//! imports no other module of the CLI.

use std::path::PathBuf;

use clap::{Args, ValueEnum};
use handheld_dense::StereoMethod;
use handheld_mesh::VoxelSize;
use handheld_pipeline::policy::PairMode;
use handheld_pipeline::stages::dense::DenseStageOptions;
use handheld_pipeline::stages::features::TrackingMode;
use handheld_pipeline::stages::mesh::{MeshMode, MeshStageOptions};
use handheld_pipeline::PipelineOptions;
use handheld_sfm::{Distortion, KnownIntrinsics};

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

/// The library's defaults: every default below is read from here, never written twice.
fn defaults() -> PipelineOptions {
    PipelineOptions::default()
}

/// Parses one of a library enum's names (the names its serde form uses).
pub fn choice<T: serde::de::DeserializeOwned>(s: &str) -> Result<T, String> {
    serde_json::from_value(serde_json::Value::String(s.to_string())).map_err(|e| e.to_string())
}

/// The name of a library enum's value (its serde form), for `--help`'s defaults. The few names are
/// leaked once per parse: clap keeps defaults as `&'static str`.
pub fn choice_name<T: serde::Serialize>(value: &T) -> &'static str {
    let name = serde_json::to_value(value)
        .ok()
        .and_then(|v| v.as_str().map(str::to_string))
        .unwrap_or_default();
    Box::leak(name.into_boxed_str())
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
    #[arg(long, default_value_t = defaults().ingest.video.stride, value_parser = clap::value_parser!(u32).range(1..))]
    pub stride: u32,
    /// Video: start time in seconds.
    #[arg(long, default_value_t = defaults().ingest.video.start_s)]
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
    #[arg(long, default_value_t = defaults().features.extraction.sift.max_features.unwrap_or(0), value_parser = clap::builder::TypedValueParser::map(clap::value_parser!(u64).range(16..=1_000_000), |v| v as usize))]
    pub max_features: usize,
    /// Features: downscale images whose longer side is larger than this (pixels).
    #[arg(long, value_parser = clap::value_parser!(u32).range(64..))]
    pub max_image_size: Option<u32>,
    /// Features: `klt` tracking and GRIC key-frames (video, §3.1), `sift` matching (photos), or
    /// `auto` (KLT for a video file, SIFT for photos).
    #[arg(long, default_value = choice_name(&defaults().features.tracking), value_parser = choice::<TrackingMode>)]
    pub tracking: TrackingMode,
    /// Features (KLT): live tracks kept per frame by re-detection.
    #[arg(long, default_value_t = defaults().features.klt_features, value_parser = clap::builder::TypedValueParser::map(clap::value_parser!(u64).range(16..=100_000), |v| v as usize))]
    pub klt_features: usize,
    /// Matching: `exhaustive`, `sequential` (each image with its --window successors), `retrieval`
    /// (its --neighbours most similar images, whatever the file order), or `auto` (exhaustive up to
    /// 40 photos; sequential for video; else the window over the content order plus retrieval).
    /// Retrieval and auto's larger sets then match weakly verified images with every other image.
    #[arg(long, default_value = choice_name(&defaults().matches.pairs), value_parser = choice::<PairMode>)]
    pub pairs: PairMode,
    /// Matching: neighbours on each side for sequential matching.
    #[arg(long, default_value_t = defaults().matches.window, value_parser = clap::builder::TypedValueParser::map(clap::value_parser!(u64).range(1..=1000), |v| v as usize))]
    pub window: usize,
    /// Matching (retrieval): the most similar images each image is matched with.
    #[arg(long, default_value_t = defaults().matches.retrieval.neighbours)]
    pub neighbours: usize,
    /// Matching: Lowe's ratio test threshold, in (0, 1].
    #[arg(long, default_value_t = defaults().matches.verification.matching.ratio)]
    pub ratio: f32,
    /// Matching: skip guided matching along epipolar lines (Table 1 step 4).
    #[arg(long)]
    pub no_guided: bool,
    /// Matching: brute force only over this many strongest features per image, then guided
    /// matching over all of them (0: brute force over all features).
    #[arg(long, default_value_t = defaults().matches.verification.seed_features.unwrap_or(0))]
    pub seed_features: usize,
    /// Matching: with sequential pairs, do not look for close views outside the window (§3.2).
    #[arg(long)]
    pub no_close_views: bool,
    /// Sparse: seed of every random choice (the same seed gives the same model).
    #[arg(long, default_value_t = defaults().sparse.sfm.seed)]
    pub seed: u64,
    /// Sparse: radial distortion estimated by metric BA (eq. 3): `none`, `k1` or `k1k2`.
    #[arg(long, default_value = choice_name(&defaults().sparse.sfm.distortion), value_parser = choice::<Distortion>)]
    pub distortion: Distortion,
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
    /// Sparse: weight every metric BA observation alike instead of by its keypoint's detection
    /// scale (σ ∝ √scale, the default).
    #[arg(long)]
    pub unweighted_observations: bool,
    /// Sparse: a fixed Huber scale (1.5 px) and priors stated against 1 px of noise in metric BA,
    /// instead of both from the observations' measured noise (the default).
    #[arg(long)]
    pub fixed_loss_scale: bool,
    /// Sparse: a known calibration `FX,FY,CX,CY` in pixels, COLMAP's convention (the top-left
    /// pixel's centre at 0.5, 0.5, as in a COLMAP `cameras.txt`). It pins the focal lengths and the
    /// principal point of every camera in metric BA; without it the cameras are self-calibrated.
    #[arg(long, value_name = "FX,FY,CX,CY", value_parser = parse_intrinsics)]
    pub intrinsics: Option<KnownIntrinsics>,
    /// Sparse: standard deviation of the principal point's prior at the image centre, as a fraction
    /// of width + height (eq. 25's u ≈ v ≈ 0 in K_N units).
    #[arg(long, default_value_t = defaults().sparse.sfm.principal_point_prior)]
    pub principal_point_prior: f64,
    /// Sparse: split-and-merge with clusters of at most N views (overlap included), each
    /// reconstructed on its own and merged. By default sets of more than
    /// `split.above` (1000) linked photos are split into clusters of 200.
    #[arg(long, value_name = "N")]
    pub cluster_views: Option<usize>,
    /// Sparse: never split, however large the set.
    #[arg(long, conflicts_with = "cluster_views")]
    pub no_split: bool,
    #[command(flatten)]
    pub dense: DenseArgs,
    #[command(flatten)]
    pub mesh: MeshArgs,
}

/// `--intrinsics FX,FY,CX,CY` (COLMAP convention) → Handheld's pixel convention.
fn parse_intrinsics(s: &str) -> Result<KnownIntrinsics, String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|t| t.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|e| format!("{s:?}: {e} (expected FX,FY,CX,CY in pixels)"))?;
    let [fx, fy, cx, cy] = v[..] else {
        return Err(format!(
            "{s:?}: expected 4 numbers FX,FY,CX,CY in pixels, got {}",
            v.len()
        ));
    };
    Ok(KnownIntrinsics {
        fx,
        fy,
        cx: cx - handheld_core::PIXEL_CENTER_OFFSET_COLMAP,
        cy: cy - handheld_core::PIXEL_CENTER_OFFSET_COLMAP,
    })
}

impl InputArgs {
    /// The library options these arguments ask for (checked by the library).
    pub fn options(&self) -> handheld_pipeline::Result<PipelineOptions> {
        let mut o = defaults();
        o.ingest.images.skip_unreadable = self.skip_bad_images;
        o.ingest.video.stride = self.stride;
        o.ingest.video.start_s = self.start;
        o.ingest.video.end_s = self.end;
        o.ingest.video.max_frames = self.max_frames;
        o.features.extraction.sift.max_features = Some(self.max_features);
        o.features.extraction.max_image_size = self.max_image_size;
        o.features.tracking = self.tracking;
        o.features.klt_features = self.klt_features;
        o.matches.pairs = self.pairs;
        o.matches.window = self.window;
        o.matches.retrieval.neighbours = self.neighbours;
        o.matches.close_views = !self.no_close_views;
        o.matches.verification.matching.ratio = self.ratio;
        o.matches.verification.guided = !self.no_guided;
        o.matches.verification.seed_features =
            (self.seed_features > 0).then_some(self.seed_features);
        let sfm = &mut o.sparse.sfm;
        sfm.seed = self.seed;
        sfm.distortion = self.distortion;
        sfm.refine_principal_point = !self.fixed_principal_point;
        sfm.scale_weighted_observations = !self.unweighted_observations;
        sfm.noise_scaled_loss = !self.fixed_loss_scale;
        sfm.known_intrinsics = self.intrinsics;
        sfm.principal_point_prior = self.principal_point_prior;
        sfm.estimate_aspect = match self.aspect {
            AspectArg::Auto => None,
            AspectArg::Fixed => Some(false),
            AspectArg::Free => Some(true),
        };
        if let Some(n) = self.cluster_views {
            sfm.split.cluster_views = n;
            sfm.split.above = n;
        }
        if self.no_split {
            sfm.split.above = 0;
        }
        o.sparse.refine_keypoints = self.refine_keypoints.then(Default::default);
        o.dense = self.dense.options()?;
        o.mesh = self.mesh.options();
        o.validate()?;
        Ok(o)
    }
}

/// Options of the dense stage (§4).
#[derive(Debug, Clone, Args)]
pub struct DenseArgs {
    /// Dense: images are downscaled so their longer side is at most this (0 = no limit).
    #[arg(long, default_value_t = defaults().dense.max_size)]
    pub dense_max_size: u32,
    /// Dense: images larger than this many megapixels are downscaled to it.
    #[arg(long, default_value_t = defaults().dense.max_megapixels)]
    pub dense_max_megapixels: f64,
    /// Dense: memory the views' maps may take, in GB; many large views are downscaled to fit
    /// (0 = 60 % of this machine's memory).
    #[arg(long, default_value_t = defaults().dense.max_memory_gb)]
    pub dense_max_memory_gb: f64,
    /// Dense: stereo method of each rectified pair (§4.2): `sgm` (semi-global matching, census
    /// cost; the more accurate on Middlebury) or `dp` (the paper's scanline dynamic programming).
    #[arg(long, default_value = choice_name(&defaults().dense.stereo_method()), value_parser = choice::<StereoMethod>)]
    pub stereo_method: StereoMethod,
    /// Dense: N, the views linked per reference view (the reference and (N−1)/2 on each side, §4.3).
    #[arg(long, default_value_t = defaults().dense.link_views())]
    pub link_views: usize,
    /// Dense: V_min, the fewest views a kept depth must be linked through (reference included).
    #[arg(long, default_value_t = defaults().dense.dense.link.min_visibility)]
    pub min_visibility: usize,
    /// Dense: the V a view keeps when at least half its depths reach it; views whose neighbours
    /// are too far apart to link further (an object ring) keep --min-visibility.
    #[arg(long, default_value_t = defaults().dense.dense.link.preferred_visibility)]
    pub preferred_visibility: usize,
}

impl DenseArgs {
    pub fn options(&self) -> handheld_pipeline::Result<DenseStageOptions> {
        let mut o = defaults().dense;
        o.max_size = self.dense_max_size;
        o.max_megapixels = self.dense_max_megapixels;
        o.max_memory_gb = self.dense_max_memory_gb;
        o.set_stereo_method(self.stereo_method);
        o.set_link_views(self.link_views)?;
        o.dense.link.min_visibility = self.min_visibility;
        o.dense.link.preferred_visibility = self.preferred_visibility;
        o.validate()?;
        Ok(o)
    }
}

/// Options of the mesh stage (§5.1).
#[derive(Debug, Clone, Args)]
pub struct MeshArgs {
    /// Mesh: `fused` (TSDF over all depth maps, plus per-view meshes) or `single` (per-view only).
    #[arg(long, default_value = choice_name(&defaults().mesh.mode), value_parser = choice::<MeshMode>)]
    pub mode: MeshMode,
    /// Mesh: face count after quadric simplification.
    #[arg(long, default_value_t = defaults().mesh.target_faces().unwrap_or(0))]
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
    #[arg(long, default_value_t = defaults().mesh.fusion.max_hole_perimeter_voxels)]
    pub max_hole_perimeter: f64,
    /// Mesh: samples with σ over K truncation bands count with weight (K·t/σ)², beyond max(2, √n)·K·t
    /// (n views see the place) they are left out (far background); 0 counts every sample fully.
    #[arg(long, default_value_t = defaults().mesh.fusion.tsdf.max_depth_std)]
    pub max_depth_std: f64,
}

impl MeshArgs {
    pub fn options(&self) -> MeshStageOptions {
        let mut o = defaults().mesh;
        o.mode = self.mode;
        if let Some(s) = o.fusion.simplify.as_mut() {
            s.target_faces = self.target_faces;
        }
        if let Some(v) = self.voxel_size {
            o.fusion.tsdf.voxel_size = VoxelSize::Absolute(v);
        }
        o.fusion.max_hole_perimeter_voxels = self.max_hole_perimeter;
        o.fusion.tsdf.max_depth_std = self.max_depth_std;
        o.view_meshes = !self.no_view_meshes;
        o.hold_out = self.hold_out.clone();
        o
    }
}

/// Whether metric BA estimates the aspect ratio (§3.4); maps onto `SfmOptions::estimate_aspect`.
#[derive(Debug, Clone, Copy, ValueEnum, PartialEq, Eq)]
pub enum AspectArg {
    /// Estimated for video, fixed to 1 for photos.
    Auto,
    /// Always fixed to 1 (square pixels).
    Fixed,
    /// Always estimated (one constant ratio per intrinsics group).
    Free,
}
