//! The surface stages read [`PosedView`]s: fusion, single-view meshes and evaluation their depth
//! map (and optional confidence), texturing their image (and depth, for occlusion tests). This
//! module checks those inputs and holds the projection helpers on top of them.
//!
//! Depth maps hold the camera-frame `z` of the surface seen through each pixel centre of the
//! *original* (distorted) image; non-finite or non-positive values are missing. Pixels are lifted
//! with the camera's undistortion ([`handheld_core::Intrinsics::pixel_to_normalized`]) and points are
//! projected with its distortion, so no rectified or undistorted copy is ever made.

use handheld_core::{FloatMap, PosedCamera, PosedView, ViewError};
use image::RgbImage;
use nalgebra::{Matrix3, Point3, Vector2, Vector3};

use crate::error::{MeshError, Result};

/// Checks view number `view`'s camera and pose for finiteness and a usable focal length
/// ([`PosedCamera::validate`]).
pub(crate) fn check_camera(view: usize, posed: &PosedCamera) -> Result<()> {
    posed
        .validate()
        .map_err(|reason| MeshError::BadCamera { view, reason })
}

/// The error of a [`PosedView`] check as the error of view number `view`.
fn view_error(view: usize, e: ViewError) -> MeshError {
    match e {
        ViewError::SizeMismatch {
            what,
            got_w,
            got_h,
            cam_w,
            cam_h,
            ..
        } => MeshError::SizeMismatch {
            view,
            what,
            got_w,
            got_h,
            cam_w,
            cam_h,
        },
        ViewError::MalformedMap { what, reason, .. } => {
            MeshError::MalformedMap { view, what, reason }
        }
    }
}

/// A view's depth map and optional confidence map (the fusion weight; `None` weighs every pixel
/// 1), checked against its camera: what fusion, single-view meshes and evaluation read.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Depth<'a> {
    pub posed: &'a PosedCamera,
    pub depth: &'a FloatMap,
    pub confidence: Option<&'a FloatMap>,
    /// The depth's variance, where the dense stage wrote it.
    pub variance: Option<&'a FloatMap>,
}

impl<'a> Depth<'a> {
    /// Checks camera, pose, and the depth and confidence maps' sizes of view number `index`
    /// ([`PosedView::check_map`]; the image is not read, so it may be empty).
    pub fn of(view: &'a PosedView, index: usize) -> Result<Self> {
        check_camera(index, &view.posed)?;
        let depth = view.depth.as_ref().ok_or(MeshError::MissingMap {
            view: index,
            what: "depth map",
        })?;
        let check = |what, map| view.check_map(what, map).map_err(|e| view_error(index, e));
        check("depth map", depth)?;
        if let Some(c) = &view.confidence {
            check("confidence map", c)?;
        }
        if let Some(v) = &view.variance {
            check("variance map", v)?;
        }
        Ok(Self {
            posed: &view.posed,
            depth,
            confidence: view.confidence.as_ref(),
            variance: view.variance.as_ref(),
        })
    }

    /// Standard deviation of pixel `i`'s depth: 0 without a variance map or where it holds no
    /// finite value (nothing is known against the sample).
    pub fn std(&self, i: usize) -> f64 {
        match self.variance {
            Some(v) => {
                let x = v.data[i] as f64;
                if x.is_finite() && x > 0.0 {
                    x.sqrt()
                } else {
                    0.0
                }
            }
            None => 0.0,
        }
    }

    /// Weight of pixel `i` (row-major): `0` when the depth is missing or the confidence is not
    /// above `min_confidence`, else the confidence (1 without a confidence map).
    pub fn weight(&self, i: usize, min_confidence: f64) -> f64 {
        let d = self.depth.data[i];
        if !(d.is_finite() && d > 0.0) {
            return 0.0;
        }
        match self.confidence {
            Some(c) => {
                let w = c.data[i] as f64;
                if w.is_finite() && w > min_confidence {
                    w
                } else {
                    0.0
                }
            }
            None => 1.0,
        }
    }
}

