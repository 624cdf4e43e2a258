use super::*;

#[test]
fn rays_hit_each_primitive_kind() {
    let s = Scene::new(vec![
        Primitive::Plane {
            origin: Point3::new(-1.0, -1.0, 0.0),
            edge_u: Vector3::new(2.0, 0.0, 0.0),
            edge_v: Vector3::new(0.0, 2.0, 0.0),
            texture: 1,
        },
        Primitive::Box {
            center: Point3::new(0.0, 0.0, 0.5),
            half_extents: Vector3::new(0.2, 0.3, 0.5),
            rotation: UnitQuaternion::identity(),
            texture: 2,
        },
        Primitive::Sphere {
            center: Point3::new(3.0, 0.0, 1.0),
            radius: 0.5,
            texture: 3,
        },
    ])
    .expect("valid");
    let h = s
        .intersect(&Point3::new(0.0, 0.0, 5.0), &Vector3::new(0.0, 0.0, -2.0))
        .expect("hits box top");
    assert_eq!((h.primitive, h.face), (1, 4));
    assert!((h.t - 2.0).abs() < 1e-12 && (h.normal - Vector3::z()).norm() < 1e-12);
    assert!((h.uv - Vector2::new(0.2, 0.3)).norm() < 1e-12);
    let h = s
        .intersect(&Point3::new(0.7, 0.7, 5.0), &Vector3::new(0.0, 0.0, -1.0))
        .expect("hits ground");
    assert_eq!(h.primitive, 0);
    assert!((h.uv - Vector2::new(1.7, 1.7)).norm() < 1e-12);
    let h = s
        .intersect(&Point3::new(3.0, -5.0, 1.0), &Vector3::new(0.0, 1.0, 0.0))
        .expect("hits sphere");
    assert_eq!(h.primitive, 2);
    assert!((h.point - Point3::new(3.0, -0.5, 1.0)).norm() < 1e-12);
    assert!(s
        .intersect(&Point3::new(5.0, 5.0, 5.0), &Vector3::new(0.0, 0.0, 1.0))
        .is_none());
}

#[test]
fn box_face_frames_are_right_handed_and_consistent_with_hits() {
    let s = Scene::new(vec![Primitive::Box {
        center: Point3::new(0.3, -0.2, 0.5),
        half_extents: Vector3::new(0.4, 0.3, 0.5),
        rotation: UnitQuaternion::from_euler_angles(0.1, 0.2, 0.7),
        texture: 2,
    }])
    .expect("valid");
    for f in 0..6 {
        let r = s.face_rect(0, f).expect("box face");
        let uv = Vector2::new(0.3 * r.size.x, 0.6 * r.size.y);
        let p = r.point(&uv);
        let h = s
            .intersect(&(p + r.normal * 2.0), &(-r.normal))
            .expect("face is hit from outside");
        assert_eq!(h.face, f);
        assert!((h.uv - uv).norm() < 1e-9 && (h.normal - r.normal).norm() < 1e-12);
    }
}

#[test]
fn default_scene_has_landmarks_outside_solids() {
    let s = Scene::default_scene(7);
    assert!(s.primitives().len() >= 5);
    assert!(s.landmarks().len() > 40, "{}", s.landmarks().len());
    for l in s.landmark_info() {
        assert!(!s.inside_solid(&(l.position + l.normal * 1e-4), Some(l.primitive)));
    }
    let (lo, hi) = s.bounds();
    assert!(lo.x <= -3.0 && hi.x >= 3.0 && (s.extent() - (hi - lo).norm()).abs() < 1e-12);
}
