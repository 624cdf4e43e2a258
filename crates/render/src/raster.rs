//! A software rasteriser: vertices are projected exactly (distortion included) and triangles are
//! filled with edge functions, interpolating `1/z` and `uv/z` (perspective-correct), with a
//! z-buffer. The interior of a triangle is projected linearly between its distorted vertices,
//! which is exact up to the distortion's curvature over one triangle (sub-pixel for meshes of a
//! few pixels per triangle).

use handheld_core::{Camera, FloatMap, Rigid3, TriMesh};
use image::RgbImage;
use nalgebra::{Point3, Vector2};

/// A rendered view: colours, the pixels the mesh covers, and the camera-frame depth.
#[derive(Clone, Debug)]
pub struct Rendered {
    pub image: RgbImage,
    pub covered: Vec<bool>,
    pub depth: FloatMap,
}

/// Renders `mesh` seen by `camera` at `cam_from_world`. With `texture`, colours come from it at
/// the vertices' UVs (v = 0 at the top row); otherwise from the vertex colours (grey without).
pub fn render_mesh(
    mesh: &TriMesh,
    texture: Option<&RgbImage>,
    camera: &Camera,
    cam_from_world: &Rigid3,
) -> Rendered {
    let (w, h) = (camera.width as usize, camera.height as usize);
    let mut image = RgbImage::new(camera.width, camera.height);
    let mut covered = vec![false; w * h];
    let mut zbuf = FloatMap::filled(w, h, 1, f32::INFINITY);
    // Project every vertex once: pixel position and camera depth.
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
                (m, q.z)
            })
        })
        .collect();
    let use_uv = texture.is_some() && mesh.uvs.len() == mesh.vertices.len();
    let colours = &mesh.vertices.colors;
    for f in &mesh.faces {
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
        let x0 = a.x.min(b.x).min(c.x).ceil().max(0.0);
        let x1 = a.x.max(b.x).max(c.x).floor().min(w as f64 - 1.0);
        let y0 = a.y.min(b.y).min(c.y).ceil().max(0.0);
        let y1 = a.y.max(b.y).max(c.y).floor().min(h as f64 - 1.0);
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
                let k = y * w + x;
                if z as f32 >= zbuf.data[k] {
                    continue;
                }
                zbuf.data[k] = z as f32;
                covered[k] = true;
                // Perspective-correct weights.
                let wts = [l0 * inv_z[0] * z, l1 * inv_z[1] * z, l2 * inv_z[2] * z];
                let rgb = if let (true, Some(tex)) = (use_uv, texture) {
                    let mut u = 0.0;
                    let mut vv = 0.0;
                    for j in 0..3 {
                        let t = mesh.uvs[idx[j]];
                        u += wts[j] * f64::from(t[0]);
                        vv += wts[j] * f64::from(t[1]);
                    }
                    sample(
                        tex,
                        u * tex.width() as f64 - 0.5,
                        vv * tex.height() as f64 - 0.5,
                    )
                } else if colours.len() == mesh.vertices.len() {
                    let mut acc = [0.0f64; 3];
                    for j in 0..3 {
                        for (ch, a) in acc.iter_mut().enumerate() {
                            *a += wts[j] * f64::from(colours[idx[j]][ch]);
                        }
                    }
                    acc.map(|v| v.round().clamp(0.0, 255.0) as u8)
                } else {
                    [180, 180, 180]
                };
                image.put_pixel(x as u32, y as u32, image::Rgb(rgb));
            }
        }
    }
    let depth = FloatMap {
        data: zbuf
            .data
            .iter()
            .map(|z| if z.is_finite() { *z } else { f32::NAN })
            .collect(),
        ..zbuf
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
    use handheld_core::{CameraId, Intrinsics, PointCloud};

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
        let r = render_mesh(&mesh, None, &camera, &Rigid3::identity());
        // Corners at 31.5 ± 12.5, 23.5 ± 12.5: a 25×25 square (x 19..=44, y 11..=36).
        let n = r.covered.iter().filter(|c| **c).count();
        assert!((24 * 24..=26 * 26).contains(&n), "{n} pixels");
        assert_eq!(r.image.get_pixel(31, 23).0, [200, 10, 10]);
        assert!((r.depth.get(31, 23, 0) - 2.0).abs() < 1e-5);
        assert!(!r.covered[0]);
    }
}
