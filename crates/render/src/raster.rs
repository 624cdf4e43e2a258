//! A software rasteriser: vertices are projected exactly (distortion included) and triangles are
//! filled with edge functions, interpolating `1/z` and `uv/z` (perspective-correct), with a
//! z-buffer. The interior of a triangle is projected linearly between its distorted vertices,
//! which is exact up to the distortion's curvature over one triangle (sub-pixel for meshes of a
//! few pixels per triangle).

use handheld_core::{FloatMap, PosedCamera, TriMesh};
use image::RgbImage;
use nalgebra::{Point3, Vector2};

/// A rendered view: colours, the pixels the mesh covers, and the camera-frame depth.
#[derive(Clone, Debug)]
pub struct Rendered {
    pub image: RgbImage,
    pub covered: Vec<bool>,
    pub depth: FloatMap,
}

/// A fragment of [`rasterise`]: the sample it covers, its camera depth, the face and the
/// perspective-correct barycentric weights of the face's vertices.
#[derive(Clone, Copy, Debug)]
pub struct Fragment {
    /// Sample column and row on the supersampled grid (`sub` samples per pixel and axis).
    pub sx: usize,
    pub sy: usize,
    pub z: f64,
    pub face: usize,
    pub weights: [f64; 3],
}

/// Rasterises `mesh` seen by `view` on a grid of `sub × sub` samples per
/// pixel (sample `(sx, sy)` sits at pixel position `((sx + ½)/sub − ½, (sy + ½)/sub − ½)`; with
/// `sub = 1`, the pixel centres), inside the sample window `window` (x0, y0, x1, y1, exclusive
/// ends; clipped to the image). Vertices are projected exactly, distortion included; a triangle's
/// interior is linear between its projected vertices. `zbuf` (the window's size, reset to +∞ here)
/// keeps the nearest fragment: `frag` is called for each fragment nearer than what the sample
/// held, so the last call for a sample is its visible surface.
pub fn rasterise(
    mesh: &TriMesh,
    view: &PosedCamera,
    sub: usize,
    window: (usize, usize, usize, usize),
    zbuf: &mut Vec<f32>,
    mut frag: impl FnMut(&Fragment),
) {
    let (camera, cam_from_world) = (&view.camera, &view.cam_from_world);
    let sub = sub.max(1);
    let (sw, sh) = (camera.width as usize * sub, camera.height as usize * sub);
    let (wx0, wy0) = (window.0.min(sw), window.1.min(sh));
    let (wx1, wy1) = (window.2.min(sw), window.3.min(sh));
    if wx0 >= wx1 || wy0 >= wy1 {
        return;
    }
    let ww = wx1 - wx0;
    zbuf.clear();
    zbuf.resize(ww * (wy1 - wy0), f32::INFINITY);
    let s = sub as f64;
    // Project every vertex once: sample-grid position and camera depth.
    let proj: Vec<Option<(Vector2<f64>, f64)>> = mesh
        .vertices
        .positions
        .iter()
        .map(|p| {
            let q = cam_from_world.transform_point(&Point3::new(
                f64::from(p[0]),
                f64::from(p[1]),
                f64::from(p[2]),
            ));
            (q.z > 1e-9).then(|| {
                let m = camera
                    .intrinsics
                    .normalized_to_pixel(Vector2::new(q.x / q.z, q.y / q.z));
                ((m.add_scalar(0.5)) * s - Vector2::repeat(0.5), q.z)
            })
        })
        .collect();
    for (fi, f) in mesh.faces.iter().enumerate() {
        let idx = f.map(|i| i as usize);
        let Some(v) = idx
            .iter()
            .map(|&i| proj.get(i).copied().flatten())
            .collect::<Option<Vec<_>>>()
        else {
            continue;
        };
        let (a, b, c) = (v[0].0, v[1].0, v[2].0);
        let area = (b - a).perp(&(c - a));
        if area.abs() < 1e-12 {
            continue;
        }
        let x0 = a.x.min(b.x).min(c.x).ceil().max(wx0 as f64);
        let x1 = a.x.max(b.x).max(c.x).floor().min(wx1 as f64 - 1.0);
        let y0 = a.y.min(b.y).min(c.y).ceil().max(wy0 as f64);
        let y1 = a.y.max(b.y).max(c.y).floor().min(wy1 as f64 - 1.0);
        if x0 > x1 || y0 > y1 {
            continue;
        }
        let inv_z = [1.0 / v[0].1, 1.0 / v[1].1, 1.0 / v[2].1];
        for y in y0 as usize..=y1 as usize {
            for x in x0 as usize..=x1 as usize {
                let p = Vector2::new(x as f64, y as f64);
                let l0 = (b - p).perp(&(c - p)) / area;
                let l1 = (c - p).perp(&(a - p)) / area;
                let l2 = 1.0 - l0 - l1;
                if l0 < 0.0 || l1 < 0.0 || l2 < 0.0 {
                    continue;
                }
                let iz = l0 * inv_z[0] + l1 * inv_z[1] + l2 * inv_z[2];
                let z = 1.0 / iz;
                let k = (y - wy0) * ww + (x - wx0);
                if z as f32 >= zbuf[k] {
                    continue;
                }
                zbuf[k] = z as f32;
                frag(&Fragment {
                    sx: x,
                    sy: y,
                    z,
                    face: fi,
                    weights: [l0 * inv_z[0] * z, l1 * inv_z[1] * z, l2 * inv_z[2] * z],
                });
            }
        }
    }
}

