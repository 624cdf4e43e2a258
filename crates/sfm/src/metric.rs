//! From the projective model to the metric one (§3.4): the upgrade of eq. 27 with the dual absolute
//! quadric, decomposition of the cameras into `K [R | t]`, intrinsics groups, and metric bundle
//! adjustment with radial distortion and the paper's constraints (photos: one shared camera, constant
//! f, principal point and k1, aspect 1, skew 0; video: also a constant aspect ratio), robust loss,
//! outlier removal and re-adjustment.

use std::collections::BTreeMap;

use handheld_bundle::{
    bundle_adjust_metric, BundleOptions, GaussianPrior, IntrinsicParam, IntrinsicsMask,
    MetricBundleConfig, RobustLoss,
};
use handheld_core::{
    Camera, CameraId, ImageId, Intrinsics, MetricReconstruction, Observation, Point3D, PointId,
    Rigid3, Track, TrackElement, View,
};
use nalgebra::{Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector2, Vector3};
use serde::Serialize;

use crate::options::Distortion;
use crate::projective::{cameras_in_order, Context, ProjectiveModel};
use crate::selfcal::{decompose_camera, self_calibrate, SelfCalibration};

/// Self-calibration diagnostics for the summary.
#[derive(Clone, Debug, Serialize)]
pub struct SelfCalibrationReport {
    /// Why the motion is critical, when it is (the DAQ is then not determined by the images alone).
    pub degenerate: Option<String>,
    /// True when the linear estimate was unusable and the priors alone (f ≈ w + h, principal point at
    /// the centre, square pixels: the quasi-Euclidean initial frame) gave the metric frame.
    pub used_prior_fallback: bool,
    pub iterations: usize,
    pub singular_values: Vec<f64>,
    pub omega_eigenvalues: [f64; 4],
    /// Per intrinsics group: the focal length (pixels) right after self-calibration, before any
    /// metric bundle adjustment.
    pub focal_before_ba_px: BTreeMap<u32, f64>,
    /// Same for the aspect ratio.
    pub aspect_before_ba: BTreeMap<u32, f64>,
}

/// The metric reconstruction right after the upgrade, before bundle adjustment.
pub(crate) struct Upgraded {
    pub rec: MetricReconstruction,
    pub report: SelfCalibrationReport,
    #[allow(dead_code)]
    pub selfcal: Option<SelfCalibration>,
}

pub(crate) fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Applies eq. 27 and builds the [`MetricReconstruction`] with one camera per intrinsics group.
pub(crate) fn upgrade(
    ctx: &Context,
    model: &ProjectiveModel,
    estimate_aspect: bool,
) -> Result<Upgraded, String> {
    let cams = cameras_in_order(model);
    let ps: Vec<_> = cams.iter().map(|c| c.1).collect();
    let mut sc_opts = ctx.opts.self_calibration.clone();
    sc_opts.estimate_aspect = estimate_aspect;
    let sc = self_calibrate(&ps, &sc_opts).map_err(|e| format!("self-calibration: {e}"))?;
    let mut fallback = false;
    let t = {
        let ok = sc.t.iter().all(|v| v.is_finite()) && sc.t.try_inverse().is_some();
        if ok {
            sc.t
        } else {
            fallback = true;
            nalgebra::Matrix4::identity()
        }
    };
    let build = |t: &nalgebra::Matrix4<f64>| build_metric(ctx, model, &cams, t, estimate_aspect);
    let (mut rec, mut focal, mut aspect) = build(&t)?;
    // Sanity check on the linear estimate: focal lengths must be plausible, within the range the
    // focal hypotheses search (0.2–5 × (w + h): a 150° to 8° diagonal field of view); otherwise
    // the estimate is reported as degenerate and the priors and hypotheses take over.
    let mut degenerate = sc.degenerate.clone();
    let (lo, hi) = crate::hypotheses::RANGE;
    let implausible: Vec<f64> = focal
        .values()
        .copied()
        .filter(|f| {
            let s = ctx.kn[0][(0, 0)];
            !(f.is_finite() && *f > lo * s && *f < hi * s)
        })
        .collect();
    if !implausible.is_empty() {
        let why = format!(
            "implausible focal length {:.0} px from the linear estimate (outside {lo}–{hi} × (w + h))",
            implausible[0]
        );
        degenerate = Some(match degenerate {
            Some(d) => format!("{d}; {why}"),
            None => why,
        });
        if !fallback {
            fallback = true;
            (rec, focal, aspect) = build(&nalgebra::Matrix4::identity())?;
        }
    }
    let report = SelfCalibrationReport {
        degenerate,
        used_prior_fallback: fallback,
        iterations: sc.iterations,
        singular_values: sc.singular_values.clone(),
        omega_eigenvalues: sc.omega_eigenvalues,
        focal_before_ba_px: focal,
        aspect_before_ba: aspect,
    };
    Ok(Upgraded {
        rec,
        report,
        selfcal: Some(sc),
    })
}

