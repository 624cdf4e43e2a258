//! A bounding-volume hierarchy over a mesh's triangles for nearest-surface distance queries (the
//! metrics of [`crate::eval`] and the texture stage's checks). Axis-aligned boxes, median split
//! along the widest centroid axis, up to [`LEAF`] triangles per leaf; the query descends the
//! nearer child first and prunes boxes farther than the best distance found.

use handheld_core::closest::point_triangle_distance_squared;
use handheld_core::TriMesh;
use nalgebra::{Point3, Vector3};

/// Triangles per leaf.
const LEAF: usize = 4;

#[derive(Clone, Debug)]
struct Node {
    lo: Vector3<f64>,
    hi: Vector3<f64>,
    /// Leaf: first triangle in `order`; inner: index of the left child (right = left + 1).
    start: usize,
    /// Leaf: number of triangles; inner: 0.
    count: usize,
}

/// Nearest-triangle queries over one mesh (positions converted to `f64` once).
#[derive(Clone, Debug)]
pub struct MeshIndex {
    tris: Vec<[Point3<f64>; 3]>,
    order: Vec<usize>,
    nodes: Vec<Node>,
}

/// Squared distance from `p` to the triangle `t` (Ericson §5.1.5, in `handheld_core::closest`).
fn point_triangle_distance2(p: &Point3<f64>, t: &[Point3<f64>; 3]) -> f64 {
    point_triangle_distance_squared(p, &t[0], &t[1], &t[2])
}

fn box_distance2(p: &Point3<f64>, lo: &Vector3<f64>, hi: &Vector3<f64>) -> f64 {
    (0..3)
        .map(|k| {
            let d = (lo[k] - p[k]).max(p[k] - hi[k]).max(0.0);
            d * d
        })
        .sum()
}

impl MeshIndex {
    /// Builds the hierarchy over the faces of `mesh` (faces with an out-of-range index are skipped).
    pub fn new(mesh: &TriMesh) -> Self {
        let pos = &mesh.vertices.positions;
        let tris: Vec<[Point3<f64>; 3]> = mesh
            .faces
            .iter()
            .filter(|f| f.iter().all(|&i| (i as usize) < pos.len()))
            .map(|f| {
                f.map(|i| {
                    let q = pos[i as usize];
                    Point3::new(q[0] as f64, q[1] as f64, q[2] as f64)
                })
            })
            .collect();
        let mut index = Self {
            order: (0..tris.len()).collect(),
            tris,
            nodes: Vec::new(),
        };
        if !index.tris.is_empty() {
            index.nodes.push(Node {
                lo: Vector3::zeros(),
                hi: Vector3::zeros(),
                start: 0,
                count: 0,
            });
            index.build(0, 0, index.tris.len());
        }
        index
    }

    /// Number of indexed triangles.
    pub fn len(&self) -> usize {
        self.tris.len()
    }

    pub fn is_empty(&self) -> bool {
        self.tris.is_empty()
    }

    fn build(&mut self, node: usize, start: usize, end: usize) {
        let mut lo = Vector3::repeat(f64::INFINITY);
        let mut hi = Vector3::repeat(f64::NEG_INFINITY);
        let mut clo = lo;
        let mut chi = hi;
        for &t in &self.order[start..end] {
            for p in &self.tris[t] {
                lo = lo.inf(&p.coords);
                hi = hi.sup(&p.coords);
            }
            let c = self.centroid(t);
            clo = clo.inf(&c);
            chi = chi.sup(&c);
        }
        self.nodes[node].lo = lo;
        self.nodes[node].hi = hi;
        if end - start <= LEAF {
            self.nodes[node].start = start;
            self.nodes[node].count = end - start;
            return;
        }
        let axis = (chi - clo).imax();
        let mid = (start + end) / 2;
        let tris = &self.tris;
        let key = |t: &usize| {
            let c = &tris[*t];
            c[0][axis] + c[1][axis] + c[2][axis]
        };
        self.order[start..end]
            .select_nth_unstable_by(mid - start, |a, b| key(a).total_cmp(&key(b)));
        let left = self.nodes.len();
        let empty = Node {
            lo,
            hi,
            start: 0,
            count: 0,
        };
        self.nodes.push(empty.clone());
        self.nodes.push(empty);
        self.nodes[node].start = left;
        self.nodes[node].count = 0;
        self.build(left, start, mid);
        self.build(left + 1, mid, end);
    }

    fn centroid(&self, t: usize) -> Vector3<f64> {
        let c = &self.tris[t];
        (c[0].coords + c[1].coords + c[2].coords) / 3.0
    }

    /// Distance from `p` to the nearest triangle, or `f64::INFINITY` for an empty index.
    pub fn distance(&self, p: &Point3<f64>) -> f64 {
        self.distance_within(p, f64::INFINITY)
    }

    /// Distance from `p` to the nearest triangle when it is below `max_distance`, else
    /// `f64::INFINITY` (faster for thresholded counts).
    pub fn distance_within(&self, p: &Point3<f64>, max_distance: f64) -> f64 {
        if self.nodes.is_empty() {
            return f64::INFINITY;
        }
        let limit = max_distance * max_distance;
        let mut best = limit;
        let mut stack = vec![0usize];
        while let Some(n) = stack.pop() {
            let node = &self.nodes[n];
            if box_distance2(p, &node.lo, &node.hi) >= best {
                continue;
            }
            if node.count > 0 {
                for &t in &self.order[node.start..node.start + node.count] {
                    best = best.min(point_triangle_distance2(p, &self.tris[t]));
                }
                continue;
            }
            let (l, r) = (node.start, node.start + 1);
            let dl = box_distance2(p, &self.nodes[l].lo, &self.nodes[l].hi);
            let dr = box_distance2(p, &self.nodes[r].lo, &self.nodes[r].hi);
            if dl < dr {
                stack.push(r);
                stack.push(l);
            } else {
                stack.push(l);
                stack.push(r);
            }
        }
        if best < limit {
            best.sqrt()
        } else {
            f64::INFINITY
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use handheld_core::PointCloud;

    #[test]
    fn matches_brute_force() {
        let mut mesh = TriMesh {
            vertices: PointCloud::default(),
            uvs: Vec::new(),
            faces: Vec::new(),
        };
        // A bumpy grid of 20 × 20 squares.
        for j in 0..21 {
            for i in 0..21 {
                let (x, y) = (i as f32 * 0.1, j as f32 * 0.1);
                mesh.vertices
                    .positions
                    .push([x, y, (3.0 * x).sin() * (2.0 * y).cos() * 0.2]);
            }
        }
        for j in 0..20u32 {
            for i in 0..20u32 {
                let a = j * 21 + i;
                mesh.faces.push([a, a + 1, a + 22]);
                mesh.faces.push([a, a + 22, a + 21]);
            }
        }
        let index = MeshIndex::new(&mesh);
        for k in 0..200 {
            let t = k as f64;
            let p = Point3::new(
                (t * 0.37).sin() * 1.5 + 1.0,
                (t * 0.91).cos() * 1.5 + 1.0,
                (t * 0.13).sin(),
            );
            let brute = index
                .tris
                .iter()
                .map(|tri| point_triangle_distance2(&p, tri))
                .fold(f64::INFINITY, f64::min)
                .sqrt();
            assert!((index.distance(&p) - brute).abs() < 1e-12);
            let capped = index.distance_within(&p, 0.05);
            assert!(if brute < 0.05 {
                (capped - brute).abs() < 1e-12
            } else {
                capped >= 0.05 - 1e-12
            });
        }
    }
}
