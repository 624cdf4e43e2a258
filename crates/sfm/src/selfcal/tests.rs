//! Tests of the DAQ self-calibration against seeded synthetic cameras with exact ground truth.

use super::*;
use nalgebra::{Rotation3, Unit, Vector4};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const W: u32 = 3072;
const H: u32 = 2048;
/// Pixel focal of the main scenario: a wide-angle lens, normalized focal 2400/5120 ≈ 0.47.
const F_PX: f64 = 2400.0;

/// Ground truth of a synthetic sequence.
struct Truth {
    /// Pixel intrinsics of each camera.
    k: Vec<Matrix3<f64>>,
    /// World-to-camera rotations.
    r: Vec<Matrix3<f64>>,
    /// Camera centres.
    c: Vec<Vector3<f64>>,
    /// The projective corruption: `P_proj ∼ P_metric H⁻¹`, `M_proj = H M_metric`.
    h: Matrix4<f64>,
}

fn pixel_k(f: f64, du: f64, dv: f64) -> Matrix3<f64> {
    Matrix3::new(
        f,
        0.0,
        f64::from(W) / 2.0 + du,
        0.0,
        f,
        f64::from(H) / 2.0 + dv,
        0.0,
        0.0,
        1.0,
    )
}

fn normalized(k: &Matrix3<f64>) -> NormalizedIntrinsics {
    NormalizedIntrinsics::from_k(&(normalization_matrix(W, H).try_inverse().unwrap() * k))
}

fn random_unit(rng: &mut ChaCha8Rng) -> Vector3<f64> {
    loop {
        let v = Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        );
        let n = v.norm();
        if n > 0.1 && n <= 1.0 {
            return v / n;
        }
    }
}

fn random_rotation(rng: &mut ChaCha8Rng, min_deg: f64, max_deg: f64) -> Matrix3<f64> {
    let axis = Unit::new_normalize(random_unit(rng));
    let angle = rng.random_range(min_deg..max_deg).to_radians();
    Rotation3::from_axis_angle(&axis, angle).into_inner()
}

fn gaussian(rng: &mut ChaCha8Rng) -> f64 {
    // Box–Muller.
    let u1: f64 = rng.random_range(f64::MIN_POSITIVE..1.0);
    let u2: f64 = rng.random_range(0.0..1.0);
    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
}

/// General motion: cameras 4–6 units from the origin looking at it (the point cloud around
/// the origin), each rotated from a reference view by 10°–40° about a random axis, plus a
/// small jitter.
fn general_poses(rng: &mut ChaCha8Rng, count: usize) -> (Vec<Matrix3<f64>>, Vec<Vector3<f64>>) {
    (0..count)
        .map(|_| {
            let q = random_rotation(rng, 10.0, 40.0);
            let d = rng.random_range(4.0..6.0);
            let c = q * Vector3::new(0.0, 0.0, -d);
            let r = random_rotation(rng, 0.0, 3.0) * q.transpose();
            (r, c)
        })
        .unzip()
}

fn random_homography(rng: &mut ChaCha8Rng) -> Matrix4<f64> {
    loop {
        let h = Matrix4::identity() + Matrix4::from_fn(|_, _| rng.random_range(-0.5..0.5));
        let sv = h.singular_values();
        if sv.max() / sv.min() < 20.0 {
            return h;
        }
    }
}

fn metric_camera(k: &Matrix3<f64>, r: &Matrix3<f64>, c: &Vector3<f64>) -> Matrix3x4<f64> {
    let mut rt = Matrix3x4::zeros();
    rt.fixed_view_mut::<3, 3>(0, 0).copy_from(r);
    rt.set_column(3, &(-r * c));
    k * rt
}