/// The metric frame from the priors alone: the quasi-Euclidean frame of the initial pair (`K = K_N`:
/// f ≈ w + h, centred principal point, square pixels), kept by projective BA's fixed first camera.
pub(crate) fn prior_frame(
    ctx: &Context,
    model: &ProjectiveModel,
    estimate_aspect: bool,
) -> Result<MetricReconstruction, String> {
    from_transform(ctx, model, &nalgebra::Matrix4::identity(), estimate_aspect)
}

/// The metric reconstruction for a given upgrade `T` (eq. 27), before bundle adjustment.
pub(crate) fn from_transform(
    ctx: &Context,
    model: &ProjectiveModel,
    t: &nalgebra::Matrix4<f64>,
    estimate_aspect: bool,
) -> Result<MetricReconstruction, String> {
    let cams = cameras_in_order(model);
    Ok(build_metric(ctx, model, &cams, t, estimate_aspect)?.0)
}

type Groups = BTreeMap<u32, f64>;

fn build_metric(
    ctx: &Context,
    model: &ProjectiveModel,
    cams: &[(usize, nalgebra::Matrix3x4<f64>)],
    t: &nalgebra::Matrix4<f64>,
    estimate_aspect: bool,
) -> Result<(MetricReconstruction, Groups, Groups), String> {
    let t_inv = t
        .try_inverse()
        .ok_or("the upgrade transformation is singular")?;
    // Eq. 27: P_M = P T⁻¹, M_M = T M; then P_M = K_N⁻¹ K [R | t] per view.
    // Per image: the estimated K_N-normalised calibration, R and t.
    type KRt = (Matrix3<f64>, Matrix3<f64>, Vector3<f64>);
    let mut poses: BTreeMap<usize, KRt> = BTreeMap::new();
    for &(img, p) in cams {
        let pm = p * t_inv;
        let (kn_est, r, tt) = decompose_camera(&pm).ok_or_else(|| {
            format!(
                "camera of {} cannot be decomposed",
                ctx.input.images[img].name
            )
        })?;
        poses.insert(img, (ctx.kn[img] * kn_est, r, tt));
    }
    let mut xyz: Vec<Option<Point3<f64>>> = model
        .points
        .iter()
        .map(|p| {
            p.as_ref().and_then(|p| {
                let m = t * p.m;
                (m.w.abs() > 1e-9 * m.norm()).then(|| Point3::from(m.xyz() / m.w))
            })
        })
        .collect();
    // Orientation: a mirrored solution puts the points behind the cameras; reflect it.
    let (mut front, mut behind) = (0usize, 0usize);
    for (pt, x) in model.points.iter().zip(&xyz) {
        let (Some(pt), Some(x)) = (pt, x) else {
            continue;
        };
        for &(i, _) in &pt.obs {
            let (_, r, tt) = &poses[&(i as usize)];
            if (r * x.coords + tt).z > 0.0 {
                front += 1;
            } else {
                behind += 1;
            }
        }
    }
    if behind > front {
        for x in xyz.iter_mut().flatten() {
            *x = Point3::from(-x.coords);
        }
        for (_, (_, _, tt)) in poses.iter_mut() {
            *tt = -*tt;
        }
    }
    // Intrinsics groups.
    let mut group_of_key: BTreeMap<&str, u32> = BTreeMap::new();
    for &(img, _) in cams {
        let n = group_of_key.len() as u32;
        group_of_key
            .entry(ctx.input.images[img].camera_key.as_str())
            .or_insert(n + 1);
    }
    let mut rec = MetricReconstruction::default();
    let mut focal = BTreeMap::new();
    let mut aspect = BTreeMap::new();
    for (key, &gid) in &group_of_key {
        let members: Vec<usize> = cams
            .iter()
            .map(|c| c.0)
            .filter(|&i| ctx.input.images[i].camera_key == *key)
            .collect();
        let mut fs: Vec<f64> = members.iter().map(|i| poses[i].0[(0, 0)]).collect();
        let mut asp: Vec<f64> = members
            .iter()
            .map(|i| poses[i].0[(1, 1)] / poses[i].0[(0, 0)])
            .collect();
        let f = median(&mut fs);
        let a = if estimate_aspect {
            median(&mut asp)
        } else {
            1.0
        };
        let im = &ctx.input.images[members[0]];
        let intr = Intrinsics {
            f,
            aspect: a,
            skew: 0.0,
            pp: Vector2::new(
                (im.width as f64 - 1.0) / 2.0,
                (im.height as f64 - 1.0) / 2.0,
            ),
            k1: 0.0,
            k2: 0.0,
        };
        focal.insert(gid, f);
        aspect.insert(gid, median(&mut asp));
        rec.cameras.insert(
            CameraId(gid),
            Camera {
                id: CameraId(gid),
                width: im.width,
                height: im.height,
                intrinsics: intr,
            },
        );
    }
    for &(img, _) in cams {
        let im = &ctx.input.images[img];
        let (_, r, tt) = &poses[&img];
        let rot = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(*r));
        let observations = im
            .keypoints
            .iter()
            .map(|&xy| Observation { xy, point_id: None })
            .collect();
        rec.views.insert(
            im.id,
            View {
                id: im.id,
                name: im.name.clone(),
                camera_id: CameraId(group_of_key[im.camera_key.as_str()]),
                cam_from_world: Rigid3::from_parts(Translation3::from(*tt), rot),
                observations,
                frame: im.frame,
            },
        );
    }
    let mut next = 0u64;
    for (pt, x) in model.points.iter().zip(&xyz) {
        let (Some(pt), Some(x)) = (pt, x) else {
            continue;
        };
        let id = PointId(next);
        next += 1;
        let mut track = Track::default();
        for &(i, k) in &pt.obs {
            let image_id = ctx.input.images[i as usize].id;
            track.elements.push(TrackElement {
                image_id,
                point2d_idx: k,
            });
            if let Some(v) = rec.views.get_mut(&image_id) {
                v.observations[k as usize].point_id = Some(id);
            }
        }
        rec.points.insert(
            id,
            Point3D {
                xyz: *x,
                color: [128, 128, 128],
                error: 0.0,
                track,
            },
        );
    }
    Ok((rec, focal, aspect))
}

