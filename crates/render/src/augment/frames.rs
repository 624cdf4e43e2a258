//! The augmented video's frame loop (§5.3), frame by frame: the real scene's depth in the object's
//! window (occlusion), the object composited through the frame's camera, the anchor's image
//! position (jitter), the frame's RMS reprojection error, and the camera track. The caller reads
//! and writes the frames (the pipeline streams them from and to video files).

use std::collections::BTreeMap;

use handheld_core::{FloatMap, MetricReconstruction, PosedCamera, Rigid3, TriMesh, View};
use image::RgbImage;
use nalgebra::{Point3, Vector2};
use serde::{Deserialize, Serialize};

use super::{bounds, Compositor, Placement};
use crate::raster::rasterise;

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

/// One posed frame of the camera track.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrackedFrame {
    /// The frame's index in the video (or its rank among the posed frames).
    pub frame: u64,
    pub time_s: f64,
    pub cam_from_world: Rigid3,
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

/// Whether the placed object shows in at least one posed frame (a vertex in front of the camera
/// and inside the image).
pub fn visible_somewhere(rec: &MetricReconstruction, placed: &TriMesh) -> bool {
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

/// What hides the object: the reconstructed mesh, or (without one) the dense depth maps of the
/// frames, warped into the frame being drawn.
#[derive(Clone, Copy, Debug)]
pub enum Occluder<'a> {
    Mesh(&'a TriMesh),
    DepthMaps(&'a [DepthSource]),
}

/// One view's dense depth map and the camera it was computed with (possibly downscaled).
#[derive(Clone, Debug)]
pub struct DepthSource {
    pub name: String,
    pub posed: PosedCamera,
    /// Camera-frame z per pixel; NaN or ≤ 0 where missing.
    pub depth: FloatMap,
}

/// The object's window in the frame, with a margin: `(x0, y0, x1, y1)`, `None` when empty.
fn object_window(view: &PosedCamera, placed: &TriMesh) -> Option<(usize, usize, usize, usize)> {
    let (camera, pose) = (&view.camera, &view.cam_from_world);
    let (w, h) = (camera.width as usize, camera.height as usize);
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
        return None;
    }
    let x0 = (lo.x - 2.0).max(0.0) as usize;
    let y0 = (lo.y - 2.0).max(0.0) as usize;
    let x1 = ((hi.x + 3.0).max(0.0) as usize).min(w);
    let y1 = ((hi.y + 3.0).max(0.0) as usize).min(h);
    (x0 < x1 && y0 < y1).then_some((x0, y0, x1, y1))
}

/// `out` sized to the view's image and cleared to NaN.
fn clear_depth(view: &PosedCamera, out: &mut FloatMap) {
    let (w, h) = (view.camera.width as usize, view.camera.height as usize);
    if out.width != w || out.height != h {
        *out = FloatMap::filled(w, h, 1, f32::NAN);
    }
    out.data.fill(f32::NAN);
}

/// The real scene's depth in the frame seen from `view`, inside the object's window (NaN
/// elsewhere).
pub fn scene_depth(
    mesh: &TriMesh,
    view: &PosedCamera,
    placed: &TriMesh,
    buf: &mut Vec<f32>,
    out: &mut FloatMap,
) {
    clear_depth(view, out);
    let Some(window) = object_window(view, placed) else {
        return;
    };
    let w = view.camera.width as usize;
    let data = &mut out.data;
    rasterise(mesh, view, 1, window, buf, |f| {
        data[f.sy * w + f.sx] = f.z as f32;
    });
}

/// The depth maps that stand in for the scene in the frame `name` seen from `view`: its own, when
/// it has one, else the two whose cameras are nearest.
pub fn nearest_sources<'s>(
    sources: &'s [DepthSource],
    name: &str,
    view: &PosedCamera,
) -> Vec<&'s DepthSource> {
    if let Some(own) = sources.iter().find(|s| s.name == name) {
        return vec![own];
    }
    let c = view.center();
    let mut by_distance: Vec<(f64, &DepthSource)> = sources
        .iter()
        .map(|s| ((s.posed.center() - c).norm(), s))
        .collect();
    by_distance.sort_by(|a, b| a.0.total_cmp(&b.0));
    by_distance.into_iter().take(2).map(|(_, s)| s).collect()
}

/// The real scene's depth in the frame seen from `view`, inside the object's window, from depth
/// maps: every pixel of each source is lifted to the world and projected into the frame, splatted
/// over the pixels its footprint covers, the nearest depth kept (a forward warp with a z-buffer).
/// Pixels no source reaches stay NaN (they do not hide the object).
pub fn warped_depth(
    sources: &[&DepthSource],
    view: &PosedCamera,
    placed: &TriMesh,
    out: &mut FloatMap,
) {
    clear_depth(view, out);
    let Some((x0, y0, x1, y1)) = object_window(view, placed) else {
        return;
    };
    let w = view.camera.width as usize;
    let ft = view.camera.intrinsics.f;
    for src in sources {
        let (sw, sh) = (src.depth.width, src.depth.height);
        let to_frame = view.cam_from_world * src.posed.cam_from_world.inverse();
        let fs = src.posed.camera.intrinsics.f;
        for sy in 0..sh {
            for sx in 0..sw {
                let z = src.depth.data[sy * sw + sx];
                if !(z.is_finite() && z > 0.0) {
                    continue;
                }
                let ray = src
                    .posed
                    .camera
                    .ray_in_cam(Vector2::new(sx as f64, sy as f64));
                let pc = ray * (z as f64 / ray.z);
                let q = to_frame * Point3::from(pc);
                if q.z <= 0.0 {
                    continue;
                }
                let px = view
                    .camera
                    .intrinsics
                    .normalized_to_pixel(Vector2::new(q.x / q.z, q.y / q.z));
                // The source pixel's footprint in the frame, in pixels.
                let r = (0.5 * (ft / fs) * (z as f64 / q.z)).clamp(0.5, 8.0);
                let (ax, bx) = (
                    (px.x - r).round().max(x0 as f64),
                    (px.x + r).round().min(x1 as f64 - 1.0),
                );
                let (ay, by) = (
                    (px.y - r).round().max(y0 as f64),
                    (px.y + r).round().min(y1 as f64 - 1.0),
                );
                if ax > bx || ay > by {
                    continue;
                }
                for yy in ay as usize..=by as usize {
                    for xx in ax as usize..=bx as usize {
                        let d = &mut out.data[yy * w + xx];
                        if !(d.is_finite() && *d <= q.z as f32) {
                            *d = q.z as f32;
                        }
                    }
                }
            }
        }
    }
}