/// Normalized projective cameras `K_N⁻¹ K [R | −RC] H⁻¹`, with relative noise on every entry
/// and a random scale and sign per camera.
fn projective_cameras(
    rng: &mut ChaCha8Rng,
    k: Vec<Matrix3<f64>>,
    r: Vec<Matrix3<f64>>,
    c: Vec<Vector3<f64>>,
    relative_noise: f64,
) -> (Vec<Matrix3x4<f64>>, Truth) {
    let kn_inv = normalization_matrix(W, H).try_inverse().unwrap();
    let h = random_homography(rng);
    let h_inv = h.try_inverse().unwrap();
    let cams = (0..r.len())
        .map(|i| {
            let p = kn_inv * metric_camera(&k[i], &r[i], &c[i]) * h_inv;
            let p = p.map(|v| v * (1.0 + relative_noise * gaussian(rng)));
            let s = rng.random_range(0.5..3.0) * if rng.random_bool(0.5) { 1.0 } else { -1.0 };
            p * s
        })
        .collect();
    (cams, Truth { k, r, c, h })
}

/// The main scenario: 8–15 cameras, general motion, constant wide-angle K with the principal
/// point at (+30, −20) px from the centre.
fn general_scene(seed: u64, relative_noise: f64) -> (Vec<Matrix3x4<f64>>, Truth) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let count = rng.random_range(8..=15);
    let (r, c) = general_poses(&mut rng, count);
    let k = vec![pixel_k(F_PX, 30.0, -20.0); count];
    projective_cameras(&mut rng, k, r, c, relative_noise)
}

fn rotation_angle_deg(r: &Matrix3<f64>) -> f64 {
    ((r.trace() - 1.0) / 2.0)
        .clamp(-1.0, 1.0)
        .acos()
        .to_degrees()
}

/// Worst-case errors of a self-calibration against the ground truth.
#[derive(Debug)]
struct Errors {
    focal_rel: f64,
    aspect: f64,
    principal_point_px: f64,
    skew: f64,
    /// Angle of `R̂ᵢR̂ⱼᵀ (RᵢRⱼᵀ)ᵀ` over all pairs.
    relative_rotation_deg: f64,
    /// Error of the angle between the optical axes of each pair.
    optical_axis_deg: f64,
    /// Relative spread of |Ĉᵢ − Ĉⱼ| / |Cᵢ − Cⱼ| over all pairs (0 for a similarity).
    distance_ratio: f64,
}

fn evaluate(sc: &SelfCalibration, cams: &[Matrix3x4<f64>], truth: &Truth) -> Errors {
    let s = f64::from(W + H);
    let mut e = Errors {
        focal_rel: 0.0,
        aspect: 0.0,
        principal_point_px: 0.0,
        skew: 0.0,
        relative_rotation_deg: 0.0,
        optical_axis_deg: 0.0,
        distance_ratio: 0.0,
    };
    let mut rs = Vec::new();
    let mut cs = Vec::new();
    for (i, (p, est)) in cams.iter().zip(&sc.per_camera).enumerate() {
        let gt = normalized(&truth.k[i]);
        e.focal_rel = e.focal_rel.max((est.f - gt.f).abs() / gt.f);
        e.aspect = e.aspect.max((est.aspect - gt.aspect).abs());
        e.skew = e.skew.max(est.skew.abs());
        e.principal_point_px = e
            .principal_point_px
            .max(((est.u - gt.u) * s).abs().max(((est.v - gt.v) * s).abs()));
        let (_, r, t) = decompose_camera(&sc.upgrade_camera(p)).expect("decomposable");
        cs.push(-r.transpose() * t);
        rs.push(r);
    }
    let mut ratios = Vec::new();
    for i in 0..rs.len() {
        for j in (i + 1)..rs.len() {
            let rel_true = truth.r[i] * truth.r[j].transpose();
            let rel_est = rs[i] * rs[j].transpose();
            e.relative_rotation_deg = e
                .relative_rotation_deg
                .max(rotation_angle_deg(&(rel_est * rel_true.transpose())));
            let axis = |r: &Matrix3<f64>| r.row(2).transpose();
            let a_true = axis(&truth.r[i]).angle(&axis(&truth.r[j])).to_degrees();
            let a_est = axis(&rs[i]).angle(&axis(&rs[j])).to_degrees();
            e.optical_axis_deg = e.optical_axis_deg.max((a_true - a_est).abs());
            ratios.push((cs[i] - cs[j]).norm() / (truth.c[i] - truth.c[j]).norm());
        }
    }
    let mean = ratios.iter().sum::<f64>() / ratios.len() as f64;
    e.distance_ratio = ratios
        .iter()
        .map(|r| (r / mean - 1.0).abs())
        .fold(0.0, f64::max);
    e
}

