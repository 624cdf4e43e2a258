//! The support mesh of a virtual view (§5.2, Fig. 10): the recorded camera centres projected into
//! the virtual image and triangulated (2D Delaunay, with the four image corners added as
//! Buehler et al. 2001 do), and the view-dependent geometry of each triangle at the paper's three
//! levels: one fixed plane L, one plane per triangle through the eq. 29 points of its corners,
//! and adaptive subdivision where the depth inside a triangle departs from its plane.

use nalgebra::{Matrix3, Point3, Vector2, Vector3};
use spade::{DelaunayTriangulation, Point2, Triangulation};

use super::source::Source;
use super::{IbrMethod, IbrOptions, Plane};

/// The virtual camera as matrices, in *ideal* (undistorted) pixels.
#[derive(Clone, Debug)]
pub struct Virtual {
    pub k: Matrix3<f64>,
    /// World → camera rotation and translation.
    pub r: Matrix3<f64>,
    pub t: Vector3<f64>,
    pub center: Vector3<f64>,
    /// Ideal pixel (homogeneous) → world ray direction: `Rᵀ K⁻¹`.
    pub d: Matrix3<f64>,
}

impl Virtual {
    /// The world direction of the ray through an ideal pixel.
    #[inline]
    pub fn ray(&self, p: &Vector2<f64>) -> Vector3<f64> {
        self.d * Vector3::new(p.x, p.y, 1.0)
    }

    /// The point where the ray through `p` meets `plane`, with its ray parameter; `None` when it
    /// meets it behind the camera or not at all.
    #[inline]
    pub fn hit(&self, p: &Vector2<f64>, plane: &Plane) -> Option<(Vector3<f64>, f64)> {
        let dir = self.ray(p);
        let lambda = plane.ray_parameter(&self.center, &dir)?;
        Some((self.center + dir * lambda, lambda))
    }
}

/// The blending weights at one point: up to [`MAX_BLEND`] (source, weight) pairs.
#[derive(Clone, Copy, Debug, Default)]
pub struct Blend {
    pub len: u8,
    pub source: [u16; MAX_BLEND],
    pub weight: [f32; MAX_BLEND],
}

pub const MAX_BLEND: usize = 4;

impl Blend {
    pub fn single(s: usize) -> Self {
        let mut b = Self::default();
        b.push(s, 1.0);
        b
    }

    pub fn push(&mut self, s: usize, w: f32) {
        if (self.len as usize) < MAX_BLEND {
            self.source[self.len as usize] = s as u16;
            self.weight[self.len as usize] = w;
            self.len += 1;
        }
    }

    pub fn iter(&self) -> impl Iterator<Item = (usize, f32)> + '_ {
        (0..self.len as usize).map(|i| (self.source[i] as usize, self.weight[i]))
    }

    /// The source with the largest weight.
    pub fn main(&self) -> Option<usize> {
        self.iter()
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(s, _)| s)
    }
}

/// A vertex of the support mesh.
#[derive(Clone, Copy, Debug)]
pub struct Vertex {
    /// Ideal pixel position in the virtual view.
    pub p: Vector2<f64>,
    /// Its scene point (on the ray through `p`).
    pub x: Vector3<f64>,
    /// Its weights (the paper: weight 1 for its own camera).
    pub blend: Blend,
}

/// A triangle of the Delaunay triangulation: the paper's weights are interpolated over it.
#[derive(Clone, Copy, Debug)]
pub struct Root {
    pub v: [usize; 3],
    /// Barycentric coordinates of an ideal pixel `p`: `bary · (p.x, p.y, 1)`.
    pub bary: Matrix3<f64>,
}

/// A triangle that is drawn: a root triangle or a piece of one, with its plane.
#[derive(Clone, Copy, Debug)]
pub struct Leaf {
    pub p: [Vector2<f64>; 3],
    pub root: u32,
    pub plane: Plane,
}

/// Counts of one frame's support mesh.
#[derive(Clone, Copy, Debug, Default)]
pub struct SupportStats {
    pub cameras: usize,
    pub roots: usize,
    pub leaves: usize,
    pub depth_searches: usize,
}

