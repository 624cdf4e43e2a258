//! Watertight where observed: boundary loops, hole filling and non-manifold repair.
//!
//! A fused surface has two kinds of open boundary. The *outer* boundary of each connected piece is
//! where observation stops (the edge of what the cameras saw); it stays open. Every other loop is a
//! *hole* inside observed surface (a patch the depth maps missed, a specular spot, a thin occluded
//! strip), and small holes are closed here, so that the model is watertight wherever it was
//! observed.
//!
//! * Loops are traced over directed border half-edges; a loop that passes a vertex twice (a pinch
//!   vertex) is split there, so every loop is simple.
//! * In each connected piece the longest loop is its outer boundary, unless it is short against the
//!   piece's own size (a hole in a closed object, e.g. its unobserved underside).
//! * A hole is triangulated by ear clipping (Meisters 1975) in the plane of its Newell normal,
//!   smallest interior angle first, as in the advancing-front fill of Zhao, Gao & Lin (*A robust
//!   hole-filling algorithm for triangular mesh*, 2007). A diagonal that already exists as a mesh edge
//!   is never used, so the fill cannot create a non-manifold edge. Where the projection folds (no ear
//!   left), the rest of the hole is closed by a fan around its centroid.
//! * New triangles keep the orientation of their neighbours (each border half-edge `a → b` gets
//!   the twin `b → a`).
//!
//! [`remove_non_manifold`] deletes the faces around edges shared by more than two faces (or used
//! twice in one direction), which quadric simplification can create; the holes this leaves are
//! small and [`fill_holes`] closes them.

use std::collections::{HashMap, HashSet};

use handheld_core::TriMesh;
use nalgebra::{Vector2, Vector3};

use crate::topology::{edge_key, face_components};

/// Options of [`fill_holes`].
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct HoleFillOptions {
    /// Holes whose boundary is longer than this (world units) stay open; 0 fills none.
    pub max_perimeter: f64,
    /// Holes with more boundary edges than this stay open. Default 3000.
    pub max_edges: usize,
    /// A piece's longest loop counts as a hole (not its outer boundary) when its length is below
    /// this fraction of the piece's bounding-box diagonal. An open disk's outline is about 2.2
    /// diagonals long, a missing cap on a closed object well under one. Default 1.0.
    pub closed_piece_ratio: f64,
}

impl Default for HoleFillOptions {
    fn default() -> Self {
        Self {
            max_perimeter: f64::INFINITY,
            max_edges: 3000,
            closed_piece_ratio: 1.0,
        }
    }
}

/// One closed loop of border edges, in the direction of the faces that own them.
#[derive(Clone, Debug, PartialEq)]
pub struct BoundaryLoop {
    pub vertices: Vec<u32>,
    /// Length of the loop (world units).
    pub perimeter: f64,
    /// Connected piece (label of [`face_components`]).
    pub component: u32,
    /// The outer boundary of its piece (where observation stops), not a hole.
    pub outer: bool,
}

/// What [`fill_holes`] found and did.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct HoleReport {
    /// Outer boundaries (one per open piece) and holes found.
    pub outer_loops: usize,
    pub holes: usize,
    /// Holes closed, faces and centroid vertices added.
    pub filled: usize,
    pub faces_added: usize,
    pub vertices_added: usize,
    /// Holes left open (too long), and the longest of them (world units, 0 if none).
    pub holes_open: usize,
    pub largest_open_perimeter: f64,
}

fn pos(mesh: &TriMesh, v: u32) -> Vector3<f64> {
    let p = mesh.vertices.positions[v as usize];
    Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64)
}

