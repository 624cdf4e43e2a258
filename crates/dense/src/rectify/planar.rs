//! Planar (homography) rectification (paper §4.1, the standard method it contrasts with polar
//! rectification; built here from the metric cameras as in Fusiello, Trucco & Verri 2000).
//!
//! Both views are rotated about their centres to a common orientation whose x axis is the
//! baseline, and re-imaged with a common focal length, so corresponding points share a row. It is
//! the fast path when both epipoles lie far outside the images; when an epipole is inside (forward
//! motion) the homography sends part of the image to infinity and polar rectification is needed.

use nalgebra::{Matrix3, Rotation3, Vector2, Vector3};

use super::ideal::IdealView;
use crate::error::{DenseError, Result};

/// A planar rectification: one homography per view, from ideal pixels to rectified pixels.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct PlanarRect {
    pub(crate) h: [Matrix3<f64>; 2],
    pub(crate) h_inv: [Matrix3<f64>; 2],
    pub width: usize,
    pub height: usize,
}

impl PlanarRect {
    /// `max_pixels_ratio` bounds the rectified size against the larger input (a strongly slanted
    /// rectification blows pixels up; polar rectification is then the better choice).
    pub fn new(v1: &IdealView, v2: &IdealView, max_pixels_ratio: f64) -> Result<Self> {
        let degenerate = |reason: String| Err(DenseError::Rectification { reason });
        let (c1, c2) = (v1.center(), v2.center());
        let base = c2 - c1;
        if base.norm() == 0.0 {
            return degenerate("the two camera centres coincide".into());
        }
        let x = base.normalize();
        // Mean viewing direction of the two cameras, in the world.
        let z_of = |v: &IdealView| v.posed.cam_from_world.rotation.inverse() * Vector3::z();
        let zm = (z_of(v1) + z_of(v2)).normalize();
        let y = zm.cross(&x);
        if y.norm() < 1e-6 {
            return degenerate(
                "the cameras look along the baseline (use polar rectification)".into(),
            );
        }
        let y = y.normalize();
        let z = x.cross(&y);
        let rect_from_world = Rotation3::from_matrix_unchecked(Matrix3::from_rows(&[
            x.transpose(),
            y.transpose(),
            z.transpose(),
        ]));
        let f = 0.5 * (v1.k[(0, 0)] + v1.k[(1, 1)]).max(0.5 * (v2.k[(0, 0)] + v2.k[(1, 1)]));
        let k_new = Matrix3::new(f, 0.0, 0.0, 0.0, f, 0.0, 0.0, 0.0, 1.0);
        let mut h = [Matrix3::zeros(); 2];
        let mut boxes = [(
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ); 2];
        for (i, v) in [v1, v2].into_iter().enumerate() {
            let r_cam = v.posed.cam_from_world.rotation.to_rotation_matrix();
            let hi = k_new * (rect_from_world * r_cam.inverse()).matrix() * v.k_inv;
            for p in &v.border {
                let q = hi * Vector3::new(p.x, p.y, 1.0);
                if q.z <= 1e-9 * q.xy().norm() {
                    return degenerate(
                        "an epipole lies inside an image (use polar rectification)".into(),
                    );
                }
                let (qx, qy) = (q.x / q.z, q.y / q.z);
                let b = &mut boxes[i];
                *b = (b.0.min(qx), b.1.min(qy), b.2.max(qx), b.3.max(qy));
            }
            h[i] = hi;
        }
        // Common rows: the union of both images' row ranges; each image its own column origin.
        let y0 = boxes[0].1.min(boxes[1].1).floor();
        let y1 = boxes[0].3.max(boxes[1].3).ceil();
        let widths = boxes.map(|b| (b.2.ceil() - b.0.floor()) as usize + 1);
        let width = widths[0].max(widths[1]);
        let height = (y1 - y0) as usize + 1;
        let input = [v1, v2]
            .iter()
            .map(|v| v.width() as f64 * v.height() as f64)
            .fold(0.0, f64::max);
        if width as f64 * height as f64 > max_pixels_ratio * input {
            return degenerate(format!(
                "the rectified images would be {width}x{height}, over {max_pixels_ratio}× the input"
            ));
        }
        let mut h_inv = [Matrix3::zeros(); 2];
        for i in 0..2 {
            let shift = Matrix3::new(1.0, 0.0, -boxes[i].0.floor(), 0.0, 1.0, -y0, 0.0, 0.0, 1.0);
            h[i] = shift * h[i];
            h_inv[i] = match h[i].try_inverse() {
                Some(m) => m,
                None => return degenerate("singular rectifying homography".into()),
            };
        }
        Ok(Self {
            h,
            h_inv,
            width,
            height,
        })
    }

    /// Ideal pixel of image `side` → rectified `(column, row)`.
    pub fn to_rect(&self, side: usize, p: Vector2<f64>) -> Option<Vector2<f64>> {
        apply(&self.h[side], p)
    }

    /// Rectified `(column, row)` → ideal pixel of image `side`.
    pub fn from_rect(&self, side: usize, r: Vector2<f64>) -> Option<Vector2<f64>> {
        apply(&self.h_inv[side], r)
    }
}

fn apply(h: &Matrix3<f64>, p: Vector2<f64>) -> Option<Vector2<f64>> {
    let q = h * Vector3::new(p.x, p.y, 1.0);
    (q.z > 0.0).then(|| q.xy() / q.z)
}
