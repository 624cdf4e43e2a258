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

/// The real scene's depth in the frame seen from `view`, inside the object's window (NaN
/// elsewhere).
pub fn scene_depth(
    mesh: &TriMesh,
    view: &PosedCamera,
    placed: &TriMesh,
    buf: &mut Vec<f32>,
    out: &mut FloatMap,
) {
    let (camera, pose) = (&view.camera, &view.cam_from_world);
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
    rasterise(mesh, view, 1, (x0, y0, x1, y1), buf, |f| {
        data[f.sy * w + f.sx] = f.z as f32;
    });
}

/// The placed object composited into the frames of a model, one frame at a time, with every
/// frame's figures and the camera track kept.
pub struct FrameLoop<'a> {
    rec: &'a MetricReconstruction,
    by_name: BTreeMap<&'a str, &'a View>,
    placed: &'a TriMesh,
    texture: Option<&'a RgbImage>,
    /// The reconstructed mesh, which hides the object where it is nearer.
    occluder: Option<&'a TriMesh>,
    anchor: Point3<f64>,
    rms: BTreeMap<String, f64>,
    fps: f64,
    compositor: Compositor,
    zbuf: Vec<f32>,
    depth: FloatMap,
    /// Every frame's figures, in the order given.
    pub per_frame: Vec<FrameFigures>,
    /// The anchor's image position in every frame (`None` where unposed or behind).
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
        occluder: Option<&'a TriMesh>,
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
                Some(m) => {
                    scene_depth(m, &posed, self.placed, &mut self.zbuf, &mut self.depth);
                    Some(&self.depth)
                }
                None => None,
            };
            self.compositor
                .composite(image, self.placed, self.texture, &posed, occ);
            anchor_px = cam.project(&v.cam_from_world, &self.anchor);
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
