//! Cheap multi-view sets for bundle-adjustment and SfM tests, without rendering.
//!
//! `num_points` points uniform in a ball of radius 1.5 m around the origin are seen by `num_views`
//! cameras spread over a 90° arc about 6 m away (seeded jitter in position, aim and roll). Each view
//! observes every point that projects inside its image; points seen by fewer than `min_track_len`
//! views are dropped. The returned [`MetricReconstruction`] holds the exact cameras, poses and points,
//! and **noisy** observations (Gaussian `noise_px` per coordinate); `round(outlier_fraction · total)`
//! observations are outliers, replaced by uniform random pixels at least
//! [`crate::correspondences::OUTLIER_MIN_ERROR_PX`] from their true projection. Intrinsics are shared
//! (one camera) or per view, optionally with radial distortion.

use std::collections::BTreeMap;

use handheld_core::{
    Camera, CameraId, ImageId, Intrinsics, MetricReconstruction, Observation, Point3D, PointId,
    Track, TrackElement, View,
};
use nalgebra::{Point3, Vector2};
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::correspondences::{aimed_pose, outlier_pixel, random_vec, OUTLIER_MIN_ERROR_PX};
use crate::util::gaussian;

#[derive(Clone, Debug, PartialEq)]
pub struct MultiViewOptions {
    pub num_views: usize,
    pub num_points: usize,
    pub noise_px: f64,
    pub outlier_fraction: f64,
    /// Use `k1 = −0.08, k2 = 0.01` instead of a pinhole.
    pub radial_distortion: bool,
    /// One camera for all views; otherwise one per view with focal lengths varying by ±10 %.
    pub shared_intrinsics: bool,
    pub min_track_len: usize,
    pub seed: u64,
    pub width: u32,
    pub height: u32,
}

impl Default for MultiViewOptions {
    fn default() -> Self {
        Self {
            num_views: 8,
            num_points: 300,
            noise_px: 0.5,
            outlier_fraction: 0.0,
            radial_distortion: false,
            shared_intrinsics: true,
            min_track_len: 2,
            seed: 0,
            width: 640,
            height: 480,
        }
    }
}

/// A multi-view set: the reconstruction with noisy observations plus the exact ones.
#[derive(Clone, Debug, PartialEq)]
pub struct MultiViewSet {
    /// Exact cameras, poses and points; observations are noisy (and possibly outliers).
    pub reconstruction: MetricReconstruction,
    /// Exact projection of each observation, indexed like `View::observations`.
    pub exact: BTreeMap<ImageId, Vec<Vector2<f64>>>,
    /// Whether each observation is an inlier, indexed like `View::observations`.
    pub is_inlier: BTreeMap<ImageId, Vec<bool>>,
}

impl MultiViewSet {
    /// The reconstruction with exact observations (zero reprojection error).
    pub fn ground_truth(&self) -> MetricReconstruction {
        let mut rec = self.reconstruction.clone();
        for (id, view) in rec.views.iter_mut() {
            if let Some(ex) = self.exact.get(id) {
                for (o, x) in view.observations.iter_mut().zip(ex) {
                    o.xy = *x;
                }
            }
        }
        rec
    }
}

