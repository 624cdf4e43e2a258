//! The per-pixel loop: the leaf under an output pixel, its plane (or the proxy depth), and the
//! weighted, visibility-checked look-ups in the recorded views; and the leaf-id raster it reads.

use handheld_core::FloatMap;
use nalgebra::{Vector2, Vector3};

use super::support::{self, Blend, Leaf, Root, Vertex, Virtual};
use super::{IbrMethod, IbrOptions, IbrScene};

/// Writes `id` into every ideal pixel (integer positions offset by `lo`) inside `leaf`.
pub(crate) fn raster_ids(
    leaf: &Leaf,
    id: u32,
    lo: Vector2<f64>,
    dw: usize,
    dh: usize,
    ids: &mut [u32],
) {
    let [a, b, c] = leaf.p.map(|p| p - lo);
    let area = (b - a).perp(&(c - a));
    if area.abs() < 1e-12 {
        return;
    }
    let x0 = a.x.min(b.x).min(c.x).floor().max(0.0) as usize;
    let y0 = a.y.min(b.y).min(c.y).floor().max(0.0) as usize;
    let x1 = (a.x.max(b.x).max(c.x).ceil().max(0.0) as usize).min(dw - 1);
    let y1 = (a.y.max(b.y).max(c.y).ceil().max(0.0) as usize).min(dh - 1);
    let eps = -1e-9 * area.abs();
    for y in y0..=y1 {
        for x in x0..=x1 {
            let p = Vector2::new(x as f64, y as f64);
            let l0 = (b - p).perp(&(c - p)) * area.signum();
            let l1 = (c - p).perp(&(a - p)) * area.signum();
            let l2 = (a - p).perp(&(b - p)) * area.signum();
            if l0 >= eps && l1 >= eps && l2 >= eps {
                ids[y * dw + x] = id;
            }
        }
    }
}

/// The views of several weighted blends (the corners of a triangle or of a grid cell), each view
/// once with its weights summed, so that a view shared by corners is sampled once.
fn merge(parts: &[(&Blend, f32)]) -> ([(usize, f32); 4 * support::MAX_BLEND], usize) {
    let mut srcs = [(usize::MAX, 0.0f32); 4 * support::MAX_BLEND];
    let mut n = 0;
    for (blend, cw) in parts {
        for (s, wt) in blend.iter() {
            match srcs[..n].iter_mut().find(|e| e.0 == s) {
                Some(e) => e.1 += cw * wt,
                None => {
                    // At most 4 parts of MAX_BLEND views each: it always fits.
                    srcs[n] = (s, cw * wt);
                    n += 1;
                }
            }
        }
    }
    (srcs, n)
}

/// A weighted colour sum.
#[derive(Clone, Copy, Default)]
struct Sum {
    colour: [f32; 3],
    weight: f32,
}

impl Sum {
    #[inline]
    fn add(&mut self, c: [f32; 3], w: f32) {
        for (s, &x) in self.colour.iter_mut().zip(&c) {
            *s += w * x;
        }
        self.weight += w;
    }
}

#[derive(Clone, Copy, Default)]
struct Acc {
    visible: Sum,
    all: Sum,
}

/// Everything the per-pixel loop reads.
pub(crate) struct Shade<'a> {
    pub(crate) scene: &'a IbrScene,
    pub(crate) virt: &'a Virtual,
    pub(crate) method: IbrMethod,
    pub(crate) opts: &'a IbrOptions,
    pub(crate) lo: Vector2<f64>,
    pub(crate) dw: usize,
    pub(crate) dh: usize,
    pub(crate) ids: &'a [u32],
    pub(crate) leaves: &'a [Leaf],
    pub(crate) roots: &'a [Root],
    pub(crate) vertices: &'a [Vertex],
    pub(crate) grid: (&'a [Blend], usize, usize),
    pub(crate) order: &'a [usize],
    pub(crate) ideal: Option<&'a [Vector2<f32>]>,
    pub(crate) proxy: Option<&'a FloatMap>,
}

