//! Self-consistency of the rendered ground truth: landmark disks appear where the GT cameras project
//! the GT points (< 0.1 px), depth maps equal independent ray casts, the GT mesh carries every GT
//! surface point, rendering is deterministic in its seed, and the GT reconstruction reprojects exactly.

use std::sync::OnceLock;

use handheld_core::pose::center_of;
use handheld_core::ImageId;
use handheld_testkit::{
    distance_to_mesh, pixel_ray, render_sequence, render_sequence_with_scene, CameraPath,
    PathOptions, Primitive, Scene, SequenceOptions, SyntheticSequence, LANDMARK_HALF_SQUARE,
    LANDMARK_RADIUS,
};
use nalgebra::{Point3, Vector2};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn small_options() -> SequenceOptions {
    SequenceOptions {
        width: 320,
        height: 240,
        num_frames: 3,
        samples_per_axis: 4,
        seed: 11,
        ..SequenceOptions::default()
    }
}

fn sequence() -> &'static SyntheticSequence {
    static SEQ: OnceLock<SyntheticSequence> = OnceLock::new();
    SEQ.get_or_init(|| render_sequence(&small_options()).expect("valid options"))
}

/// Distance from `p` to the convex quadrilateral `q` (corners in order), 0 inside.
fn dist_to_quad(p: &Vector2<f64>, q: &[Vector2<f64>; 4]) -> f64 {
    let cross = |a: &Vector2<f64>, b: &Vector2<f64>| a.x * b.y - a.y * b.x;
    let signs: Vec<f64> = (0..4)
        .map(|i| cross(&(q[(i + 1) % 4] - q[i]), &(p - q[i])))
        .collect();
    if signs.iter().all(|s| *s >= 0.0) || signs.iter().all(|s| *s <= 0.0) {
        return 0.0;
    }
    (0..4)
        .map(|i| {
            let (a, b) = (q[i], q[(i + 1) % 4]);
            let t = ((p - a).dot(&(b - a)) / (b - a).norm_squared()).clamp(0.0, 1.0);
            (p - (a + (b - a) * t)).norm()
        })
        .fold(f64::INFINITY, f64::min)
}

/// Area centroid of the exact image of landmark `lm_idx`'s disk in `frame` (its boundary projected
/// with distortion as a 720-gon): the disk centroid without the renderer, to separate the perspective
/// offset between a disk's image centroid and its centre's projection from rendering errors.
fn projected_disk_centroid(
    seq: &SyntheticSequence,
    frame: usize,
    lm_idx: usize,
) -> Option<Vector2<f64>> {
    let view = seq.frame(frame)?;
    let (cam, pose) = (&view.camera, &view.cam_from_world);
    let lm = seq.scene.landmark_info()[lm_idx];
    let rect = seq.scene.face_rect(lm.primitive, lm.face)?;
    let poly: Vec<Vector2<f64>> = (0..720)
        .map(|k| {
            let a = std::f64::consts::TAU * k as f64 / 720.0;
            cam.project(
                pose,
                &(lm.position + (rect.u * a.cos() + rect.v * a.sin()) * LANDMARK_RADIUS),
            )
        })
        .collect::<Option<_>>()?;
    let (mut area, mut c) = (0.0, Vector2::zeros());
    for k in 0..poly.len() {
        let (p, q) = (poly[k], poly[(k + 1) % poly.len()]);
        let cr = p.x * q.y - q.x * p.y;
        area += cr;
        c += (p + q) * cr;
    }
    Some(c / (3.0 * area))
}

