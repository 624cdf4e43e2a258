//! From the projective model to the metric one (§3.4): the linear self-calibration (`selfcal/`)
//! gives the upgrade `T`, and eq. 27 (`P_M = P T⁻¹`, `M_M = T M`) is applied to the model: every
//! camera decomposed into `K [R | t]` (with `K_N` of eq. 24 put back), the mirror frame turned so
//! that the points lie in front of the cameras, one camera per intrinsics group (the median focal
//! length and aspect ratio of its views, the principal point at the image centre, no distortion
//! yet). A linear estimate that is unusable, or whose focal length is implausible (outside the
//! 0.2–5 × (w + h) the focal hypotheses search), is reported degenerate and the priors' frame (the
//! quasi-Euclidean frame of the initial pair, `K = K_N`) takes over; [`SelfCalibrationReport`]
//! records all of it. The metric adjustment of the result is in `metric/ba.rs`.

use std::collections::BTreeMap;

use handheld_core::{
    Camera, CameraId, Intrinsics, MetricReconstruction, Observation, Point3D, PointId, Rigid3,
    Track, TrackElement, View,
};
use nalgebra::{Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use serde::Serialize;

use crate::common::{image_centre, median};
use crate::context::Context;
use crate::metric::profile::PrincipalPointSpread;
use crate::projective::model::{cameras_in_order, ProjectiveModel};
use crate::upgrade::guard::CandidateRecord;
use crate::upgrade::hypotheses::RANGE;
use crate::upgrade::selfcal::{decompose_camera, self_calibrate, SelfCalibration};

/// Self-calibration diagnostics for the summary.
#[derive(Clone, Debug, Default, Serialize, serde::Deserialize)]
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
    /// Every metric frame that was adjusted and judged (see [`crate::upgrade::guard`]), in the order tried;
    /// the last one was kept.
    pub candidates: Vec<CandidateRecord>,
    /// Projective models started from a better-ranked initial pair whose metric frame no candidate
    /// survived, before the one reported (see `pipeline/model.rs`).
    pub rejected_starts: Vec<RejectedStart>,
    /// Set when two sound candidates with different focal lengths explain the images about as
    /// well (see [`crate::upgrade::guard::focal_ambiguity`]).
    pub focal_ambiguity: Option<String>,
    /// The robust cost of the kept model adjusted with its focal length held 20 % below and above
    /// its value, relative to the cost with it free (`metric::profile::focal_profile`); near 1 when the
    /// images do not determine the focal length.
    pub focal_profile: Option<[f64; 2]>,
    /// Per intrinsics group, the principal point's offset from the image centre against its
    /// jackknife spread over the views (`metric::profile::principal_point_spread`).
    pub principal_point_spread: Vec<PrincipalPointSpread>,
    /// True when no group's principal point was significantly away from the image centre, or
    /// when the views hardly rotate (see `orientation_spread_deg`), so the model was adjusted
    /// again with it held there.
    pub principal_point_held: bool,
    /// Largest angle between a view's orientation and the views' mean orientation, degrees.
    pub orientation_spread_deg: Option<f64>,
    /// True when no stratified start gave a sound metric frame and the model was built by the
    /// calibrated incremental candidate instead (`calibrated.rs`).
    pub calibrated_incremental: bool,
}

/// A start of the model that was abandoned: its initial pair and why.
#[derive(Clone, Debug, Default, Serialize, serde::Deserialize)]
pub struct RejectedStart {
    pub initial_pair: [String; 2],
    pub reason: String,
}

