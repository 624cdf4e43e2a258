//! Occlusion and automatic placement, against exact answers.

use super::*;
use handheld_core::FloatMap;
use handheld_core::{Camera, CameraId, Intrinsics, Rigid3};
use image::RgbImage;

/// A real box face (a plane at z = 3, for x < edge) passes in front of the virtual box (at
/// z ≈ 5): the object's pixels are hidden exactly where the real surface is nearer, to
/// within one pixel of the true occlusion edge, for three positions of the edge.
#[test]
fn a_real_box_in_front_hides_the_object_up_to_its_edge() {
    let mut intr = Intrinsics::pinhole(300.0, 159.5, 119.5);
    intr.k1 = -0.05;
    let camera = Camera {
        id: CameraId(0),
        width: 320,
        height: 240,
        intrinsics: intr,
    };
    let view = PosedCamera::new(camera, Rigid3::identity());
    let (obj, tex) = object_box();
    let placement = Placement::new(
        2.0,
        &Rotation3::from_axis_angle(&Vector3::y_axis(), 0.4),
        &Vector3::new(0.0, -1.0, 5.0),
    );
    let placed = placement.transform(&obj);
    let (w, h) = (320usize, 240usize);
    for edge_x in [-0.6, -0.1, 0.35] {
        // The occluder's depth per pixel centre: z = 3 where x < edge_x on that plane.
        let mut depth = FloatMap::filled(w, h, 1, f32::NAN);
        let mut edge_px = f64::NAN;
        for y in 0..h {
            for x in 0..w {
                let n = intr.pixel_to_normalized(Vector2::new(x as f64, y as f64));
                if n.x * 3.0 < edge_x {
                    depth.data[y * w + x] = 3.0;
                }
            }
        }
        let mut frame = RgbImage::new(320, 240);
        let mut unoccluded = RgbImage::new(320, 240);
        let mut c = Compositor::new();
        let s = c.composite(&mut frame, &placed, Some(&tex), &view, Some(&depth));
        c.composite(&mut unoccluded, &placed, Some(&tex), &view, None);
        assert!(
            s.hidden_samples > 0 || edge_x < -0.5,
            "{edge_x}: nothing hidden"
        );
        for y in 0..h {
            for x in 0..w {
                let drawn = frame.get_pixel(x as u32, y as u32).0 != [0, 0, 0];
                let full = unoccluded.get_pixel(x as u32, y as u32).0 != [0, 0, 0];
                // The true edge through this row, in pixels (distortion included).
                let n = intr.pixel_to_normalized(Vector2::new(x as f64, y as f64));
                let at_edge = intr.normalized_to_pixel(Vector2::new(edge_x / 3.0, n.y));
                edge_px = at_edge.x;
                let d = x as f64 - at_edge.x;
                if d < -1.0 {
                    assert!(!drawn, "{edge_x}: ({x}, {y}) drawn behind the real box");
                } else if d > 1.0 {
                    assert_eq!(drawn, full, "{edge_x}: ({x}, {y}) hidden in the open");
                }
            }
        }
        assert!(edge_px.is_finite());
    }
}

/// The automatic placement stands the object on the ground plane of a point set, upright,
/// at the point most cameras see, with the requested height.
#[test]
fn auto_placement_stands_on_the_ground() {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    // Ground z = 0 (world up +z), a wall at y = 4, cameras at z = 1.5 looking along +y.
    let mut points = Vec::new();
    for _ in 0..600 {
        let p = Point3::new(rng.random_range(-3.0..3.0), rng.random_range(0.0..4.0), 0.0);
        points.push((p, 5));
    }
    for _ in 0..900 {
        let p = Point3::new(rng.random_range(-3.0..3.0), 4.0, rng.random_range(0.0..2.5));
        points.push((p, 8));
    }
    let cams: Vec<Rigid3> = (0..5)
        .map(|i| {
            let c = Point3::new(-1.0 + 0.5 * f64::from(i), -3.0, 1.5);
            crate::path::look_at(&c, &Point3::new(0.0, 2.0, 0.3), &Vector3::z()).unwrap()
        })
        .collect();
    let (obj, _) = object_box();
    let (p, r) = auto_place(&obj, &points, &cams, &PlaceOptions::default()).unwrap();
    // The ground (a few wall points at its foot tilt the refit by a fraction of a degree).
    let n = Vector3::from(r.plane.normal);
    assert!((n - Vector3::z()).norm() < 0.01, "{n}");
    assert!(r.anchor[2].abs() < 0.01);
    // Upright on that plane: the object's +Y along its normal, its base on it.
    let up = p.rotation_matrix() * Vector3::y();
    assert!((up - n).norm() < 1e-9);
    let base = p.apply(&Point3::new(0.0, 0.0, 0.0));
    assert!((n.dot(&base.coords) - r.plane.d).abs() < 1e-9);
    let top = p.apply(&Point3::new(0.0, 1.0, 0.0));
    assert!((n.dot(&top.coords) - r.plane.d - r.height).abs() < 1e-9);
}