/// Measures the centre of landmark `point_idx`'s disk in frame `frame` as the background-subtracted
/// darkness centroid over the pixels that overlap the disk. `None` when the disk is not cleanly
/// measurable (grazing view, near the image border, bright square occluded or cut by the window).
fn measure_disk(
    seq: &SyntheticSequence,
    frame: usize,
    lm_idx: usize,
    predicted: Vector2<f64>,
) -> Option<Vector2<f64>> {
    let view = seq.frame(frame)?;
    let (cam, pose) = (&view.camera, &view.cam_from_world);
    let lm = seq.scene.landmark_info()[lm_idx];
    let c = center_of(pose);
    let view_dir = (lm.position - c).normalize();
    if view_dir.dot(&lm.normal).abs() < 0.3 {
        return None;
    }
    let z = pose.transform_point(&lm.position).z;
    let r_px = cam.intrinsics.f * LANDMARK_RADIUS / z;
    let half = (1.3 * r_px).ceil() as i64 + 3;
    let (cx, cy) = (predicted.x.round() as i64, predicted.y.round() as i64);
    if cx - half < 0
        || cy - half < 0
        || cx + half >= cam.width as i64
        || cy + half >= cam.height as i64
    {
        return None;
    }
    let img = &seq.images[frame];
    let (mut bg_sum, mut bg_n) = (0.0, 0usize);
    let mut disk = Vec::new();
    for y in (cy - half)..=(cy + half) {
        for x in (cx - half)..=(cx + half) {
            let mut in_square = true;
            let mut corners = [Vector2::zeros(); 4];
            for (k, (dx, dy)) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)]
                .iter()
                .enumerate()
            {
                let (o, d) = pixel_ray(&view, Vector2::new(x as f64 + dx, y as f64 + dy));
                match seq.scene.intersect(&o, &d) {
                    Some(h) if h.primitive == lm.primitive && h.face == lm.face => {
                        corners[k] = h.uv;
                        let duv = h.uv - lm.uv;
                        in_square &= duv.x.abs() < LANDMARK_HALF_SQUARE
                            && duv.y.abs() < LANDMARK_HALF_SQUARE;
                    }
                    _ => in_square = false,
                }
            }
            // A pixel sees the disk when its filter footprint (the tent reaches ±1 px) comes within the
            // radius (plus a margin for the footprint's curvature under distortion) of the disk centre.
            let near_disk = !in_square || dist_to_quad(&lm.uv, &corners) < LANDMARK_RADIUS + 1e-3;
            let border = (x - cx).abs() == half || (y - cy).abs() == half;
            let p = img.get_pixel(x as u32, y as u32).0;
            let grey = (p[0] as f64 + p[1] as f64 + p[2] as f64) / 3.0;
            match (in_square, near_disk) {
                (true, false) => {
                    bg_sum += grey;
                    bg_n += 1;
                }
                (true, true) if !border => disk.push((x as f64, y as f64, grey)),
                (false, _)
                    if !border && dist_to_quad(&lm.uv, &corners) < LANDMARK_RADIUS + 1e-3 =>
                {
                    return None
                }
                (true, true) => return None,
                _ => {}
            }
        }
    }
    if bg_n < 8 || disk.is_empty() {
        return None;
    }
    let bg = bg_sum / bg_n as f64;
    let (mut sw, mut sx, mut sy) = (0.0, 0.0, 0.0);
    for (x, y, g) in disk {
        let w = bg - g;
        sw += w;
        sx += w * x;
        sy += w * y;
    }
    (sw > 0.0).then(|| Vector2::new(sx / sw, sy / sw))
}

#[test]
fn landmarks_project_onto_rendered_disks() {
    let seq = sequence();
    let (mut errors, mut render_errors) = (Vec::new(), Vec::new());
    for (pid, point) in &seq.gt.points {
        for el in &point.track.elements {
            let (frame, lm) = (el.image_id.0 as usize, pid.0 as usize);
            let predicted = seq.gt.views[&el.image_id].observations[el.point2d_idx as usize].xy;
            assert!(
                (seq.gt.project(el.image_id, &point.xyz).expect("in front") - predicted).norm()
                    < 1e-9
            );
            if let Some(m) = measure_disk(seq, frame, lm, predicted) {
                errors.push((m - predicted).norm());
                if let Some(c) = projected_disk_centroid(seq, frame, lm) {
                    render_errors.push((m - c).norm());
                }
            }
        }
    }
    let stats = |e: &[f64]| {
        (
            e.iter().sum::<f64>() / e.len().max(1) as f64,
            e.iter().cloned().fold(0.0, f64::max),
        )
    };
    let ((mean, max), (rmean, rmax)) = (stats(&errors), stats(&render_errors));
    println!(
        "landmark disks: {} measured of {} observations; centroid vs GT projection: mean {mean:.4} px, max {max:.4} px; \
         vs exact projected-disk centroid: mean {rmean:.4} px, max {rmax:.4} px",
        errors.len(),
        seq.gt.reprojection_errors().len()
    );
    assert!(
        errors.len() >= 10,
        "only {} landmark disks measurable",
        errors.len()
    );
    assert!(max < 0.1, "max landmark error {max} px (mean {mean})");
    assert!(rmax < 0.1, "max rendering error {rmax} px (mean {rmean})");
}