/// The metric reconstruction right after the upgrade, before bundle adjustment.
pub(crate) struct Upgraded {
    pub rec: MetricReconstruction,
    pub report: SelfCalibrationReport,
    #[allow(dead_code)]
    pub selfcal: Option<SelfCalibration>,
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
    let (lo, hi) = RANGE;
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
        candidates: Vec::new(),
        rejected_starts: Vec::new(),
        focal_ambiguity: None,
        focal_profile: None,
        principal_point_spread: Vec::new(),
        principal_point_held: false,
        orientation_spread_deg: None,
        calibrated_incremental: false,
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

/// Per image: the estimated calibration (`K_N ·` the decomposed, `K_N`-normalised one), `R` and `t`.
type KRt = (Matrix3<f64>, Matrix3<f64>, Vector3<f64>);

/// The metric reconstruction of `model` upgraded by `t` (eq. 27), oriented so that the points are
/// in front of the cameras, with one camera per intrinsics group; and the focal length and aspect
/// ratio of each group before any adjustment.
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
    let mut poses = upgraded_poses(ctx, cams, &t_inv)?;
    let mut xyz = upgraded_points(model, t);
    orient(model, &mut xyz, &mut poses);
    let mut rec = MetricReconstruction::default();
    let (group_of_key, focal, aspect) =
        intrinsics_groups(ctx, cams, &poses, estimate_aspect, &mut rec);
    add_views(ctx, cams, &poses, &group_of_key, &mut rec);
    add_points(ctx, model, &xyz, &mut rec);
    Ok((rec, focal, aspect))
}

/// Eq. 27: `P_M = P T⁻¹`; then `P_M = K_N⁻¹ K [R | t]` per view.
fn upgraded_poses(
    ctx: &Context,
    cams: &[(usize, nalgebra::Matrix3x4<f64>)],
    t_inv: &nalgebra::Matrix4<f64>,
) -> Result<BTreeMap<usize, KRt>, String> {
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
    Ok(poses)
}

/// Eq. 27: `M_M = T M`, in Euclidean coordinates (`None` for a point at infinity).
fn upgraded_points(
    model: &ProjectiveModel,
    t: &nalgebra::Matrix4<f64>,
) -> Vec<Option<Point3<f64>>> {
    model
        .points
        .iter()
        .map(|p| {
            p.as_ref().and_then(|p| {
                let m = t * p.m;
                (m.w.abs() > 1e-9 * m.norm()).then(|| Point3::from(m.xyz() / m.w))
            })
        })
        .collect()
}

/// Orientation: a mirrored solution puts the points behind the cameras; reflect it.
fn orient(
    model: &ProjectiveModel,
    xyz: &mut [Option<Point3<f64>>],
    poses: &mut BTreeMap<usize, KRt>,
) {
    let (mut front, mut behind) = (0usize, 0usize);
    for (pt, x) in model.points.iter().zip(xyz.iter()) {
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
}

/// One intrinsics group per camera key (numbered in registration order), each a camera in `rec`
/// with the median focal length (and aspect ratio, when estimated) of its members; returns the
/// groups and the focal length and aspect ratio of each.
fn intrinsics_groups<'a>(
    ctx: &'a Context,
    cams: &[(usize, nalgebra::Matrix3x4<f64>)],
    poses: &BTreeMap<usize, KRt>,
    estimate_aspect: bool,
    rec: &mut MetricReconstruction,
) -> (BTreeMap<&'a str, u32>, Groups, Groups) {
    let mut group_of_key: BTreeMap<&str, u32> = BTreeMap::new();
    for &(img, _) in cams {
        let n = group_of_key.len() as u32;
        group_of_key
            .entry(ctx.input.images[img].camera_key.as_str())
            .or_insert(n + 1);
    }
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
            pp: image_centre(im.width, im.height),
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
    (group_of_key, focal, aspect)
}

/// A view per upgraded camera, with every keypoint as an observation (no point yet).
fn add_views(
    ctx: &Context,
    cams: &[(usize, nalgebra::Matrix3x4<f64>)],
    poses: &BTreeMap<usize, KRt>,
    group_of_key: &BTreeMap<&str, u32>,
    rec: &mut MetricReconstruction,
) {
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
}

/// A point per upgraded projective point, linked to its observations.
fn add_points(
    ctx: &Context,
    model: &ProjectiveModel,
    xyz: &[Option<Point3<f64>>],
    rec: &mut MetricReconstruction,
) {
    let mut next = 0u64;
    for (pt, x) in model.points.iter().zip(xyz) {
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
}
