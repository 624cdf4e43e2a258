//! Projective structure and motion (§3.1–3.3, Table 2, steps 2–4), in the image coordinates
//! normalised by `K_N` of eq. 24 so that every linear system is well conditioned and the cameras come
//! out ready for self-calibration.
//!
//! - Initial frame (§3.1, in `init.rs`): the pair that maximises matches × image-based distance (eq. 14); the camera
//!   pair of eq. 16 with the reference plane `a` chosen to make the frame quasi-Euclidean (see
//!   [`initial_cameras`]); points by the optimal method of Hartley & Sturm (eqs. 17–18).
//! - Adding views (§3.2): 2D–3D candidates from every registered view matched to the new one (the
//!   predecessor and all close views), projective resection by the 6-point DLT inside the shared
//!   RANSAC with T(1,1); structure refinement by eq. 20; new points from all registered partners.
//! - Projective bundle adjustment (§3.3, eq. 21) after the model grows by a fixed factor and at the end,
//!   each followed by removal of observations that no longer reproject within the threshold.

use handheld_core::ImageId;
use std::collections::BTreeMap;
use std::sync::Arc;

use handheld_geometry::{reprojection_distance, resection_iterative, triangulate_iterative};
use handheld_robust::{
    run as ransac, Match2d3d, Msac, RansacOptions, ResectionEstimator, UniformSampler,
};
use nalgebra::{Matrix3, Matrix3x4, Vector2, Vector4};

use crate::graph::CorrespondenceGraph;
use crate::input::SfmInput;
use crate::options::SfmOptions;
use crate::projective_ba::ProjectiveBaRecord;

/// "No point" in [`ProjectiveModel::kp_point`].
pub(crate) const NONE: u32 = u32::MAX;

/// A projective point and its observations `(image index, keypoint index)`; `m` is unit-norm with
/// `p3·m > 0` for every observing camera (oriented projective geometry).
#[derive(Clone, Debug)]
pub(crate) struct PPoint {
    pub m: Vector4<f64>,
    pub obs: Vec<(u32, u32)>,
}

/// Shared read-only data of a reconstruction.
pub(crate) struct Context<'a> {
    pub input: &'a SfmInput,
    pub graph: &'a CorrespondenceGraph,
    pub opts: &'a SfmOptions,
    /// Keypoints normalised by `K_N⁻¹` (eq. 24).
    pub kps: Vec<Vec<Vector2<f64>>>,
    /// `K_N` per image.
    pub kn: Vec<Matrix3<f64>>,
    /// Pixels → normalised units (`1 / (w + h)`).
    pub scale: Vec<f64>,
    /// Localisation σ (pixels) of every keypoint, per image id, for metric BA; empty when the
    /// observations are not weighted (see [`keypoint_sigmas`]).
    pub keypoint_sigma: BTreeMap<ImageId, Arc<[f64]>>,
}

/// σ = √(s / median s), clamped to [0.5, 4], of every keypoint with a detection scale `s`
/// (`SfmOptions::scale_weighted_observations`). The median is over all keypoints of all images,
/// so the median keypoint keeps σ = 1 px and thresholds stay in pixels.
fn keypoint_sigmas(input: &SfmInput, opts: &SfmOptions) -> BTreeMap<ImageId, Arc<[f64]>> {
    if !opts.scale_weighted_observations {
        return BTreeMap::new();
    }
    let mut all: Vec<f32> = input
        .images
        .iter()
        .flat_map(|im| im.keypoint_scales.iter().copied())
        .collect();
    if all.is_empty() {
        return BTreeMap::new();
    }
    let mid = all.len() / 2;
    let median = f64::from(*all.select_nth_unstable_by(mid, f32::total_cmp).1);
    input
        .images
        .iter()
        .filter(|im| !im.keypoint_scales.is_empty())
        .map(|im| {
            let s: Arc<[f64]> = im
                .keypoint_scales
                .iter()
                .map(|&s| (f64::from(s) / median).sqrt().clamp(0.5, 4.0))
                .collect();
            (im.id, s)
        })
        .collect()
}

impl<'a> Context<'a> {
    pub fn new(input: &'a SfmInput, graph: &'a CorrespondenceGraph, opts: &'a SfmOptions) -> Self {
        let kn: Vec<Matrix3<f64>> = input
            .images
            .iter()
            .map(|im| crate::selfcal::normalization_matrix(im.width, im.height))
            .collect();
        let kps = input
            .images
            .iter()
            .zip(&kn)
            .map(|(im, k)| {
                let s = k[(0, 0)];
                let (cx, cy) = (k[(0, 2)], k[(1, 2)]);
                im.keypoints
                    .iter()
                    .map(|p| Vector2::new((p.x - cx) / s, (p.y - cy) / s))
                    .collect()
            })
            .collect();
        let scale = kn.iter().map(|k| 1.0 / k[(0, 0)]).collect();
        Self {
            input,
            graph,
            opts,
            kps,
            kn,
            scale,
            keypoint_sigma: keypoint_sigmas(input, opts),
        }
    }

