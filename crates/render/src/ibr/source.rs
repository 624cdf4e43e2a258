//! A recorded view prepared for image-based rendering: its camera as plain matrices, its colours
//! as `f32` for bilinear look-ups, and its depth map with the holes filled by diffusion (§5.2:
//! "to avoid a runtime penalty a diffusion algorithm is used to fill in undefined depth values").

use handheld_core::{FloatMap, PosedCamera, PosedView};
use nalgebra::{Matrix3, Point3, Vector2, Vector3};

/// One recorded view, ready for look-ups.
#[derive(Clone, Debug)]
pub struct Source {
    pub name: String,
    /// The view's camera and pose; `r`, `t` and `center` below are the pose as matrices.
    pub posed: PosedCamera,
    /// World → camera rotation and translation (`p_cam = r · p + t`).
    pub r: Matrix3<f64>,
    pub t: Vector3<f64>,
    pub center: Point3<f64>,
    pub width: usize,
    pub height: usize,
    /// RGB, row-major, 0..=255.
    pub rgb: Vec<[f32; 3]>,
    /// Camera-frame depth, holes filled; empty when the view has no depth map.
    pub depth: Vec<f32>,
}

impl Source {
    pub fn new(view: &PosedView) -> Self {
        let (w, h) = (view.image.width() as usize, view.image.height() as usize);
        let rgb = view
            .image
            .pixels()
            .map(|p| p.0.map(f32::from))
            .collect::<Vec<_>>();
        let depth = view
            .depth
            .as_ref()
            .filter(|d| d.width == w && d.height == h)
            .map(fill_by_diffusion)
            .unwrap_or_default();
        let r = *view
            .posed
            .cam_from_world
            .rotation
            .to_rotation_matrix()
            .matrix();
        Self {
            name: view.name.clone(),
            posed: view.posed.clone(),
            r,
            t: view.posed.cam_from_world.translation.vector,
            center: view.center(),
            width: w,
            height: h,
            rgb,
            depth,
        }
    }

    pub fn has_depth(&self) -> bool {
        !self.depth.is_empty()
    }

    /// The camera-frame position of a world point.
    #[inline]
    pub fn to_cam(&self, x: &Vector3<f64>) -> Vector3<f64> {
        self.r * x + self.t
    }

    /// Pixel of a camera-frame point in front of the camera (distortion applied, eq. 3).
    #[inline]
    pub fn pixel_of_cam(&self, y: &Vector3<f64>) -> Option<Vector2<f64>> {
        if y.z <= 1e-12 {
            return None;
        }
        let px = self
            .posed
            .camera
            .intrinsics
            .normalized_to_pixel(Vector2::new(y.x / y.z, y.y / y.z));
        self.inside(&px).then_some(px)
    }

    /// Whether a pixel position can be sampled bilinearly (pixel centres at integers).
    #[inline]
    pub fn inside(&self, px: &Vector2<f64>) -> bool {
        px.x >= -0.5
            && px.y >= -0.5
            && px.x <= self.width as f64 - 0.5
            && px.y <= self.height as f64 - 0.5
    }

    /// Bilinear colour at a pixel position (clamped at the border).
    #[inline]
    pub fn colour(&self, px: &Vector2<f64>) -> [f32; 3] {
        let (x0, y0, x1, y1, fx, fy) = self.cell(px);
        let (a, b) = (
            self.rgb[y0 * self.width + x0],
            self.rgb[y0 * self.width + x1],
        );
        let (c, d) = (
            self.rgb[y1 * self.width + x0],
            self.rgb[y1 * self.width + x1],
        );
        let mut out = [0.0f32; 3];
        for k in 0..3 {
            let top = a[k] + (b[k] - a[k]) * fx;
            let bot = c[k] + (d[k] - c[k]) * fx;
            out[k] = top + (bot - top) * fy;
        }
        out
    }

    /// Depth at a pixel position: the nearest of the four neighbours' values, so that a look-up
    /// on a depth edge returns one surface and not a point in mid-air. `None` without depth.
    #[inline]
    pub fn depth_at(&self, px: &Vector2<f64>) -> Option<f64> {
        if self.depth.is_empty() {
            return None;
        }
        let x = (px.x.round().max(0.0) as usize).min(self.width - 1);
        let y = (px.y.round().max(0.0) as usize).min(self.height - 1);
        let d = self.depth[y * self.width + x];
        (d > 0.0).then_some(f64::from(d))
    }

    fn cell(&self, px: &Vector2<f64>) -> (usize, usize, usize, usize, f32, f32) {
        let x = px.x.clamp(0.0, (self.width - 1) as f64);
        let y = px.y.clamp(0.0, (self.height - 1) as f64);
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(self.width - 1), (y0 + 1).min(self.height - 1));
        (
            x0,
            y0,
            x1,
            y1,
            (x - x0 as f64) as f32,
            (y - y0 as f64) as f32,
        )
    }
}

