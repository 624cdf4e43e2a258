//! Adding views to the projective model (§3.2, Table 2 step 3): 2D–3D candidates from every
//! registered view matched to the new one (the predecessor and all close views), projective
//! resection by the 6-point DLT inside the shared RANSAC with T(1,1), refinement of the structure
//! by eq. 20 and new points from all registered partners.

use handheld_geometry::{reprojection_distance, resection_iterative, triangulate_iterative};
use handheld_robust::{run as ransac, Match2d3d, Msac, ResectionEstimator, UniformSampler};
use nalgebra::{Matrix3x4, Vector2, Vector4};

use super::model::{ProjectiveModel, NONE};
use super::planar::{recover_parallax, PlaneTest};
use crate::context::Context;

impl ProjectiveModel {
    /// 2D–3D candidates of an unregistered image: `(keypoint, point)` pairs through the
    /// correspondence graph, from every registered view it was matched to.
    pub(super) fn candidates(&self, ctx: &Context, image: usize) -> Vec<(u32, u32, u32)> {
        let mut out: Vec<(u32, u32, u32)> = Vec::new();
        for kp in 0..ctx.graph.num_keypoints(image) {
            let start = out.len();
            for &(oi, ok) in ctx.graph.correspondences(image, kp) {
                if self.cams[oi as usize].is_none() {
                    continue;
                }
                let pid = self.kp_point[oi as usize][ok as usize];
                if pid == NONE {
                    continue;
                }
                match out[start..].iter_mut().find(|c| c.1 == pid) {
                    Some(c) => c.2 += 1,
                    None => out.push((kp as u32, pid, 1)),
                }
            }
        }
        out
    }

    /// Table 2 step 3 for one image: robust resection, structure refinement, new points. Returns the
    /// number of resection inliers, or why it failed.
    pub(super) fn register(&mut self, ctx: &Context, image: usize) -> Result<usize, String> {
        let cand = self.candidates(ctx, image);
        let all: Vec<Match2d3d> = cand
            .iter()
            .map(|&(kp, pid, _)| Match2d3d {
                x: ctx.kps[image][kp as usize],
                m: self.points[pid as usize]
                    .as_ref()
                    .map(|p| p.m)
                    .unwrap_or_default(),
            })
            .collect();
        let min = ctx.opts.min_resection_inliers;
        if all.len() < min {
            return Err(format!("{} 2D–3D correspondences, need {min}", all.len()));
        }
        // Hypotheses come from the candidates that several registered views agree on (the keypoint
        // was matched to two or more observations of the same point) when there are enough of them:
        // a false pairwise match rarely repeats, so their inlier ratio is far higher.
        let strong: Vec<usize> = (0..cand.len()).filter(|&k| cand[k].2 >= 2).collect();
        let sample_idx: Vec<usize> = if strong.len() >= min.max(30) {
            strong
        } else {
            (0..cand.len()).collect()
        };
        let samples: Vec<Match2d3d> = sample_idx.iter().map(|&k| all[k]).collect();
        let thr = ctx.threshold(image);
        let ropts = ctx.resection_ransac(image, thr);
        let rep = ransac(
            &ResectionEstimator::default(),
            &Msac,
            &mut UniformSampler::new(ropts.seed),
            &samples,
            &ropts,
        )
        .map_err(|e| e.to_string())?;
        let Some(mut p) = rep.model.filter(|_| rep.success) else {
            return Err(format!(
                "resection RANSAC found no camera among {} 2D–3D correspondences (best support {}, {} trials, {} T(d,d) rejections)",
                samples.len(),
                rep.support,
                rep.num_trials,
                rep.num_tdd_rejections
            ));
        };
        // Refit on the inliers among all candidates, twice (the set grows once the camera is good).
        let mut inl = refit(&mut p, &all, thr);
        // A plane's points leave the camera undetermined (`planar.rs`): take the member of the
        // degenerate family the off-plane matches support, or wait for structure off the plane.
        let (m, x): (Vec<_>, Vec<_>) = inl.iter().map(|&k| (all[k].m, all[k].x)).unzip();
        if let Some(test) = PlaneTest::of(&p, &m, &x).filter(PlaneTest::planar) {
            let (am, ax): (Vec<_>, Vec<_>) = all.iter().map(|c| (c.m, c.x)).unzip();
            let planar = |t: &PlaneTest| {
                format!(
                    "its {} resection inliers lie on one plane (GRIC: camera {:.0}, plane {:.0}), which leaves its camera undetermined; it waits for structure off the plane, or calibrated resection after the upgrade",
                    inl.len(),
                    t.gric_camera,
                    t.gric_plane
                )
            };
            let Some(q) = recover_parallax(&p, &test.plane, &am, &ax, thr, ropts.seed) else {
                return Err(planar(&test));
            };
            let mut q = q;
            let inl_q = refit(&mut q, &all, thr);
            let (m, x): (Vec<_>, Vec<_>) = inl_q.iter().map(|&k| (all[k].m, all[k].x)).unzip();
            match PlaneTest::of(&q, &m, &x) {
                Some(t) if !t.planar() => {
                    tracing::debug!(
                        "{}: resection on a plane, completed by {} matches off it",
                        ctx.input.images[image].name,
                        inl_q.len().saturating_sub(inl.len())
                    );
                    p = q;
                    inl = inl_q;
                    self.planar_completed.push(image);
                }
                _ => return Err(planar(&test)),
            }
        }
        let samples = all;
        let m: Vec<Vector4<f64>> = inl.iter().map(|&k| samples[k].m).collect();
        // Orientation: the camera's sign makes the points' depths positive (points are oriented so).
        let pos = m.iter().filter(|m| (p.row(2) * *m)[0] > 0.0).count();
        if 2 * pos < m.len() {
            p = -p;
        }
        self.cams[image] = Some(p);
        let mut scored: Vec<(f64, u32, u32)> = inl
            .iter()
            .map(|&k| {
                let (kp, pid, _) = cand[k];
                (
                    self.obs_error(ctx, &samples[k].m, image as u32, kp),
                    kp,
                    pid,
                )
            })
            .filter(|s| s.0 < thr)
            .collect();
        scored.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut touched = Vec::new();
        for (_, kp, pid) in scored {
            if self.kp_point[image][kp as usize] != NONE {
                continue;
            }
            let Some(pt) = self.points[pid as usize].as_mut() else {
                continue;
            };
            if pt.obs.iter().any(|&(i, _)| i as usize == image) {
                continue;
            }
            pt.obs.push((image as u32, kp));
            self.kp_point[image][kp as usize] = pid;
            touched.push(pid as usize);
        }
        let n_inliers = touched.len();
        if n_inliers < min {
            // Undo: the camera is not trustworthy.
            for pid in touched {
                if let Some(pt) = self.points[pid].as_mut() {
                    pt.obs.retain(|&(i, _)| i as usize != image);
                }
            }
            for v in self.kp_point[image].iter_mut() {
                *v = NONE;
            }
            self.cams[image] = None;
            return Err(format!(
                "only {n_inliers} consistent resection inliers, need {min}"
            ));
        }
        // Step 3.2: refine the touched points with eq. 20 over all their views.
        for pid in touched {
            self.refine_point(ctx, pid);
        }
        self.order.push(image);
        // Step 3.5: new points.
        self.triangulate_image(ctx, image);
        Ok(n_inliers)
    }