    /// RANSAC options of a resection (projective or calibrated) of `image`: T(1,1), a seed per
    /// image derived from the options' seed (same seed, same model), at most 5000 trials.
    pub fn resection_ransac(&self, image: usize, max_error: f64) -> RansacOptions {
        RansacOptions {
            max_error,
            tdd: Some(1),
            seed: self.opts.seed ^ (image as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15),
            min_inlier_ratio: 0.02,
            max_iterations: 5000,
            ..Default::default()
        }
    }

    /// The projective inlier threshold of an image in normalised units.
    pub fn threshold(&self, image: usize) -> f64 {
        self.opts.projective_max_error_px * self.scale[image]
    }

    pub(crate) fn median_scale(&self) -> f64 {
        let mut s = self.scale.clone();
        s.sort_by(f64::total_cmp);
        s[s.len() / 2]
    }
}

/// The growing projective model.
pub(crate) struct ProjectiveModel {
    pub cams: Vec<Option<Matrix3x4<f64>>>,
    pub kp_point: Vec<Vec<u32>>,
    pub points: Vec<Option<PPoint>>,
    /// Registration order (the initial pair first).
    pub order: Vec<usize>,
    pub init_pair: (usize, usize),
    pub ba: Vec<ProjectiveBaRecord>,
    /// Images whose resection failed, with the reason (the last attempt).
    pub failures: BTreeMap<usize, String>,
}

impl ProjectiveModel {
    pub(crate) fn new(ctx: &Context) -> Self {
        let n = ctx.input.images.len();
        Self {
            cams: vec![None; n],
            kp_point: ctx
                .input
                .images
                .iter()
                .map(|im| vec![NONE; im.keypoints.len()])
                .collect(),
            points: Vec::new(),
            order: Vec::new(),
            init_pair: (0, 0),
            ba: Vec::new(),
            failures: BTreeMap::new(),
        }
    }

    pub fn num_points(&self) -> usize {
        self.points.iter().filter(|p| p.is_some()).count()
    }

    pub(crate) fn add_point(&mut self, m: Vector4<f64>, obs: Vec<(u32, u32)>) {
        let id = self.points.len() as u32;
        for &(i, k) in &obs {
            self.kp_point[i as usize][k as usize] = id;
        }
        self.points.push(Some(PPoint { m, obs }));
    }

    pub(crate) fn remove_point(&mut self, id: usize) {
        if let Some(p) = self.points[id].take() {
            for (i, k) in p.obs {
                self.kp_point[i as usize][k as usize] = NONE;
            }
        }
    }

    /// The observations of `pt` that its position does not reproject within the threshold.
    pub(crate) fn unexplained(&self, ctx: &Context, pt: &PPoint) -> Vec<(u32, u32)> {
        pt.obs
            .iter()
            .copied()
            .filter(|&(i, k)| self.obs_error(ctx, &pt.m, i, k) >= ctx.threshold(i as usize))
            .collect()
    }

    /// Reprojection error (normalised units) and orientation of one observation.
    pub(crate) fn obs_error(&self, ctx: &Context, m: &Vector4<f64>, image: u32, kp: u32) -> f64 {
        let Some(p) = &self.cams[image as usize] else {
            return f64::INFINITY;
        };
        if (p.row(2) * m)[0] <= 0.0 {
            return f64::INFINITY;
        }
        reprojection_distance(p, m, &ctx.kps[image as usize][kp as usize])
    }
}

