//! Augmented video (§5.3) on a workspace: the object placed (automatically or by a given
//! similarity), composited into every ingested frame through that frame's camera (hidden where
//! the reconstructed mesh is nearer), encoded at the input's size and rate with its audio; the
//! camera track exported as an animated glTF camera and a Nuke `.chan`; per-frame reprojection
//! error and the anchored object's image jitter measured.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use handheld_core::{
    Camera, FloatMap, MetricReconstruction, PosedCamera, Progress, Rigid3, TriMesh,
};
use handheld_io::track::{write_chan, write_track_glb, TrackFrame};
use handheld_io::video::encode::VideoWriter;
use handheld_render::augment::{
    auto_place, bounds, object_axes, object_box, Compositor, PlaceOptions, Placement,
    PlacementReport,
};
use handheld_render::raster::rasterise;
use image::RgbImage;
use nalgebra::{Point3, Vector2};
use serde::{Deserialize, Serialize};

use crate::error::{PipelineError, Result};
use crate::files::{stage, write_json, MODEL_GLB};
use crate::manifest::Workspace;

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

/// One frame's figures.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct FrameFigures {
    pub image: String,
    pub posed: bool,
    /// RMS reprojection error of the frame's observations (pixels).
    pub rms_px: Option<f64>,
    /// The anchored object point's pixel position.
    pub anchor_px: Option<[f64; 2]>,
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
    pub warnings: Vec<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub per_frame: Option<Vec<FrameFigures>>,
}

/// Per-frame RMS reprojection error of a model's views.
pub fn frame_rms(rec: &MetricReconstruction) -> BTreeMap<String, f64> {
    rec.views
        .values()
        .filter_map(|v| {
            let cam = rec.cameras.get(&v.camera_id)?;
            let mut sum = 0.0;
            let mut n = 0usize;
            for o in &v.observations {
                let Some(p) = o.point_id.and_then(|id| rec.points.get(&id)) else {
                    continue;
                };
                if let Some(px) = cam.project(&v.cam_from_world, &p.xyz) {
                    sum += (px - o.xy).norm_squared();
                    n += 1;
                }
            }
            (n > 0).then(|| (v.name.clone(), (sum / n as f64).sqrt()))
        })
        .collect()
}

/// RMS of the second difference of a track of positions, over runs without gaps.
pub fn jitter(track: &[Option<Vector2<f64>>]) -> f64 {
    let mut sum = 0.0;
    let mut n = 0usize;
    for w in track.windows(3) {
        if let [Some(a), Some(b), Some(c)] = w {
            sum += (a - 2.0 * b + c).norm_squared();
            n += 1;
        }
    }
    if n == 0 {
        0.0
    } else {
        (sum / n as f64).sqrt()
    }
}

