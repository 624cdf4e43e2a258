//! The §5.1 single-depth-map mesh and its texture enhancement on a synthetic frame.

mod common;

use handheld_core::NoProgress;
use handheld_mesh::{
    enhance_texture, mesh_from_depth_map, EnhanceOptions, MeshIndex, SingleMeshOptions,
};
use nalgebra::Point3;

fn p64(q: [f32; 3]) -> Point3<f64> {
    Point3::new(q[0] as f64, q[1] as f64, q[2] as f64)
}

#[test]
fn single_view_mesh_is_accurate_oriented_and_textured_by_its_image() {
    let seq = common::sequence(9, 320);
    let views = common::views(&seq);
    let reference = 4;
    let size = seq.scene.extent();
    let gt = MeshIndex::new(&seq.mesh);
    let frame = seq.frame(reference).unwrap();
    let (cam, pose) = (&frame.camera, &frame.cam_from_world);
    let centre = frame.center();
    let mut far_faces = Vec::new();
    for max_angle in [85.0, 90.0] {
        let opts = SingleMeshOptions {
            max_angle_deg: max_angle,
            ..Default::default()
        };
        let (mesh, summary) = mesh_from_depth_map(&views[reference], &opts, &NoProgress).unwrap();
        mesh.validate().unwrap();
        assert_eq!(mesh.vertices.colors.len(), mesh.vertices.len());
        assert!(mesh.uvs.iter().flatten().all(|u| (0.0..=1.0).contains(u)));
        // UVs are the vertices' own pixels: projecting a vertex lands on its texture coordinate.
        for (q, uv) in mesh.vertices.positions.iter().zip(&mesh.uvs).step_by(97) {
            let px = cam.project(pose, &p64(*q)).unwrap();
            let (u, v) = (
                (px.x + 0.5) / cam.width as f64,
                (px.y + 0.5) / cam.height as f64,
            );
            assert!((u - uv[0] as f64).abs() < 1e-4 && (v - uv[1] as f64).abs() < 1e-4);
        }
        let mut d: Vec<f64> = mesh
            .vertices
            .positions
            .iter()
            .map(|q| gt.distance(&p64(*q)))
            .collect();
        let acc = handheld_mesh::eval::percentile(&mut d, 0.9);
        // Centroids far from the surface are triangles bridging a depth discontinuity.
        let bridging = mesh
            .faces
            .iter()
            .filter(|f| {
                let c = f
                    .iter()
                    .map(|&i| p64(mesh.vertices.positions[i as usize]).coords)
                    .sum::<nalgebra::Vector3<f64>>()
                    / 3.0;
                gt.distance(&Point3::from(c)) > 0.05
            })
            .count();
        far_faces.push(bridging);
        println!("max angle {max_angle}: {summary:?}; vertex accuracy@90 {acc:.4} ({:.3}% of size); bridging faces {bridging}", 100.0 * acc / size);
        assert!(acc < 0.005 * size);
        assert!(summary.dropped_missing > 0, "the sky has no depth");
        for f in &mesh.faces {
            let [a, b, c] = f.map(|i| p64(mesh.vertices.positions[i as usize]));
            let n = (b - a).cross(&(c - a));
            assert!(
                n.dot(&(centre - a)) > 0.0,
                "counter-clockwise seen from the camera"
            );
        }
    }
    assert!(
        far_faces[0] * 5 < far_faces[1].max(5),
        "the 85° test drops the triangles across discontinuities: {far_faces:?}"
    );
}

#[test]
fn enhancement_removes_a_highlight_seen_in_one_view_only() {
    let seq = common::sequence(9, 320);
    let reference = 4;
    let views = common::views(&seq);
    let clean = &seq.images[reference];
    let mut spotted = views[reference].clone();
    // A specular highlight: a saturated disk on the surface in the reference image only.
    let (cx, cy, r) = (150i64, 150i64, 12i64);
    let in_spot = |x: i64, y: i64| (x - cx).pow(2) + (y - cy).pow(2) <= r * r;
    for (x, y, p) in spotted.image.enumerate_pixels_mut() {
        if in_spot(x as i64, y as i64) {
            *p = image::Rgb([255, 255, 255]);
        }
    }
    let linked: Vec<_> = [2, 3, 5, 6].iter().map(|&i| views[i].clone()).collect();
    let (enhanced, summary) =
        enhance_texture(&spotted, &linked, &EnhanceOptions::default(), &NoProgress).unwrap();
    let mad = |a: &image::RgbImage, spot: bool| {
        let (mut s, mut n) = (0.0, 0usize);
        for (x, y, p) in a.enumerate_pixels() {
            if in_spot(x as i64, y as i64) != spot {
                continue;
            }
            let q = clean.get_pixel(x, y);
            s += (0..3)
                .map(|k| (p[k] as f64 - q[k] as f64).abs())
                .sum::<f64>()
                / 3.0;
            n += 1;
        }
        s / n as f64
    };
    println!(
        "{summary:?}; highlight error {:.1} -> {:.1}; elsewhere {:.1}",
        mad(&spotted.image, true),
        mad(&enhanced, true),
        mad(&enhanced, false)
    );
    assert!(summary.texels_replaced > 10_000);
    assert!(mad(&enhanced, true) < 0.25 * mad(&spotted.image, true));
    assert!(mad(&enhanced, false) < 20.0);
}
