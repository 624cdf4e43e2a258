//! The augment stage (§5.3), registered in the graph when an object is given
//! (`PipelineOptions::augment`): the object placed (automatically or by a given similarity),
//! composited into every ingested frame by `handheld_render::augment::FrameLoop` (hidden where the
//! reconstructed mesh is nearer), encoded at the input's size and rate with its audio; the camera
//! track exported as an animated glTF camera and a Nuke `.chan`. It needs the sparse model and
//! uses the mesh when the workspace has one (so `handheld augment` is one run of the graph). When
//! the mesh stage failed, the dense depth maps hide the object instead (each frame's own, or the
//! two nearest key-frames' warped into it), with a warning; without either it is drawn over
//! everything, with a warning.

use std::path::{Path, PathBuf};

use handheld_core::{MetricReconstruction, PosedCamera, Progress, Rigid3, TriMesh};
use handheld_io::dense_folder::{map_file, read_cameras, MapKind};
use handheld_io::track::{write_chan, write_track_glb, TrackFrame};
use handheld_io::video::encode::VideoWriter;
use handheld_render::augment::{
    anchor_of, auto_place, object_axes, object_box, visible_somewhere, DepthSource, FrameFigures,
    FrameLoop, Occluder, PlaceOptions, Placement, PlacementReport,
};
use image::RgbImage;
use nalgebra::Point3;
use serde::{Deserialize, Serialize};

use crate::error::{PipelineError, Result};
use crate::files::{stage, write_json, MODEL_GLB};
use crate::manifest::Workspace;
use crate::stage::{Produced, Stage, StageContext, SummaryFile};
use crate::warning::{code, Warning};

/// `augment/placement.json`, `augment/camera.glb`, `augment/camera.chan`.
pub const PLACEMENT_JSON: &str = "placement.json";
pub const CAMERA_GLB: &str = "camera.glb";
pub const CAMERA_CHAN: &str = "camera.chan";
/// The augmented video when no output is given.
pub const AUGMENTED_MP4: &str = "augmented.mp4";

/// The virtual object: one the project ships, or a glTF 2.0 file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ObjectSource {
    /// A textured box (`--object box`).
    Box,
    /// A coordinate-axes marker (`--object axes`).
    Axes,
    File(PathBuf),
}

impl ObjectSource {
    pub fn parse(s: &str) -> Self {
        match s {
            "box" => Self::Box,
            "axes" => Self::Axes,
            _ => Self::File(PathBuf::from(s)),
        }
    }

    /// The object's mesh and texture; a file that is not glTF gives an error naming it.
    pub fn load(&self) -> Result<(TriMesh, Option<RgbImage>)> {
        match self {
            Self::Box => {
                let (m, t) = object_box();
                Ok((m, Some(t)))
            }
            Self::Axes => Ok((object_axes(), None)),
            Self::File(p) => Ok(handheld_io::glb::read_glb(p)?),
        }
    }
}

/// Where the object goes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PlacementMode {
    /// On the dominant supporting plane of the sparse points.
    Auto,
    /// A similarity in the model's frame, from a JSON file (the format of `placement.json`).
    Transform(PathBuf),
}

/// Options of the augment stage.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(default)]
pub struct AugmentOptions {
    pub object: ObjectSource,
    pub placement: PlacementMode,
    pub place: PlaceOptions,
    /// The augmented video (`WS/augment/augmented.mp4` when `None`).
    pub output: Option<PathBuf>,
    /// Hide the object where the reconstructed mesh is nearer (when the workspace has a mesh).
    pub occlusion: bool,
    /// x264 constant rate factor of the output.
    pub crf: u8,
}

impl Default for AugmentOptions {
    fn default() -> Self {
        Self {
            object: ObjectSource::Box,
            placement: PlacementMode::Auto,
            place: PlaceOptions::default(),
            output: None,
            occlusion: true,
            crf: 18,
        }
    }
}

impl AugmentOptions {
    pub fn validate(&self) -> Result<()> {
        if self.crf > 51 {
            return Err(PipelineError::option(
                "--crf",
                format!("must be in 0..=51, got {}", self.crf),
            ));
        }
        let f = self.place.height_fraction;
        if !(f.is_finite() && f > 0.0 && f < 10.0) {
            return Err(PipelineError::option(
                "--object-height",
                format!("must be in (0, 10), got {f}"),
            ));
        }
        Ok(())
    }
}

