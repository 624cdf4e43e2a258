//! The ground-truth triangle mesh of a [`Scene`] and a brute-force point-to-mesh distance for checks.
//!
//! Planes become two triangles, boxes twelve (four vertices per face, so face normals stay flat),
//! spheres a latitude/longitude tessellation with `resolution` rings and `2·resolution` segments whose
//! vertices lie on the sphere (the mesh is inscribed: it deviates inwards by at most the sagitta
//! `r·(1 − cos(π/resolution))`). Triangles are counter-clockwise seen from the outside (from the
//! `edge_u × edge_v` side for planes); vertex normals are area-weighted from the faces.

/// Distance from a point to a triangle (Ericson §5.1.5), shared with `handheld-mesh` through
/// `handheld_core::closest` and re-exported here for the tests that use it.
pub use handheld_core::closest::point_triangle_distance;
use handheld_core::{PointCloud, TriMesh};
use nalgebra::{Point3, Vector2, Vector3};

use crate::scene::{Primitive, Scene};

fn push_vertex(mesh: &mut TriMesh, p: &Point3<f64>) -> u32 {
    mesh.vertices
        .positions
        .push([p.x as f32, p.y as f32, p.z as f32]);
    (mesh.vertices.positions.len() - 1) as u32
}

impl Scene {
    /// The scene as a triangle mesh; `resolution` (≥ 3) is the number of latitude rings per sphere.
    pub fn to_mesh(&self, resolution: usize) -> TriMesh {
        let res = resolution.max(3);
        let mut mesh = TriMesh {
            vertices: PointCloud::default(),
            uvs: Vec::new(),
            faces: Vec::new(),
        };
        for (k, prim) in self.primitives().iter().enumerate() {
            match prim {
                Primitive::Plane { .. } | Primitive::Box { .. } => {
                    let n_faces = if matches!(prim, Primitive::Plane { .. }) {
                        1
                    } else {
                        6
                    };
                    for f in 0..n_faces {
                        let Some(r) = self.face_rect(k, f) else {
                            continue;
                        };
                        let corners = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)];
                        let ids: Vec<u32> = corners
                            .iter()
                            .map(|&(a, b)| {
                                push_vertex(
                                    &mut mesh,
                                    &r.point(&Vector2::new(a * r.size.x, b * r.size.y)),
                                )
                            })
                            .collect();
                        mesh.faces.push([ids[0], ids[1], ids[2]]);
                        mesh.faces.push([ids[0], ids[2], ids[3]]);
                    }
                }
                Primitive::Sphere { center, radius, .. } => {
                    let segs = 2 * res;
                    let at = |theta: f64, phi: f64| {
                        center
                            + Vector3::new(
                                theta.sin() * phi.cos(),
                                theta.sin() * phi.sin(),
                                theta.cos(),
                            ) * *radius
                    };
                    let top = push_vertex(&mut mesh, &at(0.0, 0.0));
                    let first = mesh.vertices.positions.len() as u32;
                    for i in 1..res {
                        let theta = std::f64::consts::PI * i as f64 / res as f64;
                        for j in 0..segs {
                            push_vertex(
                                &mut mesh,
                                &at(theta, std::f64::consts::TAU * j as f64 / segs as f64),
                            );
                        }
                    }
                    let bottom = push_vertex(&mut mesh, &at(std::f64::consts::PI, 0.0));
                    let idx = |i: usize, j: usize| first + ((i - 1) * segs + j % segs) as u32;
                    for j in 0..segs {
                        mesh.faces.push([top, idx(1, j), idx(1, j + 1)]);
                        for i in 1..res - 1 {
                            let (a, b, c, d) =
                                (idx(i, j), idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1));
                            mesh.faces.push([a, b, c]);
                            mesh.faces.push([a, c, d]);
                        }
                        mesh.faces
                            .push([idx(res - 1, j), bottom, idx(res - 1, j + 1)]);
                    }
                }
            }
        }
        mesh.compute_vertex_normals();
        mesh
    }
}

/// Distance from `p` to the nearest triangle of `mesh` (brute force; meant for tests and evaluation).
pub fn distance_to_mesh(mesh: &TriMesh, p: &Point3<f64>) -> f64 {
    let v = |i: u32| {
        let q = mesh.vertices.positions[i as usize];
        Point3::new(q[0] as f64, q[1] as f64, q[2] as f64)
    };
    mesh.faces
        .iter()
        .map(|f| point_triangle_distance(p, &v(f[0]), &v(f[1]), &v(f[2])))
        .fold(f64::INFINITY, f64::min)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mesh_is_valid_closed_where_solid_and_outward() {
        let scene = Scene::default_scene(3);
        let mesh = scene.to_mesh(16);
        mesh.validate().expect("valid mesh");
        // Outward orientation: every triangle's normal points away from the centre of its solid.
        let p = |i: u32| {
            let q = mesh.vertices.positions[i as usize];
            Point3::new(q[0] as f64, q[1] as f64, q[2] as f64)
        };
        let mut checked = 0;
        for f in &mesh.faces {
            let (a, b, c) = (p(f[0]), p(f[1]), p(f[2]));
            let n = (b - a).cross(&(c - a));
            if n.norm() < 1e-9 {
                continue;
            }
            let centroid = Point3::from((a.coords + b.coords + c.coords) / 3.0);
            for prim in scene.primitives() {
                let centre = match prim {
                    Primitive::Sphere { center, radius, .. }
                        if ((centroid - center).norm() - radius).abs() < 0.05 =>
                    {
                        *center
                    }
                    _ => continue,
                };
                assert!(n.dot(&(centroid - centre)) > 0.0);
                checked += 1;
            }
        }
        assert!(checked > 100);
    }
}
