//! Merging through 2D–3D links, for pieces that share too few triangulated points.
//!
//! A piece that hangs on the rest by weak pairs (templeSparseRing without view 8: four views
//! joined to the other eleven by pairs of 15–39 inliers) has triangulated few of the points the
//! two pieces see in common, and those few are poorly placed along their rays: the 3D–3D
//! correspondences of [`super::correspondences::correspondences`] are too few, or too noisy, for a similarity.
//! Every keypoint of one piece's views that is matched, in a verified pair, to a point of the
//! other piece is still a *sighting* of that point: a 2D–3D correspondence, whose image position
//! is as precise as any keypoint and whose point is triangulated by the other piece's views.
//!
//! The similarity is then a generalised resection with scale (the pose and scale of a calibrated
//! multi-camera rig, 7 degrees of freedom; Ventura et al., *A minimal solution to the generalized
//! pose-and-scale problem*, CVPR 2014). We form it from four sightings rather than by their
//! minimal solver: three sightings in one view give that view's pose in the other piece's frame
//! (Grunert's P3P, [`handheld_geometry::p3p`]), which fixes the rotation and, up to the scale, the
//! translation; one sighting in a second view of the same piece fixes the scale in closed form
//! (below). Hypotheses are drawn in both directions (views of B seeing points of A and views of A
//! seeing points of B) inside a seeded RANSAC whose inliers are the sightings that reproject within
//! the metric threshold, then refined by Gauss–Newton on all inliers.
//!
//! **The scale from one sighting.** Let view `j` of piece `P` have the pose `(R_jP, t_jP)` in `P`
//! and, from P3P, `(R_jQ, t_jQ)` in `Q`. The similarity `P ← Q`, `X_P = s R X_Q + t`, has
//! `R = R_jPᵀ R_jQ` and `t = R_jPᵀ (s t_jQ − t_jP)` (camera coordinates in `P` are `s` times those
//! in `Q`). A point `X` of `Q` sighted in view `k ≠ j` of `P` has camera coordinates
//! `y = s a + b` with `a = R_kj (R_jQ X + t_jQ)`, `b = t_kP − R_kj t_jP`, `R_kj = R_kP R_jPᵀ`.
//! Its viewing ray `u` must be parallel to `y`: `u × (s a + b) = 0`, whose least-squares solution
//! is `s = −(u × a)·(u × b) / ‖u × a‖²`.

use std::collections::{BTreeMap, BTreeSet};

use handheld_core::{ImageId, MetricReconstruction, PointId, Sim3};
use handheld_geometry::p3p;
use nalgebra::{SMatrix, SVector, UnitQuaternion, Vector2, Vector3};
use rand::Rng;
use rand_chacha::ChaCha8Rng;

use super::correspondences::{matches_between, point_of};
use crate::context::Context;

/// Fewest sightings the similarity must explain (a similarity has 7 degrees of freedom; each
/// sighting gives 2 equations). As many as the fewest inliers of a verified pair.
pub const MIN_SIGHTING_INLIERS: usize = 15;

/// A keypoint of a view of one piece (the viewer) matched to a point of the other (the seen).
#[derive(Clone, Copy, Debug)]
pub(super) struct Sighting {
    pub view: ImageId,
    pub key: u32,
    pub xy: Vector2<f64>,
    pub point: PointId,
}

/// The sightings of `seen`'s points from `viewer`'s views, through the verified pairs: at most
/// one per keypoint (the first match found).
pub(super) fn sightings(
    ctx: &Context,
    viewer: &MetricReconstruction,
    seen: &MetricReconstruction,
) -> Vec<Sighting> {
    let points = point_of(ctx, seen);
    let mut taken = BTreeSet::new();
    let mut out = Vec::new();
    for (iv, kv, is, ks) in matches_between(ctx, viewer, seen) {
        let Some(&point) = points.get(&(is, ks)) else {
            continue;
        };
        let view = ctx.input.images[iv].id;
        if taken.insert((view, kv)) {
            out.push(Sighting {
                view,
                key: kv,
                xy: ctx.input.images[iv].keypoints[kv as usize],
                point,
            });
        }
    }
    out
}

