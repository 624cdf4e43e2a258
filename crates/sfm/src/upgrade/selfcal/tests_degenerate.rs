//! Self-calibration tests on critical motions and bad inputs: degenerate cases are reported, never
//! a panic.

use super::test_scenes::*;
use super::*;
use nalgebra::{Matrix3, Matrix3x4};
use nalgebra::{Rotation3, Unit, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

#[test]
fn pure_translation_is_degenerate() {
    for (seed, noise) in [(11u64, 0.0), (12, 1e-4)] {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let r0 = random_rotation(&mut rng, 5.0, 20.0);
        let c: Vec<_> = (0..10)
            .map(|_| {
                Vector3::new(
                    rng.random_range(-2.0..2.0),
                    rng.random_range(-2.0..2.0),
                    rng.random_range(-6.0..-4.0),
                )
            })
            .collect();
        let k = vec![pixel_k(F_PX, 30.0, -20.0); 10];
        let (cams, _) = projective_cameras(&mut rng, k, vec![r0; 10], c, noise);
        let sc = self_calibrate(&cams, &SelfCalibrationOptions::default()).unwrap();
        assert_finite(&sc);
        eprintln!(
            "pure translation, noise {noise}: critical ratio {:.2e}, degenerate {:?}",
            sc.critical_ratio, sc.degenerate
        );
        assert!(sc.degenerate.is_some());
    }
}

#[test]
fn pure_rotation_is_degenerate() {
    for (seed, noise) in [(13u64, 0.0), (14, 1e-4)] {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let c = Vector3::new(0.3, -0.2, -5.0);
        let axis = Unit::new_normalize(Vector3::new(0.1, 1.0, 0.05));
        let r: Vec<_> = (0..10)
            .map(|i| {
                Rotation3::from_axis_angle(&axis, (-30.0 + 6.0 * i as f64).to_radians())
                    .into_inner()
            })
            .collect();
        let k = vec![pixel_k(F_PX, 30.0, -20.0); 10];
        let (cams, _) = projective_cameras(&mut rng, k, r, vec![c; 10], noise);
        let sc = self_calibrate(&cams, &SelfCalibrationOptions::default()).unwrap();
        assert_finite(&sc);
        eprintln!(
            "pure rotation, noise {noise}: critical ratio {:.2e}, degenerate {:?}",
            sc.critical_ratio, sc.degenerate
        );
        assert!(sc.degenerate.is_some());
    }
}

#[test]
fn two_cameras_are_reported_degenerate() {
    let (cams, _) = general_scene(21, 0.0);
    let sc = self_calibrate(&cams[..2], &SelfCalibrationOptions::default()).unwrap();
    assert_finite(&sc);
    assert!(sc.degenerate.is_some());
}

#[test]
fn invalid_inputs_are_errors() {
    let opts = SelfCalibrationOptions::default();
    let p = Matrix3x4::new(1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0);
    assert_eq!(
        self_calibrate(&[], &opts),
        Err(SelfCalibrationError::TooFewCameras(0))
    );
    assert_eq!(
        self_calibrate(&[p], &opts),
        Err(SelfCalibrationError::TooFewCameras(1))
    );
    let mut bad = p;
    bad[(1, 2)] = f64::NAN;
    assert_eq!(
        self_calibrate(&[p, bad], &opts),
        Err(SelfCalibrationError::NonFiniteCamera { index: 1 })
    );
    bad[(1, 2)] = f64::INFINITY;
    assert_eq!(
        self_calibrate(&[bad, p], &opts),
        Err(SelfCalibrationError::NonFiniteCamera { index: 0 })
    );
    assert_eq!(
        self_calibrate(&[p, Matrix3x4::zeros()], &opts),
        Err(SelfCalibrationError::ZeroCamera { index: 1 })
    );
    let bad_opts = SelfCalibrationOptions {
        iterations: 0,
        ..Default::default()
    };
    assert!(matches!(
        self_calibrate(&[p, p], &bad_opts),
        Err(SelfCalibrationError::InvalidOption { .. })
    ));
}

#[test]
fn odd_inputs_do_not_panic() {
    let p = Matrix3x4::new(1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0);
    let huge = p * 1e300;
    let tiny = p * 1e-300;
    let rank1 = Matrix3x4::from_fn(|i, j| (i + 1) as f64 * (j + 1) as f64);
    for opts in [
        SelfCalibrationOptions::default(),
        SelfCalibrationOptions {
            estimate_prior_means: false,
            ..Default::default()
        },
        SelfCalibrationOptions {
            prior_mean_weight: 0.0,
            iterations: 20,
            ..Default::default()
        },
        SelfCalibrationOptions {
            prior_mean_weight: 1e6,
            sigma_skew: 1e-12,
            ..Default::default()
        },
        SelfCalibrationOptions {
            sigma_focal_sq: 1e12,
            sigma_aspect: 1e-12,
            ..Default::default()
        },
    ] {
        for cams in [
            vec![p, p],
            vec![huge, tiny, p],
            vec![rank1, rank1, p],
            vec![rank1; 5],
        ] {
            let sc = self_calibrate(&cams, &opts).unwrap();
            assert_finite(&sc);
            assert!(sc.degenerate.is_some());
        }
        let mut rng = ChaCha8Rng::seed_from_u64(99);
        for _ in 0..50 {
            let n = rng.random_range(2..8);
            let cams: Vec<_> = (0..n)
                .map(|_| Matrix3x4::from_fn(|_, _| rng.random_range(-1.0..1.0)))
                .collect();
            let sc = self_calibrate(&cams, &opts).unwrap();
            assert_finite(&sc);
        }
    }
}

#[test]
fn decompose_camera_round_trip() {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let mut worst: f64 = 0.0;
    for _ in 0..500 {
        let f = rng.random_range(0.3..3.0);
        let k = Matrix3::new(
            f,
            rng.random_range(-0.05..0.05),
            rng.random_range(-0.2..0.2),
            0.0,
            f * rng.random_range(0.8..1.2),
            rng.random_range(-0.2..0.2),
            0.0,
            0.0,
            1.0,
        );
        let r = random_rotation(&mut rng, 0.0, 180.0);
        let t = Vector3::new(
            rng.random_range(-5.0..5.0),
            rng.random_range(-5.0..5.0),
            rng.random_range(-5.0..5.0),
        );
        let mut rt = Matrix3x4::zeros();
        rt.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
        rt.set_column(3, &t);
        let scale = rng.random_range(0.1..10.0) * if rng.random_bool(0.5) { 1.0 } else { -1.0 };
        let p = k * rt * scale;
        let (k2, r2, t2) = decompose_camera(&p).unwrap();
        worst = worst
            .max((k2 - k).amax())
            .max((r2 - r).amax())
            .max((t2 - t).amax());
        assert!((k2 - k).amax() < 1e-10, "{k} vs {k2}");
        assert!((r2 - r).amax() < 1e-10);
        assert!((t2 - t).amax() < 1e-9);
        assert!((r2.determinant() - 1.0).abs() < 1e-12);
        assert!((r2 * r2.transpose() - Matrix3::identity()).amax() < 1e-12);
        assert!(k2[(0, 0)] > 0.0 && k2[(1, 1)] > 0.0 && k2[(2, 2)] == 1.0);
        assert_eq!(k2[(1, 0)], 0.0);
    }
    eprintln!("decompose_camera round trip: worst entry error {worst:.1e}");
    assert!(decompose_camera(&Matrix3x4::zeros()).is_none());
    let singular = Matrix3x4::new(1.0, 2.0, 3.0, 1.0, 2.0, 4.0, 6.0, 0.0, 0.0, 0.0, 1.0, 1.0);
    assert!(decompose_camera(&singular).is_none());
    let mut nan = Matrix3x4::identity();
    nan[(0, 0)] = f64::NAN;
    assert!(decompose_camera(&nan).is_none());
}

#[test]
fn a_known_focal_upgrades_circular_motion_with_a_long_lens() {
    // dinoSparseRing's geometry: 16 views on a circle about one axis (a critical motion, Sturm
    // 1997) through a long lens (normalized focal 3). With the focal given, eq. 26 has no free
    // direction left: the upgraded cameras have that focal and the ring's 22.5° steps.
    let f_px = 3.0 * f64::from(W + H);
    let mut rng = ChaCha8Rng::seed_from_u64(21);
    let (r, c): (Vec<_>, Vec<_>) = (0..16)
        .map(|i| {
            let q = Rotation3::from_axis_angle(&Vector3::y_axis(), (22.5 * i as f64).to_radians())
                .into_inner();
            (q.transpose(), q * Vector3::new(0.0, 0.0, -5.0))
        })
        .unzip();
    let k = pixel_k(f_px, 0.0, 0.0);
    let (cams, truth) = projective_cameras(&mut rng, vec![k; 16], r, c, 1e-6);
    let sc = self_calibrate(&cams, &SelfCalibrationOptions::default()).unwrap();
    eprintln!("circular motion: degenerate {:?}", sc.degenerate);
    assert!(sc.degenerate.is_some(), "circular motion is critical");
    let up = upgrade_for_focal(&cams, 3.0, 3).unwrap();
    assert!(!up.clamped, "{up:?}");
    let kn = normalization_matrix(W, H);
    let metric: Vec<_> = cams
        .iter()
        .map(|p| decompose_camera(&(kn * p * up.t_inv)).unwrap())
        .collect();
    for (i, (k_est, r_est, _)) in metric.iter().enumerate() {
        let f_est = 0.5 * (k_est[(0, 0)] + k_est[(1, 1)]);
        assert!(
            (f_est / f_px - 1.0).abs() < 1e-3,
            "view {i}: f {f_est} against {f_px}"
        );
        if i > 0 {
            let step =
                Rotation3::from_matrix_unchecked(r_est * metric[i - 1].1.transpose()).angle();
            let truth_step =
                Rotation3::from_matrix_unchecked(truth.r[i] * truth.r[i - 1].transpose()).angle();
            assert!(
                (step - truth_step).abs().to_degrees() < 0.01,
                "view {i}: step {}°",
                step.to_degrees()
            );
        }
    }
}
