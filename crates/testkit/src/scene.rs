//! The synthetic 3D scene: finite planes, oriented boxes and spheres with procedural texture
//! ([`crate::texture`]), exact nearest-hit ray casting and the landmark ground truth.
//!
//! World frame: metres, `z` up, ground at `z = 0`; [`Scene::default_scene`] (in
//! [`crate::default_scene`]) is the standard layout. Every face of a plane or box has orthonormal surface axes `(u, v)` with `u × v` the outward
//! normal and surface coordinates in metres, which is what makes the landmark disks true 3D circles.

use nalgebra::{Matrix3, Point3, UnitQuaternion, Vector2, Vector3};
use serde::{Deserialize, Serialize};

pub use crate::finish::Finish;
use crate::texture::{FaceTexture, LANDMARK_HALF_SQUARE};

/// Smallest accepted ray parameter (self-intersection guard), in units of the ray direction.
const T_MIN: f64 = 1e-9;

/// One textured primitive. `texture` seeds its procedural texture.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum Primitive {
    /// The rectangle `origin + s·edge_u + t·edge_v`, `s, t ∈ [0, 1]`; edges must be orthogonal. Its
    /// front normal is `edge_u × edge_v` (it is visible from both sides).
    Plane {
        origin: Point3<f64>,
        edge_u: Vector3<f64>,
        edge_v: Vector3<f64>,
        texture: u64,
    },
    /// An oriented box: `rotation` maps box axes to world axes.
    Box {
        center: Point3<f64>,
        half_extents: Vector3<f64>,
        rotation: UnitQuaternion<f64>,
        texture: u64,
    },
    Sphere {
        center: Point3<f64>,
        radius: f64,
        texture: u64,
    },
}

/// The nearest intersection of a ray with the scene.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Ray parameter: `point = origin + t·dir` (in units of `|dir|`).
    pub t: f64,
    pub point: Point3<f64>,
    /// Unit geometric normal: outward for boxes and spheres, `edge_u × edge_v` for planes.
    pub normal: Vector3<f64>,
    /// Index into [`Scene::primitives`].
    pub primitive: usize,
    /// Face of the primitive: 0 for planes and spheres; `2·axis + (1 if the negative side)` for boxes.
    pub face: u32,
    /// Surface coordinates on the face, in metres.
    pub uv: Vector2<f64>,
}

/// A rectangular face: `point(uv) = origin + uv.x·u + uv.y·v` with `uv ∈ [0, size]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FaceRect {
    pub origin: Point3<f64>,
    pub u: Vector3<f64>,
    pub v: Vector3<f64>,
    /// `u × v`.
    pub normal: Vector3<f64>,
    pub size: Vector2<f64>,
}

impl FaceRect {
    pub fn point(&self, uv: &Vector2<f64>) -> Point3<f64> {
        self.origin + self.u * uv.x + self.v * uv.y
    }
}

/// A ground-truth feature: the centre of a dark landmark disk.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Landmark {
    pub position: Point3<f64>,
    /// Outward unit normal of the face carrying it.
    pub normal: Vector3<f64>,
    pub primitive: usize,
    pub face: u32,
    /// Disk centre in the face's surface coordinates (metres).
    pub uv: Vector2<f64>,
}

#[derive(Clone, Debug)]
enum Prepared {
    Plane {
        rect: FaceRect,
    },
    Box {
        center: Point3<f64>,
        world_from_box: Matrix3<f64>,
        box_from_world: Matrix3<f64>,
        half: Vector3<f64>,
        bound_r2: f64,
    },
    Sphere {
        center: Point3<f64>,
        radius: f64,
    },
}

/// A scene ready for ray casting. Construct with [`Scene::new`] or [`Scene::default_scene`].
#[derive(Clone, Debug)]
pub struct Scene {
    primitives: Vec<Primitive>,
    prepared: Vec<Prepared>,
    textures: Vec<Vec<FaceTexture>>,
    landmarks: Vec<Landmark>,
    /// Per primitive: the strength of its specular (Blinn–Phong) highlight, 0 for matte.
    gloss: Vec<f64>,
    /// Per primitive: how its albedo is drawn from its texture.
    finish: Vec<Finish>,
}