/// The two directions of sightings between pieces `a` and `b`.
pub(super) struct Links {
    /// Views of `b` seeing points of `a`.
    pub b_sees_a: Vec<Sighting>,
    /// Views of `a` seeing points of `b`.
    pub a_sees_b: Vec<Sighting>,
}

impl Links {
    pub fn new(ctx: &Context, a: &MetricReconstruction, b: &MetricReconstruction) -> Self {
        Self {
            b_sees_a: sightings(ctx, b, a),
            a_sees_b: sightings(ctx, a, b),
        }
    }

    pub fn len(&self) -> usize {
        self.b_sees_a.len() + self.a_sees_b.len()
    }
}

/// The pixel residual of a sighting when `seen`'s point is mapped by `viewer_from_seen`.
fn residual(
    viewer: &MetricReconstruction,
    seen: &MetricReconstruction,
    viewer_from_seen: &Sim3,
    s: &Sighting,
) -> Option<Vector2<f64>> {
    let p = seen.points.get(&s.point)?;
    viewer
        .project(s.view, &viewer_from_seen.transform_point(&p.xyz))
        .map(|x| x - s.xy)
}

/// Indices of the sightings of each direction that `a_from_b` explains within `thr` pixels.
pub(super) fn inliers(
    a: &MetricReconstruction,
    b: &MetricReconstruction,
    links: &Links,
    a_from_b: &Sim3,
    thr: f64,
) -> Inliers {
    let b_from_a = a_from_b.inverse();
    let within = |r: Option<Vector2<f64>>| r.is_some_and(|r| r.norm() <= thr);
    (
        (0..links.b_sees_a.len())
            .filter(|&k| within(residual(b, a, &b_from_a, &links.b_sees_a[k])))
            .collect(),
        (0..links.a_sees_b.len())
            .filter(|&k| within(residual(a, b, a_from_b, &links.a_sees_b[k])))
            .collect(),
    )
}

/// The viewing ray `(x, y, 1)` of a sighting in its view's camera.
fn ray(viewer: &MetricReconstruction, s: &Sighting) -> Option<Vector3<f64>> {
    let v = viewer.views.get(&s.view)?;
    let cam = viewer.cameras.get(&v.camera_id)?;
    let x = cam.intrinsics.pixel_to_normalized(s.xy);
    Some(Vector3::new(x.x, x.y, 1.0))
}

/// Hypotheses `viewer_from_seen` from three sightings in one view of `viewer` (P3P) and one in
/// another (the scale; see the module's notes).
fn hypotheses(
    viewer: &MetricReconstruction,
    seen: &MetricReconstruction,
    list: &[Sighting],
    by_view: &BTreeMap<ImageId, Vec<usize>>,
    rng: &mut ChaCha8Rng,
    out: &mut Vec<Sim3>,
) {
    let views: Vec<&ImageId> = by_view
        .iter()
        .filter(|(_, v)| v.len() >= 3)
        .map(|(k, _)| k)
        .collect();
    if views.is_empty() || by_view.len() < 2 {
        return;
    }
    let j = *views[rng.random_range(0..views.len())];
    let in_j = &by_view[&j];
    let pick: Vec<usize> = (0..3)
        .map(|_| in_j[rng.random_range(0..in_j.len())])
        .collect();
    if pick[0] == pick[1] || pick[1] == pick[2] || pick[0] == pick[2] {
        return;
    }
    let others: usize = list.len() - in_j.len();
    if others == 0 {
        return;
    }
    // The scale's sighting: uniform over the sightings outside view j.
    let mut n = rng.random_range(0..others);
    let scale_sighting = list
        .iter()
        .filter(|s| s.view != j)
        .find(|_| {
            let hit = n == 0;
            n = n.saturating_sub(1);
            hit
        })
        .copied();
    let (Some(rays), Some(world), Some(k_sighting)) = (
        pick.iter()
            .map(|&i| ray(viewer, &list[i]))
            .collect::<Option<Vec<_>>>(),
        pick.iter()
            .map(|&i| seen.points.get(&list[i].point).map(|p| p.xyz.coords))
            .collect::<Option<Vec<_>>>(),
        scale_sighting,
    ) else {
        return;
    };
    let (Some(u), Some(x_k), Some(vj), Some(vk)) = (
        ray(viewer, &k_sighting),
        seen.points.get(&k_sighting.point).map(|p| p.xyz.coords),
        viewer.views.get(&j),
        viewer.views.get(&k_sighting.view),
    ) else {
        return;
    };
    let rays: [Vector3<f64>; 3] = [rays[0], rays[1], rays[2]];
    let world: [Vector3<f64>; 3] = [world[0], world[1], world[2]];
    let (r_jp, t_jp) = (
        vj.cam_from_world.rotation,
        vj.cam_from_world.translation.vector,
    );
    let (r_kp, t_kp) = (
        vk.cam_from_world.rotation,
        vk.cam_from_world.translation.vector,
    );
    let r_kj = r_kp * r_jp.inverse();
    let b = t_kp - r_kj * t_jp;
    for pose in p3p(&rays, &world) {
        let a = r_kj * pose.transform(&x_k);
        let (ua, ub) = (u.cross(&a), u.cross(&b));
        let den = ua.norm_squared();
        if den < 1e-18 {
            continue;
        }
        let s = -ua.dot(&ub) / den;
        if !(s.is_finite() && s > 0.0) || (s * a + b).dot(&u) <= 0.0 {
            continue;
        }
        let rotation = r_jp.inverse() * pose.rotation;
        out.push(Sim3 {
            scale: s,
            rotation,
            translation: r_jp.inverse() * (s * pose.translation - t_jp),
        });
    }
}