/// The point the object stands on (its base centre), in the model frame.
pub fn anchor_of(object: &TriMesh, p: &Placement) -> Point3<f64> {
    let (lo, hi) = bounds(object);
    p.apply(&Point3::new((lo.x + hi.x) / 2.0, lo.y, (lo.z + hi.z) / 2.0))
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

/// Whether the placed object shows in at least one posed frame (a vertex in front of the camera
/// and inside the image).
fn visible_somewhere(rec: &MetricReconstruction, placed: &TriMesh) -> bool {
    rec.views.values().any(|v| {
        let Some(cam) = rec.cameras.get(&v.camera_id) else {
            return false;
        };
        placed.vertices.positions.iter().any(|p| {
            let q = Point3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
            cam.project(&v.cam_from_world, &q)
                .is_some_and(|px| cam.contains(&px))
        })
    })
}

/// The real scene's depth in a frame, inside the object's window (NaN elsewhere).
pub fn scene_depth(
    mesh: &TriMesh,
    camera: &Camera,
    pose: &Rigid3,
    placed: &TriMesh,
    buf: &mut Vec<f32>,
    out: &mut FloatMap,
) {
    let (w, h) = (camera.width as usize, camera.height as usize);
    if out.width != w || out.height != h {
        *out = FloatMap::filled(w, h, 1, f32::NAN);
    }
    out.data.fill(f32::NAN);
    // The object's window, with a margin.
    let mut lo = Vector2::repeat(f64::INFINITY);
    let mut hi = Vector2::repeat(f64::NEG_INFINITY);
    for p in &placed.vertices.positions {
        let q = Point3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
        match camera.project(pose, &q) {
            Some(px) => {
                lo = lo.inf(&px);
                hi = hi.sup(&px);
            }
            None => {
                lo = Vector2::zeros();
                hi = Vector2::new(w as f64, h as f64);
            }
        }
    }
    if !lo.x.is_finite() {
        return;
    }
    let x0 = (lo.x - 2.0).max(0.0) as usize;
    let y0 = (lo.y - 2.0).max(0.0) as usize;
    let x1 = ((hi.x + 3.0).max(0.0) as usize).min(w);
    let y1 = ((hi.y + 3.0).max(0.0) as usize).min(h);
    if x0 >= x1 || y0 >= y1 {
        return;
    }
    let data = &mut out.data;
    let view = PosedCamera::new(camera.clone(), *pose);
    rasterise(mesh, &view, 1, (x0, y0, x1, y1), buf, |f| {
        data[f.sy * w + f.sx] = f.z as f32;
    });
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
    let mut warnings: Vec<String> = auto.iter().flat_map(|a| a.warnings.clone()).collect();
    // The real scene for occlusion.
    let mesh_path = ws.path(stage::MESH, MODEL_GLB);
    let scene_mesh = if opts.occlusion && mesh_path.exists() {
        Some(handheld_io::glb::read_glb(&mesh_path)?.0)
    } else {
        if opts.occlusion {
            warnings.push("no reconstructed mesh: the object is drawn without occlusion".into());
        }
        None
    };
    // Frames, in ingest order; their cameras by name.
    let by_name: BTreeMap<&str, &handheld_core::View> =
        rec.views.values().map(|v| (v.name.as_str(), v)).collect();
    let first = handheld_io::images::load_image(
        &ingest.images[0].info.path,
        &handheld_io::images::ImageIngestOptions {
            min_dimension: 1,
            ..Default::default()
        },
    )?
    .image
    .to_rgb8();
    let (w, h) = (first.width(), first.height());
    let (ew, eh) = (w + w % 2, h + h % 2);
    if (ew, eh) != (w, h) {
        warnings.push(format!(
            "frames are {w}×{h}; H.264 needs even sizes, so the last column/row is repeated ({ew}×{eh})"
        ));
    }
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
        warnings.push(format!(
            "frames were kept with stride {stride}: the video is {fps:.3} frames per second and has no audio"
        ));
    }
    let output = opts
        .output
        .clone()
        .unwrap_or_else(|| dir.join(AUGMENTED_MP4));
    let mut writer = VideoWriter::create(&output, ew, eh, fps, opts.crf, audio)?;
    let rms = frame_rms(&rec);
    let anchor = anchor_of(&object, &placement);
    let mut compositor = Compositor::new();
    let mut zbuf = Vec::new();
    let mut depth = FloatMap::filled(0, 0, 1, 0.0);
    let mut per_frame = Vec::with_capacity(ingest.images.len());
    let mut track = Vec::with_capacity(ingest.images.len());
    let mut track_frames = Vec::new();
    let load_opts = handheld_io::images::ImageIngestOptions {
        min_dimension: 1,
        ..Default::default()
    };
    let mut busy = 0.0;
    progress.start("augmenting the frames", ingest.images.len() as u64);
    for img in &ingest.images {
        let name = &img.info.name;
        let mut frame = handheld_io::images::load_image(&img.info.path, &load_opts)?
            .image
            .to_rgb8();
        let t = std::time::Instant::now();
        let view = by_name.get(name.as_str()).copied();
        let cam = view.and_then(|v| rec.cameras.get(&v.camera_id));
        let mut anchor_px = None;
        if let (Some(v), Some(cam)) = (view, cam) {
            let occ = scene_mesh.as_ref().map(|m| {
                scene_depth(m, cam, &v.cam_from_world, &placed, &mut zbuf, &mut depth);
                &depth
            });
            compositor.composite(
                &mut frame,
                &placed,
                texture.as_ref(),
                &PosedCamera::new(cam.clone(), v.cam_from_world),
                occ,
            );
            anchor_px = cam.project(&v.cam_from_world, &anchor);
            track_frames.push(TrackFrame {
                frame: img.frame.map_or(track_frames.len() as u64, |f| f.index),
                time_s: img
                    .frame
                    .map_or(track_frames.len() as f64 / fps, |f| f.time_s),
                cam_from_world: v.cam_from_world,
            });
        }
        track.push(anchor_px);
        per_frame.push(FrameFigures {
            image: name.clone(),
            posed: view.is_some(),
            rms_px: rms.get(name).copied(),
            anchor_px: anchor_px.map(|p| [p.x, p.y]),
        });
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
    let frames = writer.finish()?;
    busy += t_enc.elapsed().as_secs_f64();
    let posed = per_frame.iter().filter(|f| f.posed).count();
    if posed < frames {
        warnings.push(format!(
            "{} of {frames} frames have no camera and are left as they are",
            frames - posed
        ));
    }
    // The camera track.
    if let Some(c) = rec.cameras.values().next() {
        let fy = c.intrinsics.f * c.intrinsics.aspect;
        let yfov = 2.0 * (f64::from(c.height) / 2.0 / fy).atan();
        let points: Vec<([f64; 3], [u8; 3])> = rec
            .points
            .values()
            .map(|p| ([p.xyz.x, p.xyz.y, p.xyz.z], p.color))
            .collect();
        write_track_glb(
            &dir.join(CAMERA_GLB),
            &track_frames,
            yfov,
            f64::from(c.width) / f64::from(c.height),
            &points,
        )?;
        write_chan(&dir.join(CAMERA_CHAN), &track_frames, yfov.to_degrees())?;
    }
    let mut rms_all: Vec<f64> = per_frame.iter().filter_map(|f| f.rms_px).collect();
    rms_all.sort_by(f64::total_cmp);
    Ok(AugmentSummary {
        output,
        frames,
        posed_frames: posed,
        width: ew,
        height: eh,
        fps,
        placement,
        occlusion: scene_mesh.is_some(),
        jitter_px: jitter(&track),
        median_frame_rms_px: rms_all.get(rms_all.len() / 2).copied().unwrap_or(f64::NAN),
        composite_fps: frames as f64 / busy.max(1e-9),
        warnings,
        per_frame: Some(per_frame),
    })
}

/// The vertices of the placed object in the model frame (f64), for accuracy checks.
pub fn placed_vertices(object: &TriMesh, p: &Placement) -> Vec<Point3<f64>> {
    object
        .vertices
        .positions
        .iter()
        .map(|v| {
            p.apply(&Point3::new(
                f64::from(v[0]),
                f64::from(v[1]),
                f64::from(v[2]),
            ))
        })
        .collect()
}