impl Shade<'_> {
    /// The colour and virtual-camera depth of output pixel (x, y).
    #[inline]
    pub(crate) fn pixel(&self, x: usize, y: usize, w: usize) -> Option<([f32; 3], f64)> {
        let p = match self.ideal {
            Some(t) => t[y * w + x].cast::<f64>(),
            None => Vector2::new(x as f64, y as f64),
        };
        let cx = ((p.x - self.lo.x).round().max(0.0) as usize).min(self.dw - 1);
        let cy = ((p.y - self.lo.y).round().max(0.0) as usize).min(self.dh - 1);
        let li = self.ids[cy * self.dw + cx];
        let leaf = self.leaves.get(li as usize)?;
        let dir = self.virt.ray(&p);
        let from_proxy = self
            .proxy
            .map(|d| f64::from(d.data[y * w + x]))
            .filter(|z| z.is_finite() && *z > 0.0);
        let lambda = match from_proxy {
            Some(z) => z,
            None => leaf.plane.ray_parameter(&self.virt.center, &dir)?,
        };
        let xw = self.virt.center + dir * lambda;
        let z = lambda; // ray direction has unit z in the virtual camera (K⁻¹ p̃).
                        // Samples whose point is visible in their view, and all samples (used when every view
                        // hides the point: the geometry is then off, and a ghost beats a hole).
        let mut acc = Acc::default();
        let check = matches!(self.method, IbrMethod::Subdivided | IbrMethod::Ulr);
        let sample = |s: usize, wt: f32, acc: &mut Acc| {
            if wt <= 1e-4 {
                return;
            }
            let src = &self.scene.sources[s];
            let yc = src.to_cam(&xw);
            let Some(px) = src.pixel_of_cam(&yc) else {
                return;
            };
            let c = src.colour(&px);
            acc.all.add(c, wt);
            if check {
                if let Some(d) = src.depth_at(&px) {
                    if yc.z > d * (1.0 + self.opts.occlusion_tolerance) {
                        return;
                    }
                }
            }
            acc.visible.add(c, wt);
        };
        if self.method == IbrMethod::Ulr {
            let (grid, gw, g) = self.grid;
            let gx = (p.x - self.lo.x) / g as f64;
            let gy = (p.y - self.lo.y) / g as f64;
            let (ix, iy) = (gx.floor().max(0.0) as usize, gy.floor().max(0.0) as usize);
            let ix = ix.min(gw - 2);
            let iy = iy.min(grid.len() / gw - 2);
            let (fx, fy) = ((gx - ix as f64) as f32, (gy - iy as f64) as f32);
            let corners = [
                (ix, iy, (1.0 - fx) * (1.0 - fy)),
                (ix + 1, iy, fx * (1.0 - fy)),
                (ix, iy + 1, (1.0 - fx) * fy),
                (ix + 1, iy + 1, fx * fy),
            ];
            let parts = corners.map(|(gx, gy, cw)| (&grid[gy * gw + gx], cw));
            let (srcs, n) = merge(&parts);
            for &(s, wt) in &srcs[..n] {
                sample(s, wt, &mut acc);
            }
        } else {
            let root = &self.roots[leaf.root as usize];
            let bary = root.bary * Vector3::new(p.x, p.y, 1.0);
            let parts: [(&Blend, f32); 3] = std::array::from_fn(|j| {
                (
                    &self.vertices[root.v[j]].blend,
                    bary[j].clamp(0.0, 1.0) as f32,
                )
            });
            let (srcs, n) = merge(&parts);
            for &(s, wt) in &srcs[..n] {
                sample(s, wt, &mut acc);
            }
        }
        if acc.visible.weight <= 1e-3 {
            // No triangle camera sees the point: the nearest view that does.
            let all = acc.all;
            acc = Acc::default();
            for &s in self.order.iter().take(8) {
                sample(s, 1.0, &mut acc);
                if acc.visible.weight > 0.0 {
                    break;
                }
            }
            if acc.visible.weight <= 0.0 {
                acc.visible = if all.weight > 1e-3 { all } else { acc.all };
            }
        }
        let v = acc.visible;
        (v.weight > 0.0).then(|| (v.colour.map(|c| c / v.weight), z))
    }
}