/// Tangent axes of box face `face`: (normal axis, positive side, u axis, v axis), with `u × v` outward.
fn box_face_axes(face: u32) -> (usize, bool, usize, usize) {
    let a = (face / 2) as usize;
    let positive = face & 1 == 0;
    let (b, c) = ((a + 1) % 3, (a + 2) % 3);
    if positive {
        (a, true, b, c)
    } else {
        (a, false, c, b)
    }
}

impl Scene {
    /// Validates and prepares the primitives, then places the landmarks.
    pub fn new(primitives: Vec<Primitive>) -> Result<Self, String> {
        let mut prepared = Vec::with_capacity(primitives.len());
        let mut textures = Vec::with_capacity(primitives.len());
        for (k, p) in primitives.iter().enumerate() {
            match p {
                Primitive::Plane {
                    origin,
                    edge_u,
                    edge_v,
                    texture,
                } => {
                    let (lu, lv) = (edge_u.norm(), edge_v.norm());
                    if !(lu > 0.0
                        && lv > 0.0
                        && lu.is_finite()
                        && lv.is_finite()
                        && origin.coords.iter().all(|c| c.is_finite()))
                    {
                        return Err(format!("plane {k}: degenerate or non-finite"));
                    }
                    if edge_u.dot(edge_v).abs() > 1e-9 * lu * lv {
                        return Err(format!("plane {k}: edges are not orthogonal"));
                    }
                    let (u, v) = (edge_u / lu, edge_v / lv);
                    let rect = FaceRect {
                        origin: *origin,
                        u,
                        v,
                        normal: u.cross(&v),
                        size: Vector2::new(lu, lv),
                    };
                    textures.push(vec![FaceTexture::new(*texture, 0, rect.size, true)]);
                    prepared.push(Prepared::Plane { rect });
                }
                Primitive::Box {
                    center,
                    half_extents,
                    rotation,
                    texture,
                } => {
                    if !half_extents.iter().all(|h| *h > 0.0 && h.is_finite())
                        || !center.coords.iter().all(|c| c.is_finite())
                    {
                        return Err(format!("box {k}: half extents must be positive and finite"));
                    }
                    let r = *rotation.to_rotation_matrix().matrix();
                    let faces = (0..6)
                        .map(|f| {
                            let (_, _, ua, va) = box_face_axes(f);
                            FaceTexture::new(
                                *texture,
                                f,
                                Vector2::new(2.0 * half_extents[ua], 2.0 * half_extents[va]),
                                true,
                            )
                        })
                        .collect();
                    textures.push(faces);
                    prepared.push(Prepared::Box {
                        center: *center,
                        world_from_box: r,
                        box_from_world: r.transpose(),
                        half: *half_extents,
                        bound_r2: half_extents.norm_squared() * (1.0 + 1e-9),
                    });
                }
                Primitive::Sphere {
                    center,
                    radius,
                    texture,
                } => {
                    if !(*radius > 0.0
                        && radius.is_finite()
                        && center.coords.iter().all(|c| c.is_finite()))
                    {
                        return Err(format!("sphere {k}: radius must be positive and finite"));
                    }
                    let size = Vector2::new(
                        std::f64::consts::TAU * radius,
                        std::f64::consts::PI * radius,
                    );
                    textures.push(vec![FaceTexture::new(*texture, 0, size, false)]);
                    prepared.push(Prepared::Sphere {
                        center: *center,
                        radius: *radius,
                    });
                }
            }
        }
        let gloss = vec![0.0; primitives.len()];
        let finish = vec![Finish::Textured; primitives.len()];
        let mut scene = Self {
            primitives,
            prepared,
            textures,
            landmarks: Vec::new(),
            gloss,
            finish,
        };
        scene.landmarks = scene.place_landmarks();
        Ok(scene)
    }