/// One metric bundle adjustment, for the summary.
#[derive(Clone, Debug, Serialize)]
pub struct MetricBaRecord {
    pub step: String,
    pub iterations: usize,
    pub initial_rms_px: f64,
    pub final_rms_px: f64,
    pub seconds: f64,
    /// Observations removed by the filtering that followed.
    pub observations_removed: usize,
    pub points_removed: usize,
}

/// Removes observations whose reprojection error exceeds `max_px` (or that lie behind their
/// camera) and points left with fewer than `min_track` views. Returns (observations, points) removed.
pub(crate) fn filter_metric(
    rec: &mut MetricReconstruction,
    max_px: f64,
    min_track: usize,
) -> (usize, usize) {
    let mut bad_obs = Vec::new();
    for (pid, pt) in &rec.points {
        for el in &pt.track.elements {
            let ok = rec.views.get(&el.image_id).and_then(|v| {
                let cam = rec.cameras.get(&v.camera_id)?;
                let px = cam.project(&v.cam_from_world, &pt.xyz)?;
                Some((px - v.observations[el.point2d_idx as usize].xy).norm() <= max_px)
            });
            if ok != Some(true) {
                bad_obs.push((*pid, *el));
            }
        }
    }
    let n_obs = bad_obs.len();
    for (pid, el) in bad_obs {
        if let Some(pt) = rec.points.get_mut(&pid) {
            pt.track.elements.retain(|e| e != &el);
        }
        if let Some(v) = rec.views.get_mut(&el.image_id) {
            v.observations[el.point2d_idx as usize].point_id = None;
        }
    }
    let short: Vec<PointId> = rec
        .points
        .iter()
        .filter(|(_, p)| p.track.len() < min_track)
        .map(|(id, _)| *id)
        .collect();
    for id in &short {
        if let Some(p) = rec.points.remove(id) {
            for el in p.track.elements {
                if let Some(v) = rec.views.get_mut(&el.image_id) {
                    v.observations[el.point2d_idx as usize].point_id = None;
                }
            }
        }
    }
    (n_obs, short.len())
}

