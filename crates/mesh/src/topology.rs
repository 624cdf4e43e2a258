//! Mesh connectivity: edge → faces maps, face adjacency, connected components, and the
//! watertightness check the tests use. Shared by the fusion clean-up and the texture charts.

use std::collections::HashMap;

use handheld_core::TriMesh;

/// Undirected edge key, smaller index first.
pub fn edge_key(a: u32, b: u32) -> (u32, u32) {
    (a.min(b), a.max(b))
}

/// For every face, its up to three neighbours across an edge shared by exactly two faces
/// (`u32::MAX` where the edge is a border or non-manifold).
pub fn face_neighbours(mesh: &TriMesh) -> Vec<[u32; 3]> {
    let mut edges: HashMap<(u32, u32), (u32, u32)> = HashMap::with_capacity(mesh.faces.len() * 2);
    for (fi, f) in mesh.faces.iter().enumerate() {
        for k in 0..3 {
            let e = edge_key(f[k], f[(k + 1) % 3]);
            edges
                .entry(e)
                .and_modify(|s| {
                    s.1 = if s.1 == u32::MAX {
                        fi as u32
                    } else {
                        u32::MAX - 1
                    };
                })
                .or_insert((fi as u32, u32::MAX));
        }
    }
    mesh.faces
        .iter()
        .enumerate()
        .map(|(fi, f)| {
            std::array::from_fn(|k| match edges.get(&edge_key(f[k], f[(k + 1) % 3])) {
                Some(&(a, b)) if b < u32::MAX - 1 => {
                    if a as usize == fi {
                        b
                    } else {
                        a
                    }
                }
                _ => u32::MAX,
            })
        })
        .collect()
}

fn find(parent: &mut [u32], mut x: u32) -> u32 {
    while parent[x as usize] != x {
        parent[x as usize] = parent[parent[x as usize] as usize];
        x = parent[x as usize];
    }
    x
}

/// Component label per face (faces connected through shared vertices), labels `0..n` in order of
/// first appearance, and the number of components.
pub fn face_components(mesh: &TriMesh) -> (Vec<u32>, usize) {
    let n = mesh.vertices.len();
    let mut parent: Vec<u32> = (0..n as u32).collect();
    for f in &mesh.faces {
        let r0 = find(&mut parent, f[0]);
        for &v in &f[1..] {
            let r = find(&mut parent, v);
            if r != r0 {
                parent[r as usize] = r0;
            }
        }
    }
    let mut label = vec![u32::MAX; n];
    let mut count = 0u32;
    let labels = mesh
        .faces
        .iter()
        .map(|f| {
            let r = find(&mut parent, f[0]) as usize;
            if label[r] == u32::MAX {
                label[r] = count;
                count += 1;
            }
            label[r]
        })
        .collect();
    (labels, count as usize)
}

/// Drops the faces of connected components with fewer than `min_faces` faces (floating specks of
/// noise); returns the kept faces.
pub fn remove_small_components(mesh: &TriMesh, min_faces: usize) -> Vec<[u32; 3]> {
    if min_faces <= 1 {
        return mesh.faces.clone();
    }
    let (labels, n) = face_components(mesh);
    let mut size = vec![0usize; n];
    for &l in &labels {
        size[l as usize] += 1;
    }
    mesh.faces
        .iter()
        .zip(&labels)
        .filter(|(_, &l)| size[l as usize] >= min_faces)
        .map(|(f, _)| *f)
        .collect()
}

/// Edge statistics of a mesh: `(border, non_manifold, inconsistently_oriented)` undirected edges.
/// A closed, consistently oriented 2-manifold has all three zero.
pub fn edge_report(mesh: &TriMesh) -> (usize, usize, usize) {
    let mut directed: HashMap<(u32, u32), u32> = HashMap::new();
    for f in &mesh.faces {
        for k in 0..3 {
            *directed.entry((f[k], f[(k + 1) % 3])).or_default() += 1;
        }
    }
    let (mut border, mut non_manifold, mut flipped) = (0, 0, 0);
    for (&(a, b), &n) in &directed {
        let back = directed.get(&(b, a)).copied().unwrap_or(0);
        if a > b && back > 0 {
            continue; // counted from the other direction
        }
        match (n, back) {
            (1, 0) => border += 1,
            (1, 1) => {}
            (n, 0) if n >= 2 => flipped += 1,
            _ => non_manifold += 1,
        }
    }
    (border, non_manifold, flipped)
}