/// All boundary loops of `mesh`, each simple (no repeated vertex), classified outer or hole.
pub fn boundary_loops(mesh: &TriMesh, closed_piece_ratio: f64) -> Vec<BoundaryLoop> {
    let mut directed: HashMap<(u32, u32), u32> = HashMap::with_capacity(mesh.faces.len() * 3);
    for (fi, f) in mesh.faces.iter().enumerate() {
        for k in 0..3 {
            directed.insert((f[k], f[(k + 1) % 3]), fi as u32);
        }
    }
    // Border half-edges, grouped by their start vertex.
    let mut out: HashMap<u32, Vec<(u32, u32)>> = HashMap::new();
    let mut border: Vec<(u32, u32)> = directed
        .keys()
        .filter(|&&(a, b)| !directed.contains_key(&(b, a)))
        .copied()
        .collect();
    border.sort_unstable();
    for &(a, b) in &border {
        out.entry(a).or_default().push((b, directed[&(a, b)]));
    }
    let (labels, _) = face_components(mesh);
    let mut used: HashSet<(u32, u32)> = HashSet::with_capacity(border.len());
    let mut loops = Vec::new();
    for &(a0, b0) in &border {
        if used.contains(&(a0, b0)) {
            continue;
        }
        used.insert((a0, b0));
        let component = labels[directed[&(a0, b0)] as usize];
        let mut path = vec![a0];
        let mut at: HashMap<u32, usize> = HashMap::from([(a0, 0)]);
        let mut cur = b0;
        loop {
            if let Some(&i) = at.get(&cur) {
                // Closed a loop (the whole path when i = 0, else a sub-loop at a pinch vertex).
                let sub: Vec<u32> = path.split_off(i);
                for v in &sub {
                    at.remove(v);
                }
                loops.push((sub, component));
                if path.is_empty() {
                    break;
                }
            }
            at.insert(cur, path.len());
            path.push(cur);
            let next = out
                .get(&cur)
                .and_then(|c| c.iter().find(|&&(b, _)| !used.contains(&(cur, b))));
            match next {
                Some(&(b, _)) => {
                    used.insert((cur, b));
                    cur = b;
                }
                None => break, // an open chain (inconsistent orientation); not a loop
            }
        }
    }
    let mut result: Vec<BoundaryLoop> = loops
        .into_iter()
        .filter(|(l, _)| l.len() >= 3)
        .map(|(vertices, component)| {
            let n = vertices.len();
            let perimeter = (0..n)
                .map(|i| (pos(mesh, vertices[(i + 1) % n]) - pos(mesh, vertices[i])).norm())
                .sum();
            BoundaryLoop {
                vertices,
                perimeter,
                component,
                outer: false,
            }
        })
        .collect();
    // The longest loop of each piece is its outer boundary unless short against the piece.
    let ncomp = labels.iter().map(|&l| l as usize + 1).max().unwrap_or(0);
    let mut lo = vec![Vector3::repeat(f64::INFINITY); ncomp];
    let mut hi = vec![Vector3::repeat(f64::NEG_INFINITY); ncomp];
    for (f, &l) in mesh.faces.iter().zip(&labels) {
        for &v in f {
            let p = pos(mesh, v);
            lo[l as usize] = lo[l as usize].inf(&p);
            hi[l as usize] = hi[l as usize].sup(&p);
        }
    }
    let mut longest: HashMap<u32, usize> = HashMap::new();
    for (i, l) in result.iter().enumerate() {
        let e = longest.entry(l.component).or_insert(i);
        if result[*e].perimeter < l.perimeter {
            *e = i;
        }
    }
    for (&c, &i) in &longest {
        let diag = (hi[c as usize] - lo[c as usize]).norm();
        result[i].outer = result[i].perimeter >= closed_piece_ratio * diag;
    }
    result
}

/// Ear-clipping triangulation of one hole; `None` when no valid ear remains (the caller fans).
/// Triangles are `(next, v, prev)`, the twins of the loop's half-edges.
fn clip_ears(
    mesh: &TriMesh,
    hole: &[u32],
    edges: &mut HashSet<(u32, u32)>,
) -> (Vec<[u32; 3]>, Vec<u32>) {
    let p3: Vec<Vector3<f64>> = hole.iter().map(|&v| pos(mesh, v)).collect();
    let n = hole.len();
    let mut normal = Vector3::zeros();
    for i in 0..n {
        normal += p3[i].cross(&p3[(i + 1) % n]);
    }
    let mut faces = Vec::with_capacity(n.saturating_sub(2));
    let mut ring: Vec<usize> = (0..n).collect();
    if normal.norm() < 1e-20 {
        return (faces, ring.iter().map(|&i| hole[i]).collect());
    }
    let nz = normal.normalize();
    let ax = if nz.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let ux = nz.cross(&ax).normalize();
    let uy = nz.cross(&ux);
    let p2: Vec<Vector2<f64>> = p3
        .iter()
        .map(|p| Vector2::new(p.dot(&ux), p.dot(&uy)))
        .collect();
    let cross = |a: Vector2<f64>, b: Vector2<f64>| a.x * b.y - a.y * b.x;
    while ring.len() > 3 {
        let m = ring.len();
        // Convex corners by interior angle (the loop runs counter-clockwise about `nz`).
        let mut cands: Vec<(f64, usize)> = (0..m)
            .filter_map(|k| {
                let (a, b, c) = (ring[(k + m - 1) % m], ring[k], ring[(k + 1) % m]);
                let (e1, e2) = (p2[b] - p2[a], p2[c] - p2[b]);
                if cross(e1, e2) <= 0.0 {
                    return None;
                }
                let angle = (p3[a] - p3[b]).angle(&(p3[c] - p3[b]));
                Some((angle, k))
            })
            .collect();
        cands.sort_by(|x, y| x.0.total_cmp(&y.0));
        let ear = cands.into_iter().map(|(_, k)| k).find(|&k| {
            let (a, b, c) = (ring[(k + m - 1) % m], ring[k], ring[(k + 1) % m]);
            if edges.contains(&edge_key(hole[a], hole[c])) {
                return false;
            }
            ring.iter().all(|&q| {
                if q == a || q == b || q == c {
                    return true;
                }
                let s1 = cross(p2[b] - p2[a], p2[q] - p2[a]);
                let s2 = cross(p2[c] - p2[b], p2[q] - p2[b]);
                let s3 = cross(p2[a] - p2[c], p2[q] - p2[c]);
                !(s1 >= 0.0 && s2 >= 0.0 && s3 >= 0.0)
            })
        });
        let Some(k) = ear else {
            break;
        };
        let (a, b, c) = (ring[(k + m - 1) % m], ring[k], ring[(k + 1) % m]);
        faces.push([hole[c], hole[b], hole[a]]);
        edges.insert(edge_key(hole[a], hole[c]));
        ring.remove(k);
    }
    if ring.len() == 3 {
        let (a, b, c) = (ring[0], ring[1], ring[2]);
        faces.push([hole[c], hole[b], hole[a]]);
        ring.clear();
    }
    (faces, ring.iter().map(|&i| hole[i]).collect())
}