/// Checks camera, pose, and the image's and optional depth map's sizes of view number `index`
/// (what texturing reads; [`PosedView::check_image`], [`PosedView::check_map`]).
pub(crate) fn check_image_view(index: usize, v: &PosedView) -> Result<()> {
    check_camera(index, &v.posed)?;
    v.check_image().map_err(|e| view_error(index, e))?;
    if let Some(d) = &v.depth {
        v.check_map("depth map", d)
            .map_err(|e| view_error(index, e))?;
    }
    Ok(())
}

/// Precomputed projection of one view: rotation, translation, centre, and the largest normalised
/// radius inside the image (beyond it the polynomial distortion may fold back, so points there are
/// treated as outside).
#[derive(Clone, Debug)]
pub(crate) struct Projector {
    pub posed: PosedCamera,
    pub rot: Matrix3<f64>,
    pub trans: Vector3<f64>,
    pub center: Point3<f64>,
    max_radius2: f64,
    /// Bounds `[x_min, x_max, y_min, y_max]` of the image border in normalised (undistorted)
    /// coordinates, with a small margin.
    pub bounds: [f64; 4],
}

impl Projector {
    pub fn new(posed: &PosedCamera) -> Self {
        let (camera, cam_from_world) = (&posed.camera, &posed.cam_from_world);
        let k = &camera.intrinsics;
        let (w, h) = (camera.width as f64, camera.height as f64);
        let corners = [
            (-0.5, -0.5),
            (w - 0.5, -0.5),
            (-0.5, h - 0.5),
            (w - 0.5, h - 0.5),
        ];
        let r = corners
            .iter()
            .map(|&(x, y)| k.pixel_to_normalized(Vector2::new(x, y)).norm())
            .fold(0.0, f64::max);
        let mut bounds = [
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ];
        let steps = 64;
        for i in 0..=steps {
            let t = i as f64 / steps as f64;
            let (x, y) = (-0.5 + t * w, -0.5 + t * h);
            for (px, py) in [(x, -0.5), (x, h - 0.5), (-0.5, y), (w - 0.5, y)] {
                let n = k.pixel_to_normalized(Vector2::new(px, py));
                bounds = [
                    bounds[0].min(n.x),
                    bounds[1].max(n.x),
                    bounds[2].min(n.y),
                    bounds[3].max(n.y),
                ];
            }
        }
        let (mx, my) = (
            0.02 * (bounds[1] - bounds[0]),
            0.02 * (bounds[3] - bounds[2]),
        );
        Self {
            posed: posed.clone(),
            rot: *cam_from_world.rotation.to_rotation_matrix().matrix(),
            trans: cam_from_world.translation.vector,
            center: posed.center(),
            max_radius2: (1.05 * r).powi(2),
            bounds: [
                bounds[0] - mx,
                bounds[1] + mx,
                bounds[2] - my,
                bounds[3] + my,
            ],
        }
    }

    /// True when the convex hull of the camera-frame points `pc` certainly misses the view frustum:
    /// all behind the camera, or all (in front) beyond one side of the image.
    pub fn outside_frustum(&self, pc: &[Vector3<f64>]) -> bool {
        if pc.iter().all(|p| p.z <= 0.0) {
            return true;
        }
        if pc.iter().any(|p| p.z <= 0.0) {
            return false;
        }
        let b = &self.bounds;
        pc.iter().all(|p| p.x < b[0] * p.z)
            || pc.iter().all(|p| p.x > b[1] * p.z)
            || pc.iter().all(|p| p.y < b[2] * p.z)
            || pc.iter().all(|p| p.y > b[3] * p.z)
    }

    /// World point → camera frame.
    pub fn to_cam(&self, p: &Point3<f64>) -> Vector3<f64> {
        self.rot * p.coords + self.trans
    }

    /// Camera-frame point → distorted pixel, `None` behind the camera or beyond the image's radius.
    pub fn cam_to_pixel(&self, pc: &Vector3<f64>) -> Option<Vector2<f64>> {
        if pc.z <= 0.0 {
            return None;
        }
        let n = Vector2::new(pc.x / pc.z, pc.y / pc.z);
        if n.norm_squared() > self.max_radius2 {
            return None;
        }
        Some(self.posed.camera.intrinsics.normalized_to_pixel(n))
    }

