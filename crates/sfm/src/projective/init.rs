//! The initial frame of §3.1 (Table 2, step 2): candidate pairs scored by inliers × the image-based
//! distance of eq. 14, the camera pair of eq. 16 in a quasi-Euclidean frame, and the initial structure
//! by the optimal method of Hartley & Sturm (eqs. 17–18).

use handheld_core::ProjectiveCamera;
use handheld_geometry::{
    fundamental_8point, optimal_correction, sampson_distance, skew, triangulate_iterative,
    triangulate_linear,
};
use nalgebra::{Matrix3, Matrix3x4, Vector2, Vector3};

use crate::context::Context;
use crate::projective::model::{ProjectiveModel, NONE};

/// The eq. 16 pair for a fundamental matrix `F` (normalised coordinates, `x2ᵀ F x1 = 0`):
/// `P1 = [I | 0]`, `P2 = [[e]× F + e aᵀ | σ e]`. Any `a` and `σ` reproduce `F`; we choose them so
/// that `P2` is as close as possible to the `[R | t]` of the essential matrix nearest to `F` (what
/// the cameras would be if `K_N` were the true calibration). This quasi-Euclidean frame (Beardsley,
/// Zisserman & Murray 1997) keeps the later linear steps and the projective bundle adjustment well
/// conditioned and makes orientation tests meaningful. Returns `P2` and the points' cheirality count.
pub(crate) fn initial_cameras(
    f: &Matrix3<f64>,
    x1: &[Vector2<f64>],
    x2: &[Vector2<f64>],
) -> Option<Matrix3x4<f64>> {
    let svd = f.svd(true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    // Singular values are not sorted by nalgebra's SVD for 3×3; find the smallest.
    let smallest =
        (0..3).min_by(|&a, &b| svd.singular_values[a].total_cmp(&svd.singular_values[b]))?;
    let mut d = Matrix3::identity();
    d[(smallest, smallest)] = 0.0;
    let e_mat = u * d * vt;
    let (_, r, t) = essential_pose(&e_mat, x1, x2)?;
    // e: the epipole in image 2 (Fᵀ e = 0), oriented along t; F scaled to best match E = [t]× R.
    let e = t.normalize();
    let target = skew(&e) * r;
    let mut fs = f * (target.norm() / f.norm());
    if (fs.transpose() * target).trace() < 0.0 {
        fs = -fs;
    }
    let m = skew(&e) * fs;
    let proj = Matrix3::identity() - e * e.transpose();
    let pr = proj * r;
    let s = (pr.transpose() * (proj * m)).trace() / pr.norm_squared();
    if s.abs() <= 1e-12 || s.is_nan() {
        return None;
    }
    let a = (s * r - m).transpose() * e;
    let left = (m + e * a.transpose()) / s;
    let mut p2 = Matrix3x4::zeros();
    p2.fixed_view_mut::<3, 3>(0, 0).copy_from(&left);
    p2.fixed_view_mut::<3, 1>(0, 3).copy_from(&e);
    Some(p2)
}

/// The one of the four `(R, t)` of an essential matrix (H&Z §9.6.2) that puts the most of the
/// normalised matches `x1 ↔ x2` (`x2ᵀ E x1 = 0`; at most 200 of them, evenly spaced) in front of
/// both cameras: `x2 ~ R x1 + t`. Returns that count with the pose; `e` need not have two equal
/// singular values (its SVD is re-ordered, only `U` and `Vᵀ` are used).
pub(crate) fn essential_pose(
    e_mat: &Matrix3<f64>,
    x1: &[Vector2<f64>],
    x2: &[Vector2<f64>],
) -> Option<(usize, Matrix3<f64>, Vector3<f64>)> {
    let w = Matrix3::new(0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0);
    // Four (R, t) candidates of the essential matrix E ≈ F (H&Z §9.6.2); the ordering of singular
    // values is handled by building E's own SVD.
    let esvd = e_mat.svd(true, true);
    let (mut eu, mut evt) = (esvd.u?, esvd.v_t?);
    let order = {
        let mut o = [0usize, 1, 2];
        o.sort_by(|&a, &b| esvd.singular_values[b].total_cmp(&esvd.singular_values[a]));
        o
    };
    eu = Matrix3::from_columns(&[
        eu.column(order[0]),
        eu.column(order[1]),
        eu.column(order[2]),
    ]);
    evt = Matrix3::from_rows(&[evt.row(order[0]), evt.row(order[1]), evt.row(order[2])]);
    if eu.determinant() < 0.0 {
        eu = -eu;
    }
    if evt.determinant() < 0.0 {
        evt = -evt;
    }
    let t = eu.column(2).into_owned();
    let mut best: Option<(usize, Matrix3<f64>, Vector3<f64>)> = None;
    for r in [eu * w * evt, eu * w.transpose() * evt] {
        for tt in [t, -t] {
            let mut p2 = Matrix3x4::zeros();
            p2.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
            p2.fixed_view_mut::<3, 1>(0, 3).copy_from(&tt);
            let cams = [ProjectiveCamera::canonical(), ProjectiveCamera { P: p2 }];
            let mut good = 0;
            for (a, b) in x1.iter().zip(x2).step_by((x1.len() / 200).max(1)) {
                if let Ok(x) = triangulate_linear(&cams, &[*a, *b]) {
                    let m = x.X;
                    let d1 = m.z * m.w;
                    let d2 = (p2.row(2) * m)[0] * m.w;
                    if d1 > 0.0 && d2 > 0.0 {
                        good += 1;
                    }
                }
            }
            if best.as_ref().is_none_or(|b| good > b.0) {
                best = Some((good, r, tt));
            }
        }
    }
    best
}

/// Sets up the initial frame from a verified pair (Table 2, steps 2.1–2.4). `None` when the pair
/// gives too few well-triangulated points.
pub(crate) fn initialize(ctx: &Context, a: usize, b: usize) -> Option<ProjectiveModel> {
    let pair = ctx
        .input
        .pairs
        .iter()
        .find(|p| (p.a == a && p.b == b) || (p.a == b && p.b == a))?;
    let swap = pair.a != a;
    let matches: Vec<(u32, u32)> = pair
        .matches
        .iter()
        .map(|&(i, j)| if swap { (j, i) } else { (i, j) })
        .collect();
    let x1: Vec<Vector2<f64>> = matches.iter().map(|m| ctx.kps[a][m.0 as usize]).collect();
    let x2: Vec<Vector2<f64>> = matches.iter().map(|m| ctx.kps[b][m.1 as usize]).collect();
    let f = fundamental_8point(&x1, &x2).ok()?;
    let f = handheld_geometry::refine_fundamental(&f, &x1, &x2, &Default::default())
        .map(|r| r.f)
        .unwrap_or(f);
    let thr = ctx.threshold(a).max(ctx.threshold(b));
    let keep: Vec<usize> = (0..matches.len())
        .filter(|&k| sampson_distance(&f, &x1[k], &x2[k]) < thr)
        .collect();
    let (k1, k2): (Vec<_>, Vec<_>) = keep.iter().map(|&k| (x1[k], x2[k])).unzip();
    let p2 = initial_cameras(&f, &k1, &k2)?;
    let p1 = Matrix3x4::identity();
    let fc = handheld_geometry::fundamental_from_cameras(
        &ProjectiveCamera { P: p1 },
        &ProjectiveCamera { P: p2 },
    )
    .ok()?;
    let mut model = ProjectiveModel::new(ctx);
    model.cams[a] = Some(p1);
    model.cams[b] = Some(p2);
    model.order = vec![a, b];
    model.init_pair = (a, b);
    for &k in &keep {
        let (ia, ib) = matches[k];
        if model.kp_point[a][ia as usize] != NONE || model.kp_point[b][ib as usize] != NONE {
            continue;
        }
        // Hartley–Sturm (eq. 18) then the exact intersection of the corrected rays.
        let Ok((c1, c2)) = optimal_correction(&fc, &x1[k], &x2[k]) else {
            continue;
        };
        let Ok(x) = triangulate_iterative(&[p1, p2], &[c1, c2], 0) else {
            continue;
        };
        let obs = vec![(a as u32, ia), (b as u32, ib)];
        if obs
            .iter()
            .all(|&(i, kp)| model.obs_error(ctx, &x, i, kp) < thr)
        {
            model.add_point(x, obs);
        }
    }
    if model.num_points() < ctx.opts.init_min_points {
        return None;
    }
    Some(model)
}

/// Whether a verified pair could start a model: both views allowed, and enough inliers.
pub(crate) fn can_start(ctx: &Context, allowed: &[bool], p: &crate::input::SfmPair) -> bool {
    allowed[p.a] && allowed[p.b] && p.matches.len() >= ctx.opts.init_min_points
}

/// Candidate initial pairs among `allowed` images, best first: general (non-planar, non-rotation)
/// pairs scored by inliers × the image-based distance of eq. 14.
pub(crate) fn initial_pair_candidates(ctx: &Context, allowed: &[bool]) -> Vec<(usize, usize, f64)> {
    use handheld_robust::TwoViewConfiguration as C;
    let mut v: Vec<(usize, usize, f64)> = ctx
        .input
        .pairs
        .iter()
        .filter(|p| p.configuration == C::General && can_start(ctx, allowed, p))
        .map(|p| {
            let d = p.view_distance_px.unwrap_or(1.0).max(1e-3);
            (p.a.min(p.b), p.a.max(p.b), p.matches.len() as f64 * d)
        })
        .collect();
    v.sort_by(|a, b| b.2.total_cmp(&a.2).then((a.0, a.1).cmp(&(b.0, b.1))));
    v
}
