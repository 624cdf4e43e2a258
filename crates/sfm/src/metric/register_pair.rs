//! Registering a view that shares no 3D points with the metric model, through a verified pair with
//! a registered view ("partner").
//!
//! Resection (§3.2) needs 2D–3D matches, i.e. keypoints matched to observations that already have a
//! 3D point. A view can be verified against a registered partner (Table 1) and still have none: on
//! iclnuim-5, view 3 is matched only to view 1, on the part of the back wall that no other view
//! sees, so none of those matches has a point. The pair fixes the relative rotation and the
//! direction of the baseline but not its length, which only the model's scale can give.
//!
//! The partner's depth at each matched keypoint is read from the model instead. The points the
//! partner observes are segmented into planes (sequential RANSAC in its camera frame: the largest
//! plane, then the largest among the rest, ...; `planes.rs`). A matched keypoint takes the plane
//! that most of its nearest observed points belong to, and its depth where its ray meets that
//! plane. This extends planar structure, e.g. the rest of a wall, past where the model's points
//! stop. A plane fitted to the nearest points alone extrapolates badly: on iclnuim-5 its depths
//! were 36 % off in median against the ground-truth depth maps, the whole wall's plane 1.7 %. The
//! view is then resected (P3P inside the shared RANSAC) from these pseudo-points with a looser
//! threshold, and [`crate::metric::register::triangulate_new`] makes real points of the pair's matches,
//! which the following bundle adjustment refines. A placement whose matches would fit about as
//! well on tilted planes (a plane seen through a narrow field of view) is refused
//! (`undetermined_tilt`): its orientation would be the planes' guess, not the images'.

use handheld_core::{MetricReconstruction, Observation, View};
use handheld_geometry::refine_pose;
use handheld_robust::CalibratedMatch;
use nalgebra::{Vector2, Vector3};

use crate::context::Context;
use crate::metric::consistency::MAX_DISAGREEMENT_DEG;
use crate::metric::planes::{segment_planes, Plane};
use crate::metric::resect::{camera_of, insert_view, resect};

/// Nearest observed points that vote for a keypoint's plane; a majority must agree.
const NEIGHBOURS: usize = 20;
/// The resection threshold is this multiple of the metric threshold: the planes extrapolate.
const THRESHOLD_FACTOR: f64 = 2.0;
/// Partners tried, most matches first.
const MAX_PARTNERS: usize = 3;

/// Places `image` from the depths of its registered partners (module docs); on success the view is
/// in `rec` without observations of existing points.
pub(crate) fn register_from_partner(
    ctx: &Context,
    rec: &mut MetricReconstruction,
    image: usize,
) -> Result<(), String> {
    let im = &ctx.input.images[image];
    let cam_id =
        camera_of(ctx, rec, image).ok_or("no intrinsics group of its size in the model")?;
    let cam = rec.cameras[&cam_id].clone();
    // Registered partners with their matches oriented (keypoint here, keypoint there).
    let mut partners: Vec<(usize, Vec<(u32, u32)>)> = ctx
        .input
        .pairs
        .iter()
        .filter_map(|p| {
            let (j, m) = if p.a == image {
                (p.b, p.matches.clone())
            } else if p.b == image {
                (p.a, p.matches.iter().map(|&(a, b)| (b, a)).collect())
            } else {
                return None;
            };
            rec.views
                .contains_key(&ctx.input.images[j].id)
                .then_some((j, m))
        })
        .collect();
    if partners.is_empty() {
        return Err("no registered view is matched to it".into());
    }
    partners.sort_by_key(|(j, m)| (std::cmp::Reverse(m.len()), *j));
    let mut last = String::new();
    for (j, matches) in partners.iter().take(MAX_PARTNERS) {
        let jm = &ctx.input.images[*j];
        let vj = &rec.views[&jm.id];
        let depth = PartnerDepth::new(rec, vj, ctx.opts.seed ^ *j as u64);
        let cam_j = &rec.cameras[&vj.camera_id];
        let (samples, labels): (Vec<CalibratedMatch>, Vec<usize>) = matches
            .iter()
            .filter_map(|&(ki, kj)| {
                let px = *jm.keypoints.get(kj as usize)?;
                let (world, label) =
                    depth.world_point(&cam_j.intrinsics.pixel_to_normalized(px), px)?;
                let x = cam
                    .intrinsics
                    .pixel_to_normalized(*im.keypoints.get(ki as usize)?);
                Some((CalibratedMatch { x, world }, label))
            })
            .unzip();
        if samples.len() < ctx.opts.min_resection_inliers {
            last = format!(
                "the model gives a depth to only {} of its {} matches with {}",
                samples.len(),
                matches.len(),
                jm.name
            );
            continue;
        }
        let thr = THRESHOLD_FACTOR * ctx.opts.metric_max_error_px / cam.intrinsics.f;
        match resect(ctx, image, &samples, thr) {
            Ok((pose, inliers)) => {
                if let Some(why) = undetermined_tilt(
                    &pose,
                    &samples,
                    &labels,
                    &inliers,
                    &depth.world_from_cam.translation.vector,
                ) {
                    last = format!("placing it from the depths of {}: {why}", jm.name);
                    continue;
                }
                tracing::info!(
                    "{}: placed from the model's depths in {} ({} of {} matches)",
                    im.name,
                    jm.name,
                    inliers.len(),
                    samples.len()
                );
                let observations = im
                    .keypoints
                    .iter()
                    .map(|&xy| Observation { xy, point_id: None })
                    .collect();
                insert_view(ctx, rec, image, cam_id, &pose, observations);
                return Ok(());
            }
            Err(e) => last = format!("placing it from the depths of {}: {e}", jm.name),
        }
    }
    Err(last)
}

