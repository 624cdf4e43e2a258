//! Texturing a fused synthetic mesh: UVs in [0, 1], few untextured faces, and the atlas reproduces
//! a held-out view's colours where that view sees the surface.

mod common;

use handheld_core::NoProgress;
use handheld_mesh::{fuse_depth_maps, texture_mesh, FusionOptions, TextureOptions, VoxelSize};
use nalgebra::Point3;

fn bilinear(img: &image::RgbImage, x: f64, y: f64) -> [f64; 3] {
    let (w, h) = (img.width() as f64, img.height() as f64);
    let (x, y) = (x.clamp(0.0, w - 1.0), y.clamp(0.0, h - 1.0));
    let (x0, y0) = (x.floor() as u32, y.floor() as u32);
    let (x1, y1) = (
        (x0 + 1).min(img.width() - 1),
        (y0 + 1).min(img.height() - 1),
    );
    let (ax, ay) = (x - x0 as f64, y - y0 as f64);
    std::array::from_fn(|c| {
        let g = |xx: u32, yy: u32| img.get_pixel(xx, yy)[c] as f64;
        (g(x0, y0) * (1.0 - ax) + g(x1, y0) * ax) * (1.0 - ay)
            + (g(x0, y1) * (1.0 - ax) + g(x1, y1) * ax) * ay
    })
}

#[test]
fn textured_mesh_reproduces_a_held_out_view() {
    let seq = common::sequence(11, 320);
    let held_out = 5;
    // The held-out view is removed from the views the model is fused and textured from.
    let mut views = common::views(&seq);
    let held = views.remove(held_out);
    let mut opts = FusionOptions::default();
    opts.tsdf.voxel_size = VoxelSize::Absolute(0.02);
    opts.simplify.as_mut().unwrap().target_faces = 40_000;
    let (mesh, _) = fuse_depth_maps(&views, &opts, &NoProgress).unwrap();
    let t = std::time::Instant::now();
    let (tm, summary) =
        texture_mesh(&mesh, &views, &TextureOptions::default(), &NoProgress).unwrap();
    println!("{summary:?}; {:.2}s", t.elapsed().as_secs_f64());
    tm.mesh.validate().unwrap();
    assert_eq!(tm.mesh.faces.len(), mesh.faces.len());
    assert_eq!(tm.mesh.uvs.len(), tm.mesh.vertices.len());
    assert!(tm
        .mesh
        .uvs
        .iter()
        .flatten()
        .all(|&u| (0.0..=1.0).contains(&u)));
    assert!(summary.untextured_faces * 20 < summary.faces, "{summary:?}");
    assert!(summary.atlas_width <= 8192 && summary.atlas_height <= 8192);
    // Colour check against the held-out view, at face centroids it sees (GT depth agrees).
    let (cam, pose) = (&held.posed.camera, &held.posed.cam_from_world);
    let gt_depth = held.depth.as_ref().unwrap();
    let (aw, ah) = (tm.texture.width() as f64, tm.texture.height() as f64);
    let (mut sum, mut floor, mut n) = (0.0, 0.0, 0usize);
    for f in &tm.mesh.faces {
        let p = f.map(|i| {
            let q = tm.mesh.vertices.positions[i as usize];
            Point3::new(q[0] as f64, q[1] as f64, q[2] as f64)
        });
        let c = Point3::from((p[0].coords + p[1].coords + p[2].coords) / 3.0);
        let Some(px) = cam.project(pose, &c) else {
            continue;
        };
        if !cam.contains(&px) {
            continue;
        }
        let (x, y) = (px.x.round() as usize, px.y.round() as usize);
        let d = gt_depth.get(x, y, 0) as f64;
        if (pose.transform_point(&c).z - d).abs() > 0.01 * d {
            continue;
        }
        let uv = f.map(|i| tm.mesh.uvs[i as usize]);
        let u = (uv[0][0] + uv[1][0] + uv[2][0]) as f64 / 3.0;
        let v = (uv[0][1] + uv[1][1] + uv[2][1]) as f64 / 3.0;
        let a = bilinear(&tm.texture, u * aw - 0.5, v * ah - 0.5);
        let b = bilinear(&held.image, px.x, px.y);
        // Floor: the same comparison between two real neighbouring images.
        let frame4 = seq.frame(held_out - 1).unwrap();
        let Some(q) = frame4.project(&c).filter(|q| frame4.camera.contains(q)) else {
            continue;
        };
        let d4 = seq.depths[held_out - 1].get(q.x.round() as usize, q.y.round() as usize, 0) as f64;
        if (frame4.to_cam(&c).z - d4).abs() > 0.01 * d4 {
            continue;
        }
        let r = bilinear(&seq.images[held_out - 1], q.x, q.y);
        floor += (0..3).map(|k| (r[k] - b[k]).abs()).sum::<f64>() / 3.0;
        sum += (0..3).map(|k| (a[k] - b[k]).abs()).sum::<f64>() / 3.0;
        n += 1;
    }
    let mad = sum / n as f64;
    let floor = floor / n as f64;
    println!("held-out view: mean absolute colour difference {mad:.2} grey levels over {n} faces (neighbouring input image: {floor:.2})");
    assert!(n > 1000);
    assert!(mad < floor + 5.0, "{mad} vs {floor}");
}
