use handheld_core::{pose::cam_from_world_from_center, Camera, CameraId, Intrinsics, Rigid3};
use nalgebra::{Rotation3, Vector2, Vector3};

use super::*;

fn camera(k1: f64) -> Camera {
    Camera {
        id: CameraId(0),
        width: 640,
        height: 480,
        intrinsics: Intrinsics {
            f: 520.0,
            aspect: 1.0,
            skew: 0.0,
            pp: Vector2::new(318.0, 242.0),
            k1,
            k2: 0.0,
        },
    }
}

fn pose(center: [f64; 3], yaw: f64, pitch: f64) -> Rigid3 {
    let r = Rotation3::from_euler_angles(pitch, yaw, 0.0);
    cam_from_world_from_center(&r, &Point3::from(Vector3::from(center)))
}

/// World points spread over both views' fields of view, 2–8 units in front of camera 1.
fn points(view1: &PosedCamera) -> Vec<Point3<f64>> {
    let (cam, inv) = (&view1.camera, view1.cam_from_world.inverse());
    let mut out = Vec::new();
    for i in 0..40 {
        for j in 0..30 {
            let px = Vector2::new(8.0 + i as f64 * 15.7, 6.0 + j as f64 * 15.9);
            let ray = cam.ray_in_cam(px);
            let depth = 2.0 + ((i * 7 + j * 13) % 17) as f64 * 0.35;
            out.push(inv.transform_point(&Point3::from(ray / ray.z * depth)));
        }
    }
    out
}

/// Corresponding points land on the same rectified row, and the maps invert each other.
fn check_rows(rect: &Rectification, pts: &[Point3<f64>], min_seen: usize) -> f64 {
    let mut worst = 0.0f64;
    let mut seen = 0;
    for p in pts {
        let (Some(m0), Some(m1)) = (rect.project(0, p), rect.project(1, p)) else {
            continue;
        };
        let (Some(r0), Some(r1)) = (rect.to_rect(0, m0), rect.to_rect(1, m1)) else {
            continue;
        };
        seen += 1;
        worst = worst.max((r0.y - r1.y).abs());
        for (side, m, r) in [(0, m0, r0), (1, m1, r1)] {
            let back = rect.from_rect(side, r).expect("inverse map");
            assert!((back - m).norm() < 1e-6, "R⁻¹(R(m)) = {back} for {m}");
        }
    }
    assert!(seen >= min_seen, "only {seen} points seen in both views");
    worst
}

#[test]
fn polar_rectification_aligns_rows_under_forward_motion() {
    // The camera walks forward and turns slightly: both epipoles lie inside the images.
    let cam = camera(-0.12);
    let (p1, p2) = (
        pose([0.0, 0.0, 0.0], 0.0, 0.0),
        pose([0.05, -0.02, 0.6], 0.03, 0.01),
    );
    let rect = rectify_pair(
        &PosedCamera::new(cam.clone(), p1),
        &PosedCamera::new(cam.clone(), p2),
        &RectifyOptions::default(),
    )
    .unwrap();
    assert!(rect.is_polar());
    let worst = check_rows(&rect, &points(&PosedCamera::new(cam.clone(), p1)), 500);
    assert!(worst < 0.1, "row error {worst} px");
    let (w, h) = rect.size();
    assert!(w < 1000 && h < 5000, "rectified size {w}x{h}");
}

