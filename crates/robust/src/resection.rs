//! The projective resection estimator of §3.2: 6-point DLT hypotheses inside the shared RANSAC loop
//! (usually with the T(d,d) pre-test), the reprojection distance as residual and the iterated
//! weighted DLT (the resection counterpart of eq. 20) as refit. The algorithms live in
//! `handheld-geometry`; this file is the glue.

use handheld_geometry::{
    p3p, refine_pose, reprojection_distance, resection_dlt, resection_iterative, Pose,
};
use nalgebra::{Matrix3x4, Vector2, Vector3, Vector4};

use crate::estimator::Estimator;

/// A 2D–3D correspondence: image point `x` of a homogeneous world point `m`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Match2d3d {
    pub x: Vector2<f64>,
    pub m: Vector4<f64>,
}

/// Projective camera `x ~ P M` from ≥ 6 2D–3D matches (H&Z alg. 7.1). The residual is the image
/// distance in the units of `x` (pixels, or normalised units when `x` is normalised).
#[derive(Clone, Copy, Debug)]
pub struct ResectionEstimator {
    /// Weighted re-solves of the refit. Default 3.
    pub refit_iterations: usize,
}

impl Default for ResectionEstimator {
    fn default() -> Self {
        Self {
            refit_iterations: 3,
        }
    }
}

fn split(samples: &[Match2d3d]) -> (Vec<Vector4<f64>>, Vec<Vector2<f64>>) {
    samples.iter().map(|s| (s.m, s.x)).unzip()
}

impl Estimator for ResectionEstimator {
    type Model = Matrix3x4<f64>;
    type Sample = Match2d3d;
    const SAMPLE_SIZE: usize = 6;

    fn fit(&self, samples: &[Match2d3d], out: &mut Vec<Matrix3x4<f64>>) {
        let (m, x) = split(samples);
        if let Ok(p) = resection_dlt(&m, &x) {
            out.push(p);
        }
    }

    fn residual(&self, model: &Matrix3x4<f64>, s: &Match2d3d) -> f64 {
        reprojection_distance(model, &s.m, &s.x)
    }

    fn refit(&self, samples: &[Match2d3d], _model: &Matrix3x4<f64>) -> Option<Matrix3x4<f64>> {
        let (m, x) = split(samples);
        resection_iterative(&m, &x, self.refit_iterations).ok()
    }
}

/// A calibrated 2D–3D correspondence: normalized (undistorted, `K⁻¹`) image point `x` of a
/// Euclidean world point `world`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CalibratedMatch {
    pub x: Vector2<f64>,
    pub world: Vector3<f64>,
}

/// Calibrated resection: a pose from ≥ 3 matches (Grunert's P3P, [`handheld_geometry::p3p`]),
/// Gauss–Newton on all inliers as the refit. The residual is the normalized reprojection error
/// (multiply a pixel threshold by `1 / f`).
#[derive(Clone, Copy, Debug, Default)]
pub struct P3pEstimator;

impl Estimator for P3pEstimator {
    type Model = Pose;
    type Sample = CalibratedMatch;
    const SAMPLE_SIZE: usize = 3;

    fn fit(&self, samples: &[CalibratedMatch], out: &mut Vec<Pose>) {
        let rays = std::array::from_fn(|i| Vector3::new(samples[i].x.x, samples[i].x.y, 1.0));
        let world = std::array::from_fn(|i| samples[i].world);
        out.extend(p3p(&rays, &world));
    }

    fn residual(&self, model: &Pose, s: &CalibratedMatch) -> f64 {
        model.reprojection_error(&s.x, &s.world)
    }