    pub fn primitives(&self) -> &[Primitive] {
        &self.primitives
    }

    /// Makes primitive `k` glossy: a white Blinn–Phong highlight of `strength` (0 = matte) is
    /// added to its shading, so its appearance depends on the viewpoint (non-Lambertian).
    pub fn with_gloss(mut self, k: usize, strength: f64) -> Self {
        if let Some(g) = self.gloss.get_mut(k) {
            *g = strength.max(0.0);
        }
        self
    }

    /// Gives primitive `k` the finish `f` (plain paint, tiles). Its landmarks stay in
    /// [`Scene::landmarks`] (the ground truth's points) but are not drawn, or drawn faintly.
    pub fn with_finish(mut self, k: usize, f: Finish) -> Self {
        if let Some(x) = self.finish.get_mut(k) {
            *x = f;
        }
        self
    }

    /// The finish of primitive `k` (textured for an invalid index).
    pub fn finish(&self, k: usize) -> Finish {
        self.finish.get(k).copied().unwrap_or_default()
    }

    /// The specular strength of the primitive a ray hit.
    pub fn gloss(&self, hit: &Hit) -> f64 {
        self.gloss.get(hit.primitive).copied().unwrap_or(0.0)
    }

    /// The default scene with its first sphere glossy (issue #19's view-dependent highlight).
    pub fn glossy_scene(seed: u64) -> Self {
        let scene = Self::default_scene(seed);
        let k = scene
            .primitives
            .iter()
            .position(|p| matches!(p, Primitive::Sphere { .. }))
            .unwrap_or(0);
        scene.with_gloss(k, 0.9)
    }

    /// The rectangle of face `face` of primitive `k` (`None` for spheres and invalid indices).
    pub fn face_rect(&self, k: usize, face: u32) -> Option<FaceRect> {
        match self.prepared.get(k)? {
            Prepared::Plane { rect } => (face == 0).then_some(*rect),
            Prepared::Box {
                center,
                world_from_box,
                half,
                ..
            } => {
                if face >= 6 {
                    return None;
                }
                let (a, positive, ua, va) = box_face_axes(face);
                let mut o = Vector3::zeros();
                o[a] = if positive { half[a] } else { -half[a] };
                o[ua] = -half[ua];
                o[va] = -half[va];
                let (u, v) = (
                    world_from_box.column(ua).into_owned(),
                    world_from_box.column(va).into_owned(),
                );
                Some(FaceRect {
                    origin: center + world_from_box * o,
                    u,
                    v,
                    normal: u.cross(&v),
                    size: Vector2::new(2.0 * half[ua], 2.0 * half[va]),
                })
            }
            Prepared::Sphere { .. } => None,
        }
    }

    /// True when `p` lies strictly inside a solid primitive (box or sphere) other than `except`.
    pub fn inside_solid(&self, p: &Point3<f64>, except: Option<usize>) -> bool {
        self.prepared.iter().enumerate().any(|(k, pr)| {
            if Some(k) == except {
                return false;
            }
            match pr {
                Prepared::Plane { .. } => false,
                Prepared::Box {
                    center,
                    box_from_world,
                    half,
                    ..
                } => {
                    let l = box_from_world * (p - center);
                    (0..3).all(|a| l[a].abs() < half[a])
                }
                Prepared::Sphere { center, radius } => (p - center).norm() < *radius,
            }
        })
    }

    /// Landmarks of every rectangular face whose bright square is not buried in another solid.
    /// Downward-facing box faces are skipped: they rest on the ground and are never visible.
    fn place_landmarks(&self) -> Vec<Landmark> {
        let mut out = Vec::new();
        for k in 0..self.prepared.len() {
            for (f, tex) in self.textures[k].iter().enumerate() {
                let Some(rect) = self.face_rect(k, f as u32) else {
                    continue;
                };
                if matches!(self.prepared[k], Prepared::Box { .. }) && rect.normal.z < -0.9 {
                    continue;
                }
                for uv in tex.landmarks() {
                    let buried = (-2..=2).any(|i| {
                        (-2..=2).any(|j| {
                            let d = Vector2::new(i as f64, j as f64) * (LANDMARK_HALF_SQUARE / 2.0);
                            let p = rect.point(&(uv + d)) + rect.normal * 1e-4;
                            self.inside_solid(&p, Some(k))
                        })
                    });
                    if !buried {
                        out.push(Landmark {
                            position: rect.point(&uv),
                            normal: rect.normal,
                            primitive: k,
                            face: f as u32,
                            uv,
                        });
                    }
                }
            }
        }
        out
    }

