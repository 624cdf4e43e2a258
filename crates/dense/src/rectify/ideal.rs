//! "Ideal" image coordinates: the pixel a distortion-free pinhole with the same `K` would see.
//! Rectification is defined on ideal coordinates, so the single resampling step goes
//! rectified → ideal → original (distorted) pixel, and radial distortion is removed on the way.

use handheld_core::PosedCamera;
use nalgebra::{Matrix3, Point3, Vector2, Vector3};

/// One calibrated view seen through its ideal (undistorted) pixel coordinates: the camera in its
/// pose plus what rectification reads over and over (`K`, its inverse, the image border).
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct IdealView {
    pub posed: PosedCamera,
    pub k: Matrix3<f64>,
    pub k_inv: Matrix3<f64>,
    /// The image border mapped to ideal coordinates, a closed polygon (last vertex ≠ first).
    pub border: Vec<Vector2<f64>>,
}

impl IdealView {
    /// `None` when `K` is singular.
    pub fn new(posed: &PosedCamera) -> Option<Self> {
        let camera = &posed.camera;
        let k = camera.intrinsics.k_matrix();
        let k_inv = k.try_inverse()?;
        let mut view = Self {
            posed: posed.clone(),
            k,
            k_inv,
            border: Vec::new(),
        };
        let (w, h) = (camera.width as f64 - 0.5, camera.height as f64 - 0.5);
        let steps = 24;
        let mut border = Vec::with_capacity(4 * steps);
        let corners = [(-0.5, -0.5), (w, -0.5), (w, h), (-0.5, h)];
        for s in 0..4 {
            let (a, b) = (corners[s], corners[(s + 1) % 4]);
            for i in 0..steps {
                let t = i as f64 / steps as f64;
                let p = Vector2::new(a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1));
                border.push(view.to_ideal(p));
            }
        }
        view.border = border;
        Some(view)
    }

    /// Original (distorted) pixel → ideal pixel.
    pub fn to_ideal(&self, px: Vector2<f64>) -> Vector2<f64> {
        let n = self.posed.camera.intrinsics.pixel_to_normalized(px);
        (self.k * Vector3::new(n.x, n.y, 1.0)).xy()
    }

    /// Ideal pixel → original (distorted) pixel.
    pub fn from_ideal(&self, p: Vector2<f64>) -> Vector2<f64> {
        let n = self.k_inv * Vector3::new(p.x, p.y, 1.0);
        self.posed
            .camera
            .intrinsics
            .normalized_to_pixel(Vector2::new(n.x / n.z, n.y / n.z))
    }

    /// Image width in pixels.
    pub fn width(&self) -> u32 {
        self.posed.camera.width
    }

    /// Image height in pixels.
    pub fn height(&self) -> u32 {
        self.posed.camera.height
    }

    /// True when an original pixel position lies inside the image.
    pub fn contains(&self, px: &Vector2<f64>) -> bool {
        self.posed.camera.contains(px)
    }

    /// The camera centre in the world.
    pub fn center(&self) -> Point3<f64> {
        self.posed.center()
    }

    /// `P = K [R | t]` in ideal pixels.
    pub fn projection(&self) -> nalgebra::Matrix3x4<f64> {
        self.k * handheld_core::pose::to_matrix3x4(&self.posed.cam_from_world)
    }

    /// The world direction of the ray through an ideal pixel.
    pub fn ray_world(&self, p: Vector2<f64>) -> Vector3<f64> {
        let d = self.k_inv * Vector3::new(p.x, p.y, 1.0);
        self.posed.cam_from_world.rotation.inverse() * d
    }

    /// Whether an ideal point lies inside the border polygon (crossing number).
    pub fn ideal_inside(&self, p: &Vector2<f64>) -> bool {
        let b = &self.border;
        let mut inside = false;
        for i in 0..b.len() {
            let (a, c) = (b[i], b[(i + 1) % b.len()]);
            if (a.y > p.y) != (c.y > p.y) {
                let x = a.x + (p.y - a.y) / (c.y - a.y) * (c.x - a.x);
                if x > p.x {
                    inside = !inside;
                }
            }
        }
        inside
    }

    /// The interval `[t0, t1]` (t ≥ 0) of the half-line `o + t·u` inside the border polygon, or
    /// `None` when the half-line misses the image.
    pub fn clip_half_line(&self, o: &Vector2<f64>, u: &Vector2<f64>) -> Option<(f64, f64)> {
        let b = &self.border;
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for i in 0..b.len() {
            let (a, c) = (b[i], b[(i + 1) % b.len()]);
            let e = c - a;
            let den = u.x * e.y - u.y * e.x;
            if den.abs() < 1e-15 {
                continue;
            }
            let w = a - o;
            let t = (w.x * e.y - w.y * e.x) / den;
            let s = (w.x * u.y - w.y * u.x) / den;
            if (0.0..=1.0).contains(&s) && t >= 0.0 {
                lo = lo.min(t);
                hi = hi.max(t);
            }
        }
        if self.ideal_inside(o) {
            lo = 0.0;
        }
        (hi > lo).then_some((lo, hi))
    }
}

/// Bilinear sample of channel `c` at an original pixel position; `None` outside the image.
pub fn bilinear(map: &handheld_core::FloatMap, x: f64, y: f64, c: usize) -> Option<f32> {
    if !(x >= -0.5 && y >= -0.5 && x <= map.width as f64 - 0.5 && y <= map.height as f64 - 0.5) {
        return None;
    }
    let xc = x.clamp(0.0, (map.width - 1) as f64);
    let yc = y.clamp(0.0, (map.height - 1) as f64);
    let (x0, y0) = (xc.floor() as usize, yc.floor() as usize);
    let (x1, y1) = ((x0 + 1).min(map.width - 1), (y0 + 1).min(map.height - 1));
    let (fx, fy) = ((xc - x0 as f64) as f32, (yc - y0 as f64) as f32);
    let v = |x: usize, y: usize| map.data[(y * map.width + x) * map.channels + c];
    let top = v(x0, y0) * (1.0 - fx) + v(x1, y0) * fx;
    let bot = v(x0, y1) * (1.0 - fx) + v(x1, y1) * fx;
    Some(top * (1.0 - fy) + bot * fy)
}