    fn refit(&self, samples: &[CalibratedMatch], model: &Pose) -> Option<Pose> {
        if samples.len() < 4 {
            return None;
        }
        let (x, w): (Vec<_>, Vec<_>) = samples.iter().map(|s| (s.x, s.world)).unzip();
        Some(refine_pose(model, &x, &w, 10))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{run, Msac, RansacOptions, UniformSampler};
    use nalgebra::{Matrix3, Rotation3, Vector3};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn ransac_resection_with_outliers_and_tdd() {
        let mut r = ChaCha8Rng::seed_from_u64(3);
        let k = Matrix3::new(700.0, 0.0, 320.0, 0.0, 700.0, 240.0, 0.0, 0.0, 1.0);
        let rot = Rotation3::from_euler_angles(0.05, 0.2, -0.1);
        let t = Vector3::new(0.1, 0.2, 6.0);
        let mut rt = Matrix3x4::zeros();
        rt.fixed_view_mut::<3, 3>(0, 0).copy_from(rot.matrix());
        rt.fixed_view_mut::<3, 1>(0, 3).copy_from(&t);
        let p = k * rt;
        let mut samples = Vec::new();
        let mut inlier = Vec::new();
        for i in 0..300 {
            let m = Vector4::new(
                r.random_range(-1.5..1.5),
                r.random_range(-1.0..1.0),
                r.random_range(-1.0..1.0),
                1.0,
            );
            let q = p * m;
            let mut x = Vector2::new(q.x / q.z, q.y / q.z)
                + Vector2::new(r.random_range(-0.5..0.5), r.random_range(-0.5..0.5));
            let out = i % 3 == 0;
            if out {
                x = Vector2::new(r.random_range(0.0..640.0), r.random_range(0.0..480.0));
            }
            inlier.push(!out);
            samples.push(Match2d3d { x, m });
        }
        let opts = RansacOptions {
            max_error: 2.0,
            tdd: Some(1),
            seed: 5,
            ..Default::default()
        };
        let rep = run(
            &ResectionEstimator::default(),
            &Msac,
            &mut UniformSampler::new(5),
            &samples,
            &opts,
        )
        .unwrap();
        assert!(rep.success);
        let found = rep
            .inlier_mask
            .iter()
            .zip(&inlier)
            .filter(|(a, b)| **a && **b)
            .count();
        assert!(found >= 190, "found {found} of 200 inliers");
        let wrong = rep
            .inlier_mask
            .iter()
            .zip(&inlier)
            .filter(|(a, b)| **a && !**b)
            .count();
        assert!(wrong <= 3, "{wrong} outliers accepted");
        let est = rep.model.unwrap();
        // The estimate reprojects the exact points to well within the ±0.5 px noise.
        let mut worst = 0.0f64;
        for s in &samples {
            let (q, e) = (p * s.m, est * s.m);
            worst = worst.max((q.xy() / q.z - e.xy() / e.z).norm());
        }
        assert!(worst < 0.3, "worst reprojection difference {worst} px");
    }

    /// P3P inside RANSAC on a *planar* scene (where the 6-point DLT is degenerate) with a third of
    /// outliers: the pose is recovered to a fraction of a degree.
    #[test]
    fn ransac_p3p_on_a_planar_scene_with_outliers() {
        let mut r = ChaCha8Rng::seed_from_u64(11);
        let rot = nalgebra::UnitQuaternion::from_euler_angles(0.3, -0.2, 0.1);
        let t = Vector3::new(0.2, -0.1, 5.0);
        let f = 600.0;
        let mut samples = Vec::new();
        for i in 0..300 {
            let world = Vector3::new(r.random_range(-2.0..2.0), r.random_range(-1.5..1.5), 0.0);
            let y = rot * world + t;
            let mut x = Vector2::new(y.x / y.z, y.y / y.z)
                + Vector2::new(r.random_range(-0.5..0.5), r.random_range(-0.5..0.5)) / f;
            if i % 3 == 0 {
                x = Vector2::new(r.random_range(-0.5..0.5), r.random_range(-0.4..0.4));
            }
            samples.push(CalibratedMatch { x, world });
        }
        let opts = RansacOptions {
            max_error: 2.0 / f,
            tdd: Some(1),
            seed: 2,
            ..Default::default()
        };
        let rep = run(
            &P3pEstimator,
            &Msac,
            &mut UniformSampler::new(2),
            &samples,
            &opts,
        )
        .unwrap();
        let pose = rep.model.expect("a pose");
        assert!(rep.success && rep.support >= 190, "support {}", rep.support);
        assert!(pose.rotation.angle_to(&rot).to_degrees() < 0.2);
        assert!((pose.translation - t).norm() < 0.05 * t.norm());
    }
}