/// Builds the support mesh of `virt` over the ideal-pixel rectangle `domain` (min, max) into
/// `roots`, `leaves` and `vertices` (cleared first).
#[allow(clippy::too_many_arguments)]
pub fn build(
    virt: &Virtual,
    domain: (Vector2<f64>, Vector2<f64>),
    sources: &[Source],
    scene_plane: &Plane,
    range: (f64, f64),
    method: IbrMethod,
    opts: &IbrOptions,
    vertices: &mut Vec<Vertex>,
    roots: &mut Vec<Root>,
    leaves: &mut Vec<Leaf>,
) -> SupportStats {
    vertices.clear();
    roots.clear();
    leaves.clear();
    let mut stats = SupportStats::default();
    let (lo, hi) = domain;
    let size = hi - lo;
    let mut tri: DelaunayTriangulation<Point2<f64>> = DelaunayTriangulation::new();
    // Spade hands out vertex handles in insertion order; a duplicate position returns the
    // handle of the vertex already there, which keeps its data.
    let mut insert = |p: Vector2<f64>, v: Vertex, vertices: &mut Vec<Vertex>| {
        if let Ok(h) = tri.insert(Point2::new(p.x, p.y)) {
            if h.index() == vertices.len() {
                vertices.push(v);
            }
        }
    };
    // The four image corners (Buehler et al. 2001): their camera is the one whose ray to the
    // corner's scene point is closest in angle; their point is searched along the corner's ray.
    for (cx, cy) in [(lo.x, lo.y), (hi.x, lo.y), (hi.x, hi.y), (lo.x, hi.y)] {
        let p = Vector2::new(cx, cy);
        let v = corner_vertex(
            virt,
            &p,
            sources,
            scene_plane,
            range,
            method,
            opts,
            &mut stats,
        );
        insert(p, v, vertices);
    }
    // The recorded camera centres, projected (a centre behind the virtual camera projects
    // through the mirrored ray; eq. 29's sign is reversed for it).
    let margin = 0.5;
    for (i, s) in sources.iter().enumerate() {
        let c = virt.r * s.center.coords + virt.t;
        if c.z.abs() < 1e-9 * c.norm().max(1e-300) {
            continue;
        }
        let q = virt.k * (c / c.z);
        let p = Vector2::new(q.x, q.y);
        if p.x < lo.x - margin * size.x
            || p.x > hi.x + margin * size.x
            || p.y < lo.y - margin * size.y
            || p.y > hi.y + margin * size.y
        {
            continue;
        }
        stats.cameras += 1;
        let x = match method {
            IbrMethod::Plane => virt.hit(&p, scene_plane).map(|h| h.0),
            _ => eq29_point(virt, &p, i, sources, c.z < 0.0)
                .or_else(|| {
                    stats.depth_searches += 1;
                    search_depth(virt, &p, &sources[i], scene_plane, range, opts)
                })
                .or_else(|| virt.hit(&p, scene_plane).map(|h| h.0)),
        };
        let x = x.unwrap_or(virt.center + virt.ray(&p) * 1e3);
        insert(
            p,
            Vertex {
                p,
                x,
                blend: Blend::single(i),
            },
            vertices,
        );
    }
    for face in tri.inner_faces() {
        let v = face.vertices().map(|h| h.fix().index());
        if v.iter().any(|&i| i >= vertices.len()) {
            continue;
        }
        let [a, b, c] = v.map(|i| vertices[i].p);
        let m = Matrix3::new(a.x, b.x, c.x, a.y, b.y, c.y, 1.0, 1.0, 1.0);
        let Some(bary) = m.try_inverse() else {
            continue;
        };
        let root = roots.len() as u32;
        roots.push(Root { v, bary });
        let pts = v.map(|i| vertices[i].x);
        let plane = match method {
            IbrMethod::Plane => *scene_plane,
            _ => Plane::through(&pts).unwrap_or(*scene_plane),
        };
        let leaf = Leaf {
            p: [a, b, c],
            root,
            plane,
        };
        if matches!(method, IbrMethod::Subdivided | IbrMethod::Ulr) {
            let blends = v.map(|i| vertices[i].blend);
            subdivide(
                virt, leaf, pts, &blends, sources, range, opts, 0, leaves, &mut stats,
            );
        } else {
            leaves.push(leaf);
        }
    }
    stats.roots = roots.len();
    stats.leaves = leaves.len();
    stats
}