    /// The landmark disk centres: the ground-truth 3D feature points. `PointId(i)` in generated
    /// reconstructions refers to `landmarks()[i]`.
    pub fn landmarks(&self) -> Vec<Point3<f64>> {
        self.landmarks.iter().map(|l| l.position).collect()
    }

    /// The landmarks with their faces and normals.
    pub fn landmark_info(&self) -> &[Landmark] {
        &self.landmarks
    }

    /// Ray parameter of the nearest hit of primitive `k`, with an auxiliary code (box axis).
    #[inline(always)]
    fn hit_t(&self, k: usize, ro: &Point3<f64>, d: &Vector3<f64>) -> Option<(f64, usize)> {
        match &self.prepared[k] {
            Prepared::Plane { rect } => {
                let denom = rect.normal.dot(d);
                if denom.abs() < 1e-300 {
                    return None;
                }
                let t = rect.normal.dot(&(rect.origin - ro)) / denom;
                if t <= T_MIN {
                    return None;
                }
                let q = ro + d * t - rect.origin;
                let (s, w) = (q.dot(&rect.u), q.dot(&rect.v));
                (s >= 0.0 && s <= rect.size.x && w >= 0.0 && w <= rect.size.y).then_some((t, 0))
            }
            Prepared::Box {
                center,
                box_from_world,
                half,
                bound_r2,
                ..
            } => {
                // Bounding-sphere rejection first: most rays miss most boxes.
                let oc = ro - center;
                let (b, c) = (oc.dot(d), oc.norm_squared() - bound_r2);
                if (c > 0.0 && b > 0.0) || b * b - d.norm_squared() * c < 0.0 {
                    return None;
                }
                let o = box_from_world * oc;
                let dl = box_from_world * d;
                let (mut tn, mut tf, mut an, mut af) = (f64::NEG_INFINITY, f64::INFINITY, 0, 0);
                for a in 0..3 {
                    if dl[a] == 0.0 {
                        if o[a].abs() > half[a] {
                            return None;
                        }
                        continue;
                    }
                    let inv = 1.0 / dl[a];
                    let (mut t0, mut t1) = ((-half[a] - o[a]) * inv, (half[a] - o[a]) * inv);
                    if t0 > t1 {
                        std::mem::swap(&mut t0, &mut t1);
                    }
                    if t0 > tn {
                        tn = t0;
                        an = a;
                    }
                    if t1 < tf {
                        tf = t1;
                        af = a;
                    }
                }
                if tn > tf {
                    None
                } else if tn > T_MIN {
                    Some((tn, an))
                } else if tf > T_MIN {
                    Some((tf, af))
                } else {
                    None
                }
            }
            Prepared::Sphere { center, radius } => {
                let oc = ro - center;
                let a = d.norm_squared();
                let b = oc.dot(d);
                let c = oc.norm_squared() - radius * radius;
                let disc = b * b - a * c;
                if disc < 0.0 {
                    return None;
                }
                let sq = disc.sqrt();
                // Numerically stable roots.
                let q = if b > 0.0 { -(b + sq) } else { -b + sq };
                let (mut t0, mut t1) = (q / a, if q != 0.0 { c / q } else { 0.0 });
                if t0 > t1 {
                    std::mem::swap(&mut t0, &mut t1);
                }
                if t0 > T_MIN {
                    Some((t0, 0))
                } else if t1 > T_MIN {
                    Some((t1, 0))
                } else {
                    None
                }
            }
        }
    }

