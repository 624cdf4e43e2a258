//! The compositor: the object rendered with sub-samples (anti-aliased edges), Lambert-shaded with
//! the frame's average colour, hidden where the real scene is nearer, blended over the frame.

use handheld_core::{FloatMap, PosedCamera, TriMesh};
use image::RgbImage;
use nalgebra::{Point3, Vector2, Vector3};
use serde::{Deserialize, Serialize};

use crate::raster::{fragment_colour, rasterise};

/// Samples per pixel and axis of the object's anti-aliasing.
pub const SUB: usize = 3;

/// Renders an object into frames; keeps its buffers from frame to frame.
#[derive(Default)]
pub struct Compositor {
    zbuf: Vec<f32>,
    colour: Vec<[f32; 3]>,
    hit: Vec<bool>,
}

/// What one frame's compositing did.
#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize)]
pub struct CompositeStats {
    /// Pixels the object touches (any coverage), and the samples hidden by the scene.
    pub pixels: usize,
    pub hidden_samples: usize,
}

impl Compositor {
    pub fn new() -> Self {
        Self::default()
    }

    /// Composites `object` (already in the model frame, see [`Placement::transform`]) over
    /// `frame`, seen by `view`. `scene_depth`: the real scene's camera-frame depth
    /// per pixel (NaN where unknown) for occlusion. `undistorted`: draw as if the lens had no
    /// distortion (to show what ignoring it does).
    pub fn composite(
        &mut self,
        frame: &mut RgbImage,
        object: &TriMesh,
        texture: Option<&RgbImage>,
        view: &PosedCamera,
        scene_depth: Option<&FloatMap>,
    ) -> CompositeStats {
        let pose = &view.cam_from_world;
        let (w, h) = (frame.width() as usize, frame.height() as usize);
        // The light: the frame's average colour, from above and in front of the camera.
        let mean = average_colour(frame);
        let grey = (mean[0] + mean[1] + mean[2]) / 3.0;
        let light_colour =
            mean.map(|c| (c / grey.max(1.0)).clamp(0.5, 1.6) * (0.55 + grey / 255.0));
        let light_dir = pose.rotation.inverse() * Vector3::new(-0.3, -0.8, -0.5).normalize();
        // The window: the object's projected bounds on the sample grid.
        let Some((x0, y0, x1, y1)) = projected_window(object, view, w, h) else {
            return CompositeStats::default();
        };
        let (sx0, sy0, sx1, sy1) = (x0 * SUB, y0 * SUB, x1 * SUB, y1 * SUB);
        let ww = sx1 - sx0;
        let n = ww * (sy1 - sy0);
        self.colour.clear();
        self.colour.resize(n, [0.0; 3]);
        self.hit.clear();
        self.hit.resize(n, false);
        let mut hidden = 0usize;
        let normals: Vec<Vector3<f64>> = object
            .faces
            .iter()
            .map(|f| {
                let p = f.map(|i| {
                    let q = object.vertices.positions[i as usize];
                    Vector3::new(f64::from(q[0]), f64::from(q[1]), f64::from(q[2]))
                });
                (p[1] - p[0])
                    .cross(&(p[2] - p[0]))
                    .try_normalize(1e-20)
                    .unwrap_or(Vector3::z())
            })
            .collect();
        let centre = pose.inverse().translation.vector;
        let (colour, hit) = (&mut self.colour, &mut self.hit);
        rasterise(
            object,
            view,
            SUB,
            (sx0, sy0, sx1, sy1),
            &mut self.zbuf,
            |f| {
                let k = (f.sy - sy0) * ww + (f.sx - sx0);
                let (px, py) = (f.sx / SUB, f.sy / SUB);
                if let Some(d) = scene_depth {
                    let z = d.data[py * d.width + px];
                    if z.is_finite() && z > 0.0 && f64::from(z) < f.z * 0.99 {
                        hit[k] = false;
                        hidden += 1;
                        return;
                    }
                }
                let albedo = fragment_colour(object, texture, f);
                // Two-sided Lambert, the normal turned towards the camera.
                let mut nrm = normals[f.face];
                let idx = object.faces[f.face][0] as usize;
                let q = object.vertices.positions[idx];
                let to_cam =
                    centre - Vector3::new(f64::from(q[0]), f64::from(q[1]), f64::from(q[2]));
                if nrm.dot(&to_cam) < 0.0 {
                    nrm = -nrm;
                }
                let lambert = 0.45 + 0.55 * nrm.dot(&-light_dir).max(0.0);
                colour[k] = [0, 1, 2].map(|c| (albedo[c] * light_colour[c] * lambert) as f32);
                hit[k] = true;
            },
        );
        // Resolve: coverage-weighted average of the visible samples over the frame.
        let mut pixels = 0;
        let s2 = (SUB * SUB) as f32;
        for py in y0..y1 {
            for px in x0..x1 {
                let mut acc = [0.0f32; 3];
                let mut cnt = 0.0f32;
                for j in 0..SUB {
                    for i in 0..SUB {
                        let k = (py * SUB + j - sy0) * ww + (px * SUB + i - sx0);
                        if self.hit[k] {
                            for (a, &v) in acc.iter_mut().zip(&self.colour[k]) {
                                *a += v;
                            }
                            cnt += 1.0;
                        }
                    }
                }
                if cnt == 0.0 {
                    continue;
                }
                pixels += 1;
                let alpha = cnt / s2;
                let p = frame.get_pixel_mut(px as u32, py as u32);
                for (pc, &a) in p.0.iter_mut().zip(&acc) {
                    let v = f32::from(*pc) * (1.0 - alpha) + a / s2;
                    *pc = v.round().clamp(0.0, 255.0) as u8;
                }
            }
        }
        CompositeStats {
            pixels,
            hidden_samples: hidden,
        }
    }
}