/// Eq. 29: the scene point on the line from the virtual centre through camera `i`'s centre,
/// `M_i = D_i(P_i C_V) · (C_i − C_V)/‖C_i − C_V‖ + C_i`, with the depth map of view `i` read
/// where that line pierces it. `D_i` is a camera-frame z here, so the distance along the line is
/// `D_i / cos`, the cosine being the line's z-component in camera `i`. `behind`: camera `i` is
/// behind the virtual camera, and the line is followed the other way (the paper's reversed sign).
fn eq29_point(
    virt: &Virtual,
    p: &Vector2<f64>,
    i: usize,
    sources: &[Source],
    behind: bool,
) -> Option<Vector3<f64>> {
    let s = &sources[i];
    let mut u = s.center.coords - virt.center;
    let len = u.norm();
    if len < 1e-12 {
        return None;
    }
    u /= len;
    if behind {
        u = -u;
    }
    let uc = s.r * u;
    let px = s.pixel_of_cam(&uc)?;
    let depth = s.depth_at(&px)?;
    let m = s.center.coords + u * (depth / uc.z);
    // It must lie ahead of the virtual camera, on the ray through p.
    let ahead = (m - virt.center).dot(&virt.ray(p)) > 0.0;
    ahead.then_some(m)
}

/// The scene point on the virtual ray through `p` found in view `s`'s depth map. The
/// correspondence between the two views depends on the depth itself, so it is found
/// iteratively (§5.2): start from the plane's point, read `s`'s depth where it projects, move to
/// the point of the ray at that depth, and repeat until it settles. Where that does not settle
/// (on a depth edge, or a surface seen at a grazing angle) the ray is marched instead: sampled
/// uniformly in inverse depth, the first crossing from in front of `s`'s surface to behind it is
/// kept and refined by bisection.
pub fn search_depth(
    virt: &Virtual,
    p: &Vector2<f64>,
    s: &Source,
    start: &Plane,
    range: (f64, f64),
    opts: &IbrOptions,
) -> Option<Vector3<f64>> {
    if !s.has_depth() {
        return None;
    }
    let dir = virt.ray(p);
    let c_in_s = s.to_cam(&virt.center);
    let dir_in_s = s.r * dir;
    // g(λ) = depth map − depth of the ray's point, in view s (positive: in front of the surface).
    let g = |lambda: f64| -> Option<(f64, f64)> {
        let y = c_in_s + dir_in_s * lambda;
        let px = s.pixel_of_cam(&y)?;
        let depth = s.depth_at(&px)?;
        Some((depth - y.z, depth))
    };
    if dir_in_s.z.abs() > 1e-9 * dir.norm() {
        if let Some(mut lambda) = start.ray_parameter(&virt.center, &dir) {
            for _ in 0..opts.depth_iterations {
                let Some((res, depth)) = g(lambda) else { break };
                if res.abs() <= 1e-3 * depth {
                    return Some(virt.center + dir * lambda);
                }
                let next = (depth - c_in_s.z) / dir_in_s.z;
                if !(next.is_finite() && next > 0.0) {
                    break;
                }
                lambda = next;
            }
        }
    }
    // March from near to far, uniformly in 1/λ.
    let (near, far) = range;
    let steps = opts.march_steps.max(2);
    let at = |k: usize| {
        let t = k as f64 / (steps - 1) as f64;
        1.0 / (1.0 / near + t * (1.0 / far - 1.0 / near))
    };
    let mut prev: Option<(f64, f64)> = None; // (λ, g) in front of the surface
    for k in 0..steps {
        let lambda = at(k);
        let Some((res, depth)) = g(lambda) else {
            prev = None;
            continue;
        };
        if res >= 0.0 {
            prev = Some((lambda, res));
            continue;
        }
        // Behind the surface: a crossing when the previous sample was in front and the jump is
        // not a depth edge (the surface must be reached, not passed under).
        if let Some((mut a, _)) = prev {
            let mut b = lambda;
            for _ in 0..8 {
                let m = 0.5 * (a + b);
                match g(m) {
                    Some((r, _)) if r >= 0.0 => a = m,
                    Some(_) => b = m,
                    None => break,
                }
            }
            let lam = 0.5 * (a + b);
            if g(lam).is_some_and(|(r, d)| r.abs() <= 0.05 * d) {
                return Some(virt.center + dir * lam);
            }
        }
        let _ = depth;
        prev = None;
    }
    None
}