/// The colour of a fragment: the texture at its interpolated UV, else its vertex colours, else grey.
pub fn fragment_colour(mesh: &TriMesh, texture: Option<&RgbImage>, f: &Fragment) -> [f64; 3] {
    let idx = mesh.faces[f.face].map(|i| i as usize);
    let wts = f.weights;
    if let Some(tex) = texture.filter(|_| mesh.uvs.len() == mesh.vertices.len()) {
        let (mut u, mut v) = (0.0, 0.0);
        for j in 0..3 {
            let t = mesh.uvs[idx[j]];
            u += wts[j] * f64::from(t[0]);
            v += wts[j] * f64::from(t[1]);
        }
        sample(
            tex,
            u * tex.width() as f64 - 0.5,
            v * tex.height() as f64 - 0.5,
        )
        .map(f64::from)
    } else if mesh.vertices.colors.len() == mesh.vertices.len() {
        let mut acc = [0.0f64; 3];
        for j in 0..3 {
            for (ch, a) in acc.iter_mut().enumerate() {
                *a += wts[j] * f64::from(mesh.vertices.colors[idx[j]][ch]);
            }
        }
        acc
    } else {
        [180.0; 3]
    }
}

/// Renders `mesh` seen by `view`. With `texture`, colours come from it at
/// the vertices' UVs (v = 0 at the top row); otherwise from the vertex colours (grey without).
pub fn render_mesh(mesh: &TriMesh, texture: Option<&RgbImage>, view: &PosedCamera) -> Rendered {
    let camera = &view.camera;
    let (w, h) = (camera.width as usize, camera.height as usize);
    let mut image = RgbImage::new(camera.width, camera.height);
    let mut covered = vec![false; w * h];
    let mut zbuf = Vec::new();
    rasterise(mesh, view, 1, (0, 0, w, h), &mut zbuf, |f| {
        let rgb = fragment_colour(mesh, texture, f).map(|v| v.round().clamp(0.0, 255.0) as u8);
        covered[f.sy * w + f.sx] = true;
        image.put_pixel(f.sx as u32, f.sy as u32, image::Rgb(rgb));
    });
    let depth = FloatMap {
        width: w,
        height: h,
        channels: 1,
        data: zbuf
            .iter()
            .map(|z| if z.is_finite() { *z } else { f32::NAN })
            .collect(),
    };
    Rendered {
        image,
        covered,
        depth,
    }
}

/// Bilinear texture sample at a pixel-centre position (clamped to the texture).
fn sample(tex: &RgbImage, x: f64, y: f64) -> [u8; 3] {
    let (w, h) = (tex.width() as f64, tex.height() as f64);
    let x = x.clamp(0.0, w - 1.0);
    let y = y.clamp(0.0, h - 1.0);
    let (x0, y0) = (x.floor() as u32, y.floor() as u32);
    let (x1, y1) = (
        (x0 + 1).min(tex.width() - 1),
        (y0 + 1).min(tex.height() - 1),
    );
    let (fx, fy) = (x - f64::from(x0), y - f64::from(y0));
    let p = |x, y| tex.get_pixel(x, y).0.map(f64::from);
    let (a, b, c, d) = (p(x0, y0), p(x1, y0), p(x0, y1), p(x1, y1));
    let mut out = [0u8; 3];
    for k in 0..3 {
        let top = a[k] * (1.0 - fx) + b[k] * fx;
        let bot = c[k] * (1.0 - fx) + d[k] * fx;
        out[k] = (top * (1.0 - fy) + bot * fy).round().clamp(0.0, 255.0) as u8;
    }
    out
}

/// Mean absolute colour difference (grey levels, averaged over the three channels) between a
/// rendering and a photo over the covered pixels, and the covered fraction.
pub fn mean_absolute_difference(rendered: &Rendered, photo: &RgbImage) -> (f64, f64) {
    let (mut sum, mut n) = (0.0, 0usize);
    for (k, (r, p)) in rendered.image.pixels().zip(photo.pixels()).enumerate() {
        if !rendered.covered[k] {
            continue;
        }
        n += 1;
        sum += (0..3)
            .map(|c| (f64::from(r.0[c]) - f64::from(p.0[c])).abs())
            .sum::<f64>()
            / 3.0;
    }
    (
        sum / n.max(1) as f64,
        n as f64 / rendered.covered.len().max(1) as f64,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use handheld_core::{Camera, CameraId, Intrinsics, PointCloud};

    /// A quad facing the camera renders where its corners project, with its vertex colours.
    #[test]
    fn quad_covers_its_projection() {
        let camera = Camera {
            id: CameraId(0),
            width: 64,
            height: 48,
            intrinsics: Intrinsics::pinhole(50.0, 31.5, 23.5),
        };
        let z = 2.0f32;
        let mesh = TriMesh {
            vertices: PointCloud {
                positions: vec![
                    [-0.5, -0.5, z],
                    [0.5, -0.5, z],
                    [0.5, 0.5, z],
                    [-0.5, 0.5, z],
                ],
                colors: vec![[200, 10, 10]; 4],
                normals: Vec::new(),
            },
            uvs: Vec::new(),
            faces: vec![[0, 1, 2], [0, 2, 3]],
        };
        let r = render_mesh(
            &mesh,
            None,
            &PosedCamera::new(camera, handheld_core::Rigid3::identity()),
        );
        // Corners at 31.5 ± 12.5, 23.5 ± 12.5: a 25×25 square (x 19..=44, y 11..=36).
        let n = r.covered.iter().filter(|c| **c).count();
        assert!((24 * 24..=26 * 26).contains(&n), "{n} pixels");
        assert_eq!(r.image.get_pixel(31, 23).0, [200, 10, 10]);
        assert!((r.depth.get(31, 23, 0) - 2.0).abs() < 1e-5);
        assert!(!r.covered[0]);
    }
}