/// `sim` moved by the 7-vector `d`: `ln s`, a rotation vector (applied on the left) and a
/// translation step, relative to the scene's size `extent`.
fn perturbed(sim: &Sim3, d: &SVector<f64, 7>, extent: f64) -> Sim3 {
    let dr = UnitQuaternion::from_scaled_axis(Vector3::new(d[1], d[2], d[3]));
    Sim3 {
        scale: sim.scale * d[0].exp(),
        rotation: dr * sim.rotation,
        translation: dr * sim.translation + extent * Vector3::new(d[4], d[5], d[6]),
    }
}

/// Gauss–Newton (with a small Levenberg damping) on the pixel residuals of the inlier sightings,
/// by central differences: 7 parameters, so the Jacobian costs 14 residual passes.
fn refine(
    a: &MetricReconstruction,
    b: &MetricReconstruction,
    links: &Links,
    a_from_b: &Sim3,
    (ib, ia): (&[usize], &[usize]),
) -> Sim3 {
    let extent = {
        let c: Vec<Vector3<f64>> = a.points.values().map(|p| p.xyz.coords).collect();
        let n = c.len().max(1) as f64;
        let mean = c.iter().sum::<Vector3<f64>>() / n;
        (c.iter().map(|x| (x - mean).norm_squared()).sum::<f64>() / n)
            .sqrt()
            .max(1e-9)
    };
    let residuals = |sim: &Sim3| -> Option<Vec<f64>> {
        let inv = sim.inverse();
        let mut r = Vec::with_capacity(2 * (ib.len() + ia.len()));
        for &k in ib {
            let e = residual(b, a, &inv, &links.b_sees_a[k])?;
            r.extend([e.x, e.y]);
        }
        for &k in ia {
            let e = residual(a, b, sim, &links.a_sees_b[k])?;
            r.extend([e.x, e.y]);
        }
        Some(r)
    };
    let cost = |r: &[f64]| r.iter().map(|x| x * x).sum::<f64>();
    let mut sim = *a_from_b;
    let Some(mut r0) = residuals(&sim) else {
        return sim;
    };
    let mut lambda = 1e-4;
    for _ in 0..20 {
        let h = 1e-6;
        let mut jac: Vec<Vec<f64>> = Vec::with_capacity(7);
        for p in 0..7 {
            let mut d = SVector::<f64, 7>::zeros();
            d[p] = h;
            let (Some(rp), Some(rm)) = (
                residuals(&perturbed(&sim, &d, extent)),
                residuals(&perturbed(&sim, &(-d), extent)),
            ) else {
                return sim;
            };
            jac.push(
                rp.iter()
                    .zip(&rm)
                    .map(|(x, y)| (x - y) / (2.0 * h))
                    .collect(),
            );
        }
        let mut jtj = SMatrix::<f64, 7, 7>::zeros();
        let mut jtr = SVector::<f64, 7>::zeros();
        for p in 0..7 {
            jtr[p] = jac[p].iter().zip(&r0).map(|(x, y)| x * y).sum();
            for q in p..7 {
                let v: f64 = jac[p].iter().zip(&jac[q]).map(|(x, y)| x * y).sum();
                jtj[(p, q)] = v;
                jtj[(q, p)] = v;
            }
        }
        let mut improved = false;
        while lambda < 1e6 {
            let mut m = jtj;
            for p in 0..7 {
                m[(p, p)] *= 1.0 + lambda;
            }
            let Some(step) = m.cholesky().map(|c| c.solve(&(-jtr))) else {
                lambda *= 10.0;
                continue;
            };
            let cand = perturbed(&sim, &step, extent);
            match residuals(&cand) {
                Some(r) if cost(&r) < cost(&r0) => {
                    let gain = cost(&r0) - cost(&r);
                    sim = cand;
                    r0 = r;
                    lambda = (lambda / 10.0).max(1e-8);
                    improved = gain > 1e-10 * cost(&r0).max(1e-300);
                    break;
                }
                _ => lambda *= 10.0,
            }
        }
        if !improved {
            break;
        }
    }
    sim
}