/// Without a mesh, a key-frame's depth map warped into the frame stands in for the scene: a real
/// half-plane at z = 3 (x < edge) seen by a half-size key-frame 0.3 to the side gives the frame's
/// exact depth up to two pixels from the edge, and nothing where the plane is not.
#[test]
fn a_key_frame_depth_map_warped_into_the_frame_hides_the_object() {
    let intr = Intrinsics::pinhole(300.0, 159.5, 119.5);
    let camera = Camera {
        id: CameraId(0),
        width: 320,
        height: 240,
        intrinsics: intr,
    };
    let view = PosedCamera::new(camera.clone(), Rigid3::identity());
    let small = camera.scaled(0.5, 0.5);
    let key_pose = Rigid3::translation(-0.3, 0.0, 0.0); // centre at x = +0.3
    let (sw, sh) = (small.width as usize, small.height as usize);
    let edge_x = 0.2;
    let mut depth = FloatMap::filled(sw, sh, 1, f32::NAN);
    for y in 0..sh {
        for x in 0..sw {
            let n = small
                .intrinsics
                .pixel_to_normalized(Vector2::new(x as f64, y as f64));
            if 0.3 + 3.0 * n.x < edge_x {
                depth.data[y * sw + x] = 3.0;
            }
        }
    }
    let key = DepthSource {
        name: "key".into(),
        posed: PosedCamera::new(small, key_pose),
        depth,
    };
    let (obj, _) = object_box();
    let placed =
        Placement::new(2.0, &Rotation3::identity(), &Vector3::new(-0.5, -1.0, 5.0)).transform(&obj);
    let sources = [key];
    let near = nearest_sources(&sources, "frame", &view);
    assert_eq!(near.len(), 1);
    let mut out = FloatMap::filled(0, 0, 1, 0.0);
    warped_depth(&near, &view, &placed, &mut out);
    let edge_px = intr.normalized_to_pixel(Vector2::new(edge_x / 3.0, 0.0)).x;
    // Where the object shows (drawn without occlusion), the warped depth is the plane's left of
    // the edge and nothing right of it.
    let mut c = Compositor::new();
    let mut full = RgbImage::new(320, 240);
    c.composite(&mut full, &placed, None, &view, None);
    let (mut behind, mut open) = (0, 0);
    for y in 0..240usize {
        for x in 0..320usize {
            let d = out.data[y * 320 + x];
            let dx = x as f64 - edge_px;
            if d.is_finite() {
                assert!((d - 3.0).abs() < 1e-3, "({x}, {y}): {d}");
                assert!(dx < 2.0, "({x}, {y}) covered right of the edge");
            }
            if full.get_pixel(x as u32, y as u32).0 == [0, 0, 0] {
                continue;
            }
            if dx < -2.0 {
                assert!(
                    d.is_finite(),
                    "({x}, {y}): the object shows behind the plane"
                );
                behind += 1;
            } else if dx > 2.0 {
                open += 1;
            }
        }
    }
    assert!(
        behind > 500 && open > 500,
        "{behind} pixels behind, {open} in the open"
    );
    let mut frame = RgbImage::new(320, 240);
    let s = c.composite(&mut frame, &placed, None, &view, Some(&out));
    assert!(s.hidden_samples > 0, "the plane hides part of the object");
}

/// A camera driving past the object: once the anchor leaves the image (beside the camera, where it
/// projects thousands of pixels out), the track drops it, so the jitter measures the object where
/// the frames show it.
#[test]
fn the_anchor_track_keeps_only_frames_that_show_it() {
    use handheld_testkit::path::PathOptions;
    use handheld_testkit::render::{render_sequence, SequenceOptions};
    let seq = render_sequence(&SequenceOptions {
        width: 160,
        height: 120,
        num_frames: 12,
        path: PathOptions::forward(12),
        samples_per_axis: 1,
        ..Default::default()
    })
    .expect("sequence");
    let rec = &seq.gt;
    // An anchor 1.2 m ahead of the first camera and 0.5 m to its side: the 1.6 m drive passes it.
    let first = rec.views.values().next().expect("a view");
    let c0 = first.center();
    let rot = first.cam_from_world.rotation.inverse();
    let anchor = c0 + rot * Vector3::new(0.5, 0.0, 1.2);
    let (obj, _) = object_box();
    let placed = Placement::new(0.05, &Rotation3::identity(), &anchor.coords).transform(&obj);
    let mut frames = FrameLoop::new(rec, &placed, None, None, anchor, 10.0);
    for v in rec.views.values() {
        let cam = &rec.cameras[&v.camera_id];
        let mut img = RgbImage::new(cam.width, cam.height);
        frames.frame(&v.name, None, &mut img);
    }
    let shown = frames
        .per_frame
        .iter()
        .filter(|f| f.anchor_px.is_some())
        .count();
    assert!(
        shown >= 2 && shown < frames.per_frame.len(),
        "{shown} frames show the anchor"
    );
    for f in &frames.per_frame {
        if let Some([x, y]) = f.anchor_px {
            assert!(
                (-0.5..160.0).contains(&x) && (-0.5..120.0).contains(&y),
                "{x}, {y}"
            );
        }
    }
    assert!(frames.jitter() < 20.0, "jitter {}", frames.jitter());
}