impl ProjectiveModel {
    /// 2D–3D candidates of an unregistered image: `(keypoint, point)` pairs through the
    /// correspondence graph, from every registered view it was matched to.
    fn candidates(&self, ctx: &Context, image: usize) -> Vec<(u32, u32, u32)> {
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
    fn register(&mut self, ctx: &Context, image: usize) -> Result<usize, String> {
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
        let thr_all = thr;
        let mut inl: Vec<usize> = Vec::new();
        for _ in 0..2 {
            let next: Vec<usize> = (0..all.len())
                .filter(|&k| reprojection_distance(&p, &all[k].m, &all[k].x) < thr_all)
                .collect();
            if next.len() < 6 {
                break;
            }
            inl = next;
            let (m, x): (Vec<_>, Vec<_>) = inl.iter().map(|&k| (all[k].m, all[k].x)).unzip();
            if let Ok(r) = resection_iterative(&m, &x, 3) {
                p = r;
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

    /// Re-triangulates a point from all its observations (eq. 20); keeps the new position only if every
    /// observation stays within the threshold, else drops the worst observations.
    pub(crate) fn refine_point(&mut self, ctx: &Context, pid: usize) {
        let Some(pt) = self.points[pid].clone() else {
            return;
        };
        let cams: Vec<Matrix3x4<f64>> = pt
            .obs
            .iter()
            .filter_map(|&(i, _)| self.cams[i as usize])
            .collect();
        let xs: Vec<Vector2<f64>> = pt
            .obs
            .iter()
            .map(|&(i, k)| ctx.kps[i as usize][k as usize])
            .collect();
        if cams.len() != xs.len() {
            return;
        }
        if let Ok(m) = triangulate_iterative(&cams, &xs, ctx.opts.triangulation_iterations) {
            if pt
                .obs
                .iter()
                .all(|&(i, k)| self.obs_error(ctx, &m, i, k) < ctx.threshold(i as usize))
            {
                if let Some(p) = self.points[pid].as_mut() {
                    p.m = m;
                }
                return;
            }
        }
        // Keep the old position; drop observations that it does not explain.
        let bad = self.unexplained(ctx, &pt);
        for (i, k) in bad {
            self.kp_point[i as usize][k as usize] = NONE;
            if let Some(p) = self.points[pid].as_mut() {
                p.obs.retain(|&(a, b)| (a, b) != (i, k));
            }
        }
        if self.points[pid].as_ref().is_some_and(|p| p.obs.len() < 2) {
            self.remove_point(pid);
        }
    }

    /// New points from the keypoints of `image` that have registered partners without a point.
    fn triangulate_image(&mut self, ctx: &Context, image: usize) {
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
            if obs.len() < 2 {
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
                self.add_point(m, obs);
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

/// Table 2 steps 2–4 on the `allowed` images: tries initial pairs in order until one grows into a
/// model of at least 3 views (or the only 2 allowed), then adds views until none can be registered.
pub(crate) fn reconstruct_projective(
    ctx: &Context,
    allowed: &[bool],
    progress: &dyn handheld_core::Progress,
) -> Result<ProjectiveModel, String> {
    let candidates = crate::init::initial_pair_candidates(ctx, allowed);
    if candidates.is_empty() {
        return Err(
            "no image pair has enough verified, non-degenerate matches to start a model".into(),
        );
    }
    let n_allowed = allowed.iter().filter(|a| **a).count();
    let mut last_err = String::new();
    let mut best: Option<ProjectiveModel> = None;
    for &(a, b, _) in candidates.iter().take(ctx.opts.max_initial_pairs) {
        let Some(mut model) = crate::init::initialize(ctx, a, b) else {
            last_err = format!(
                "initial pair ({}, {}) gave too few points",
                ctx.input.images[a].name, ctx.input.images[b].name
            );
            tracing::debug!("{last_err}");
            continue;
        };
        model.bundle(ctx, 30)?;
        grow(ctx, &mut model, allowed, progress)?;
        let good = model.order.len() >= 3.min(n_allowed);
        if good {
            return Ok(model);
        }
        last_err = format!(
            "initial pair ({}, {}) could not be extended",
            ctx.input.images[a].name, ctx.input.images[b].name
        );
        if best
            .as_ref()
            .is_none_or(|b| model.order.len() > b.order.len())
        {
            best = Some(model);
        }
    }
    best.ok_or(last_err)
}

fn grow(
    ctx: &Context,
    model: &mut ProjectiveModel,
    allowed: &[bool],
    progress: &dyn handheld_core::Progress,
) -> Result<(), String> {
    let mut last_ba = model.order.len();
    let mut attempts = vec![0usize; ctx.input.images.len()];
    let mut structure_changed = true;
    progress.start(
        "projective reconstruction",
        allowed.iter().filter(|a| **a).count() as u64,
    );
    progress.inc(2);
    while structure_changed {
        structure_changed = false;
        // Unregistered images by number of 2D–3D candidates, best first.
        let mut cands: Vec<(usize, usize)> = (0..ctx.input.images.len())
            .filter(|&i| {
                allowed[i]
                    && model.cams[i].is_none()
                    && attempts[i] < ctx.opts.max_resection_attempts
            })
            .map(|i| (i, model.candidates(ctx, i).len()))
            .filter(|c| c.1 >= ctx.opts.min_resection_inliers)
            .collect();
        cands.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
        for (img, _) in cands {
            attempts[img] += 1;
            match model.register(ctx, img) {
                Ok(n) => {
                    tracing::debug!("registered {} with {n} inliers", ctx.input.images[img].name);
                    model.failures.remove(&img);
                    progress.inc(1);
                    let r = model.order.len();
                    if r <= 5 || r as f64 >= last_ba as f64 * ctx.opts.ba_growth_factor {
                        model.bundle(ctx, 30)?;
                        last_ba = r;
                    }
                    structure_changed = true;
                    break;
                }
                Err(e) => {
                    tracing::debug!("{}: {e}", ctx.input.images[img].name);
                    model.failures.insert(img, e);
                }
            }
        }
    }
    // The growth schedule may have just adjusted the complete model; otherwise adjust it now.
    if last_ba != model.order.len() {
        model.bundle(ctx, 100)?;
    }
    // A second pass of structure refinement after the final adjustment: new points, then every
    // point completed with all the registered views that match it (see `tracks`).
    for &img in &model.order.clone() {
        model.triangulate_image(ctx, img);
    }
    let growth = model.complete_and_merge_tracks(ctx);
    tracing::debug!(?growth, "track completion");
    model.bundle(ctx, 100)?;
    progress.finish();
    Ok(())
}

/// The projective cameras (normalised coordinates) in registration order.
pub(crate) fn cameras_in_order(model: &ProjectiveModel) -> Vec<(usize, Matrix3x4<f64>)> {
    model
        .order
        .iter()
        .filter_map(|&i| model.cams[i].map(|p| (i, p)))
        .collect()
}