/// The metric bundle adjustment schedule: (1) poses, points, f, k1 (and the aspect ratio for
/// video) with the principal point at the image centre; filter; (2) everything the options allow
/// (principal point, k2); filter at the final threshold; (3) a last adjustment of the survivors.
pub(crate) fn refine_metric(
    ctx: &Context,
    rec: &mut MetricReconstruction,
    estimate_aspect: bool,
) -> Result<Vec<MetricBaRecord>, String> {
    adjust_metric(ctx, rec, estimate_aspect, false)
}

/// Only the last step of [`refine_metric`]: for a model that was adjusted and then extended (new
/// observations of existing points).
pub(crate) fn final_adjustment(
    ctx: &Context,
    rec: &mut MetricReconstruction,
    estimate_aspect: bool,
) -> Result<Vec<MetricBaRecord>, String> {
    adjust_metric(ctx, rec, estimate_aspect, true)
}

fn adjust_metric(
    ctx: &Context,
    rec: &mut MetricReconstruction,
    estimate_aspect: bool,
    only_final: bool,
) -> Result<Vec<MetricBaRecord>, String> {
    let o = ctx.opts;
    let mut records = Vec::new();
    let distortion = o.distortion != Distortion::None && !long_lens(rec);
    let base = IntrinsicsMask {
        f: true,
        aspect: estimate_aspect,
        skew: false,
        principal_point: false,
        k1: distortion,
        k2: false,
    };
    let full = IntrinsicsMask {
        principal_point: o.refine_principal_point,
        k2: distortion && o.distortion == Distortion::K1K2,
        ..base
    };
    let mut priors = focal_priors(ctx, rec);
    // A soft prior keeps the principal point near the image centre (σ = principal_point_prior ·
    // (w + h), eq. 25's u ≈ v ≈ 0 in K_N units): free where the views determine it (wide-angle,
    // deep scenes), held where it would trade off against rotation (narrow field, shallow scenes).
    if o.refine_principal_point {
        for cam in rec.cameras.values() {
            let s = o.principal_point_prior * (cam.width + cam.height) as f64;
            let e = priors.entry(cam.id).or_default();
            e.push((
                IntrinsicParam::Ppx,
                GaussianPrior {
                    mean: (cam.width as f64 - 1.0) / 2.0,
                    sigma: s,
                },
            ));
            e.push((
                IntrinsicParam::Ppy,
                GaussianPrior {
                    mean: (cam.height as f64 - 1.0) / 2.0,
                    sigma: s,
                },
            ));
        }
    }
    // A known calibration pins f, the aspect ratio and the principal point of every group.
    let full = match o.known_intrinsics {
        Some(k) => {
            for cam in rec.cameras.values() {
                let e = priors.entry(cam.id).or_default();
                e.retain(|(p, _)| {
                    !matches!(
                        p,
                        IntrinsicParam::F
                            | IntrinsicParam::Aspect
                            | IntrinsicParam::Ppx
                            | IntrinsicParam::Ppy
                    )
                });
                let pin = |mean: f64, sigma: f64| GaussianPrior { mean, sigma };
                e.push((IntrinsicParam::F, pin(k.fx, 1e-6 * k.fx)));
                e.push((IntrinsicParam::Aspect, pin(k.fy / k.fx, 1e-9)));
                e.push((IntrinsicParam::Ppx, pin(k.cx, 1e-3)));
                e.push((IntrinsicParam::Ppy, pin(k.cy, 1e-3)));
            }
            IntrinsicsMask {
                aspect: true,
                principal_point: true,
                ..full
            }
        }
        None => full,
    };
    let steps: [(&str, IntrinsicsMask, f64, usize); 3] = [
        ("f+k1", base, o.metric_max_error_px, 50),
        ("all intrinsics", full, o.final_max_error_px, 100),
        ("final", full, o.final_max_error_px, 100),
    ];
    for (name, mask, thr, iters) in steps {
        if only_final && name != "final" {
            continue;
        }
        let config = MetricBundleConfig {
            refine: mask,
            priors: priors.clone(),
            keypoint_sigma: ctx.keypoint_sigma.clone(),
            ..Default::default()
        };
        let bopts = BundleOptions {
            max_iterations: iters,
            loss: RobustLoss::Huber(o.loss_scale_px),
            // Tight tolerances only for the last adjustment; the earlier ones feed a filter.
            function_tolerance: if name == "final" { 1e-7 } else { 1e-5 },
            parameter_tolerance: if name == "final" { 1e-10 } else { 1e-8 },
            ..Default::default()
        };
        let s = bundle_adjust_metric(rec, &config, &bopts)
            .map_err(|e| format!("metric bundle adjustment ({name}): {e}"))?;
        let (ro, rp) = filter_metric(rec, thr, o.min_track_length);
        records.push(MetricBaRecord {
            step: name.to_string(),
            iterations: s.iterations,
            initial_rms_px: s.initial_rms_px,
            final_rms_px: s.final_rms_px,
            seconds: s.total_seconds,
            observations_removed: ro,
            points_removed: rp,
        });
    }
    Ok(records)
}