fn assert_finite(sc: &SelfCalibration) {
    assert!(sc.t.iter().all(|v| v.is_finite()));
    assert!(sc.t_inv.iter().all(|v| v.is_finite()));
    assert!(sc.omega.iter().all(|v| v.is_finite()));
    assert!(sc.singular_values.iter().all(|v| v.is_finite()));
    assert!(sc.critical_ratio.is_finite());
    assert!(sc.omega_eigenvalues.iter().all(|v| v.is_finite()));
    for k in &sc.per_camera {
        assert!([k.f, k.aspect, k.skew, k.u, k.v]
            .iter()
            .all(|v| v.is_finite()));
    }
}

fn daq() -> Matrix4<f64> {
    Matrix4::from_diagonal(&Vector4::new(1.0, 1.0, 1.0, 0.0))
}

#[test]
fn normalization_matrix_matches_eq_24() {
    let kn = normalization_matrix(3072, 2048);
    let expected = Matrix3::new(5120.0, 0.0, 1536.0, 0.0, 5120.0, 1024.0, 0.0, 0.0, 1.0);
    assert_eq!(kn, expected);
}

#[test]
fn options_validate() {
    assert!(SelfCalibrationOptions::default().validate().is_ok());
    let bad = [
        SelfCalibrationOptions {
            iterations: 0,
            ..Default::default()
        },
        SelfCalibrationOptions {
            sigma_skew: 0.0,
            ..Default::default()
        },
        SelfCalibrationOptions {
            sigma_focal_sq: f64::NAN,
            ..Default::default()
        },
        SelfCalibrationOptions {
            sigma_aspect: -1.0,
            ..Default::default()
        },
        SelfCalibrationOptions {
            sigma_principal_point: f64::INFINITY,
            ..Default::default()
        },
        SelfCalibrationOptions {
            estimated_aspect_weight: 0.0,
            ..Default::default()
        },
        SelfCalibrationOptions {
            prior_mean_weight: -1.0,
            ..Default::default()
        },
        SelfCalibrationOptions {
            degenerate_singular_ratio: 1.0,
            ..Default::default()
        },
    ];
    for o in bad {
        assert!(
            matches!(o.validate(), Err(SelfCalibrationError::InvalidOptions(_))),
            "{o:?}"
        );
    }
}