/// `placement.json`: the similarity used, and how the automatic placement decided.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct PlacementFile {
    #[serde(flatten)]
    pub placement: Placement,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub auto: Option<PlacementReport>,
}

/// What the augment stage did.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct AugmentSummary {
    pub output: PathBuf,
    pub frames: usize,
    pub posed_frames: usize,
    pub width: u32,
    pub height: u32,
    pub fps: f64,
    pub placement: Placement,
    pub occlusion: bool,
    /// RMS of the second difference of the anchor's image track (pixels), over runs of
    /// consecutive posed frames.
    pub jitter_px: f64,
    /// Median over frames of the per-frame RMS reprojection error.
    pub median_frame_rms_px: f64,
    /// Compositing and encoding speed (frames per second, SfM not counted).
    pub composite_fps: f64,
    pub warnings: Vec<Warning>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub per_frame: Option<Vec<FrameFigures>>,
}

/// Decides the placement: automatic, or read from `Transform`'s file (errors name it).
pub fn place(
    rec: &MetricReconstruction,
    object: &TriMesh,
    opts: &AugmentOptions,
) -> Result<(Placement, Option<PlacementReport>)> {
    match &opts.placement {
        PlacementMode::Transform(path) => {
            let bad = |reason: String| PipelineError::Input {
                path: path.clone(),
                reason,
            };
            let bytes = std::fs::read(path).map_err(|e| bad(format!("cannot read ({e})")))?;
            let f: PlacementFile = serde_json::from_slice(&bytes).map_err(|e| {
                bad(format!(
                    "not a placement ({e}); expected JSON {{\"scale\": s, \"rotation\": [w, x, y, z], \"translation\": [x, y, z]}}"
                ))
            })?;
            f.placement.validate().map_err(|e| bad(e.to_string()))?;
            Ok((f.placement, None))
        }
        PlacementMode::Auto => {
            let points: Vec<(Point3<f64>, usize)> = rec
                .points
                .values()
                .map(|p| (p.xyz, p.track.elements.len()))
                .collect();
            let cams: Vec<Rigid3> = rec.views.values().map(|v| v.cam_from_world).collect();
            let (p, r) = auto_place(object, &points, &cams, &opts.place)
                .map_err(|e| PipelineError::workspace(stage::SPARSE, e.to_string()))?;
            Ok((p, Some(r)))
        }
    }
}

/// The augment stage.
pub struct Augment {
    pub options: AugmentOptions,
}

impl Stage for Augment {
    type Options = AugmentOptions;
    type Summary = AugmentSummary;

    const NAME: &'static str = stage::AUGMENT;
    const READS: &'static [&'static str] = &[stage::INGEST, stage::SPARSE];
    /// The mesh hides the object where the real scene is nearer; without one, the depth maps do.
    const READS_IF_PRESENT: &'static [&'static str] = &[stage::DENSE, stage::MESH];
    const ABOUT: &'static str =
        "augmented video (§5.3): a virtual object composited into every frame; the camera track as glTF and .chan";

    fn options(&self) -> &AugmentOptions {
        &self.options
    }

    fn validate(&self) -> Result<()> {
        self.options.validate()
    }

    fn reads_if_present(&self) -> &'static [&'static str] {
        if self.options.occlusion {
            Self::READS_IF_PRESENT
        } else {
            &[]
        }
    }

    fn run(&self, ctx: &StageContext, dir: &Path) -> Result<Produced<AugmentSummary>> {
        let mut summary = augment(ctx.ws, &self.options, dir, ctx.progress)?;
        let file = SummaryFile::full(&summary)?;
        summary.per_frame = None;
        let mut outputs: Vec<String> = [PLACEMENT_JSON, CAMERA_GLB, CAMERA_CHAN]
            .iter()
            .map(|s| s.to_string())
            .collect();
        if summary.output.starts_with(dir) {
            if let Some(n) = summary.output.file_name() {
                outputs.push(n.to_string_lossy().into_owned());
            }
        }
        let warnings = summary.warnings.clone();
        Ok(Produced::new(outputs, summary)
            .warn(warnings)
            .summary_file(file))
    }
}