    /// New points from the keypoints of `image` that have registered partners without a point.
    pub(super) fn triangulate_image(&mut self, ctx: &Context, image: usize) {
        for kp in 0..ctx.graph.num_keypoints(image) {
            if self.kp_point[image][kp] != NONE {
                continue;
            }
            let mut obs = vec![(image as u32, kp as u32)];
            for &(oi, ok) in ctx.graph.correspondences(image, kp) {
                if self.cams[oi as usize].is_some()
                    && self.kp_point[oi as usize][ok as usize] == NONE
                    && !obs.iter().any(|o| o.0 == oi)
                {
                    obs.push((oi, ok));
                }
            }
            // Two views of one shot (a duplicate and its twin) fix no depth.
            let twin = ctx.twin[image];
            if obs.len() < 2 || obs.iter().all(|o| ctx.twin[o.0 as usize] == twin) {
                continue;
            }
            self.try_add_point(ctx, obs);
        }
    }

    fn try_add_point(&mut self, ctx: &Context, mut obs: Vec<(u32, u32)>) {
        loop {
            let cams: Vec<Matrix3x4<f64>> = obs
                .iter()
                .filter_map(|&(i, _)| self.cams[i as usize])
                .collect();
            let xs: Vec<Vector2<f64>> = obs
                .iter()
                .map(|&(i, k)| ctx.kps[i as usize][k as usize])
                .collect();
            let Ok(m) = triangulate_iterative(&cams, &xs, ctx.opts.triangulation_iterations) else {
                return;
            };
            let errs: Vec<f64> = obs
                .iter()
                .map(|&(i, k)| self.obs_error(ctx, &m, i, k) / ctx.threshold(i as usize))
                .collect();
            let (worst, &we) = errs
                .iter()
                .enumerate()
                .max_by(|a, b| a.1.total_cmp(b.1))
                .unwrap_or((0, &0.0));
            if we < 1.0 {
                let first = ctx.twin[obs[0].0 as usize];
                if obs.iter().any(|o| ctx.twin[o.0 as usize] != first) {
                    self.add_point(m, obs);
                }
                return;
            }
            // Drop the worst view (never the new image, which is first) and retry while ≥ 2 remain.
            if obs.len() <= 2 || worst == 0 {
                return;
            }
            obs.remove(worst);
        }
    }
}

/// The camera refitted (6-point DLT then iterative, `resection_iterative`) on the candidates within
/// `thr` of it, twice (the set grows once the camera is good). Returns the inliers of the last fit.
fn refit(p: &mut Matrix3x4<f64>, all: &[Match2d3d], thr: f64) -> Vec<usize> {
    let mut inl: Vec<usize> = Vec::new();
    for _ in 0..2 {
        let next: Vec<usize> = (0..all.len())
            .filter(|&k| reprojection_distance(p, &all[k].m, &all[k].x) < thr)
            .collect();
        if next.len() < 6 {
            break;
        }
        inl = next;
        let (m, x): (Vec<_>, Vec<_>) = inl.iter().map(|&k| (all[k].m, all[k].x)).unzip();
        if let Ok(r) = resection_iterative(&m, &x, 3) {
            *p = r;
        }
    }
    inl
}