#[test]
fn general_motion_noise_free_recovers_metric_frame() {
    let opts = SelfCalibrationOptions::default();
    let mut worst_focal: f64 = 0.0;
    let mut worst_rot: f64 = 0.0;
    for seed in 0..8u64 {
        let (cams, truth) = general_scene(seed, 0.0);
        let sc = self_calibrate(&cams, &opts).unwrap();
        assert_finite(&sc);
        assert!(sc.degenerate.is_none(), "seed {seed}: {:?}", sc.degenerate);

        // Convention: diag(1,1,1,0) = T Ω* Tᵀ, T T⁻¹ = I, |Ω*| = 1.
        assert!((sc.t * sc.omega * sc.t.transpose() - daq()).amax() < 1e-9);
        assert!((sc.t * sc.t_inv - Matrix4::identity()).amax() < 1e-9);
        assert!((sc.omega.norm() - 1.0).abs() < 1e-12);
        // The fourth row of T is the plane at infinity of the projective frame, H⁻ᵀ (0,0,0,1).
        let pi_inf = truth.h.try_inverse().unwrap().transpose() * Vector4::new(0.0, 0.0, 0.0, 1.0);
        let row4 = sc.t.row(3).transpose();
        let cos = (row4.dot(&pi_inf) / (row4.norm() * pi_inf.norm())).abs();
        assert!(1.0 - cos < 1e-8, "seed {seed}: plane at infinity cos {cos}");

        // P_M diag(1,1,1,0) P_Mᵀ ∝ K Kᵀ with the true (normalized) K (eqs. 22–23, 27).
        let kt = normalized(&truth.k[0]).k();
        let kkt = kt * kt.transpose();
        let kkt = kkt / kkt.norm();
        let mut conic_err: f64 = 0.0;
        for p in &cams {
            let pm = sc.upgrade_camera(&(p / p.norm()));
            let w = pm * daq() * pm.transpose();
            conic_err = conic_err.max((w / w.norm() - kkt).amax());
        }

        let e = evaluate(&sc, &cams, &truth);
        eprintln!(
            "noise-free seed {seed} ({} cams, {} solves): focal {:.2e} rel, aspect {:.1e}, skew {:.1e}, pp {:.3} px, \
             relative rotation {:.2e}°, optical axes {:.2e}°, distances {:.1e}, ω* {:.1e}, critical ratio {:.2e}",
            cams.len(),
            sc.iterations,
            e.focal_rel,
            e.aspect,
            e.skew,
            e.principal_point_px,
            e.relative_rotation_deg,
            e.optical_axis_deg,
            e.distance_ratio,
            conic_err,
            sc.critical_ratio,
        );
        assert!(e.focal_rel < 0.01, "seed {seed}: {e:?}");
        assert!(e.relative_rotation_deg < 0.1, "seed {seed}: {e:?}");
        assert!(e.optical_axis_deg < 0.1, "seed {seed}: {e:?}");
        assert!(e.distance_ratio < 0.01, "seed {seed}: {e:?}");
        assert!(
            e.aspect < 0.01 && e.principal_point_px < 5.0,
            "seed {seed}: {e:?}"
        );
        assert!(conic_err < 1e-3, "seed {seed}: {conic_err}");
        worst_focal = worst_focal.max(e.focal_rel);
        worst_rot = worst_rot.max(e.relative_rotation_deg);
    }
    eprintln!("noise-free worst: focal {worst_focal:.2e}, relative rotation {worst_rot:.2e}°");
}

#[test]
fn general_motion_noisy_within_five_percent() {
    let opts = SelfCalibrationOptions::default();
    let mut worst_focal: f64 = 0.0;
    let mut worst_rot: f64 = 0.0;
    for seed in 100..108u64 {
        let (cams, truth) = general_scene(seed, 1e-4);
        let sc = self_calibrate(&cams, &opts).unwrap();
        assert_finite(&sc);
        assert!(sc.degenerate.is_none(), "seed {seed}: {:?}", sc.degenerate);
        let e = evaluate(&sc, &cams, &truth);
        eprintln!(
            "noisy (1e-4 relative) seed {seed} ({} cams): focal {:.2e} rel, aspect {:.1e}, pp {:.2} px, \
             relative rotation {:.3}°, optical axes {:.3}°, distances {:.1e}, critical ratio {:.2e}",
            cams.len(),
            e.focal_rel,
            e.aspect,
            e.principal_point_px,
            e.relative_rotation_deg,
            e.optical_axis_deg,
            e.distance_ratio,
            sc.critical_ratio,
        );
        assert!(e.focal_rel < 0.05, "seed {seed}: {e:?}");
        assert!(e.relative_rotation_deg < 1.0, "seed {seed}: {e:?}");
        worst_focal = worst_focal.max(e.focal_rel);
        worst_rot = worst_rot.max(e.relative_rotation_deg);
    }
    eprintln!("noisy worst: focal {worst_focal:.2e}, relative rotation {worst_rot:.3}°");
}

