//! The marching-cubes case table (Lorensen & Cline, *Marching cubes: a high resolution 3D surface
//! construction algorithm*, SIGGRAPH 1987), derived here by a program instead of written out.
//!
//! Corner `c` of the unit cube is `(c & 1, c >> 1 & 1, c >> 2 & 1)`. Edge `e` joins corner
//! [`EDGE_CORNER`]`[e]` to that corner plus one step along axis [`EDGE_AXIS`]`[e]` (edges 0–3 run
//! along x, 4–7 along y, 8–11 along z). A case is the 8-bit mask of the *inside* corners (signed
//! distance `< 0`).
//!
//! Derivation, per case: on each of the six faces the sign changes cut the face's edges; two cuts
//! are joined by one segment, and four cuts (an ambiguous face, diagonal corners alike) by two
//! segments that always cut off the two inside corners. Because that rule depends only on the
//! signs of the face's own corners, the two cubes sharing a face draw the same segments — the
//! original 1987 table's holes (its complementary cases disagree on ambiguous faces) cannot occur.
//! Each segment is directed so that, seen from outside the cube along the face normal, the
//! inside corners lie on its right; the directed segments then chain into closed loops (every cut
//! edge starts one segment and ends another), and each loop is fanned into triangles. A loop
//! directed this way is counter-clockwise seen from the outside region, so triangle normals
//! (right-hand rule) point from inside to outside.

use std::sync::OnceLock;

/// Corner at the start of each edge.
pub const EDGE_CORNER: [usize; 12] = [0, 2, 4, 6, 0, 1, 4, 5, 0, 1, 2, 3];
/// Axis (0 = x, 1 = y, 2 = z) of each edge.
pub const EDGE_AXIS: [usize; 12] = [0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 2];

/// Position of corner `c` in the unit cube.
pub fn corner_pos(c: usize) -> [f64; 3] {
    [(c & 1) as f64, (c >> 1 & 1) as f64, (c >> 2 & 1) as f64]
}

/// The edge joining corners `a` and `b` (which differ in exactly one bit).
fn edge_between(a: usize, b: usize) -> usize {
    let lo = a.min(b);
    let axis = (a ^ b).trailing_zeros() as usize;
    (0..12)
        .find(|&e| EDGE_AXIS[e] == axis && EDGE_CORNER[e] == lo)
        .unwrap_or(0)
}

fn midpoint(e: usize) -> [f64; 3] {
    let mut p = corner_pos(EDGE_CORNER[e]);
    p[EDGE_AXIS[e]] += 0.5;
    p
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// The directed segments `(from_edge, to_edge)` of one face of a case.
fn face_segments(case: usize, axis: usize, side: usize, out: &mut Vec<(usize, usize)>) {
    let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
    let corner = |a: usize, b: usize| (side << axis) | (a << u) | (b << v);
    let ring = [corner(0, 0), corner(1, 0), corner(1, 1), corner(0, 1)];
    let inside = |c: usize| case >> c & 1 == 1;
    let mut normal = [0.0; 3];
    normal[axis] = if side == 1 { 1.0 } else { -1.0 };
    // Cuts on the ring's edges i = (ring[i], ring[i + 1]).
    let cut: Vec<usize> = (0..4)
        .filter(|&i| inside(ring[i]) != inside(ring[(i + 1) % 4]))
        .collect();
    // Pairs of ring-edge indices, each with a reference corner not on the segment's line.
    let pairs: Vec<(usize, usize, usize)> = match cut.len() {
        2 => vec![(cut[0], cut[1], ring[0])],
        4 => (0..4)
            .filter(|&i| inside(ring[i]))
            .map(|i| ((i + 3) % 4, i, ring[i]))
            .collect(),
        _ => Vec::new(),
    };
    for (i, j, reference) in pairs {
        let ea = edge_between(ring[i], ring[(i + 1) % 4]);
        let eb = edge_between(ring[j], ring[(j + 1) % 4]);
        let (a, b) = (midpoint(ea), midpoint(eb));
        let side_of_ref = dot(cross(sub(b, a), sub(corner_pos(reference), a)), normal);
        // Outside corners must lie on the left of a → b (positive), inside corners on the right.
        let ok = (side_of_ref > 0.0) != inside(reference);
        out.push(if ok { (ea, eb) } else { (eb, ea) });
    }
}

/// Triangles (as edge triples) of every case, built on first use.
pub fn triangle_table() -> &'static [Vec<[u8; 3]>; 256] {
    static TABLE: OnceLock<[Vec<[u8; 3]>; 256]> = OnceLock::new();
    TABLE.get_or_init(|| std::array::from_fn(case_triangles))
}

/// The triangles of one case (see the module documentation).
fn case_triangles(case: usize) -> Vec<[u8; 3]> {
    let mut segments = Vec::new();
    for axis in 0..3 {
        for side in 0..2 {
            face_segments(case, axis, side, &mut segments);
        }
    }
    let mut next = [usize::MAX; 12];
    for &(a, b) in &segments {
        next[a] = b;
    }
    let mut used = [false; 12];
    let mut tris = Vec::new();
    for &(start, _) in &segments {
        if used[start] {
            continue;
        }
        let mut lp = vec![start];
        used[start] = true;
        let mut e = next[start];
        while e != start && e != usize::MAX && !used[e] {
            used[e] = true;
            lp.push(e);
            e = next[e];
        }
        for k in 1..lp.len().saturating_sub(1) {
            tris.push([lp[0] as u8, lp[k] as u8, lp[k + 1] as u8]);
        }
    }
    tris
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn loops_close_and_every_cut_edge_is_used_once() {
        for case in 0..256usize {
            let mut segs = Vec::new();
            for axis in 0..3 {
                for side in 0..2 {
                    face_segments(case, axis, side, &mut segs);
                }
            }
            let cut_edges: Vec<usize> = (0..12)
                .filter(|&e| {
                    let a = EDGE_CORNER[e];
                    let b = a | (1 << EDGE_AXIS[e]);
                    (case >> a & 1) != (case >> b & 1)
                })
                .collect();
            for &e in &cut_edges {
                assert_eq!(segs.iter().filter(|s| s.0 == e).count(), 1, "case {case}");
                assert_eq!(segs.iter().filter(|s| s.1 == e).count(), 1, "case {case}");
            }
            assert_eq!(segs.len(), cut_edges.len());
            // A loop of n cut edges gives n − 2 triangles.
            let tris = triangle_table()[case].len();
            assert!(tris <= cut_edges.len(), "case {case}");
            assert_eq!(tris == 0, cut_edges.is_empty());
        }
        assert_eq!(triangle_table()[1].len(), 1);
        assert_eq!(triangle_table()[3].len(), 2);
        assert_eq!(triangle_table()[0b0001_1111].len(), 3);
    }

    #[test]
    fn single_corner_cases_point_outwards() {
        for c in 0..8 {
            for (case, sign) in [(1usize << c, 1.0), (255 ^ (1usize << c), -1.0)] {
                let t = triangle_table()[case][0];
                let p = t.map(|e| midpoint(e as usize));
                let n = cross(sub(p[1], p[0]), sub(p[2], p[0]));
                // Outward = away from the inside corner (towards it when the corner is outside).
                let away = sub([0.5; 3], corner_pos(c));
                assert!(sign * dot(n, away) > 0.0, "corner {c}, case {case}");
            }
        }
    }
}
