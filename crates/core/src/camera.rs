//! The metric camera of eqs. 2–3: `K = [[f, s, u], [0, r·f, v], [0, 0, 1]]` and radial distortion
//! `x_d = (1 + k1·ρ² + k2·ρ⁴)·x` applied to normalised coordinates before `K` (eq. 3 adds only `k1`;
//! `k2` is the usual second term, as in COLMAP's RADIAL model).

use nalgebra::{Matrix3, Point3, Vector2, Vector3};
use serde::{Deserialize, Serialize};

use crate::ids::CameraId;
use crate::pose::Rigid3;

/// Intrinsic parameters of eq. 2 plus two radial distortion coefficients (eq. 3).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    /// Focal length in pixels (width of a pixel).
    pub f: f64,
    /// Pixel aspect ratio `r` (`fy = r·f`); 1 for square pixels.
    pub aspect: f64,
    /// Skew `s`; 0 for every modern sensor.
    pub skew: f64,
    /// Principal point `(u, v)` in pixels, pixel-centre convention of [`crate::PIXEL_CENTER_OFFSET_COLMAP`].
    pub pp: Vector2<f64>,
    /// First radial distortion coefficient `K1` of eq. 3.
    pub k1: f64,
    /// Second radial distortion coefficient (`ρ⁴` term).
    pub k2: f64,
}

impl Intrinsics {
    /// A pinhole camera with square pixels, no skew and no distortion.
    pub fn pinhole(f: f64, u: f64, v: f64) -> Self {
        Self {
            f,
            aspect: 1.0,
            skew: 0.0,
            pp: Vector2::new(u, v),
            k1: 0.0,
            k2: 0.0,
        }
    }

    /// The calibration matrix `K` of eq. 2.
    pub fn k_matrix(&self) -> Matrix3<f64> {
        Matrix3::new(
            self.f,
            self.skew,
            self.pp.x,
            0.0,
            self.aspect * self.f,
            self.pp.y,
            0.0,
            0.0,
            1.0,
        )
    }

    /// Builds intrinsics (without distortion) from an upper-triangular `K` with `K[2,2] ≠ 0`.
    pub fn from_k_matrix(k: &Matrix3<f64>) -> Self {
        let k = k / k[(2, 2)];
        Self {
            f: k[(0, 0)],
            aspect: k[(1, 1)] / k[(0, 0)],
            skew: k[(0, 1)],
            pp: Vector2::new(k[(0, 2)], k[(1, 2)]),
            k1: 0.0,
            k2: 0.0,
        }
    }

    /// True when there is no radial distortion.
    #[inline]
    pub fn is_undistorted(&self) -> bool {
        self.k1 == 0.0 && self.k2 == 0.0
    }

    /// Radial distortion of eq. 3 on normalised coordinates.
    #[inline]
    pub fn distort(&self, xn: Vector2<f64>) -> Vector2<f64> {
        let r2 = xn.norm_squared();
        xn * (1.0 + self.k1 * r2 + self.k2 * r2 * r2)
    }

    /// Inverse of [`Self::distort`] by Newton iteration on the radius (converges in a few steps for the
    /// distortion of real lenses). Returns the input unchanged when there is no distortion.
    pub fn undistort(&self, xd: Vector2<f64>) -> Vector2<f64> {
        if self.is_undistorted() {
            return xd;
        }
        let rd = xd.norm();
        if rd == 0.0 {
            return xd;
        }
        // Solve g(r) = r (1 + k1 r² + k2 r⁴) − rd = 0.
        let mut r = rd;
        for _ in 0..20 {
            let r2 = r * r;
            let g = r * (1.0 + self.k1 * r2 + self.k2 * r2 * r2) - rd;
            let dg = 1.0 + 3.0 * self.k1 * r2 + 5.0 * self.k2 * r2 * r2;
            if dg.abs() < 1e-12 {
                break;
            }
            let step = g / dg;
            r -= step;
            if step.abs() < 1e-15 * (1.0 + r.abs()) {
                break;
            }
        }
        xd * (r / rd)
    }

    /// Normalised (undistorted) image coordinates → pixel: distortion, then `K`.
    #[inline]
    pub fn normalized_to_pixel(&self, xn: Vector2<f64>) -> Vector2<f64> {
        let d = self.distort(xn);
        Vector2::new(
            self.f * d.x + self.skew * d.y + self.pp.x,
            self.aspect * self.f * d.y + self.pp.y,
        )
    }

    /// Pixel → normalised (undistorted) image coordinates: `K⁻¹`, then undistortion.
    pub fn pixel_to_normalized(&self, px: Vector2<f64>) -> Vector2<f64> {
        let fy = self.aspect * self.f;
        let y = (px.y - self.pp.y) / fy;
        let x = (px.x - self.pp.x - self.skew * y) / self.f;
        self.undistort(Vector2::new(x, y))
    }