/// Closes the holes of `mesh` (see the module notes) and recomputes its normals when it changed.
pub fn fill_holes(mesh: &mut TriMesh, opts: &HoleFillOptions) -> HoleReport {
    let loops = boundary_loops(mesh, opts.closed_piece_ratio);
    let mut report = HoleReport::default();
    let mut edges: HashSet<(u32, u32)> = mesh
        .faces
        .iter()
        .flat_map(|f| (0..3).map(move |k| edge_key(f[k], f[(k + 1) % 3])))
        .collect();
    for l in &loops {
        if l.outer {
            report.outer_loops += 1;
            continue;
        }
        report.holes += 1;
        if l.perimeter > opts.max_perimeter || l.vertices.len() > opts.max_edges {
            report.holes_open += 1;
            report.largest_open_perimeter = report.largest_open_perimeter.max(l.perimeter);
            continue;
        }
        let (faces, rest) = clip_ears(mesh, &l.vertices, &mut edges);
        report.faces_added += faces.len();
        mesh.faces.extend(faces);
        if rest.len() >= 3 {
            // Fan the remainder around its centroid (a new vertex, so no edge can repeat).
            let c = mesh.vertices.positions.len() as u32;
            let cen = rest.iter().map(|&v| pos(mesh, v)).sum::<Vector3<f64>>() / rest.len() as f64;
            mesh.vertices
                .positions
                .push([cen.x as f32, cen.y as f32, cen.z as f32]);
            if !mesh.vertices.colors.is_empty() {
                let mut acc = [0u32; 3];
                for &v in &rest {
                    for (a, &x) in acc.iter_mut().zip(&mesh.vertices.colors[v as usize]) {
                        *a += x as u32;
                    }
                }
                let k = rest.len() as u32;
                mesh.vertices.colors.push(acc.map(|a| (a / k) as u8));
            }
            if !mesh.vertices.normals.is_empty() {
                mesh.vertices.normals.push([0.0, 0.0, 1.0]);
            }
            if !mesh.uvs.is_empty() {
                mesh.uvs.push(mesh.uvs[rest[0] as usize]);
            }
            let k = rest.len();
            for i in 0..k {
                let (a, b) = (rest[i], rest[(i + 1) % k]);
                mesh.faces.push([b, a, c]);
                edges.insert(edge_key(a, c));
            }
            report.faces_added += k;
            report.vertices_added += 1;
        }
        report.filled += 1;
    }
    if report.faces_added > 0 {
        mesh.compute_vertex_normals();
    }
    report
}

/// Faces kept after deleting every face on an edge used by more than two faces or twice in the
/// same direction, and how many faces were deleted.
pub fn remove_non_manifold(mesh: &TriMesh) -> (Vec<[u32; 3]>, usize) {
    let mut count: HashMap<(u32, u32), (u32, u32)> = HashMap::with_capacity(mesh.faces.len() * 3);
    for f in &mesh.faces {
        for k in 0..3 {
            let (a, b) = (f[k], f[(k + 1) % 3]);
            let e = count.entry(edge_key(a, b)).or_default();
            if a < b {
                e.0 += 1;
            } else {
                e.1 += 1;
            }
        }
    }
    let bad = |a: u32, b: u32| {
        count
            .get(&edge_key(a, b))
            .is_some_and(|&(f, r)| f > 1 || r > 1)
    };
    let kept: Vec<[u32; 3]> = mesh
        .faces
        .iter()
        .filter(|f| !(0..3).any(|k| bad(f[k], f[(k + 1) % 3])))
        .copied()
        .collect();
    let removed = mesh.faces.len() - kept.len();
    (kept, removed)
}

#[cfg(test)]
#[path = "holes_tests.rs"]
mod tests;