/// Residual variances by which tilting the planes a view is placed on by [`MAX_DISAGREEMENT_DEG`]
/// must make its matches fit worse for the placement to be trusted: one, i.e. the matches fix the
/// planes' orientation, and with it the view's, to within the disagreement the view-consistency
/// check allows (one standard deviation). iclnuim-5's view 3, placed on the back wall through a
/// 67° field of view, costs 8.5 variances more with the wall tilted 5°; the hemisphere's view
/// ([`undetermined_tilt`]) fits better with its plane tilted.
const TILT_MIN_RATIO: f64 = 1.0;

/// Why the pose found for a view from its partner's planes cannot be trusted, if it cannot. The
/// pair it is placed through need not determine the relative pose (a pair explained by one
/// homography does not), so the pose rests on the planes the partner's points were segmented
/// into, extended to where the matches lie. When the view's matches would be explained about as
/// well with those planes tilted, its orientation follows the tilt: through a narrow field of view
/// a plane's image hardly changes when it tilts, and a wrong plane gives a wrong pose that fits
/// (a synthetic hemisphere at an 11° field of view: a view placed 32° off, its 55 matches
/// reprojected to 1 px). Each plane is tilted by [`MAX_DISAGREEMENT_DEG`] (about its inliers'
/// centroid, both ways about each of its two in-plane axes), the points moved along the partner's
/// rays onto it, and the pose refined: the smallest increase of the cost must exceed
/// [`TILT_MIN_RATIO`] residual variances.
fn undetermined_tilt(
    pose: &handheld_geometry::Pose,
    samples: &[CalibratedMatch],
    labels: &[usize],
    inliers: &[usize],
    centre: &Vector3<f64>,
) -> Option<String> {
    let x: Vec<Vector2<f64>> = inliers.iter().map(|&s| samples[s].x).collect();
    let w: Vec<Vector3<f64>> = inliers.iter().map(|&s| samples[s].world).collect();
    let lab: Vec<usize> = inliers.iter().map(|&s| labels[s]).collect();
    let cost = |p: &handheld_geometry::Pose, w: &[Vector3<f64>]| -> f64 {
        x.iter()
            .zip(w)
            .map(|(a, b)| p.reprojection_error(a, b).powi(2).min(1.0))
            .sum()
    };
    let best = refine_pose(pose, &x, &w, 10);
    let cb = cost(&best, &w);
    let variance = cb / (2 * x.len()).saturating_sub(6).max(1) as f64;
    // Per plane label: its inliers' centroid and principal axes (columns: two in-plane, normal).
    let mut frames = std::collections::BTreeMap::new();
    for l in lab
        .iter()
        .copied()
        .collect::<std::collections::BTreeSet<_>>()
    {
        let pts: Vec<&Vector3<f64>> = w
            .iter()
            .zip(&lab)
            .filter(|(_, k)| **k == l)
            .map(|(p, _)| p)
            .collect();
        if pts.len() < 3 {
            continue;
        }
        let c = pts.iter().copied().sum::<Vector3<f64>>() / pts.len() as f64;
        let cov: nalgebra::Matrix3<f64> = pts.iter().map(|p| (*p - c) * (*p - c).transpose()).sum();
        let e = nalgebra::SymmetricEigen::new(cov);
        let mut order = [0usize, 1, 2];
        order.sort_by(|&i, &j| e.eigenvalues[j].total_cmp(&e.eigenvalues[i]));
        let axes =
            nalgebra::Matrix3::from_columns(&order.map(|i| e.eigenvectors.column(i).into_owned()));
        frames.insert(l, (c, axes));
    }
    let delta = MAX_DISAGREEMENT_DEG.to_radians();
    let mut least = f64::INFINITY;
    for axis in 0..2 {
        for sign in [-1.0, 1.0] {
            let moved: Vec<Vector3<f64>> = w
                .iter()
                .zip(&lab)
                .map(|(p, l)| {
                    let Some((c, axes)) = frames.get(l) else {
                        return *p;
                    };
                    let turn = nalgebra::Rotation3::from_axis_angle(
                        &nalgebra::Unit::new_normalize(axes.column(axis).into_owned()),
                        sign * delta,
                    );
                    let n = turn * axes.column(2).into_owned();
                    let ray = p - *centre;
                    let along = n.dot(&ray);
                    if along.abs() < 1e-12 {
                        return *p;
                    }
                    *centre + ray * (n.dot(&(c - *centre)) / along)
                })
                .collect();
            let tilted = refine_pose(&best, &x, &moved, 10);
            least = least.min(cost(&tilted, &moved) - cb);
        }
    }
    let ratio = least / variance.max(1e-300);
    tracing::debug!(
        "{} matches on {} plane(s): tilting them by {MAX_DISAGREEMENT_DEG}° costs {ratio:.1} \
         residual variances",
        x.len(),
        frames.len()
    );
    (ratio < TILT_MIN_RATIO).then(|| {
        format!(
            "its {} matches are explained about as well with the planes they are placed on tilted \
             by {MAX_DISAGREEMENT_DEG}°, so they do not determine its orientation",
            x.len()
        )
    })
}