/// Eq. 26 verbatim (`estimate_prior_means = false`) is exact when the intrinsics equal the
/// prior means (f = 1 after K_N, centred principal point, r = 1, s = 0) ...
#[test]
fn paper_verbatim_exact_at_the_prior_means() {
    let opts = SelfCalibrationOptions {
        estimate_prior_means: false,
        ..Default::default()
    };
    for seed in 200..204u64 {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let count = rng.random_range(8..=15);
        let (r, c) = general_poses(&mut rng, count);
        let k = vec![pixel_k(f64::from(W + H), 0.0, 0.0); count];
        let (cams, truth) = projective_cameras(&mut rng, k, r, c, 0.0);
        let sc = self_calibrate(&cams, &opts).unwrap();
        assert!(sc.degenerate.is_none(), "{:?}", sc.degenerate);
        let e = evaluate(&sc, &cams, &truth);
        eprintln!("paper verbatim, intrinsics at the prior means, seed {seed}: {e:?}");
        assert!(
            e.focal_rel < 1e-6 && e.relative_rotation_deg < 1e-4,
            "{e:?}"
        );
    }
}

/// ... and biased when they are not: with the wide-angle K of the main scenario the verbatim
/// scheme is off by several percent, the mean estimation removes the bias.
#[test]
fn paper_verbatim_is_biased_away_from_the_prior_means() {
    let verbatim = SelfCalibrationOptions {
        estimate_prior_means: false,
        ..Default::default()
    };
    let default = SelfCalibrationOptions::default();
    let (mut worst_v, mut worst_v_rot, mut worst_d): (f64, f64, f64) = (0.0, 0.0, 0.0);
    for seed in 0..8u64 {
        let (cams, truth) = general_scene(seed, 0.0);
        let v = self_calibrate(&cams, &verbatim).unwrap();
        assert_finite(&v);
        assert!(v.degenerate.is_none(), "{:?}", v.degenerate);
        let ev = evaluate(&v, &cams, &truth);
        let ed = evaluate(&self_calibrate(&cams, &default).unwrap(), &cams, &truth);
        assert!(ev.focal_rel < 0.15, "{ev:?}");
        worst_v = worst_v.max(ev.focal_rel);
        worst_v_rot = worst_v_rot.max(ev.relative_rotation_deg);
        worst_d = worst_d.max(ed.focal_rel);
    }
    eprintln!(
        "paper verbatim (5 ν iterations), f = 0.47: worst focal {worst_v:.2e}, rotation {worst_v_rot:.2}°; \
         with estimated means: worst focal {worst_d:.2e}"
    );
    assert!(worst_d < 0.1 * worst_v);
}

#[test]
fn zoom_sequence_recovers_per_camera_focal() {
    let opts = SelfCalibrationOptions::default();
    let mut rng = ChaCha8Rng::seed_from_u64(300);
    let (r, c) = general_poses(&mut rng, 12);
    let k: Vec<_> = (0..12)
        .map(|i| pixel_k(F_PX * (0.8 + 0.04 * i as f64), 30.0, -20.0))
        .collect();
    let (cams, truth) = projective_cameras(&mut rng, k, r, c, 0.0);
    let sc = self_calibrate(&cams, &opts).unwrap();
    assert!(sc.degenerate.is_none(), "{:?}", sc.degenerate);
    let e = evaluate(&sc, &cams, &truth);
    eprintln!("zoom ±20 %: {e:?}");
    assert!(e.focal_rel < 0.02, "{e:?}");
    assert!(e.relative_rotation_deg < 0.5, "{e:?}");
}

#[test]
fn estimate_aspect_mode_recovers_a_non_unit_aspect() {
    let opts = SelfCalibrationOptions {
        estimate_aspect: true,
        ..Default::default()
    };
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let (r, c) = general_poses(&mut rng, 12);
    let mut k = pixel_k(F_PX, 30.0, -20.0);
    k[(1, 1)] *= 1.1;
    let (cams, truth) = projective_cameras(&mut rng, vec![k; 12], r, c, 0.0);
    let sc = self_calibrate(&cams, &opts).unwrap();
    assert!(sc.degenerate.is_none(), "{:?}", sc.degenerate);
    let e = evaluate(&sc, &cams, &truth);
    eprintln!("estimate_aspect, true aspect 1.1: {e:?}");
    assert!(e.focal_rel < 0.01 && e.aspect < 0.01, "{e:?}");
}

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
        Err(SelfCalibrationError::InvalidOptions(_))
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
