//! Polar rectification (paper §4.1; Pollefeys, Koch & Van Gool, "A simple and efficient
//! rectification method for general motion", ICCV 1999).
//!
//! Each rectified row is one pair of corresponding *half* epipolar lines: the row's angle `θ`
//! around the epipole `e₁` in image 1 and the matching angle `φ` around `e₂` in image 2. The
//! column is the distance from the epipole. Oriented epipolar geometry picks the half-line of
//! image 2 that holds the points in front of both cameras, so only half of each line is searched.
//! Rows are added one at a time with the angle step that keeps the worst-case (farthest) pixel of
//! either image at one pixel of arc, so no pixel is compressed (the "minimal image size" rule).
//! It works for any motion, including forward motion with the epipole inside the image.

use nalgebra::{Vector2, Vector3};

use super::ideal::IdealView;
use crate::error::{DenseError, Result};

/// Largest number of rectified rows before the rectification is declared degenerate.
const MAX_ROWS: usize = 40_000;

/// A polar rectification of a pair: per-row angles around both epipoles.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct PolarRect {
    pub(crate) epipoles: [Vector2<f64>; 2],
    /// Per-row angles around each epipole (image 1 increasing; image 2 monotone either way).
    pub(crate) angles: [Vec<f64>; 2],
    /// True when the epipole lies inside that image (the rows wrap the full circle).
    pub full_circle: [bool; 2],
    /// Distance from the epipole of column 0, per image.
    pub(crate) rho_min: [f64; 2],
    pub width: usize,
    pub height: usize,
}

fn unit(a: f64) -> Vector2<f64> {
    Vector2::new(a.cos(), a.sin())
}

/// Wraps an angle into `(−π, π]`.
fn wrap_pi(a: f64) -> f64 {
    let w = (a + std::f64::consts::PI).rem_euclid(2.0 * std::f64::consts::PI);
    w - std::f64::consts::PI
}

/// The epipole of the other camera's centre in `view`'s ideal coordinates, homogeneous and with
/// the sign of the centre's depth kept (oriented projective geometry).
fn oriented_epipole(view: &IdealView, other: &IdealView) -> Vector3<f64> {
    view.projection() * other.center().to_homogeneous()
}

/// Direction (unit) from `e₂` of the half epipolar line in image 2 that holds the images of the
/// points in front of camera 1 along the ray through the ideal pixel `x1` of image 1.
/// With `e = P₂C₁` and `v = P₂(d, 0)`, the image of `C₁ + λd` is `e + λv`, so for visible points
/// (`e_w + λv_w > 0`) it moves away from `e₂` along `sign(e_w)·(v_xy·e_w − e_xy·v_w)`.
pub(crate) fn half_line_in_2(
    v1: &IdealView,
    v2: &IdealView,
    e2h: &Vector3<f64>,
    x1: Vector2<f64>,
) -> f64 {
    let d = v1.ray_world(x1);
    let v = v2.projection() * d.push(0.0);
    let dir = (v.xy() * e2h.z - e2h.xy() * v.z) * e2h.z.signum();
    dir.y.atan2(dir.x)
}

impl PolarRect {
    /// Builds the rectification; `None`-like failures are errors naming the degeneracy.
    pub fn new(v1: &IdealView, v2: &IdealView) -> Result<Self> {
        let degenerate = |reason: String| Err(DenseError::Rectification { reason });
        let e1h = oriented_epipole(v1, v2);
        let e2h = oriented_epipole(v2, v1);
        let scale = |v: &IdealView| (v.width() as f64).hypot(v.height() as f64);
        for (eh, v) in [(&e1h, v1), (&e2h, v2)] {
            if eh.z.abs() * 1e6 * scale(v) < eh.xy().norm() {
                return degenerate("an epipole lies at infinity (use planar rectification)".into());
            }
        }
        let e1 = e1h.xy() / e1h.z;
        let e2 = e2h.xy() / e2h.z;

        // Angular range of image 1 seen from e1.
        let full1 = v1.ideal_inside(&e1);
        let full2 = v2.ideal_inside(&e2);
        let (t_start, t_end) = if full1 {
            (-std::f64::consts::PI, std::f64::consts::PI)
        } else {
            angular_range(&v1.border, &e1)
        };

        // Farthest image point from each epipole: the step where a half-line misses its image.
        let reach = [(v1, e1), (v2, e2)]
            .map(|(v, e)| v.border.iter().map(|b| (b - e).norm()).fold(1.0, f64::max));
        let phi_of = |t: f64, rho: f64| half_line_in_2(v1, v2, &e2h, e1 + unit(t) * rho.max(1.0));
        // Per row: θ, φ, and the ρ intervals in both images when both half-lines meet them.
        type Row = (f64, f64, Option<[(f64, f64); 2]>);
        let mut rows: Vec<Row> = Vec::new();
        let mut t = t_start;
        let mut phi_prev: Option<f64> = None;
        while t < t_end {
            if rows.len() > MAX_ROWS {
                return degenerate(format!(
                    "more than {MAX_ROWS} rows; the cameras are too close to each other"
                ));
            }
            let u1 = unit(t);
            let r1 = v1.clip_half_line(&e1, &u1);
            let rho_probe = r1.map_or(1.0, |(a, b)| 0.5 * (a + b));
            let mut phi = phi_of(t, rho_probe);
            if let Some(p) = phi_prev {
                phi = p + wrap_pi(phi - p);
            }
            let r2 = v2.clip_half_line(&e2, &unit(phi));
            // Step: one pixel of arc at the farthest point of either image.
            let eps = 1e-6;
            let dphi = (wrap_pi(phi_of(t + eps, rho_probe) - phi) / eps).abs();
            let far1 = r1.map_or(reach[0], |r| r.1);
            let far2 = r2.map_or(reach[1], |r| r.1);
            let arc = far1.max(far2 * dphi).max(1.0);
            let both = match (r1, r2) {
                (Some(a), Some(b)) => Some([a, b]),
                _ => None,
            };
            rows.push((t, phi, both));
            phi_prev = Some(phi);
            t += 1.0 / arc;
        }
        // Keep the rows between the first and last with both half-lines inside their images.
        let first = rows.iter().position(|r| r.2.is_some());
        let last = rows.iter().rposition(|r| r.2.is_some());
        let (Some(first), Some(last)) = (first, last) else {
            return degenerate("no epipolar line crosses both images".into());
        };
        let rows = &rows[first..=last];
        if rows.len() < 2 {
            return degenerate("the images share less than two epipolar lines".into());
        }
        let mut rho_min = [f64::INFINITY; 2];
        let mut rho_max = [0.0f64; 2];
        for (_, _, r) in rows {
            if let Some(r) = r {
                for i in 0..2 {
                    rho_min[i] = rho_min[i].min(r[i].0);
                    rho_max[i] = rho_max[i].max(r[i].1);
                }
            }
        }
        for r in &mut rho_min {
            *r = r.floor();
        }
        let width = (0..2)
            .map(|i| (rho_max[i] - rho_min[i]).ceil() as usize + 1)
            .max()
            .unwrap_or(1);
        Ok(Self {
            epipoles: [e1, e2],
            angles: [
                rows.iter().map(|r| r.0).collect(),
                rows.iter().map(|r| r.1).collect(),
            ],
            full_circle: [full1, full2],
            rho_min,
            width,
            height: rows.len(),
        })
    }