/// The observed points of one registered view, in its camera frame, with their pixels and plane
/// labels.
struct PartnerDepth {
    pixels: Vec<Vector2<f64>>,
    label: Vec<Option<usize>>,
    planes: Vec<Plane>,
    world_from_cam: handheld_core::Rigid3,
}

impl PartnerDepth {
    fn new(rec: &MetricReconstruction, v: &View, seed: u64) -> Self {
        let (mut pixels, mut points) = (Vec::new(), Vec::new());
        for o in &v.observations {
            let Some(p) = o.point_id.and_then(|id| rec.points.get(&id)) else {
                continue;
            };
            let xc = v.cam_from_world * p.xyz;
            if xc.z > 0.0 {
                pixels.push(o.xy);
                points.push(xc.coords);
            }
        }
        let (label, planes) = segment_planes(&points, seed);
        Self {
            pixels,
            label,
            planes,
            world_from_cam: v.cam_from_world.inverse(),
        }
    }

    /// The world point where the ray of normalized point `x` (pixel `px`) meets the plane of the
    /// nearest observed points, or `None` when they do not agree on one, or the ray grazes it.
    fn world_point(&self, x: &Vector2<f64>, px: Vector2<f64>) -> Option<(Vector3<f64>, usize)> {
        if self.pixels.len() < NEIGHBOURS || self.planes.is_empty() {
            return None;
        }
        let mut order: Vec<(f64, usize)> = self
            .pixels
            .iter()
            .enumerate()
            .map(|(i, p)| ((p - px).norm_squared(), i))
            .collect();
        order.select_nth_unstable_by(NEIGHBOURS - 1, |a, b| a.0.total_cmp(&b.0));
        let mut votes = vec![0usize; self.planes.len()];
        for &(_, i) in &order[..NEIGHBOURS] {
            if let Some(l) = self.label[i] {
                votes[l] += 1;
            }
        }
        let (best, &count) = votes
            .iter()
            .enumerate()
            .max_by_key(|(l, c)| (**c, usize::MAX - l))?;
        if 2 * count <= NEIGHBOURS {
            return None;
        }
        let (n, d) = self.planes[best];
        let ray = Vector3::new(x.x, x.y, 1.0);
        let c = n.dot(&ray);
        if c.abs() < 0.1 * ray.norm() {
            return None;
        }
        let depth = d / c;
        if !(depth.is_finite() && depth > 0.0) {
            return None;
        }
        let xc = nalgebra::Point3::from(ray * depth);
        Some(((self.world_from_cam * xc).coords, best))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Points on two walls of a room corner, seen from the origin looking down +z.
    fn corner() -> Vec<Vector3<f64>> {
        let mut pts = Vec::new();
        for i in 0..15 {
            for j in 0..10 {
                let (u, v) = (i as f64 * 0.13, j as f64 * 0.17 - 0.8);
                // Back wall z = 5 − 0.1 x, for x in [−1.5, 0.4].
                let x = -1.5 + u;
                pts.push(Vector3::new(x, v, 5.0 - 0.1 * x));
                // Left wall x = −2, z in [2, 4].
                pts.push(Vector3::new(-2.0, v, 2.0 + u));
            }
        }
        pts
    }

    #[test]
    fn segmentation_finds_both_walls_and_extends_the_back_wall() {
        let pts = corner();
        let (label, planes) = segment_planes(&pts, 3);
        assert_eq!(planes.len(), 2, "{planes:?}");
        // Every point is labelled, and each wall has one label.
        assert!(label.iter().all(Option::is_some));
        let back = label[0].expect("labelled");
        let left = label[1].expect("labelled");
        assert_ne!(back, left);
        for (k, l) in label.iter().enumerate() {
            assert_eq!(*l, Some(if k % 2 == 0 { back } else { left }));
        }
        // A ray to the right of every observed point meets the back wall's plane.
        let f = 500.0;
        let pixels: Vec<Vector2<f64>> = pts
            .iter()
            .map(|p| Vector2::new(f * p.x / p.z, f * p.y / p.z))
            .collect();
        let depth = PartnerDepth {
            pixels,
            label,
            planes,
            world_from_cam: handheld_core::Rigid3::identity(),
        };
        let target = Vector3::new(1.2, 0.3, 5.0 - 0.12);
        let x = Vector2::new(target.x / target.z, target.y / target.z);
        let (got, _) = depth.world_point(&x, x * f).expect("a plane");
        assert!((got - target).norm() < 1e-6, "{got} against {target}");
    }
    /// A view placed through an 8×8 grid on a plane tilted 30°, seen by the partner (at the
    /// origin) and by the view (turned 10° about the grid's centre) from `distance` grid widths,
    /// its image points off by up to half a pixel at focal length `f`: whether
    /// [`undetermined_tilt`] says the matches do not fix its orientation.
    fn placed_through_a_plane(distance: f64, f: f64) -> Option<String> {
        let tilt = nalgebra::UnitQuaternion::from_euler_angles(30f64.to_radians(), 0.0, 0.0);
        let centre = Vector3::new(0.0, 0.0, distance);
        let world: Vec<Vector3<f64>> = (0..64)
            .map(|k| {
                centre
                    + tilt
                        * Vector3::new((k % 8) as f64 / 7.0 - 0.5, (k / 8) as f64 / 7.0 - 0.5, 0.0)
            })
            .collect();
        // Camera from world: turned 10° about y around the grid's centre.
        let rotation = nalgebra::UnitQuaternion::from_euler_angles(0.0, 10f64.to_radians(), 0.0);
        let pose = handheld_geometry::Pose {
            rotation,
            translation: centre - rotation * centre,
        };
        let mut state = 7u64;
        let samples: Vec<CalibratedMatch> = world
            .iter()
            .map(|w| {
                let y = pose.transform(w);
                let mut noise = || {
                    state = state
                        .wrapping_mul(6364136223846793005)
                        .wrapping_add(1442695040888963407);
                    ((state >> 33) as f64 / (1u64 << 31) as f64 - 0.5) / f
                };
                let x = Vector2::new(y.x / y.z + noise(), y.y / y.z + noise());
                CalibratedMatch { x, world: *w }
            })
            .collect();
        let all: Vec<usize> = (0..samples.len()).collect();
        undetermined_tilt(
            &pose,
            &samples,
            &vec![0; samples.len()],
            &all,
            &Vector3::zeros(),
        )
    }

    #[test]
    fn a_plane_seen_through_a_narrow_field_of_view_does_not_fix_the_view_placed_on_it() {
        // 3° across the grid at f = 3300 px (the hemisphere's long lens): tilting the plane 5° is
        // absorbed by the pose (and fits the noise better). 37° across it at f = 480 px
        // (iclnuim-5's wall): it costs 480 residual variances. The boundary lies near 11° across
        // at f = 1000 px (5 widths): 11 variances.
        assert!(placed_through_a_plane(20.0, 3300.0).is_some());
        assert_eq!(placed_through_a_plane(1.5, 480.0), None);
    }
}
