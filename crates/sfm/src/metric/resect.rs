//! Calibrated resection of one view into a metric model (P3P inside the shared RANSAC, T(1,1),
//! MSAC), and adding the view with its pose and observations: what the registration of the
//! remaining views (`register.rs`), of a view from a partner's depths (`register_pair.rs`) and of a
//! video's in-between frames (`video.rs`) share.

use handheld_core::{MetricReconstruction, Observation, PointId, Rigid3, TrackElement, View};
use handheld_robust::{run as ransac, CalibratedMatch, Msac, P3pEstimator, UniformSampler};
use nalgebra::Translation3;

use crate::context::Context;

/// The intrinsics group of an image: the one its camera key maps to, else the first group of the
/// same size.
pub(crate) fn camera_of(
    ctx: &Context,
    rec: &MetricReconstruction,
    image: usize,
) -> Option<handheld_core::CameraId> {
    let im = &ctx.input.images[image];
    rec.views
        .values()
        .find(|v| {
            ctx.input
                .images
                .iter()
                .any(|o| o.id == v.id && o.camera_key == im.camera_key)
        })
        .map(|v| v.camera_id)
        .or_else(|| {
            rec.cameras
                .values()
                .find(|c| c.width == im.width && c.height == im.height)
                .map(|c| c.id)
        })
}

/// Registers `image` into `rec` by calibrated resection from its `(keypoint, point)` matches:
/// the inliers join their points' tracks.
pub(crate) fn register_one(
    ctx: &Context,
    rec: &mut MetricReconstruction,
    image: usize,
    matches: &[(usize, PointId)],
) -> Result<(), String> {
    let im = &ctx.input.images[image];
    let cam_id =
        camera_of(ctx, rec, image).ok_or("no intrinsics group of its size in the model")?;
    let cam = rec.cameras[&cam_id].clone();
    let samples: Vec<CalibratedMatch> = matches
        .iter()
        .map(|&(k, pid)| CalibratedMatch {
            x: cam.intrinsics.pixel_to_normalized(im.keypoints[k]),
            world: rec.points[&pid].xyz.coords,
        })
        .collect();
    let (pose, inliers) = resect(
        ctx,
        image,
        &samples,
        ctx.opts.metric_max_error_px / cam.intrinsics.f,
    )?;
    let mut observations: Vec<Observation> = im
        .keypoints
        .iter()
        .map(|&xy| Observation { xy, point_id: None })
        .collect();
    for &s in &inliers {
        let (k, pid) = matches[s];
        observations[k].point_id = Some(pid);
        if let Some(p) = rec.points.get_mut(&pid) {
            p.track.elements.push(TrackElement {
                image_id: im.id,
                point2d_idx: k as u32,
            });
        }
    }
    insert_view(ctx, rec, image, cam_id, &pose, observations);
    Ok(())
}

/// Adds `image` to the model with pose `pose` (camera from world) and its observations.
pub(crate) fn insert_view(
    ctx: &Context,
    rec: &mut MetricReconstruction,
    image: usize,
    cam_id: handheld_core::CameraId,
    pose: &handheld_geometry::Pose,
    observations: Vec<Observation>,
) {
    let im = &ctx.input.images[image];
    rec.views.insert(
        im.id,
        View {
            id: im.id,
            name: im.name.clone(),
            camera_id: cam_id,
            cam_from_world: Rigid3::from_parts(Translation3::from(pose.translation), pose.rotation),
            observations,
            frame: im.frame,
        },
    );
}

/// Calibrated resection (P3P in the shared RANSAC, then the inliers within `thr`, normalized units)
/// of `image` from 2D–3D samples.
pub(crate) fn resect(
    ctx: &Context,
    image: usize,
    samples: &[CalibratedMatch],
    thr: f64,
) -> Result<(handheld_geometry::Pose, Vec<usize>), String> {
    let ropts = ctx.resection_ransac(image, thr);
    let rep = ransac(
        &P3pEstimator,
        &Msac,
        &mut UniformSampler::new(ropts.seed),
        samples,
        &ropts,
    )
    .map_err(|e| e.to_string())?;
    let Some(pose) = rep.model.filter(|_| rep.success) else {
        return Err(format!(
            "calibrated resection found no pose among {} 2D–3D correspondences",
            samples.len()
        ));
    };
    let inliers: Vec<usize> = (0..samples.len())
        .filter(|&s| pose.reprojection_error(&samples[s].x, &samples[s].world) <= thr)
        .collect();
    if inliers.len() < ctx.opts.min_resection_inliers {
        return Err(format!(
            "calibrated resection: {} inliers among {} 2D–3D correspondences, need {}",
            inliers.len(),
            samples.len(),
            ctx.opts.min_resection_inliers
        ));
    }
    Ok((pose, inliers))
}
