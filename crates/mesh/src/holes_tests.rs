use super::*;
use crate::topology::edge_report;
use handheld_core::PointCloud;

fn mesh(positions: Vec<[f32; 3]>, faces: Vec<[u32; 3]>) -> TriMesh {
    TriMesh {
        vertices: PointCloud {
            positions,
            ..Default::default()
        },
        uvs: Vec::new(),
        faces,
    }
}

/// An `n × n`-cell grid in the z = 0 plane (counter-clockwise seen from +z), minus the cells
/// `skip` says to drop.
fn grid(n: usize, skip: impl Fn(usize, usize) -> bool) -> TriMesh {
    let mut positions = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            // A gentle bump so the fill is not trivially planar.
            let (x, y) = (i as f32 / n as f32, j as f32 / n as f32);
            positions.push([x, y, 0.1 * (3.0 * x).sin() * (2.0 * y).cos()]);
        }
    }
    let id = |i: usize, j: usize| (j * (n + 1) + i) as u32;
    let mut faces = Vec::new();
    for j in 0..n {
        for i in 0..n {
            if skip(i, j) {
                continue;
            }
            faces.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            faces.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    mesh(positions, faces)
}

/// A closed UV sphere of radius 1 (outward, counter-clockwise), `rings × segs`.
fn sphere(rings: usize, segs: usize) -> TriMesh {
    let mut positions = vec![[0.0, 0.0, 1.0f32]];
    for r in 1..rings {
        let th = std::f32::consts::PI * r as f32 / rings as f32;
        for s in 0..segs {
            let ph = 2.0 * std::f32::consts::PI * s as f32 / segs as f32;
            positions.push([th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos()]);
        }
    }
    positions.push([0.0, 0.0, -1.0]);
    let bottom = (positions.len() - 1) as u32;
    let id = |r: usize, s: usize| (1 + (r - 1) * segs + s % segs) as u32;
    let mut faces = Vec::new();
    for s in 0..segs {
        faces.push([0, id(1, s), id(1, s + 1)]);
        faces.push([bottom, id(rings - 1, s + 1), id(rings - 1, s)]);
    }
    for r in 1..rings - 1 {
        for s in 0..segs {
            faces.push([id(r, s), id(r + 1, s), id(r + 1, s + 1)]);
            faces.push([id(r, s), id(r + 1, s + 1), id(r, s + 1)]);
        }
    }
    mesh(positions, faces)
}

#[test]
fn sphere_is_closed_and_outward() {
    let m = sphere(12, 20);
    assert_eq!(edge_report(&m), (0, 0, 0));
    assert!(boundary_loops(&m, 1.0).is_empty());
}

#[test]
fn interior_holes_are_filled_and_the_outer_border_stays() {
    // Two holes: a 3×2 block and an L-shaped (non-convex) one.
    let holes = |i: usize, j: usize| {
        ((4..7).contains(&i) && (4..6).contains(&j))
            || ((10..16).contains(&i) && j == 12)
            || (i == 10 && (12..17).contains(&j))
    };
    let full = grid(20, |_, _| false);
    let mut m = grid(20, holes);
    let (border_before, _, _) = edge_report(&m);
    let (outer_border, _, _) = edge_report(&full);
    assert!(border_before > outer_border);
    let loops = boundary_loops(&m, 1.0);
    assert_eq!(loops.iter().filter(|l| l.outer).count(), 1);
    assert_eq!(loops.iter().filter(|l| !l.outer).count(), 2);
    let report = fill_holes(&mut m, &HoleFillOptions::default());
    assert_eq!((report.holes, report.filled, report.holes_open), (2, 2, 0));
    assert_eq!(report.vertices_added, 0, "planar-ish holes need no fan");
    // Only the outer border is left; nothing non-manifold or flipped.
    assert_eq!(edge_report(&m), (outer_border, 0, 0));
    // The fill covers the holes' area (within the bump's slope).
    let area = |m: &TriMesh| -> f64 {
        m.faces
            .iter()
            .map(|f| {
                let [a, b, c] = f.map(|i| pos(m, i));
                0.5 * (b - a).cross(&(c - a)).norm()
            })
            .sum()
    };
    assert!((area(&m) - area(&full)).abs() < 0.01 * area(&full));
}

#[test]
fn long_holes_stay_open() {
    let mut m = grid(20, |i, j| (4..12).contains(&i) && (4..12).contains(&j));
    let opts = HoleFillOptions {
        max_perimeter: 1.0, // the hole's perimeter is 1.6
        ..Default::default()
    };
    let report = fill_holes(&mut m, &opts);
    assert_eq!((report.holes, report.filled, report.holes_open), (1, 0, 1));
    assert!((report.largest_open_perimeter - 1.6).abs() < 0.05);
}

#[test]
fn a_closed_object_with_an_unobserved_cap_becomes_watertight() {
    let mut m = sphere(12, 20);
    // Drop the bottom cap (the fan around the south pole) and one ring of quads above it.
    let bottom = (m.vertices.len() - 1) as u32;
    let first_last_ring = m.vertices.len() as u32 - 1 - 20;
    m.faces
        .retain(|f| !f.contains(&bottom) && !f.iter().all(|&v| v >= first_last_ring - 20));
    let report = fill_holes(&mut m, &HoleFillOptions::default());
    assert_eq!((report.outer_loops, report.filled), (0, 1));
    assert_eq!(edge_report(&m), (0, 0, 0));
}

#[test]
fn a_flat_piece_keeps_its_outline() {
    // A disk-like open piece has one loop, long against the piece: its outer boundary.
    let mut m = grid(6, |_, _| false);
    let report = fill_holes(&mut m, &HoleFillOptions::default());
    assert_eq!((report.outer_loops, report.holes), (1, 0));
}

#[test]
fn pinch_vertices_split_loops() {
    // Two holes touching at one vertex (cells (5,5) and (6,6) share the corner (6,6)).
    let mut m = grid(12, |i, j| (i, j) == (5, 5) || (i, j) == (6, 6));
    let loops = boundary_loops(&m, 1.0);
    let holes: Vec<_> = loops.iter().filter(|l| !l.outer).collect();
    assert_eq!(holes.len(), 2);
    for h in &holes {
        let mut v = h.vertices.clone();
        v.sort_unstable();
        v.dedup();
        assert_eq!(v.len(), h.vertices.len(), "a loop repeats a vertex");
    }
    fill_holes(&mut m, &HoleFillOptions::default());
    let (border, nm, flipped) = edge_report(&m);
    assert_eq!((nm, flipped), (0, 0));
    assert_eq!(border, edge_report(&grid(12, |_, _| false)).0);
}

#[test]
fn non_manifold_edges_are_cut_out_and_refilled() {
    let mut m = grid(10, |_, _| false);
    // A fin: a third face on the interior edge (id(5,5), id(6,6)).
    let a = (5 * 11 + 5) as u32;
    let b = (6 * 11 + 6) as u32;
    m.vertices.positions.push([0.55, 0.55, 0.3]);
    let top = (m.vertices.len() - 1) as u32;
    m.faces.push([a, b, top]);
    assert_eq!(edge_report(&m).1, 1);
    let (kept, removed) = remove_non_manifold(&m);
    assert_eq!(removed, 3);
    m.faces = kept;
    let report = fill_holes(&mut m, &HoleFillOptions::default());
    assert_eq!(report.filled, 1);
    let (border, nm, flipped) = edge_report(&m);
    assert_eq!((nm, flipped), (0, 0));
    assert_eq!(border, edge_report(&grid(10, |_, _| false)).0);
}