/// Normalized radius `r = ½ diagonal / f` below which radial distortion is not estimated.
///
/// Eq. 3's displacement `k₁ r²` is unobservable at small `r`: it trades off against the focal length
/// and the principal point (on templeSparseRing, `r ≈ 0.26`, a spurious `k₁ ≈ −0.25` costs half the
/// rotation accuracy), and long lenses hardly distort. 0.3 is a diagonal field of view of ~33°, a
/// 70 mm-equivalent lens.
const MIN_DISTORTION_RADIUS: f64 = 0.3;

/// True when every intrinsics group has a narrow field of view (see [`MIN_DISTORTION_RADIUS`]).
fn long_lens(rec: &MetricReconstruction) -> bool {
    !rec.cameras.is_empty()
        && rec.cameras.values().all(|c| {
            let half_diag = 0.5 * f64::from(c.width).hypot(f64::from(c.height));
            half_diag / c.intrinsics.f.abs().max(1e-9) < MIN_DISTORTION_RADIUS
        })
}

/// A cheap comparison of candidate metric frames (different upgrades `T`): a short adjustment of
/// poses, points and focal lengths, then the number of observations within the metric threshold,
/// discounted by their RMS. Higher is better; the candidate is left unchanged.
pub(crate) fn quick_score(ctx: &Context, rec: &MetricReconstruction, estimate_aspect: bool) -> f64 {
    let mut r = rec.clone();
    let config = MetricBundleConfig {
        refine: IntrinsicsMask {
            f: true,
            aspect: estimate_aspect,
            skew: false,
            principal_point: false,
            k1: false,
            k2: false,
        },
        ..Default::default()
    };
    let bopts = BundleOptions {
        max_iterations: 25,
        loss: RobustLoss::Huber(ctx.opts.loss_scale_px),
        function_tolerance: 1e-5,
        ..Default::default()
    };
    if bundle_adjust_metric(&mut r, &config, &bopts).is_err() {
        return f64::NEG_INFINITY;
    }
    let thr = ctx.opts.metric_max_error_px;
    let (mut n, mut sq) = (0usize, 0.0);
    for pt in r.points.values() {
        for el in &pt.track.elements {
            let Some(v) = r.views.get(&el.image_id) else {
                continue;
            };
            let Some(cam) = r.cameras.get(&v.camera_id) else {
                continue;
            };
            let Some(px) = cam.project(&v.cam_from_world, &pt.xyz) else {
                continue;
            };
            let e = (px - v.observations[el.point2d_idx as usize].xy).norm();
            if e <= thr {
                n += 1;
                sq += e * e;
            }
        }
    }
    if n == 0 {
        return f64::NEG_INFINITY;
    }
    n as f64 / (1.0 + (sq / n as f64).sqrt())
}

/// EXIF focal lengths are only priors (σ = 10 %), per group, when every member agrees.
fn focal_priors(
    ctx: &Context,
    rec: &MetricReconstruction,
) -> BTreeMap<CameraId, Vec<(IntrinsicParam, GaussianPrior)>> {
    let mut out = BTreeMap::new();
    let by_id: BTreeMap<ImageId, usize> = ctx
        .input
        .images
        .iter()
        .enumerate()
        .map(|(k, im)| (im.id, k))
        .collect();
    for cam in rec.cameras.values() {
        let priors: Vec<f64> = rec
            .views
            .values()
            .filter(|v| v.camera_id == cam.id)
            .filter_map(|v| {
                by_id
                    .get(&v.id)
                    .and_then(|&k| ctx.input.images[k].focal_prior_px)
            })
            .collect();
        if let Some(&f) = priors.first() {
            if priors.iter().all(|p| (p - f).abs() < 1e-6 * f) {
                out.insert(
                    cam.id,
                    vec![(
                        IntrinsicParam::F,
                        GaussianPrior {
                            mean: f,
                            sigma: 0.1 * f,
                        },
                    )],
                );
            }
        }
    }
    out
}
