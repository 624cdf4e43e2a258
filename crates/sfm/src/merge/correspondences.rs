//! The 3D–3D correspondences between two models through the verified pairs (a keypoint of a view
//! of A that is a point of A, matched to a keypoint of a view of B that is a point of B), and the
//! similarity `a_from_b` by a seeded RANSAC over Umeyama fits of three of them, whose inliers
//! reproject within the metric threshold in A's view. The keypoint → point maps and the walk over
//! the verified matches between two models are shared with the 2D–3D links of `sightings.rs`.

use std::collections::{BTreeMap, BTreeSet};

use handheld_core::{ImageId, MetricReconstruction, PointId, Sim3};
use nalgebra::{Point3, Vector2};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::context::Context;

/// Fewest RANSAC inliers a merge needs (a similarity has 7 degrees of freedom; 3
/// correspondences fix it). templeSparseRing without view 8 splits into 11 + 4 views that share
/// 13 correspondences, 8 of them explained by one similarity.
pub const MIN_MERGE_INLIERS: usize = 8;
/// Smallest fraction of the correspondences the similarity must explain: a chance similarity
/// explains few of them.
pub const MIN_MERGE_INLIER_FRACTION: f64 = 0.5;
/// RANSAC samples of three correspondences.
const MERGE_SAMPLES: usize = 400;

/// A correspondence: a point of A, a point of B, and one observation of it in A (the view and
/// its keypoint position) where the mapped B point is checked.
pub(crate) struct Correspondence {
    pub a: PointId,
    pub b: PointId,
    pub view: ImageId,
    pub xy: Vector2<f64>,
}

/// The keypoint → point map of a model: `(input image index, keypoint) → point`.
pub(super) fn point_of(
    ctx: &Context,
    rec: &MetricReconstruction,
) -> BTreeMap<(usize, u32), PointId> {
    let mut out = BTreeMap::new();
    for (i, im) in ctx.input.images.iter().enumerate() {
        if let Some(v) = rec.views.get(&im.id) {
            for (k, o) in v.observations.iter().enumerate() {
                if let Some(p) = o.point_id {
                    out.insert((i, k as u32), p);
                }
            }
        }
    }
    out
}

/// Every verified match between a view of `x` and a view of `y`, oriented as
/// `(x's input image, its keypoint, y's input image, its keypoint)`, in the pairs' order.
pub(super) fn matches_between<'a>(
    ctx: &'a Context,
    x: &'a MetricReconstruction,
    y: &'a MetricReconstruction,
) -> impl Iterator<Item = (usize, u32, usize, u32)> + 'a {
    ctx.input.pairs.iter().flat_map(move |pair| {
        [(pair.a, pair.b, false), (pair.b, pair.a, true)]
            .into_iter()
            .filter(move |&(ix, iy, _)| {
                x.views.contains_key(&ctx.input.images[ix].id)
                    && y.views.contains_key(&ctx.input.images[iy].id)
            })
            .flat_map(move |(ix, iy, swap)| {
                pair.matches.iter().map(move |&(m0, m1)| {
                    let (kx, ky) = if swap { (m1, m0) } else { (m0, m1) };
                    (ix, kx, iy, ky)
                })
            })
    })
}

/// 3D–3D correspondences between the points of `a` and `b` through the verified pairs.
pub(crate) fn correspondences(
    ctx: &Context,
    a: &MetricReconstruction,
    b: &MetricReconstruction,
) -> Vec<Correspondence> {
    let (pa, pb) = (point_of(ctx, a), point_of(ctx, b));
    let mut seen = BTreeSet::new();
    let mut out = Vec::new();
    for (ia, ka, ib, kb) in matches_between(ctx, a, b) {
        let (Some(&x), Some(&y)) = (pa.get(&(ia, ka)), pb.get(&(ib, kb))) else {
            continue;
        };
        if seen.insert((x, y)) {
            out.push(Correspondence {
                a: x,
                b: y,
                view: ctx.input.images[ia].id,
                xy: ctx.input.images[ia].keypoints[ka as usize],
            });
        }
    }
    out
}

/// Whether the B point mapped by `sim` reprojects within `thr` pixels in A's view.
pub(super) fn explains(
    a: &MetricReconstruction,
    b: &MetricReconstruction,
    sim: &Sim3,
    c: &Correspondence,
    thr: f64,
) -> bool {
    let Some(p) = b.points.get(&c.b) else {
        return false;
    };
    a.project(c.view, &sim.transform_point(&p.xyz))
        .is_some_and(|x| (x - c.xy).norm() <= thr)
}

/// The similarity `a_from_b` by RANSAC over the correspondences, refined on its inliers; `None`
/// with fewer than [`MIN_MERGE_INLIERS`] inliers or under [`MIN_MERGE_INLIER_FRACTION`] of them.
pub(crate) fn similarity(
    ctx: &Context,
    a: &MetricReconstruction,
    b: &MetricReconstruction,
    corr: &[Correspondence],
) -> Option<(Sim3, Vec<usize>)> {
    if corr.len() < MIN_MERGE_INLIERS {
        return None;
    }
    let thr = ctx.opts.metric_max_error_px;
    let xyz = |r: &MetricReconstruction, p: PointId| r.points.get(&p).map(|q| q.xyz);
    let inliers_of = |sim: &Sim3| -> Vec<usize> {
        (0..corr.len())
            .filter(|&k| explains(a, b, sim, &corr[k], thr))
            .collect()
    };
    let mut rng = ChaCha8Rng::seed_from_u64(ctx.opts.seed ^ 0x4D45_5247);
    let mut best: Vec<usize> = Vec::new();
    let mut best_sim = Sim3::identity();
    for _ in 0..MERGE_SAMPLES {
        let s: Vec<usize> = (0..3).map(|_| rng.random_range(0..corr.len())).collect();
        if s[0] == s[1] || s[1] == s[2] || s[0] == s[2] {
            continue;
        }
        let (Some(src), Some(dst)) = (
            s.iter()
                .map(|&k| xyz(b, corr[k].b))
                .collect::<Option<Vec<Point3<f64>>>>(),
            s.iter()
                .map(|&k| xyz(a, corr[k].a))
                .collect::<Option<Vec<Point3<f64>>>>(),
        ) else {
            continue;
        };
        let Some(sim) = Sim3::align(&src, &dst) else {
            continue;
        };
        if !(sim.scale.is_finite() && sim.scale > 0.0) {
            continue;
        }
        let inl = inliers_of(&sim);
        if inl.len() > best.len() {
            best = inl;
            best_sim = sim;
        }
    }
    let enough = |n: usize| {
        n >= MIN_MERGE_INLIERS && n as f64 >= MIN_MERGE_INLIER_FRACTION * corr.len() as f64
    };
    if !enough(best.len()) {
        return None;
    }
    // Refined on every inlier, kept when it explains at least as many (a least-squares fit in 3D
    // weighs the far, poorly triangulated points most, and can explain fewer in the images).
    let src: Vec<Point3<f64>> = best.iter().filter_map(|&k| xyz(b, corr[k].b)).collect();
    let dst: Vec<Point3<f64>> = best.iter().filter_map(|&k| xyz(a, corr[k].a)).collect();
    if let Some(refined) = Sim3::align(&src, &dst) {
        let inl = inliers_of(&refined);
        if inl.len() >= best.len() {
            return Some((refined, inl));
        }
    }
    Some((best_sim, best))
}