#[test]
fn depth_maps_match_independent_ray_casting() {
    let seq = sequence();
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let (mut checked, mut empty) = (0, 0);
    for (i, depth) in seq.depths.iter().enumerate() {
        let view = seq.frame(i).expect("frame exists");
        let (cam, pose) = (&view.camera, &view.cam_from_world);
        for _ in 0..2000 {
            let (x, y) = (
                rng.random_range(0..cam.width as usize),
                rng.random_range(0..cam.height as usize),
            );
            let ray = cam.ray_in_cam(Vector2::new(x as f64, y as f64));
            let dir = pose.rotation.inverse() * ray;
            let d = depth.get(x, y, 0) as f64;
            match seq.scene.intersect(&center_of(pose), &dir) {
                Some(hit) => {
                    let zr = hit.t * ray.z;
                    assert!(
                        (d - zr).abs() <= 1e-5 * zr,
                        "frame {i} ({x},{y}): depth {d} vs ray cast {zr}"
                    );
                    checked += 1;
                }
                None => {
                    assert_eq!(d, 0.0);
                    empty += 1;
                }
            }
        }
    }
    assert!(checked > 4000, "{checked} hits, {empty} misses");

    // Back-projecting the (bilinearly interpolated) depth at landmark projections recovers the landmarks.
    let tol = 1e-3 * seq.scene.extent();
    let mut n = 0;
    let mut worst: f64 = 0.0;
    for point in seq.gt.points.values() {
        for el in &point.track.elements {
            let i = el.image_id.0 as usize;
            let view = seq.frame(i).expect("frame exists");
            let cam = &view.camera;
            let px = seq.gt.views[&el.image_id].observations[el.point2d_idx as usize].xy;
            let (x0, y0) = (px.x.floor(), px.y.floor());
            if x0 < 0.0 || y0 < 0.0 || x0 + 1.0 >= cam.width as f64 || y0 + 1.0 >= cam.height as f64
            {
                continue;
            }
            let (fx, fy) = (px.x - x0, px.y - y0);
            let g = |dx: usize, dy: usize| {
                seq.depths[i].get(x0 as usize + dx, y0 as usize + dy, 0) as f64
            };
            let ds = [g(0, 0), g(1, 0), g(0, 1), g(1, 1)];
            let (lo, hi) = ds
                .iter()
                .fold((f64::INFINITY, 0.0f64), |(a, b), &v| (a.min(v), b.max(v)));
            if lo <= 0.0 || hi - lo > 0.05 * lo {
                continue; // a depth edge next to the landmark (partly occluded)
            }
            let z = (1.0 - fy) * ((1.0 - fx) * ds[0] + fx * ds[1])
                + fy * ((1.0 - fx) * ds[2] + fx * ds[3]);
            let (o, d) = pixel_ray(&view, px);
            let err = ((o + d * z) - point.xyz).norm();
            worst = worst.max(err);
            n += 1;
        }
    }
    println!("depth back-projection at {n} landmark observations: worst {worst:.2e} m (tolerance {tol:.2e})");
    assert!(n >= 10 && worst < tol);
}

#[test]
fn gt_mesh_contains_landmarks_and_depth_points() {
    let seq = sequence();
    let res = small_options().mesh_resolution as f64;
    let r_max = seq
        .scene
        .primitives()
        .iter()
        .filter_map(|p| match p {
            Primitive::Sphere { radius, .. } => Some(*radius),
            _ => None,
        })
        .fold(0.0, f64::max);
    let sagitta = r_max * (1.0 - (std::f64::consts::PI / res).cos());
    for l in seq.scene.landmarks() {
        let d = distance_to_mesh(&seq.mesh, &l);
        assert!(d < 1e-5, "landmark {l:?} is {d} m off the mesh");
    }
    let view = seq.frame(1).expect("frame exists");
    let cam = &view.camera;
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let mut worst: f64 = 0.0;
    let mut n = 0;
    while n < 300 {
        let (x, y) = (
            rng.random_range(0..cam.width as usize),
            rng.random_range(0..cam.height as usize),
        );
        let z = seq.depths[1].get(x, y, 0) as f64;
        if z == 0.0 {
            continue;
        }
        let (o, d) = pixel_ray(&view, Vector2::new(x as f64, y as f64));
        worst = worst.max(distance_to_mesh(&seq.mesh, &(o + d * z)));
        n += 1;
    }
    println!("depth points to GT mesh: worst {worst:.2e} m (sphere sagitta bound {sagitta:.2e})");
    assert!(worst < sagitta + 1e-4);
    seq.mesh.validate().expect("valid mesh");
}