/// [`search_depth`] in the views that see the plane's point at the smallest angles to the
/// virtual ray, best first; the first that finds the surface wins.
pub fn search_depth_best(
    virt: &Virtual,
    p: &Vector2<f64>,
    sources: &[Source],
    start: &Plane,
    range: (f64, f64),
    opts: &IbrOptions,
) -> Option<(Vector3<f64>, usize)> {
    // Rank the views at the plane's point, or at mid-range when the plane is missed.
    let dir = virt.ray(p);
    let x0 = match virt.hit(p, start) {
        Some((x, l)) if l >= range.0 && l <= range.1 => x,
        _ => virt.center + dir * (2.0 / (1.0 / range.0 + 1.0 / range.1)),
    };
    let mut ranked: [(f64, usize); 3] = [(f64::NEG_INFINITY, usize::MAX); 3];
    let dv = (x0 - virt.center).normalize();
    for (i, s) in sources.iter().enumerate() {
        if s.pixel_of_cam(&s.to_cam(&x0)).is_none() {
            continue;
        }
        let cos = dv.dot(&(x0 - s.center.coords).normalize());
        if cos > ranked[2].0 {
            ranked[2] = (cos, i);
            ranked.sort_by(|a, b| b.0.total_cmp(&a.0));
        }
    }
    ranked
        .iter()
        .filter(|r| r.1 != usize::MAX)
        .find_map(|&(_, i)| search_depth(virt, p, &sources[i], start, range, opts).map(|x| (x, i)))
}

/// An image corner's vertex: its camera is the recorded view that sees the corner's scene point
/// (on the fixed plane) at the smallest angle from the virtual ray; its point is then searched
/// in that view's depth.
#[allow(clippy::too_many_arguments)]
fn corner_vertex(
    virt: &Virtual,
    p: &Vector2<f64>,
    sources: &[Source],
    scene_plane: &Plane,
    range: (f64, f64),
    method: IbrMethod,
    opts: &IbrOptions,
    stats: &mut SupportStats,
) -> Vertex {
    let on_plane = virt.hit(p, scene_plane).map(|h| h.0);
    let x0 = on_plane.unwrap_or(virt.center + virt.ray(p).normalize());
    let mut best = best_angle(virt, &x0, sources).unwrap_or(0);
    let x = match method {
        IbrMethod::Plane => x0,
        _ => {
            stats.depth_searches += 1;
            match search_depth_best(virt, p, sources, scene_plane, range, opts) {
                Some((x, s)) => {
                    best = best_angle(virt, &x, sources).unwrap_or(s);
                    x
                }
                None => x0,
            }
        }
    };
    Vertex {
        p: *p,
        x,
        blend: Blend::single(best),
    }
}

/// The source that sees `x` (in front, inside its image) with the smallest angle between its
/// ray and the virtual camera's; when none sees it, the one with the smallest angle.
pub fn best_angle(virt: &Virtual, x: &Vector3<f64>, sources: &[Source]) -> Option<usize> {
    let dv = (x - virt.center).normalize();
    let mut best: Option<(bool, f64, usize)> = None;
    for (i, s) in sources.iter().enumerate() {
        let ds = (x - s.center.coords).normalize();
        let cos = dv.dot(&ds);
        let sees = s.pixel_of_cam(&s.to_cam(x)).is_some();
        let better = match best {
            None => true,
            Some((bs, bc, _)) => (sees && !bs) || (sees == bs && cos > bc),
        };
        if better {
            best = Some((sees, cos, i));
        }
    }
    best.map(|b| b.2)
}

