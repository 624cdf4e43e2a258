//! The two objects the project ships, made here (no download): a textured box and an axes marker.

use handheld_core::{PointCloud, TriMesh};
use image::RgbImage;

/// A textured unit box standing on y = 0 (x, z in [−0.5, 0.5], y in [0, 1]): each face its own
/// colour with a darker frame and a grid, in one 256×256 texture (2×3 tiles).
pub fn object_box() -> (TriMesh, RgbImage) {
    let tile = 128u32;
    let colours: [[u8; 3]; 6] = [
        [220, 60, 50],
        [60, 170, 80],
        [60, 100, 220],
        [230, 190, 40],
        [200, 80, 200],
        [60, 200, 210],
    ];
    let mut tex = RgbImage::new(3 * tile, 2 * tile);
    for (f, c) in colours.iter().enumerate() {
        let (ox, oy) = ((f as u32 % 3) * tile, (f as u32 / 3) * tile);
        for y in 0..tile {
            for x in 0..tile {
                let edge = x < 10 || y < 10 || x >= tile - 10 || y >= tile - 10;
                let grid = x % 32 < 3 || y % 32 < 3;
                let k = if edge {
                    0.35
                } else if grid {
                    0.75
                } else {
                    1.0
                };
                let px = c.map(|v| (f64::from(v) * k) as u8);
                tex.put_pixel(ox + x, oy + y, image::Rgb(px));
            }
        }
    }
    // Faces: (+x, −x, +y, −y, +z, −z), each with its outward normal and two in-plane axes.
    let faces: [([f32; 3], [f32; 3], [f32; 3]); 6] = [
        ([1., 0., 0.], [0., 0., -1.], [0., 1., 0.]),
        ([-1., 0., 0.], [0., 0., 1.], [0., 1., 0.]),
        ([0., 1., 0.], [1., 0., 0.], [0., 0., -1.]),
        ([0., -1., 0.], [1., 0., 0.], [0., 0., 1.]),
        ([0., 0., 1.], [1., 0., 0.], [0., 1., 0.]),
        ([0., 0., -1.], [-1., 0., 0.], [0., 1., 0.]),
    ];
    let mut positions = Vec::new();
    let mut normals = Vec::new();
    let mut uvs = Vec::new();
    let mut tris = Vec::new();
    for (f, (n, u, v)) in faces.iter().enumerate() {
        let base = positions.len() as u32;
        let (tu, tv) = ((f % 3) as f32 / 3.0, (f / 3) as f32 / 2.0);
        for (a, b) in [(-0.5f32, -0.5f32), (0.5, -0.5), (0.5, 0.5), (-0.5, 0.5)] {
            let p = [
                0.5 * n[0] + a * u[0] + b * v[0],
                0.5 * n[1] + a * u[1] + b * v[1] + 0.5,
                0.5 * n[2] + a * u[2] + b * v[2],
            ];
            positions.push(p);
            normals.push(*n);
            uvs.push([tu + (a + 0.5) / 3.0, tv + (0.5 - b) / 2.0]);
        }
        tris.push([base, base + 1, base + 2]);
        tris.push([base, base + 2, base + 3]);
    }
    let mesh = TriMesh {
        vertices: PointCloud {
            colors: vec![[255, 255, 255]; positions.len()],
            positions,
            normals,
        },
        uvs,
        faces: tris,
    };
    (mesh, tex)
}

/// A coordinate-axes marker: three square bars along +X (red), +Y (green) and +Z (blue) from
/// the origin, length 1, vertex-coloured.
pub fn object_axes() -> TriMesh {
    let mut positions = Vec::new();
    let mut colors = Vec::new();
    let mut faces = Vec::new();
    let t = 0.06f32;
    for axis in 0..3 {
        let colour = match axis {
            0 => [230, 40, 40],
            1 => [40, 200, 60],
            _ => [50, 80, 240],
        };
        let mut lo = [-t; 3];
        let mut hi = [t; 3];
        lo[axis] = 0.0;
        hi[axis] = 1.0;
        let base = positions.len() as u32;
        for i in 0..8u32 {
            positions.push([
                if i & 1 == 0 { lo[0] } else { hi[0] },
                if i & 2 == 0 { lo[1] } else { hi[1] },
                if i & 4 == 0 { lo[2] } else { hi[2] },
            ]);
            colors.push(colour);
        }
        for q in [
            [0, 2, 3, 1],
            [4, 5, 7, 6],
            [0, 1, 5, 4],
            [2, 6, 7, 3],
            [0, 4, 6, 2],
            [1, 3, 7, 5],
        ] {
            faces.push([base + q[0], base + q[1], base + q[2]]);
            faces.push([base + q[0], base + q[2], base + q[3]]);
        }
    }
    TriMesh {
        vertices: PointCloud {
            positions,
            colors,
            normals: Vec::new(),
        },
        uvs: Vec::new(),
        faces,
    }
}