/// Generates a multi-view set.
pub fn multi_view_set(opts: &MultiViewOptions) -> Result<MultiViewSet, String> {
    if opts.num_views == 0 || opts.num_points == 0 {
        return Err("need at least one view and one point".into());
    }
    if !(opts.noise_px >= 0.0
        && opts.noise_px.is_finite()
        && (0.0..=1.0).contains(&opts.outlier_fraction))
    {
        return Err("noise_px must be non-negative and outlier_fraction in [0, 1]".into());
    }
    let mut rng = ChaCha8Rng::seed_from_u64(opts.seed ^ 0x3A17_0000);
    let (w, h) = (opts.width as f64, opts.height as f64);
    let (k1, k2) = if opts.radial_distortion {
        (-0.08, 0.01)
    } else {
        (0.0, 0.0)
    };
    let make_intrinsics = |rng: &mut ChaCha8Rng, vary: bool| {
        let s = if vary {
            rng.random_range(0.9..1.1)
        } else {
            1.0
        };
        Intrinsics {
            f: 0.95 * w * s,
            aspect: 1.0,
            skew: 0.0,
            pp: Vector2::new(
                w / 2.0 + rng.random_range(-4.0..4.0),
                h / 2.0 + rng.random_range(-4.0..4.0),
            ),
            k1,
            k2,
        }
    };
    let mut rec = MetricReconstruction::default();
    let shared = make_intrinsics(&mut rng, false);
    let n = opts.num_views;
    for i in 0..n {
        let camera_id = if opts.shared_intrinsics {
            CameraId(0)
        } else {
            CameraId(i as u32)
        };
        if let std::collections::btree_map::Entry::Vacant(slot) = rec.cameras.entry(camera_id) {
            let intrinsics = if opts.shared_intrinsics {
                shared
            } else {
                make_intrinsics(&mut rng, true)
            };
            slot.insert(Camera {
                id: camera_id,
                width: opts.width,
                height: opts.height,
                intrinsics,
            });
        }
        let s = if n > 1 {
            i as f64 / (n - 1) as f64
        } else {
            0.5
        };
        let az = ((s - 0.5) * 90.0 + rng.random_range(-3.0..3.0)).to_radians();
        let el = rng.random_range(10.0f64..30.0).to_radians();
        let d = rng.random_range(5.5..6.5);
        let eye = Point3::new(az.sin() * el.cos(), -az.cos() * el.cos(), el.sin()) * d;
        let pose = aimed_pose(
            &eye,
            &Point3::from(random_vec(&mut rng, 0.2)),
            rng.random_range(-0.1..0.1),
        )?;
        let id = ImageId(i as u32);
        rec.views.insert(
            id,
            View {
                id,
                name: format!("view_{i:04}.png"),
                camera_id,
                cam_from_world: pose,
                observations: Vec::new(),
                frame: None,
            },
        );
    }
    let mut exact: BTreeMap<ImageId, Vec<Vector2<f64>>> =
        rec.views.keys().map(|id| (*id, Vec::new())).collect();
    let mut next_point = 0u64;
    let min_track = opts.min_track_len.max(1);
    for _ in 0..opts.num_points {
        let x = loop {
            let v = random_vec(&mut rng, 1.5);
            if v.norm() <= 1.5 {
                break Point3::from(v);
            }
        };
        let seen: Vec<(ImageId, Vector2<f64>)> = rec
            .views
            .values()
            .filter_map(|v| {
                let cam = rec.cameras.get(&v.camera_id)?;
                let p = cam.project(&v.cam_from_world, &x)?;
                (cam.contains(&p) && v.cam_from_world.transform_point(&x).z > 0.5)
                    .then_some((v.id, p))
            })
            .collect();
        if seen.len() < min_track {
            continue;
        }
        let pid = PointId(next_point);
        next_point += 1;
        let mut elements = Vec::with_capacity(seen.len());
        for (image_id, p) in seen {
            let (Some(view), Some(ex)) = (rec.views.get_mut(&image_id), exact.get_mut(&image_id))
            else {
                continue;
            };
            elements.push(TrackElement {
                image_id,
                point2d_idx: view.observations.len() as u32,
            });
            let noisy = p + Vector2::new(gaussian(&mut rng), gaussian(&mut rng)) * opts.noise_px;
            view.observations.push(Observation {
                xy: noisy,
                point_id: Some(pid),
            });
            ex.push(p);
        }
        rec.points.insert(
            pid,
            Point3D {
                xyz: x,
                color: [128; 3],
                error: -1.0,
                track: Track { elements },
            },
        );
    }
    let mut is_inlier: BTreeMap<ImageId, Vec<bool>> = exact
        .iter()
        .map(|(id, e)| (*id, vec![true; e.len()]))
        .collect();
    let mut all: Vec<(ImageId, usize)> = exact
        .iter()
        .flat_map(|(id, e)| (0..e.len()).map(move |k| (*id, k)))
        .collect();
    let n_out = (opts.outlier_fraction * all.len() as f64).round() as usize;
    all.shuffle(&mut rng);
    let min_err = OUTLIER_MIN_ERROR_PX.max(10.0 * opts.noise_px);
    for &(id, k) in &all[..n_out] {
        let (Some(view), Some(ex), Some(inl)) = (
            rec.views.get_mut(&id),
            exact.get(&id),
            is_inlier.get_mut(&id),
        ) else {
            continue;
        };
        let Some(cam) = rec.cameras.get(&view.camera_id) else {
            continue;
        };
        let truth = ex[k];
        view.observations[k].xy = outlier_pixel(&mut rng, cam, min_err, |p| (p - truth).norm());
        inl[k] = false;
    }
    Ok(MultiViewSet {
        reconstruction: rec,
        exact,
        is_inlier,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exact_set_reprojects_perfectly_and_noisy_one_matches_noise() {
        let set = multi_view_set(&MultiViewOptions {
            radial_distortion: true,
            shared_intrinsics: false,
            ..Default::default()
        })
        .expect("valid");
        let gt = set.ground_truth();
        gt.validate().expect("consistent");
        assert!(gt.mean_reprojection_error() < 1e-9);
        assert_eq!(gt.cameras.len(), 8);
        let e = set.reconstruction.reprojection_errors();
        let rms = (e.iter().map(|v| v * v).sum::<f64>() / e.len() as f64).sqrt();
        // RMS of a 2D Gaussian with σ = 0.5 per axis is 0.5·√2.
        assert!((rms - 0.5 * 2f64.sqrt()).abs() < 0.05, "rms {rms}");
        assert!(set.reconstruction.points.len() > 250);
    }

    #[test]
    fn outlier_fraction_is_respected() {
        let set = multi_view_set(&MultiViewOptions {
            outlier_fraction: 0.2,
            ..Default::default()
        })
        .expect("valid");
        let total: usize = set.is_inlier.values().map(|v| v.len()).sum();
        let out: usize = set
            .is_inlier
            .values()
            .map(|v| v.iter().filter(|b| !**b).count())
            .sum();
        assert_eq!(out, (0.2 * total as f64).round() as usize);
        for (id, view) in &set.reconstruction.views {
            for (k, o) in view.observations.iter().enumerate() {
                let err = (o.xy - set.exact[id][k]).norm();
                assert_eq!(set.is_inlier[id][k], err < OUTLIER_MIN_ERROR_PX, "{err}");
            }
        }
    }
}