    /// Pixel `(x, y)` with depth `z` → world point.
    pub fn lift(&self, x: f64, y: f64, z: f64) -> Point3<f64> {
        let n = self
            .posed
            .camera
            .intrinsics
            .pixel_to_normalized(Vector2::new(x, y));
        let pc = Vector3::new(n.x * z, n.y * z, z);
        Point3::from(self.rot.transpose() * (pc - self.trans))
    }
}

/// Per pixel, `|cos|` of the angle between the viewing ray and the surface normal estimated from
/// the depth map (cross product of the lifted right/down neighbours, falling back to left/up; a
/// neighbour farther than 10% in depth is a discontinuity, not surface). Pixels without a usable
/// neighbourhood get 1. Curless & Levoy 1996 weigh samples by this cosine; the fusion also uses it
/// to turn distances along the line of sight into distances to the surface.
pub(crate) fn incidence_map(view: &Depth) -> Vec<u16> {
    use rayon::prelude::*;
    let (w, h) = (view.depth.width, view.depth.height);
    let k = &view.posed.camera.intrinsics;
    let ray_row = |y: usize| -> Vec<Vector3<f64>> {
        (0..w)
            .map(|x| {
                let n = k.pixel_to_normalized(Vector2::new(x as f64, y as f64));
                Vector3::new(n.x, n.y, 1.0)
            })
            .collect()
    };
    let depth = |x: usize, y: usize| -> Option<f64> {
        let d = view.depth.data[y * w + x];
        (d.is_finite() && d > 0.0).then_some(d as f64)
    };
    // Rows in chunks, each computing its rays (one undistortion per pixel) plus a one-row border.
    const CHUNK: usize = 32;
    (0..h.div_ceil(CHUNK))
        .into_par_iter()
        .flat_map_iter(|c| {
            let (y0, y1) = (c * CHUNK, ((c + 1) * CHUNK).min(h));
            let first = y0.saturating_sub(1);
            let rays: Vec<Vec<Vector3<f64>>> = (first..(y1 + 1).min(h)).map(ray_row).collect();
            let ray = |x: usize, y: usize| rays[y - first][x];
            let mut out = vec![u16::MAX; (y1 - y0) * w];
            for y in y0..y1 {
                for x in 0..w {
                    let Some(d0) = depth(x, y) else { continue };
                    let centre = ray(x, y) * d0;
                    let near = |xx: usize, yy: usize| -> Option<Vector3<f64>> {
                        let d = depth(xx, yy)?;
                        ((d - d0).abs() <= 0.1 * d0).then(|| ray(xx, yy) * d)
                    };
                    let dx = (x + 1 < w)
                        .then(|| near(x + 1, y).map(|p| p - centre))
                        .flatten()
                        .or_else(|| {
                            (x > 0)
                                .then(|| near(x - 1, y).map(|p| centre - p))
                                .flatten()
                        });
                    let dy = (y + 1 < h)
                        .then(|| near(x, y + 1).map(|p| p - centre))
                        .flatten()
                        .or_else(|| {
                            (y > 0)
                                .then(|| near(x, y - 1).map(|p| centre - p))
                                .flatten()
                        });
                    if let (Some(a), Some(b)) = (dx, dy) {
                        let n = a.cross(&b);
                        let denom = n.norm() * centre.norm();
                        if denom > 0.0 {
                            let cos = (n.dot(&centre).abs() / denom).min(1.0);
                            out[(y - y0) * w + x] = (cos * f64::from(u16::MAX)).round() as u16;
                        }
                    }
                }
            }
            out
        })
        .collect()
}