fn average_colour(frame: &RgbImage) -> [f64; 3] {
    let mut acc = [0u64; 3];
    // Every 4th pixel of every 4th row is plenty for a mean.
    let (w, h) = (frame.width(), frame.height());
    let mut n = 0u64;
    for y in (0..h).step_by(4) {
        for x in (0..w).step_by(4) {
            let p = frame.get_pixel(x, y).0;
            for c in 0..3 {
                acc[c] += u64::from(p[c]);
            }
            n += 1;
        }
    }
    acc.map(|v| v as f64 / n.max(1) as f64)
}

/// The pixel window (x0, y0, x1, y1; exclusive ends) the object can cover, one pixel of margin;
/// `None` when it is entirely behind the camera or outside the image.
fn projected_window(
    object: &TriMesh,
    view: &PosedCamera,
    w: usize,
    h: usize,
) -> Option<(usize, usize, usize, usize)> {
    let (camera, pose) = (&view.camera, &view.cam_from_world);
    let mut lo = Vector2::repeat(f64::INFINITY);
    let mut hi = Vector2::repeat(f64::NEG_INFINITY);
    let mut any = false;
    for p in &object.vertices.positions {
        let q = pose.transform_point(&Point3::new(
            f64::from(p[0]),
            f64::from(p[1]),
            f64::from(p[2]),
        ));
        if q.z <= 1e-9 {
            // A vertex behind the camera: the object may span the whole image.
            lo = Vector2::zeros();
            hi = Vector2::new(w as f64, h as f64);
            any = true;
            continue;
        }
        let m = camera
            .intrinsics
            .normalized_to_pixel(Vector2::new(q.x / q.z, q.y / q.z));
        lo = lo.inf(&m);
        hi = hi.sup(&m);
        any = true;
    }
    if !any {
        return None;
    }
    let x0 = (lo.x.floor() - 1.0).max(0.0) as usize;
    let y0 = (lo.y.floor() - 1.0).max(0.0) as usize;
    let x1 = ((hi.x.ceil() + 2.0).max(0.0) as usize).min(w);
    let y1 = ((hi.y.ceil() + 2.0).max(0.0) as usize).min(h);
    (x0 < x1 && y0 < y1).then_some((x0, y0, x1, y1))
}