/// Fills the undefined (`NaN` or ≤ 0) values of a depth map by pull-push diffusion: valid values
/// are averaged down a pyramid, and every hole takes the value of the coarsest level that has
/// one, interpolated back up (a multigrid solution of the membrane equation that the paper's
/// diffusion converges to, in one pass). Valid values are kept as they are. An empty result
/// means the map had no valid value at all.
pub fn fill_by_diffusion(map: &FloatMap) -> Vec<f32> {
    let (w, h) = (map.width, map.height);
    let valid = |d: f32| d.is_finite() && d > 0.0;
    let base: Vec<(f32, f32)> = (0..w * h)
        .map(|k| {
            let d = map.data[k * map.channels];
            if valid(d) {
                (d, 1.0)
            } else {
                (0.0, 0.0)
            }
        })
        .collect();
    if base.iter().all(|v| v.1 == 0.0) {
        return Vec::new();
    }
    // Pull: weighted sums down to 1×1.
    let mut levels = vec![(w, h, base)];
    while {
        let (lw, lh, _) = &levels[levels.len() - 1];
        *lw > 1 || *lh > 1
    } {
        let (lw, lh, cur) = &levels[levels.len() - 1];
        let (nw, nh) = (lw.div_ceil(2), lh.div_ceil(2));
        let mut next = vec![(0.0f32, 0.0f32); nw * nh];
        for y in 0..*lh {
            for x in 0..*lw {
                let (v, wt) = cur[y * lw + x];
                let n = &mut next[(y / 2) * nw + x / 2];
                n.0 += v * wt;
                n.1 += wt;
            }
        }
        for n in &mut next {
            if n.1 > 0.0 {
                n.0 /= n.1;
                n.1 = n.1.min(1.0);
            }
        }
        levels.push((nw, nh, next));
    }
    // Push: holes take the coarser level's value, bilinearly upsampled.
    for l in (0..levels.len() - 1).rev() {
        let (cw, ch, coarse) = {
            let (a, b, c) = &levels[l + 1];
            (*a, *b, c.clone())
        };
        let (lw, lh, cur) = &mut levels[l];
        for y in 0..*lh {
            for x in 0..*lw {
                let k = y * *lw + x;
                let (v, wt) = cur[k];
                if wt >= 1.0 {
                    continue;
                }
                // Centre of this pixel in the coarse grid.
                let cx = ((x as f32 + 0.5) / 2.0 - 0.5).clamp(0.0, (cw - 1) as f32);
                let cy = ((y as f32 + 0.5) / 2.0 - 0.5).clamp(0.0, (ch - 1) as f32);
                let (x0, y0) = (cx.floor() as usize, cy.floor() as usize);
                let (x1, y1) = ((x0 + 1).min(cw - 1), (y0 + 1).min(ch - 1));
                let (fx, fy) = (cx - x0 as f32, cy - y0 as f32);
                let mut acc = 0.0;
                let mut acc_w = 0.0;
                for (xx, yy, ww) in [
                    (x0, y0, (1.0 - fx) * (1.0 - fy)),
                    (x1, y0, fx * (1.0 - fy)),
                    (x0, y1, (1.0 - fx) * fy),
                    (x1, y1, fx * fy),
                ] {
                    let (cv, cwt) = coarse[yy * cw + xx];
                    if cwt > 0.0 {
                        acc += cv * ww;
                        acc_w += ww;
                    }
                }
                let up = if acc_w > 0.0 { acc / acc_w } else { v };
                cur[k] = (v * wt + up * (1.0 - wt), 1.0);
            }
        }
    }
    levels
        .swap_remove(0)
        .2
        .into_iter()
        .map(|(v, _)| v)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Holes take values between their neighbours; valid values stay; a map with nothing valid
    /// gives nothing.
    #[test]
    fn diffusion_fills_holes_between_their_borders() {
        let (w, h) = (16, 8);
        let mut data = vec![f32::NAN; w * h];
        for y in 0..h {
            data[y * w] = 2.0;
            data[y * w + w - 1] = 4.0;
        }
        let map = FloatMap {
            width: w,
            height: h,
            channels: 1,
            data,
        };
        let filled = fill_by_diffusion(&map);
        assert_eq!(filled.len(), w * h);
        for y in 0..h {
            assert_eq!(filled[y * w], 2.0);
            assert_eq!(filled[y * w + w - 1], 4.0);
            for x in 1..w - 1 {
                let v = filled[y * w + x];
                assert!((2.0..=4.0).contains(&v), "{v} at {x},{y}");
            }
            assert!(filled[y * w + 2] < filled[y * w + w - 3]);
        }
        let empty = FloatMap {
            width: 4,
            height: 4,
            channels: 1,
            data: vec![f32::NAN; 16],
        };
        assert!(fill_by_diffusion(&empty).is_empty());
    }
}
