//! Closest-point queries on triangles, shared by the mesh index of `handheld-mesh` and the
//! brute-force ground-truth distances of `handheld-testkit`.
//!
//! The method is Ericson, *Real-Time Collision Detection* (2005), §5.1.5 "Closest point on
//! triangle to point": the Voronoi region of `p` (a vertex, an edge or the face) is found from dot
//! products of the edges with the vectors from the vertices to `p`, and the closest point follows
//! from barycentric coordinates of that region.

use nalgebra::Point3;

/// Squared distance from `p` to the triangle `(a, b, c)` (Ericson §5.1.5). A degenerate triangle
/// (zero area, where the face case would divide by zero) gives the distance to its nearest vertex.
pub fn point_triangle_distance_squared(
    p: &Point3<f64>,
    a: &Point3<f64>,
    b: &Point3<f64>,
    c: &Point3<f64>,
) -> f64 {
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(&ap), ac.dot(&ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return ap.norm_squared();
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(&bp), ac.dot(&bp));
    if d3 >= 0.0 && d4 <= d3 {
        return bp.norm_squared();
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return (p - (a + ab * v)).norm_squared();
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(&cp), ac.dot(&cp));
    if d6 >= 0.0 && d5 <= d6 {
        return cp.norm_squared();
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return (p - (a + ac * w)).norm_squared();
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return (p - (b + (c - b) * w)).norm_squared();
    }
    let denom = va + vb + vc;
    if denom.abs() < f64::MIN_POSITIVE {
        return ap
            .norm_squared()
            .min(bp.norm_squared())
            .min(cp.norm_squared());
    }
    let (v, w) = (vb / denom, vc / denom);
    (p - (a + ab * v + ac * w)).norm_squared()
}

/// Distance from `p` to the triangle `(a, b, c)`: the square root of
/// [`point_triangle_distance_squared`].
pub fn point_triangle_distance(
    p: &Point3<f64>,
    a: &Point3<f64>,
    b: &Point3<f64>,
    c: &Point3<f64>,
) -> f64 {
    point_triangle_distance_squared(p, a, b, c).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_voronoi_region() {
        let (a, b, c) = (
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(1.0, 0.0, 0.0),
            Point3::new(0.0, 1.0, 0.0),
        );
        let d = |x: f64, y: f64, z: f64| point_triangle_distance(&Point3::new(x, y, z), &a, &b, &c);
        // Face, vertex a, vertex b, vertex c, edge ab, edge ac, edge bc.
        assert!((d(0.2, 0.2, 0.5) - 0.5).abs() < 1e-12);
        assert!((d(-1.0, -1.0, 0.0) - 2f64.sqrt()).abs() < 1e-12);
        assert!((d(2.0, -1.0, 0.0) - 2f64.sqrt()).abs() < 1e-12);
        assert!((d(-1.0, 2.0, 0.0) - 2f64.sqrt()).abs() < 1e-12);
        assert!((d(0.5, -2.0, 0.0) - 2.0).abs() < 1e-12);
        assert!((d(-3.0, 0.5, 0.0) - 3.0).abs() < 1e-12);
        assert!((d(1.0, 1.0, 0.0) - 0.5f64.sqrt()).abs() < 1e-12);
    }

    #[test]
    fn degenerate_triangle_gives_a_finite_distance() {
        let (a, b) = (Point3::new(0.0, 0.0, 0.0), Point3::new(1.0, 0.0, 0.0));
        let d = point_triangle_distance(&Point3::new(0.5, 0.0, 1.0), &a, &b, &b);
        assert!(d.is_finite());
        assert!((d - 1.0).abs() < 1e-12);
    }
}
