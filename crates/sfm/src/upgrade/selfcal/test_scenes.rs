//! Seeded synthetic projective reconstructions with exact metric ground truth, for the
//! self-calibration tests.

use super::*;
use nalgebra::{Matrix3, Matrix3x4, Matrix4};
use nalgebra::{Rotation3, Unit, Vector3, Vector4};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

pub(super) const W: u32 = 3072;
pub(super) const H: u32 = 2048;
/// Pixel focal of the main scenario: a wide-angle lens, normalized focal 2400/5120 ≈ 0.47.
pub(super) const F_PX: f64 = 2400.0;

/// Ground truth of a synthetic sequence.
pub(super) struct Truth {
    /// Pixel intrinsics of each camera.
    pub k: Vec<Matrix3<f64>>,
    /// World-to-camera rotations.
    pub r: Vec<Matrix3<f64>>,
    /// Camera centres.
    pub c: Vec<Vector3<f64>>,
    /// The projective corruption: `P_proj ∼ P_metric H⁻¹`, `M_proj = H M_metric`.
    pub h: Matrix4<f64>,
}

pub(super) fn pixel_k(f: f64, du: f64, dv: f64) -> Matrix3<f64> {
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

pub(super) fn normalized(k: &Matrix3<f64>) -> NormalizedIntrinsics {
    NormalizedIntrinsics::from_k(&(normalization_matrix(W, H).try_inverse().unwrap() * k))
}

pub(super) fn random_unit(rng: &mut ChaCha8Rng) -> Vector3<f64> {
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

pub(super) fn random_rotation(rng: &mut ChaCha8Rng, min_deg: f64, max_deg: f64) -> Matrix3<f64> {
    let axis = Unit::new_normalize(random_unit(rng));
    let angle = rng.random_range(min_deg..max_deg).to_radians();
    Rotation3::from_axis_angle(&axis, angle).into_inner()
}

pub(super) fn gaussian(rng: &mut ChaCha8Rng) -> f64 {
    // Box–Muller.
    let u1: f64 = rng.random_range(f64::MIN_POSITIVE..1.0);
    let u2: f64 = rng.random_range(0.0..1.0);
    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
}

/// General motion: cameras 4–6 units from the origin looking at it (the point cloud around
/// the origin), each rotated from a reference view by 10°–40° about a random axis, plus a
/// small jitter.
pub(super) fn general_poses(
    rng: &mut ChaCha8Rng,
    count: usize,
) -> (Vec<Matrix3<f64>>, Vec<Vector3<f64>>) {
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

pub(super) fn random_homography(rng: &mut ChaCha8Rng) -> Matrix4<f64> {
    loop {
        let h = Matrix4::identity() + Matrix4::from_fn(|_, _| rng.random_range(-0.5..0.5));
        let sv = h.singular_values();
        if sv.max() / sv.min() < 20.0 {
            return h;
        }
    }
}

pub(super) fn metric_camera(
    k: &Matrix3<f64>,
    r: &Matrix3<f64>,
    c: &Vector3<f64>,
) -> Matrix3x4<f64> {
    let mut rt = Matrix3x4::zeros();
    rt.fixed_view_mut::<3, 3>(0, 0).copy_from(r);
    rt.set_column(3, &(-r * c));
    k * rt
}

/// Normalized projective cameras `K_N⁻¹ K [R | −RC] H⁻¹`, with relative noise on every entry
/// and a random scale and sign per camera.
pub(super) fn projective_cameras(
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
pub(super) fn general_scene(seed: u64, relative_noise: f64) -> (Vec<Matrix3x4<f64>>, Truth) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let count = rng.random_range(8..=15);
    let (r, c) = general_poses(&mut rng, count);
    let k = vec![pixel_k(F_PX, 30.0, -20.0); count];
    projective_cameras(&mut rng, k, r, c, relative_noise)
}

pub(super) fn rotation_angle_deg(r: &Matrix3<f64>) -> f64 {
    ((r.trace() - 1.0) / 2.0)
        .clamp(-1.0, 1.0)
        .acos()
        .to_degrees()
}

/// Worst-case errors of a self-calibration against the ground truth.
#[derive(Debug)]
pub(super) struct Errors {
    pub focal_rel: f64,
    pub aspect: f64,
    pub principal_point_px: f64,
    pub skew: f64,
    /// Angle of `R̂ᵢR̂ⱼᵀ (RᵢRⱼᵀ)ᵀ` over all pairs.
    pub relative_rotation_deg: f64,
    /// Error of the angle between the optical axes of each pair.
    pub optical_axis_deg: f64,
    /// Relative spread of |Ĉᵢ − Ĉⱼ| / |Cᵢ − Cⱼ| over all pairs (0 for a similarity).
    pub distance_ratio: f64,
}

pub(super) fn evaluate(sc: &SelfCalibration, cams: &[Matrix3x4<f64>], truth: &Truth) -> Errors {
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

pub(super) fn assert_finite(sc: &SelfCalibration) {
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

pub(super) fn daq() -> Matrix4<f64> {
    Matrix4::from_diagonal(&Vector4::new(1.0, 1.0, 1.0, 0.0))
}