/// The inlier sightings of each direction: `(b_sees_a, a_sees_b)` indices.
pub(super) type Inliers = (Vec<usize>, Vec<usize>);

/// Number of seeded RANSAC draws in each direction.
const SIGHTING_SAMPLES: usize = 500;

/// The similarity `a_from_b` from the sightings in both directions (RANSAC, then refined on its
/// inliers): with the inliers of each direction, or `None` when fewer than
/// [`MIN_SIGHTING_INLIERS`], or under `min_fraction` of the sightings, are explained.
pub(super) fn similarity(
    ctx: &Context,
    a: &MetricReconstruction,
    b: &MetricReconstruction,
    links: &Links,
    min_fraction: f64,
    rng: &mut ChaCha8Rng,
) -> Option<(Sim3, Inliers)> {
    if links.len() < MIN_SIGHTING_INLIERS {
        return None;
    }
    let thr = ctx.opts.metric_max_error_px;
    let group = |list: &[Sighting]| {
        let mut m: BTreeMap<ImageId, Vec<usize>> = BTreeMap::new();
        for (k, s) in list.iter().enumerate() {
            m.entry(s.view).or_default().push(k);
        }
        m
    };
    let (gb, ga) = (group(&links.b_sees_a), group(&links.a_sees_b));
    let mut candidates: Vec<Sim3> = Vec::new();
    let mut drawn = Vec::new();
    for _ in 0..SIGHTING_SAMPLES {
        drawn.clear();
        hypotheses(b, a, &links.b_sees_a, &gb, rng, &mut drawn);
        candidates.extend(drawn.iter().map(Sim3::inverse));
        drawn.clear();
        hypotheses(a, b, &links.a_sees_b, &ga, rng, &mut drawn);
        candidates.append(&mut drawn);
    }
    let count = |(x, y): &Inliers| x.len() + y.len();
    let mut best: Option<(Sim3, Inliers)> = None;
    for sim in candidates {
        if !(sim.scale.is_finite() && sim.scale > 0.0) {
            continue;
        }
        let inl = inliers(a, b, links, &sim, thr);
        if best.as_ref().is_none_or(|(_, b)| count(&inl) > count(b)) {
            best = Some((sim, inl));
        }
    }
    let (sim, inl) = best?;
    // Refined on every inlier; the inliers taken again under the refined similarity, twice.
    let (mut sim, mut inl) = (sim, inl);
    for _ in 0..2 {
        let refined = refine(a, b, links, &sim, (&inl.0, &inl.1));
        let again = inliers(a, b, links, &refined, thr);
        if count(&again) < count(&inl) {
            break;
        }
        sim = refined;
        inl = again;
    }
    let n = count(&inl);
    if n < MIN_SIGHTING_INLIERS || (n as f64) < min_fraction * links.len() as f64 {
        tracing::debug!(
            "{n} of {} sightings explained by the best similarity",
            links.len()
        );
        return None;
    }
    Some((sim, inl))
}