/// Splits a triangle into four (edge midpoints) while the scene inside departs from its plane by
/// more than `opts.subdivision_px` source pixels, measured at the edge midpoints in each of the
/// root triangle's views; the midpoints' depths come from [`search_depth`] in the view that
/// weighs most there.
#[allow(clippy::too_many_arguments)]
fn subdivide(
    virt: &Virtual,
    leaf: Leaf,
    pts: [Vector3<f64>; 3],
    blends: &[Blend; 3],
    sources: &[Source],
    range: (f64, f64),
    opts: &IbrOptions,
    level: u32,
    leaves: &mut Vec<Leaf>,
    stats: &mut SupportStats,
) {
    let [a, b, c] = leaf.p;
    let longest = (b - a).norm().max((c - b).norm()).max((a - c).norm());
    if level >= opts.max_subdivision || longest < 2.0 * opts.min_triangle_px {
        leaves.push(leaf);
        return;
    }
    let mids = [(a + b) / 2.0, (b + c) / 2.0, (c + a) / 2.0];
    let mut mid_pts = [Vector3::zeros(); 3];
    let mut worst = 0.0f64;
    for (k, m) in mids.iter().enumerate() {
        let on_plane = virt.hit(m, &leaf.plane).map(|h| h.0);
        let found = search_depth_best(virt, m, sources, &leaf.plane, range, opts).map(|(x, _)| x);
        mid_pts[k] = match (found, on_plane) {
            (Some(t), Some(q)) => {
                stats.depth_searches += 1;
                for bl in blends {
                    for (s, _) in bl.iter() {
                        let src = &sources[s];
                        if let (Some(u), Some(v)) = (
                            src.pixel_of_cam(&src.to_cam(&t)),
                            src.pixel_of_cam(&src.to_cam(&q)),
                        ) {
                            worst = worst.max((u - v).norm());
                        }
                    }
                }
                t
            }
            (Some(t), None) => {
                worst = f64::INFINITY;
                t
            }
            (None, Some(q)) => q,
            (None, None) => (pts[k] + pts[(k + 1) % 3]) / 2.0,
        };
    }
    if worst <= opts.subdivision_px {
        leaves.push(leaf);
        return;
    }
    let [mab, mbc, mca] = mids;
    let [xab, xbc, xca] = mid_pts;
    let children = [
        ([a, mab, mca], [pts[0], xab, xca]),
        ([mab, b, mbc], [xab, pts[1], xbc]),
        ([mca, mbc, c], [xca, xbc, pts[2]]),
        ([mab, mbc, mca], [xab, xbc, xca]),
    ];
    for (p, x) in children {
        let child = Leaf {
            p,
            root: leaf.root,
            plane: Plane::through(&x).unwrap_or(leaf.plane),
        };
        subdivide(
            virt,
            child,
            x,
            blends,
            sources,
            range,
            opts,
            level + 1,
            leaves,
            stats,
        );
    }
}

/// The least-squares plane of a point set (total least squares: through the centroid, normal
/// along the smallest principal axis) — §5.2's fixed plane L.
pub fn fit_plane(points: &[Point3<f64>]) -> Option<Plane> {
    if points.len() < 3 {
        return None;
    }
    let n = points.len() as f64;
    let mean = points.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / n;
    let mut cov = Matrix3::zeros();
    for p in points {
        let d = p.coords - mean;
        cov += d * d.transpose();
    }
    let eig = cov.symmetric_eigen();
    let (k, _) = eig
        .eigenvalues
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))?;
    let normal = eig.eigenvectors.column(k).into_owned();
    (normal.norm() > 0.5).then(|| Plane {
        n: normal,
        d: -normal.dot(&mean),
    })
}