#[test]
fn planar_rectification_aligns_rows_for_sideways_motion() {
    let cam = camera(-0.08);
    let (p1, p2) = (
        pose([0.0, 0.0, 0.0], 0.0, 0.0),
        pose([0.4, 0.03, 0.05], -0.05, 0.02),
    );
    let rect = rectify_pair(
        &PosedCamera::new(cam.clone(), p1),
        &PosedCamera::new(cam.clone(), p2),
        &RectifyOptions::default(),
    )
    .unwrap();
    assert!(!rect.is_polar());
    let worst = check_rows(&rect, &points(&PosedCamera::new(cam.clone(), p1)), 500);
    assert!(worst < 0.1, "row error {worst} px");
    let opts = RectifyOptions {
        method: RectifyMethod::Polar,
        ..Default::default()
    };
    let polar = rectify_pair(
        &PosedCamera::new(cam.clone(), p1),
        &PosedCamera::new(cam.clone(), p2),
        &opts,
    )
    .unwrap();
    assert!(check_rows(&polar, &points(&PosedCamera::new(cam.clone(), p1)), 500) < 0.1);
    let rect_of = |r: &Rectification, p: &Point3<f64>| {
        let a = r.to_rect(0, r.project(0, p).unwrap()).unwrap();
        let b = r.to_rect(1, r.project(1, p).unwrap()).unwrap();
        (a, b)
    };
    // Planar: nearer points have larger disparities (left x − right x).
    let (near, far) = (Point3::new(0.1, 0.05, 2.0), Point3::new(0.1, 0.05, 8.0));
    let d = |p| {
        let (a, b) = rect_of(&rect, p);
        a.x - b.x
    };
    assert!(d(&near) > d(&far), "disparity ordering");
    // Both keep the order of points along a row (the ordering constraint of §4.2).
    for r in [&rect, &polar] {
        let (a0, b0) = rect_of(r, &Point3::new(-0.3, 0.0, 4.0));
        let (a1, b1) = rect_of(r, &Point3::new(0.3, 0.0, 4.0));
        assert_eq!(a1.x > a0.x, b1.x > b0.x, "order along the row");
    }
}

#[test]
fn backward_motion_and_disparity_range() {
    let cam = camera(0.0);
    let (p1, p2) = (
        pose([0.0, 0.0, 0.0], 0.0, 0.0),
        pose([0.0, 0.1, -0.5], 0.0, 0.05),
    );
    let rect = rectify_pair(
        &PosedCamera::new(cam.clone(), p1),
        &PosedCamera::new(cam.clone(), p2),
        &RectifyOptions::default(),
    )
    .unwrap();
    let pts = points(&PosedCamera::new(cam.clone(), p1));
    assert!(check_rows(&rect, &pts, 300) < 0.1);
    let (lo, hi) = rect.disparity_range(&pts, 0.1).unwrap();
    assert!(lo < hi);
}

#[test]
fn coincident_centres_are_an_error() {
    let cam = camera(0.0);
    let p = pose([0.0, 0.0, 0.0], 0.0, 0.0);
    let q = pose([0.0, 0.0, 0.0], 0.1, 0.0);
    assert!(rectify_pair(
        &PosedCamera::new(cam.clone(), p),
        &PosedCamera::new(cam.clone(), q),
        &RectifyOptions::default()
    )
    .is_err());
}

/// The range covers most of the image, not most of the points: on a street most sparse points are
/// far, and the few on the near road (under 1 % of the points, a fifth of the image) must still be
/// in range; a few stray points among many in their part of the image are not.
#[test]
fn the_disparity_range_weighs_points_by_the_image_area_they_stand_for() {
    let mut ds: Vec<(Vector2<f64>, f64)> = Vec::new();
    // The upper 80 % of a 640×480 image: 4000 far points, disparities 0..10 px.
    for i in 0..4000 {
        let (x, y) = ((i * 37 % 640) as f64, (i * 91 % 384) as f64);
        ds.push((Vector2::new(x, y), 10.0 * i as f64 / 3999.0));
    }
    // The lower 20 %: 30 near points (0.7 % of all), 30..40 px.
    for i in 0..30 {
        let (x, y) = ((i * 23 % 640) as f64, 390.0 + (i * 7 % 90) as f64);
        ds.push((Vector2::new(x, y), 30.0 + i as f64 / 3.0));
    }
    // Five stray points among the far ones, at 300 px.
    for i in 0..5 {
        ds.push((Vector2::new(100.0 + i as f64, 100.0), 300.0));
    }
    let (lo, hi) = area_weighted_bounds(&ds, 0.01);
    assert!(lo < 0.5, "{lo}");
    assert!(
        (35.0..40.0).contains(&hi),
        "the near points are in range, the stray ones not: {hi}"
    );
    // By point count alone, the same trim would lose the near road.
    let mut by_count: Vec<f64> = ds.iter().map(|p| p.1).collect();
    by_count.sort_by(f64::total_cmp);
    assert!(by_count[by_count.len() - 1 - by_count.len() / 100] < 11.0);
}