#[test]
fn rendering_is_deterministic_in_the_seed() {
    let opts = SequenceOptions {
        width: 96,
        height: 72,
        num_frames: 2,
        samples_per_axis: 2,
        seed: 5,
        ..SequenceOptions::default()
    };
    let a = render_sequence(&opts).expect("valid");
    let b = render_sequence(&opts).expect("valid");
    assert_eq!(a.images, b.images);
    assert_eq!(a.depths, b.depths);
    assert_eq!(a.gt, b.gt);
    let c = render_sequence(&SequenceOptions {
        seed: 6,
        ..opts.clone()
    })
    .expect("valid");
    assert_ne!(a.images, c.images);
    assert_ne!(a.gt, c.gt);
    // Noise alone differs between frames and seeds but never changes the depth.
    let d = render_sequence(&SequenceOptions {
        image_noise_sigma: 0.0,
        ..opts
    })
    .expect("valid");
    assert_eq!(a.depths, d.depths);
    assert_ne!(a.images, d.images);
}

#[test]
fn gt_reconstruction_is_exact_and_valid() {
    let seq = sequence();
    seq.gt.validate().expect("consistent GT");
    assert!(seq.gt.mean_reprojection_error() < 1e-9);
    assert_eq!(seq.gt.cameras.len(), 1);
    assert_eq!(seq.gt.views.len(), 3);
    assert_eq!(seq.gt.views[&ImageId(2)].name, "frame_0002.png");
    assert!(seq.gt.points.len() >= 10);
    let landmarks = seq.scene.landmarks();
    for (pid, p) in &seq.gt.points {
        assert_eq!(p.xyz, landmarks[pid.0 as usize]);
        assert!(p.track.len() >= 2);
    }
}

#[test]
fn other_paths_and_zoom_give_valid_ground_truth() {
    for (kind, zoom) in [
        (CameraPath::WalkThrough, None),
        (CameraPath::Forward, Some((1.0, 1.3))),
        (CameraPath::Orbit, Some((1.2, 0.9))),
        (CameraPath::Ring, None),
        (CameraPath::Hemisphere, None),
        (CameraPath::Corridor, None),
    ] {
        let path = match kind {
            CameraPath::Orbit => PathOptions::orbit(4),
            CameraPath::WalkThrough => PathOptions::walk_through(4),
            CameraPath::Forward => PathOptions::forward(4),
            CameraPath::Ring => PathOptions::ring(4),
            CameraPath::Hemisphere => PathOptions::hemisphere(4),
            // The first metre of the walk: four frames that see the same walls.
            CameraPath::Corridor => PathOptions {
                sweep: 1.0,
                ..PathOptions::corridor_walk(4)
            },
        };
        let opts = SequenceOptions {
            width: 80,
            height: 60,
            num_frames: 4,
            samples_per_axis: 1,
            path: PathOptions { zoom, ..path },
            ..SequenceOptions::default()
        };
        let seq = if kind == CameraPath::Corridor {
            render_sequence_with_scene(Scene::corridor_scene(opts.seed), &opts)
        } else {
            render_sequence(&opts)
        }
        .expect("valid");
        seq.gt.validate().expect("consistent GT");
        assert!(seq.gt.mean_reprojection_error() < 1e-9);
        assert_eq!(
            seq.gt.cameras.len(),
            if zoom.is_some() { 4 } else { 1 },
            "{kind:?}"
        );
        assert!(
            seq.gt.points.len() >= 10,
            "{kind:?}: {} points",
            seq.gt.points.len()
        );
        assert!(seq.depths.iter().all(|d| d.fill_ratio() > 0.5), "{kind:?}");
        let f: Vec<f64> = seq.gt.cameras.values().map(|c| c.intrinsics.f).collect();
        assert!(f.windows(2).all(|w| w[0] != w[1]));
    }
}

#[test]
fn invalid_options_are_rejected() {
    let bad = [
        SequenceOptions {
            width: 0,
            ..SequenceOptions::default()
        },
        SequenceOptions {
            num_frames: 0,
            ..SequenceOptions::default()
        },
        SequenceOptions {
            samples_per_axis: 0,
            ..SequenceOptions::default()
        },
        SequenceOptions {
            image_noise_sigma: f64::NAN,
            ..SequenceOptions::default()
        },
        SequenceOptions {
            k1: -0.6,
            k2: 0.0,
            ..SequenceOptions::default()
        },
        SequenceOptions {
            focal_px: Some(-1.0),
            ..SequenceOptions::default()
        },
    ];
    for o in &bad {
        assert!(o.validate().is_err(), "{o:?}");
        assert!(render_sequence(o).is_err());
    }
    assert!(SequenceOptions::default().validate().is_ok());
    let _ = Point3::<f64>::origin();
}