/// The frame rate of the ingested frames, and the input whose audio they keep (a video taken
/// whole), with a warning when a stride drops the audio.
fn timing<'a>(
    ingest: &'a handheld_io::ingest::IngestResult,
    warnings: &mut Vec<Warning>,
) -> (f64, Option<&'a Path>) {
    let stride = ingest
        .images
        .windows(2)
        .filter_map(|p| Some(p[1].frame?.index.saturating_sub(p[0].frame?.index)))
        .min()
        .unwrap_or(1)
        .max(1);
    let (fps, audio) = match &ingest.video {
        Some(v) if v.fps > 0.0 => (
            v.fps / stride as f64,
            (stride == 1).then_some(ingest.input.as_path()),
        ),
        _ => (10.0, None),
    };
    if ingest.video.is_some() && stride > 1 {
        warnings.push(Warning::new(
            code::VIDEO,
            format!("frames were kept with stride {stride}: the video is {fps:.3} frames per second and has no audio"),
        ));
    }
    (fps, audio)
}

/// Writes the camera track: `camera.glb` (an animated glTF camera and the sparse points) and
/// `camera.chan` (Nuke).
fn write_track(rec: &MetricReconstruction, tracked: &[TrackFrame], dir: &Path) -> Result<()> {
    let Some(c) = rec.cameras.values().next() else {
        return Ok(());
    };
    let fy = c.intrinsics.f * c.intrinsics.aspect;
    let yfov = 2.0 * (f64::from(c.height) / 2.0 / fy).atan();
    let points: Vec<([f64; 3], [u8; 3])> = rec
        .points
        .values()
        .map(|p| ([p.xyz.x, p.xyz.y, p.xyz.z], p.color))
        .collect();
    write_track_glb(
        &dir.join(CAMERA_GLB),
        tracked,
        yfov,
        f64::from(c.width) / f64::from(c.height),
        &points,
    )?;
    write_chan(&dir.join(CAMERA_CHAN), tracked, yfov.to_degrees())?;
    Ok(())
}

/// The real scene that hides the object.
enum Scene {
    Mesh(TriMesh),
    DepthMaps(Vec<DepthSource>),
}

impl Scene {
    fn occluder(&self) -> Occluder<'_> {
        match self {
            Scene::Mesh(m) => Occluder::Mesh(m),
            Scene::DepthMaps(d) => Occluder::DepthMaps(d),
        }
    }
}

/// The dense stage's depth maps with their cameras (`None` when the dense stage has not run).
fn dense_depth(ws: &Workspace) -> Result<Option<Vec<DepthSource>>> {
    let dir = ws.root.join(stage::DENSE);
    if ws.manifest(stage::DENSE).is_none() {
        return Ok(None);
    }
    let mut out = Vec::new();
    for e in read_cameras(&dir)? {
        let path = dir.join(map_file(MapKind::Depth, &e.image));
        let depth = handheld_io::pfm::read_pfm(&path).map_err(|err| PipelineError::Input {
            path: path.clone(),
            reason: format!("cannot read the depth map ({err}); rerun the dense stage"),
        })?;
        out.push(DepthSource {
            name: e.image,
            posed: PosedCamera::new(e.camera, e.cam_from_world),
            depth,
        });
    }
    Ok((!out.is_empty()).then_some(out))
}

/// The real scene for occlusion: the mesh stage's model when it finished, else the dense depth
/// maps (with a warning), else nothing (with a warning).
fn occluder(
    ws: &Workspace,
    opts: &AugmentOptions,
    warnings: &mut Vec<Warning>,
) -> Result<Option<Scene>> {
    if !opts.occlusion {
        return Ok(None);
    }
    let mesh_path = ws.path(stage::MESH, MODEL_GLB);
    if ws.manifest(stage::MESH).is_some() && mesh_path.exists() {
        return Ok(Some(Scene::Mesh(handheld_io::glb::read_glb(&mesh_path)?.0)));
    }
    if let Some(maps) = dense_depth(ws)? {
        warnings.push(Warning::new(
            code::FALLBACK,
            format!(
                "no reconstructed mesh: the object is hidden by the {} dense depth maps instead \
                 (each frame's own, or the two nearest key-frames' warped into it)",
                maps.len()
            ),
        ));
        return Ok(Some(Scene::DepthMaps(maps)));
    }
    warnings.push(Warning::new(
        code::INPUT_MISSING,
        "no reconstructed mesh and no depth maps: the object is drawn without occlusion",
    ));
    Ok(None)
}

