//! Watertightness and orientation of the extracted surface on analytic shapes.

use super::*;
use crate::topology::edge_report;
use handheld_core::NoProgress;
use nalgebra::{Point3, Vector3};

fn extract(vol: &TsdfVolume) -> TriMesh {
    let opts = ExtractOptions {
        min_observations: 1,
        max_jump: 2.0,
        ..Default::default()
    };
    extract_mesh(vol, &opts, &NoProgress).unwrap()
}

fn euler(mesh: &TriMesh) -> i64 {
    let mut edges = std::collections::HashSet::new();
    for f in &mesh.faces {
        for k in 0..3 {
            edges.insert(crate::topology::edge_key(f[k], f[(k + 1) % 3]));
        }
    }
    mesh.vertices.len() as i64 - edges.len() as i64 + mesh.faces.len() as i64
}

fn p64(q: [f32; 3]) -> Point3<f64> {
    Point3::new(q[0] as f64, q[1] as f64, q[2] as f64)
}

#[test]
fn sphere_is_closed_outward_and_accurate() {
    // Off-grid centre so the surface crosses block boundaries at arbitrary places.
    let c = Point3::new(0.13, -0.21, 0.37);
    let r = 0.71;
    let vol = TsdfVolume::from_sdf(
        0.05,
        4.0,
        c - Vector3::repeat(1.0),
        c + Vector3::repeat(1.0),
        |p| (p - c).norm() - r,
    )
    .unwrap();
    assert!(vol.num_blocks() > 8, "the sphere spans many blocks");
    let mesh = extract(&vol);
    assert_eq!(
        edge_report(&mesh),
        (0, 0, 0),
        "closed, manifold, consistently oriented"
    );
    assert_eq!(euler(&mesh), 2, "one sphere: V − E + F = 2");
    for f in &mesh.faces {
        let [a, b, cc] = f.map(|i| p64(mesh.vertices.positions[i as usize]));
        let n = (b - a).cross(&(cc - a));
        let centroid = Point3::from((a.coords + b.coords + cc.coords) / 3.0);
        assert!(
            n.dot(&(centroid - c)) >= 0.0,
            "outward (CCW seen from outside)"
        );
    }
    for q in &mesh.vertices.positions {
        assert!(((p64(*q) - c).norm() - r).abs() < 0.05 * 0.1);
    }
}

#[test]
fn torus_and_ambiguous_noise_are_watertight() {
    let torus = |p: &Point3<f64>| {
        let q = (p.x * p.x + p.y * p.y).sqrt() - 0.6;
        (q * q + p.z * p.z).sqrt() - 0.25
    };
    let vol = TsdfVolume::from_sdf(
        0.04,
        4.0,
        Point3::new(-1.0, -1.0, -0.4),
        Point3::new(1.0, 1.0, 0.4),
        torus,
    )
    .unwrap();
    let mesh = extract(&vol);
    assert_eq!(edge_report(&mesh), (0, 0, 0));
    assert_eq!(euler(&mesh), 0, "genus one");
    // A wobbly blob at a resolution where many cubes hit the ambiguous face cases.
    let blob = |p: &Point3<f64>| {
        p.coords.norm() - 0.8 + 0.12 * (13.0 * p.x).sin() * (11.0 * p.y).sin() * (9.0 * p.z).sin()
    };
    let vol = TsdfVolume::from_sdf(
        0.06,
        16.0,
        Point3::new(-1.2, -1.2, -1.2),
        Point3::new(1.2, 1.2, 1.2),
        blob,
    )
    .unwrap();
    let mesh = extract(&vol);
    assert!(mesh.faces.len() > 1000);
    assert_eq!(edge_report(&mesh), (0, 0, 0));
}

#[test]
fn nothing_known_is_an_error_not_an_empty_mesh() {
    // Every voxel has weight 1, below the asked minimum: an error, not an empty mesh.
    let c = Point3::new(0.0, 0.0, 0.0);
    let vol = TsdfVolume::from_sdf(
        0.05,
        4.0,
        c - Vector3::repeat(1.0),
        c + Vector3::repeat(1.0),
        |p| (p - c).norm() - 0.5,
    )
    .unwrap();
    let opts = ExtractOptions {
        min_weight: 2.0,
        ..Default::default()
    };
    let err = extract_mesh(&vol, &opts, &NoProgress).unwrap_err();
    assert!(matches!(err, MeshError::EmptyResult { .. }), "{err}");
}