    /// Nearest intersection of the ray `origin + t·dir`, `t > 0` (`dir` need not be unit).
    pub fn intersect(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> Option<Hit> {
        let mut best: Option<(f64, usize, usize)> = None;
        for k in 0..self.prepared.len() {
            if let Some((t, aux)) = self.hit_t(k, origin, dir) {
                match best {
                    Some((bt, _, _)) if bt <= t => {}
                    _ => best = Some((t, k, aux)),
                }
            }
        }
        let (t, k, aux) = best?;
        let point = origin + dir * t;
        Some(match &self.prepared[k] {
            Prepared::Plane { rect } => {
                let q = point - rect.origin;
                Hit {
                    t,
                    point,
                    normal: rect.normal,
                    primitive: k,
                    face: 0,
                    uv: Vector2::new(q.dot(&rect.u), q.dot(&rect.v)),
                }
            }
            Prepared::Box {
                center,
                world_from_box,
                box_from_world,
                half,
                ..
            } => {
                let l = box_from_world * (point - center);
                let positive = l[aux] >= 0.0;
                let face = 2 * aux as u32 + u32::from(!positive);
                let (_, _, ua, va) = box_face_axes(face);
                let mut n = Vector3::zeros();
                n[aux] = if positive { 1.0 } else { -1.0 };
                let uv = Vector2::new(
                    (l[ua] + half[ua]).clamp(0.0, 2.0 * half[ua]),
                    (l[va] + half[va]).clamp(0.0, 2.0 * half[va]),
                );
                Hit {
                    t,
                    point,
                    normal: world_from_box * n,
                    primitive: k,
                    face,
                    uv,
                }
            }
            Prepared::Sphere { center, radius } => {
                let n = (point - center) / *radius;
                let uv = Vector2::new(
                    radius * (n.y.atan2(n.x) + std::f64::consts::PI),
                    radius * n.z.clamp(-1.0, 1.0).acos(),
                );
                Hit {
                    t,
                    point,
                    normal: n,
                    primitive: k,
                    face: 0,
                    uv,
                }
            }
        })
    }

    /// RGB albedo in `[0, 1]` at a hit.
    pub fn albedo(&self, hit: &Hit) -> [f64; 3] {
        match self
            .textures
            .get(hit.primitive)
            .and_then(|f| f.get(hit.face as usize))
        {
            Some(t) => self.finish(hit.primitive).albedo(t, &hit.uv),
            None => [0.5; 3],
        }
    }

    /// Axis-aligned bounding box `(min, max)` of all primitives.
    pub fn bounds(&self) -> (Point3<f64>, Point3<f64>) {
        let mut lo = Vector3::repeat(f64::INFINITY);
        let mut hi = Vector3::repeat(f64::NEG_INFINITY);
        let mut add = |p: Vector3<f64>| {
            lo = lo.inf(&p);
            hi = hi.sup(&p);
        };
        for pr in &self.prepared {
            match pr {
                Prepared::Plane { rect } => {
                    for (a, b) in [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)] {
                        add(rect
                            .point(&Vector2::new(a * rect.size.x, b * rect.size.y))
                            .coords);
                    }
                }
                Prepared::Box {
                    center,
                    world_from_box,
                    half,
                    ..
                } => {
                    let ext = world_from_box.abs() * half;
                    add(center.coords - ext);
                    add(center.coords + ext);
                }
                Prepared::Sphere { center, radius } => {
                    add(center.coords - Vector3::repeat(*radius));
                    add(center.coords + Vector3::repeat(*radius));
                }
            }
        }
        if lo.x > hi.x {
            return (Point3::origin(), Point3::origin());
        }
        (lo.into(), hi.into())
    }

    /// Length of the bounding-box diagonal: the scene scale used for tolerances.
    pub fn extent(&self) -> f64 {
        let (lo, hi) = self.bounds();
        (hi - lo).norm()
    }
}

#[cfg(test)]
#[path = "scene_tests.rs"]
mod tests;