    /// Checks that the parameters describe a usable camera.
    pub fn validate(&self) -> Result<(), String> {
        let finite = [
            self.f,
            self.aspect,
            self.skew,
            self.pp.x,
            self.pp.y,
            self.k1,
            self.k2,
        ];
        if finite.iter().any(|v| !v.is_finite()) {
            return Err("intrinsics contain a non-finite value".into());
        }
        if self.f <= 0.0 {
            return Err(format!("focal length must be positive, got {}", self.f));
        }
        if self.aspect <= 0.0 {
            return Err(format!(
                "aspect ratio must be positive, got {}",
                self.aspect
            ));
        }
        Ok(())
    }
}

/// An intrinsics group: the image size and the intrinsics shared by every view that uses it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Camera {
    pub id: CameraId,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    pub intrinsics: Intrinsics,
}

impl Camera {
    /// Projects a world point seen from `cam_from_world`; `None` when it lies behind the camera.
    pub fn project(
        &self,
        cam_from_world: &Rigid3,
        p_in_world: &Point3<f64>,
    ) -> Option<Vector2<f64>> {
        let p_in_cam = cam_from_world.transform_point(p_in_world);
        if p_in_cam.z <= 0.0 {
            return None;
        }
        Some(self.intrinsics.normalized_to_pixel(Vector2::new(
            p_in_cam.x / p_in_cam.z,
            p_in_cam.y / p_in_cam.z,
        )))
    }

    /// The viewing ray (unit, camera frame) through a pixel.
    pub fn ray_in_cam(&self, px: Vector2<f64>) -> Vector3<f64> {
        let n = self.intrinsics.pixel_to_normalized(px);
        Vector3::new(n.x, n.y, 1.0).normalize()
    }

    /// True when a pixel position lies inside the image (pixel-centre convention).
    pub fn contains(&self, px: &Vector2<f64>) -> bool {
        px.x >= -0.5
            && px.y >= -0.5
            && px.x < self.width as f64 - 0.5
            && px.y < self.height as f64 - 0.5
    }

    /// The camera of the image resized by `(sx, sy)`: pixel centres stay at integer positions,
    /// so a pixel `x` becomes `(x + ½)·sx − ½`; the size is rounded to whole pixels.
    pub fn scaled(&self, sx: f64, sy: f64) -> Camera {
        let mut c = self.clone();
        let i = &mut c.intrinsics;
        i.f *= sx;
        i.aspect *= sy / sx;
        i.skew *= sx;
        i.pp = Vector2::new((i.pp.x + 0.5) * sx - 0.5, (i.pp.y + 0.5) * sy - 0.5);
        c.width = (self.width as f64 * sx).round() as u32;
        c.height = (self.height as f64 * sy).round() as u32;
        c
    }

    /// The camera of the image shrunk so its longer side is at most `max_size` pixels (an
    /// unchanged copy when it already fits or `max_size` is 0): the scale `max_size / longer`
    /// gives the rounded new size, and each axis is scaled by `new / old` so the size is whole.
    pub fn scaled_to(&self, max_size: u32) -> Camera {
        let longer = self.width.max(self.height);
        if max_size == 0 || longer <= max_size {
            return self.clone();
        }
        let s = f64::from(max_size) / f64::from(longer);
        let w = (f64::from(self.width) * s).round() as u32;
        let h = (f64::from(self.height) * s).round() as u32;
        self.scaled(
            f64::from(w) / f64::from(self.width),
            f64::from(h) / f64::from(self.height),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam() -> Intrinsics {
        Intrinsics {
            f: 520.0,
            aspect: 1.09,
            skew: 0.3,
            pp: Vector2::new(321.0, 238.5),
            k1: -0.21,
            k2: 0.05,
        }
    }

    #[test]
    fn k_matrix_matches_eq2() {
        let k = cam().k_matrix();
        assert_eq!(k[(0, 0)], 520.0);
        assert!((k[(1, 1)] - 1.09 * 520.0).abs() < 1e-12);
        assert_eq!(k[(0, 1)], 0.3);
        let back = Intrinsics::from_k_matrix(&(k * 2.0));
        assert!((back.aspect - 1.09).abs() < 1e-12 && (back.f - 520.0).abs() < 1e-9);
    }

    #[test]
    fn undistort_inverts_distort() {
        let c = cam();
        for &(x, y) in &[(0.0, 0.0), (0.3, -0.2), (-0.55, 0.41), (0.01, 0.6)] {
            let xn = Vector2::new(x, y);
            let back = c.undistort(c.distort(xn));
            assert!((back - xn).norm() < 1e-12, "{xn:?} -> {back:?}");
        }
    }

    #[test]
    fn pixel_round_trip() {
        let c = cam();
        let px = Vector2::new(17.0, 460.0);
        let back = c.normalized_to_pixel(c.pixel_to_normalized(px));
        assert!((back - px).norm() < 1e-9);
    }

    #[test]
    fn validate_rejects_bad_focal() {
        let mut c = cam();
        c.f = -1.0;
        assert!(c.validate().is_err());
        c.f = f64::NAN;
        assert!(c.validate().is_err());
    }
}