    /// Ideal pixel of image `side` → rectified `(column, row)`; `None` off the rectified rows.
    pub fn to_rect(&self, side: usize, p: Vector2<f64>) -> Option<Vector2<f64>> {
        let e = self.epipoles[side];
        let d = p - e;
        let rho = d.norm();
        if rho == 0.0 {
            return None;
        }
        let table = &self.angles[side];
        let (first, last) = (table[0], table[table.len() - 1]);
        let sign = if last >= first { 1.0 } else { -1.0 };
        let a = d.y.atan2(d.x);
        // Angles before the first row wrap to near 2π, past the table's span.
        let x = (sign * (a - first)).rem_euclid(2.0 * std::f64::consts::PI);
        let key = |i: usize| sign * (table[i] - first);
        if x < 0.0 || x > key(table.len() - 1) {
            return None;
        }
        // Binary search for the segment holding x.
        let (mut lo, mut hi) = (0usize, table.len() - 1);
        while hi - lo > 1 {
            let mid = (lo + hi) / 2;
            if key(mid) <= x {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        let span = key(hi) - key(lo);
        let row = lo as f64
            + if span > 0.0 {
                (x - key(lo)) / span
            } else {
                0.0
            };
        Some(Vector2::new(rho - self.rho_min[side], row))
    }

    /// The half-line of integer row `row` in image `side`: epipole, unit direction, and the
    /// distance from the epipole of column 0 (`R⁻¹(x, row) = e + (x + ρ₀)·u`).
    pub fn row_ray(&self, side: usize, row: usize) -> Option<(Vector2<f64>, Vector2<f64>, f64)> {
        let a = *self.angles[side].get(row)?;
        Some((self.epipoles[side], unit(a), self.rho_min[side]))
    }

    /// Rectified `(column, row)` → ideal pixel of image `side`; `None` off the rows.
    pub fn from_rect(&self, side: usize, r: Vector2<f64>) -> Option<Vector2<f64>> {
        let table = &self.angles[side];
        let n = table.len();
        if !(r.y >= 0.0 && r.y <= (n - 1) as f64) {
            return None;
        }
        let i = (r.y.floor() as usize).min(n - 2);
        let f = r.y - i as f64;
        let a = table[i] + f * (table[i + 1] - table[i]);
        let rho = r.x + self.rho_min[side];
        if rho <= 0.0 {
            return None;
        }
        Some(self.epipoles[side] + unit(a) * rho)
    }
}

/// The angles `[start, end]` (end > start, span < 2π) under which a polygon not containing `e`
/// is seen from `e`.
pub(crate) fn angular_range(poly: &[Vector2<f64>], e: &Vector2<f64>) -> (f64, f64) {
    let c = poly.iter().fold(Vector2::zeros(), |a, p| a + p) / poly.len() as f64;
    let base = (c - e).y.atan2((c - e).x);
    let (mut lo, mut hi) = (0.0f64, 0.0f64);
    for p in poly {
        let a = wrap_pi((p - e).y.atan2((p - e).x) - base);
        lo = lo.min(a);
        hi = hi.max(a);
    }
    (base + lo, base + hi)
}