/// The placed object composited into the frames of a model, one frame at a time, with every
/// frame's figures and the camera track kept.
pub struct FrameLoop<'a> {
    rec: &'a MetricReconstruction,
    by_name: BTreeMap<&'a str, &'a View>,
    placed: &'a TriMesh,
    texture: Option<&'a RgbImage>,
    /// The real scene, which hides the object where it is nearer.
    occluder: Option<Occluder<'a>>,
    anchor: Point3<f64>,
    rms: BTreeMap<String, f64>,
    fps: f64,
    compositor: Compositor,
    zbuf: Vec<f32>,
    depth: FloatMap,
    /// Every frame's figures, in the order given.
    pub per_frame: Vec<FrameFigures>,
    /// The anchor's image position in every frame (`None` where unposed, behind or outside the
    /// image).
    pub track: Vec<Option<Vector2<f64>>>,
    /// The posed frames' cameras.
    pub tracked: Vec<TrackedFrame>,
}

impl<'a> FrameLoop<'a> {
    /// `placed` is the object in the model's frame, `anchor` the point it stands on; `fps` times
    /// the frames that carry no time of their own.
    pub fn new(
        rec: &'a MetricReconstruction,
        placed: &'a TriMesh,
        texture: Option<&'a RgbImage>,
        occluder: Option<Occluder<'a>>,
        anchor: Point3<f64>,
        fps: f64,
    ) -> Self {
        Self {
            rec,
            by_name: rec.views.values().map(|v| (v.name.as_str(), v)).collect(),
            placed,
            texture,
            occluder,
            anchor,
            rms: frame_rms(rec),
            fps,
            compositor: Compositor::new(),
            zbuf: Vec::new(),
            depth: FloatMap::filled(0, 0, 1, 0.0),
            per_frame: Vec::new(),
            track: Vec::new(),
            tracked: Vec::new(),
        }
    }

    /// Composites the object into the frame `name` (left as it is when the model has no camera
    /// for it); `frame` is its video index and time, when it has them.
    pub fn frame(&mut self, name: &str, frame: Option<(u64, f64)>, image: &mut RgbImage) {
        let view = self.by_name.get(name).copied();
        let cam = view.and_then(|v| self.rec.cameras.get(&v.camera_id));
        let mut anchor_px = None;
        if let (Some(v), Some(cam)) = (view, cam) {
            let posed = PosedCamera::new(cam.clone(), v.cam_from_world);
            let occ = match self.occluder {
                Some(Occluder::Mesh(m)) => {
                    scene_depth(m, &posed, self.placed, &mut self.zbuf, &mut self.depth);
                    Some(&self.depth)
                }
                Some(Occluder::DepthMaps(maps)) => {
                    let near = nearest_sources(maps, name, &posed);
                    warped_depth(&near, &posed, self.placed, &mut self.depth);
                    Some(&self.depth)
                }
                None => None,
            };
            self.compositor
                .composite(image, self.placed, self.texture, &posed, occ);
            // Only where the frame shows it: a point passing beside the camera projects
            // thousands of pixels out, which is no jitter of the object.
            anchor_px = cam
                .project(&v.cam_from_world, &self.anchor)
                .filter(|p| cam.contains(p));
            let rank = self.tracked.len();
            self.tracked.push(TrackedFrame {
                frame: frame.map_or(rank as u64, |f| f.0),
                time_s: frame.map_or(rank as f64 / self.fps, |f| f.1),
                cam_from_world: v.cam_from_world,
            });
        }
        self.track.push(anchor_px);
        self.per_frame.push(FrameFigures {
            image: name.to_string(),
            posed: view.is_some(),
            rms_px: self.rms.get(name).copied(),
            anchor_px: anchor_px.map(|p| [p.x, p.y]),
        });
    }

    /// The frames with a camera.
    pub fn posed(&self) -> usize {
        self.per_frame.iter().filter(|f| f.posed).count()
    }

    /// The anchored object's image jitter ([`jitter`] of its track).
    pub fn jitter(&self) -> f64 {
        jitter(&self.track)
    }

    /// Median over frames of the per-frame RMS reprojection error (NaN with none).
    pub fn median_rms(&self) -> f64 {
        let mut rms_all: Vec<f64> = self.per_frame.iter().filter_map(|f| f.rms_px).collect();
        rms_all.sort_by(f64::total_cmp);
        rms_all.get(rms_all.len() / 2).copied().unwrap_or(f64::NAN)
    }
}