/// Runs augmentation on the workspace `ws` into `dir` (`WS/augment`).
pub fn augment(
    ws: &Workspace,
    opts: &AugmentOptions,
    dir: &Path,
    progress: &dyn Progress,
) -> Result<AugmentSummary> {
    opts.validate()?;
    let ingest = ws.read_ingest()?;
    if ingest.images.len() < 2 {
        return Err(PipelineError::Input {
            path: ingest.input.clone(),
            reason: format!(
                "{} frame(s); augmenting needs a video (or image sequence) of at least 2 frames",
                ingest.images.len()
            ),
        });
    }
    let rec = ws.read_sparse_model()?;
    let (object, texture) = opts.object.load()?;
    if object.faces.is_empty() {
        return Err(PipelineError::option(
            "--object",
            "the object has no triangles",
        ));
    }
    let (placement, auto) = place(&rec, &object, opts)?;
    let placed = placement.transform(&object);
    if !visible_somewhere(&rec, &placed) {
        return Err(PipelineError::option(
            "--transform",
            "the placement puts the object behind every camera or outside every image; give another placement",
        ));
    }
    std::fs::create_dir_all(dir).map_err(|e| handheld_io::IoError::io(dir, e))?;
    write_json(
        &dir.join(PLACEMENT_JSON),
        &PlacementFile {
            placement,
            auto: auto.clone(),
        },
    )?;
    let mut warnings: Vec<Warning> = auto
        .iter()
        .flat_map(|a| {
            a.warnings
                .iter()
                .map(|w| Warning::new(code::NOTE, w.clone()))
        })
        .collect();
    let scene_mesh = occluder(ws, opts, &mut warnings)?;
    let load_opts = handheld_io::images::ImageIngestOptions {
        min_dimension: 1,
        ..Default::default()
    };
    let first = handheld_io::images::load_image(&ingest.images[0].info.path, &load_opts)?
        .image
        .to_rgb8();
    let (w, h) = (first.width(), first.height());
    let (ew, eh) = (w + w % 2, h + h % 2);
    if (ew, eh) != (w, h) {
        warnings.push(Warning::new(
            code::VIDEO,
            format!("frames are {w}×{h}; H.264 needs even sizes, so the last column/row is repeated ({ew}×{eh})"),
        ));
    }
    let (fps, audio) = timing(&ingest, &mut warnings);
    let output = opts
        .output
        .clone()
        .unwrap_or_else(|| dir.join(AUGMENTED_MP4));
    let mut writer = VideoWriter::create(&output, ew, eh, fps, opts.crf, audio)?;
    let anchor = anchor_of(&object, &placement);
    let mut frames = FrameLoop::new(
        &rec,
        &placed,
        texture.as_ref(),
        scene_mesh.as_ref().map(Scene::occluder),
        anchor,
        fps,
    );
    let mut busy = 0.0;
    progress.start("augmenting the frames", ingest.images.len() as u64);
    for img in &ingest.images {
        let mut frame = handheld_io::images::load_image(&img.info.path, &load_opts)?
            .image
            .to_rgb8();
        let t = std::time::Instant::now();
        frames.frame(
            &img.info.name,
            img.frame.map(|f| (f.index, f.time_s)),
            &mut frame,
        );
        let frame = if (ew, eh) != (w, h) {
            RgbImage::from_fn(ew, eh, |x, y| *frame.get_pixel(x.min(w - 1), y.min(h - 1)))
        } else {
            frame
        };
        writer.push(&frame)?;
        busy += t.elapsed().as_secs_f64();
        progress.inc(1);
    }
    progress.finish();
    let t_enc = std::time::Instant::now();
    let written = writer.finish()?;
    busy += t_enc.elapsed().as_secs_f64();
    let posed = frames.posed();
    if posed < written {
        warnings.push(Warning::new(
            code::VIDEO,
            format!(
                "{} of {written} frames have no camera and are left as they are",
                written - posed
            ),
        ));
    }
    let tracked: Vec<TrackFrame> = frames
        .tracked
        .iter()
        .map(|t| TrackFrame {
            frame: t.frame,
            time_s: t.time_s,
            cam_from_world: t.cam_from_world,
        })
        .collect();
    write_track(&rec, &tracked, dir)?;
    Ok(AugmentSummary {
        output,
        frames: written,
        posed_frames: posed,
        width: ew,
        height: eh,
        fps,
        placement,
        occlusion: scene_mesh.is_some(),
        jitter_px: frames.jitter(),
        median_frame_rms_px: frames.median_rms(),
        composite_fps: written as f64 / busy.max(1e-9),
        warnings,
        per_frame: Some(frames.per_frame),
    })
}