/// Bilinear sample of a one-channel depth map at a (distorted) pixel position. The four
/// neighbours must all be valid and within `max_rel_spread` of each other (relative), else the
/// nearest valid neighbour is returned, so depths never blend across a discontinuity.
pub(crate) fn sample_depth(map: &FloatMap, px: &Vector2<f64>, max_rel_spread: f64) -> Option<f64> {
    let (w, h) = (map.width as i64, map.height as i64);
    let (fx, fy) = (px.x.floor(), px.y.floor());
    let (x0, y0) = (fx as i64, fy as i64);
    if x0 < -1 || y0 < -1 || x0 >= w || y0 >= h {
        return None;
    }
    let (ax, ay) = (px.x - fx, px.y - fy);
    let at = |x: i64, y: i64| -> Option<f64> {
        if x < 0 || y < 0 || x >= w || y >= h {
            return None;
        }
        let v = map.data[(y * w + x) as usize];
        (v.is_finite() && v > 0.0).then_some(v as f64)
    };
    let q = [
        at(x0, y0),
        at(x0 + 1, y0),
        at(x0, y0 + 1),
        at(x0 + 1, y0 + 1),
    ];
    if let [Some(a), Some(b), Some(c), Some(d)] = q {
        let (lo, hi) = (a.min(b).min(c).min(d), a.max(b).max(c).max(d));
        if hi - lo <= max_rel_spread * lo {
            let top = a + (b - a) * ax;
            let bottom = c + (d - c) * ax;
            return Some(top + (bottom - top) * ay);
        }
    }
    let nx = if ax < 0.5 { 0 } else { 1 };
    let ny = if ay < 0.5 { 0 } else { 1 };
    q[ny * 2 + nx]
}

/// Bilinear colour sample of an image at a (distorted) pixel position, clamped at the borders.
pub(crate) fn sample_rgb(img: &RgbImage, px: &Vector2<f64>) -> [f64; 3] {
    let (w, h) = (img.width() as i64, img.height() as i64);
    let x = px.x.clamp(0.0, (w - 1) as f64);
    let y = px.y.clamp(0.0, (h - 1) as f64);
    let (x0, y0) = (x.floor() as i64, y.floor() as i64);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let (ax, ay) = (x - x0 as f64, y - y0 as f64);
    let raw = img.as_raw();
    let get = |xx: i64, yy: i64, c: usize| raw[((yy * w + xx) * 3) as usize + c] as f64;
    let mut out = [0.0; 3];
    for (c, o) in out.iter_mut().enumerate() {
        let top = get(x0, y0, c) * (1.0 - ax) + get(x1, y0, c) * ax;
        let bottom = get(x0, y1, c) * (1.0 - ax) + get(x1, y1, c) * ax;
        *o = top * (1.0 - ay) + bottom * ay;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use handheld_core::{Camera, CameraId, Intrinsics, Rigid3};

    #[test]
    fn lift_then_project_round_trips_with_distortion() {
        let mut k = Intrinsics::pinhole(300.0, 159.5, 119.5);
        k.k1 = -0.1;
        k.k2 = 0.02;
        let cam = Camera {
            id: CameraId(0),
            width: 320,
            height: 240,
            intrinsics: k,
        };
        let pose = Rigid3::new(Vector3::new(0.1, -0.2, 0.3), Vector3::new(0.05, 0.1, -0.02));
        let p = Projector::new(&PosedCamera::new(cam, pose));
        let w = p.lift(12.0, 200.0, 3.5);
        let pc = p.to_cam(&w);
        assert!((pc.z - 3.5).abs() < 1e-9);
        let px = p.cam_to_pixel(&pc).unwrap();
        assert!((px - Vector2::new(12.0, 200.0)).norm() < 1e-7);
    }

    #[test]
    fn depth_sampling_does_not_blend_discontinuities() {
        let mut m = FloatMap::filled(4, 4, 1, 2.0);
        m.set(2, 1, 0, 5.0);
        let v = sample_depth(&m, &Vector2::new(0.5, 0.5), 0.05).unwrap();
        assert!((v - 2.0).abs() < 1e-12);
        let v = sample_depth(&m, &Vector2::new(1.6, 1.2), 0.05).unwrap();
        assert_eq!(v, 5.0);
        m.set(0, 0, 0, f32::NAN);
        assert!(sample_depth(&m, &Vector2::new(0.1, 0.1), 0.05).is_none());
    }
}
