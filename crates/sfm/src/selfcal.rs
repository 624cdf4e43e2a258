//! Linear self-calibration with the dual absolute quadric (§3.4 "Upgrading to Metric", eqs. 22–27).
//!
//! A projective reconstruction `{Pᵢ, Mⱼ}` is only defined up to a 4×4 homography. In a metric frame
//! the dual absolute quadric is `Ω* = diag(1, 1, 1, 0)` and it projects to the dual image of the
//! absolute conic (eqs. 22–23):
//!
//! ```text
//! ω*ᵢ ∼ Pᵢ Ω* Pᵢᵀ ∼ Kᵢ Kᵢᵀ
//! ```
//!
//! Since the images do not depend on the projective basis, prior knowledge about the intrinsics
//! (`f ≈ 1 ± 3`, `u ≈ v ≈ 0 ± 0.1`, `r ≈ 1 ± 0.1`, `s = 0` after the normalization `K_N` of eq. 24)
//! turns into linear equations on the 10 coefficients of the symmetric `Ω*` (eqs. 25–26). They are
//! solved by weighted linear least squares (smallest right singular vector of the stacked system),
//! re-weighted with `ν = P₃ Ω* P₃ᵀ` of the previous estimate, the rank-3 constraint is enforced and
//! the upgrade `T` with `diag(1, 1, 1, 0) = T Ω* Tᵀ` gives the metric cameras and points
//! `P_M = P T⁻¹`, `M_M = T M` (eq. 27).
//!
//! Two additions to the paper, both documented on [`SelfCalibrationOptions`]:
//! - the means of the priors can be estimated jointly (still one linear system), which removes the
//!   bias of eq. 26 when the intrinsics are far from the prior means (on by default; the verbatim
//!   scheme is `estimate_prior_means: false`);
//! - critical motions are detected from the singular values of the equations that do not involve
//!   the focal prior, and reported in [`SelfCalibration::degenerate`] rather than as an error.

use nalgebra::{DMatrix, Matrix3, Matrix3x4, Matrix4, RowVector4, SymmetricEigen, Vector3, SVD};
use serde::Serialize;
use thiserror::Error;
use tracing::debug;

/// Errors of [`self_calibrate`] and [`SelfCalibrationOptions::validate`].
#[derive(Clone, Debug, PartialEq, Error)]
pub enum SelfCalibrationError {
    /// Fewer than two cameras were given; the dual absolute quadric cannot be determined.
    #[error("self-calibration needs at least 2 cameras, got {0}")]
    TooFewCameras(usize),
    /// A camera matrix contains NaN or an infinity.
    #[error("camera {index} has a non-finite entry")]
    NonFiniteCamera {
        /// Index of the offending camera in the input slice.
        index: usize,
    },
    /// A camera matrix is identically zero.
    #[error("camera {index} is the zero matrix")]
    ZeroCamera {
        /// Index of the offending camera in the input slice.
        index: usize,
    },
    /// An option is out of its valid range.
    #[error("invalid self-calibration options: {0}")]
    InvalidOptions(String),
    /// A decomposition (SVD or symmetric eigen-decomposition) did not converge.
    #[error("self-calibration linear algebra failed: {0}")]
    Numerical(String),
}

/// The normalization `K_N` of eq. 24:
///
/// ```text
///       ⎡ w+h   0   w/2 ⎤
/// K_N = ⎢  0   w+h  h/2 ⎥
///       ⎣  0    0    1  ⎦
/// ```
///
/// `P_N = K_N⁻¹ P` has a focal length of the order of unity (a 60 mm lens on a 35 mm frame maps
/// to 1) and a principal point close to the origin.
pub fn normalization_matrix(width: u32, height: u32) -> Matrix3<f64> {
    let w = f64::from(width);
    let h = f64::from(height);
    let s = w + h;
    Matrix3::new(s, 0.0, w / 2.0, 0.0, s, h / 2.0, 0.0, 0.0, 1.0)
}

/// Options of [`self_calibrate`]. The defaults are the a-priori standard deviations of the paper
/// (eq. 25) and the weights of eq. 26.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SelfCalibrationOptions {
    /// Maximum number of linear solves (eq. 26). The first uses `ν = 1` for every camera, each
    /// further one `ν = |P₃ Ω* P₃ᵀ|` of the previous estimate; the loop stops early once the `ν`
    /// factors have converged. Default 5.
    pub iterations: usize,
    /// Standard deviation of the `f²` entries `ω*₁₁`, `ω*₂₂` relative to `ω*₃₃`
    /// (`f ≈ 1 ± 3` gives `f² ≈ 1 ± 9`): the equations `P₁Ω*P₁ᵀ − P₃Ω*P₃ᵀ = 0` and
    /// `P₂Ω*P₂ᵀ − P₃Ω*P₃ᵀ = 0` get weight `1 / (9 ν)`. Default 9.
    pub sigma_focal_sq: f64,
    /// Standard deviation of `ω*₂₂ / ω*₁₁ ≈ 1 ± 0.2` (aspect ratio `r ≈ 1 ± 0.1`): the equation
    /// `P₁Ω*P₁ᵀ − P₂Ω*P₂ᵀ = 0` gets weight `1 / (0.2 ν)`. Default 0.2.
    pub sigma_aspect: f64,
    /// Standard deviation of the principal-point entries `ω*₁₃ = u`, `ω*₂₃ = v` (`u ≈ v ≈ 0 ± 0.1`):
    /// the equations `P₁Ω*P₃ᵀ = 0` and `P₂Ω*P₃ᵀ = 0` get weight `1 / (0.1 ν)`. Default 0.1.
    pub sigma_principal_point: f64,
    /// Standard deviation of the skew entry `ω*₁₂ = s r f + u v ≈ 0 ± 0.01`: the equation
    /// `P₁Ω*P₂ᵀ = 0` gets weight `1 / (0.01 ν)`. Default 0.01.
    ///
    /// Eq. 26 as printed puts `1/0.1` on `P₁Ω*P₂ᵀ` and `1/0.01` on `P₂Ω*P₃ᵀ`, which contradicts
    /// the uncertainties of eq. 25 it is derived from (`ω*₁₂ ± 0.01`, `ω*₂₃ ± 0.1`); the weights
    /// here follow eq. 25.
    pub sigma_skew: f64,
    /// Video mode: the aspect ratio of a camcorder may differ markedly from one and is estimated
    /// later in the metric bundle adjustment, so the aspect equation is down-weighted by
    /// [`Self::estimated_aspect_weight`]. Default false.
    pub estimate_aspect: bool,
    /// Extra factor on the aspect equation when [`Self::estimate_aspect`] is set. Default 0.1.
    pub estimated_aspect_weight: f64,
    /// Estimate the common means of the prior equations (extension of eq. 26, default true).
    ///
    /// Eq. 26 asks every camera to have exactly the prior means `f = 1`, `r = 1`, `u = v = s = 0`
    /// (weighted by their uncertainty). When the true intrinsics are elsewhere — a wide-angle lens
    /// gives a normalized focal of about 0.45, the principal point is rarely exactly central — the
    /// linear estimate is biased, by up to ~10 % in focal and several degrees in rotation on the
    /// synthetic tests of this module. With this set, the first solve is eq. 26 verbatim, and each
    /// later one (which has the `ν` factors) adds the common values `μₑ` of the six normalized
    /// forms (`ω*₁₁/ω*₃₃ − 1`, `ω*₂₂/ω*₃₃ − 1`, `(ω*₁₁ − ω*₂₂)/ω*₃₃`, `ω*₁₂/ω*₃₃`, `ω*₁₃/ω*₃₃`,
    /// `ω*₂₃/ω*₃₃`) as six extra linear unknowns: `(Pᵢ-forms Ω* / ν − μₑ)/σₑ = 0` for every camera,
    /// and the priors of eq. 25 act on the means only, as [`Self::prior_mean_weight`] virtual
    /// cameras. The system stays linear (16 unknowns, homogeneous), the weights stay those of
    /// eq. 26, and with constant intrinsics and noise-free cameras the fixed point is the exact
    /// `Ω*`. False: the paper's scheme verbatim (only `ν` is iterated).
    pub estimate_prior_means: bool,
    /// Weight of the eq. 25 priors on the estimated means, in number of virtual cameras
    /// (see [`Self::estimate_prior_means`]). Default 0.01: enough to pin the means down when the
    /// data leave them free, small enough not to bias well-conditioned sequences (on the
    /// synthetic wide-angle tests, 1 leaves ~0.5° rotation errors, 0.01 about 0.02°, 0 is exact).
    pub prior_mean_weight: f64,
    /// The motion is reported as critical when [`SelfCalibration::critical_ratio`] (second-smallest
    /// over largest singular value of the system without the two focal-prior equations) is below
    /// this ratio: the aspect, skew and principal-point equations alone leave a null space of
    /// dimension larger than one, so `Ω*` is fixed only by the weak focal prior. Default 1e-3.
    pub degenerate_singular_ratio: f64,
}

impl Default for SelfCalibrationOptions {
    fn default() -> Self {
        Self {
            iterations: 5,
            sigma_focal_sq: 9.0,
            sigma_aspect: 0.2,
            sigma_principal_point: 0.1,
            sigma_skew: 0.01,
            estimate_aspect: false,
            estimated_aspect_weight: 0.1,
            estimate_prior_means: true,
            prior_mean_weight: 0.01,
            degenerate_singular_ratio: 1e-3,
        }
    }
}

impl SelfCalibrationOptions {
    /// Checks every field: at least one iteration (at most 1000), standard deviations finite and in
    /// `[1e-12, 1e12]`, the aspect factor in `(0, 1]`, the prior-mean weight in `[0, 1e6]`, the
    /// degeneracy ratio in `[0, 1)`.
    pub fn validate(&self) -> Result<(), SelfCalibrationError> {
        if self.iterations == 0 || self.iterations > 1000 {
            return Err(SelfCalibrationError::InvalidOptions(format!(
                "iterations must be in 1..=1000, got {}",
                self.iterations
            )));
        }
        for (name, value) in [
            ("sigma_focal_sq", self.sigma_focal_sq),
            ("sigma_aspect", self.sigma_aspect),
            ("sigma_principal_point", self.sigma_principal_point),
            ("sigma_skew", self.sigma_skew),
        ] {
            if !(value.is_finite() && (1e-12..=1e12).contains(&value)) {
                return Err(SelfCalibrationError::InvalidOptions(format!(
                    "{name} must be a finite standard deviation in [1e-12, 1e12], got {value}"
                )));
            }
        }
        if !(self.estimated_aspect_weight > 0.0 && self.estimated_aspect_weight <= 1.0) {
            return Err(SelfCalibrationError::InvalidOptions(format!(
                "estimated_aspect_weight must be in (0, 1], got {}",
                self.estimated_aspect_weight
            )));
        }
        if !(self.prior_mean_weight.is_finite() && (0.0..=1e6).contains(&self.prior_mean_weight)) {
            return Err(SelfCalibrationError::InvalidOptions(format!(
                "prior_mean_weight must be in [0, 1e6], got {}",
                self.prior_mean_weight
            )));
        }
        if !(self.degenerate_singular_ratio >= 0.0 && self.degenerate_singular_ratio < 1.0) {
            return Err(SelfCalibrationError::InvalidOptions(format!(
                "degenerate_singular_ratio must be in [0, 1), got {}",
                self.degenerate_singular_ratio
            )));
        }
        Ok(())
    }
}

/// Intrinsics in normalized units (after `K_N⁻¹`, eq. 24) with the parametrization of eq. 25:
///
/// ```text
///     ⎡ f  s   u ⎤
/// K = ⎢ 0  rf  v ⎥
///     ⎣ 0  0   1 ⎦
/// ```
///
/// Pixel values follow from `K_N K`: focal `f (w+h)`, principal point `(u (w+h) + w/2, v (w+h) + h/2)`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct NormalizedIntrinsics {
    /// Focal length `f = K₁₁`.
    pub f: f64,
    /// Aspect ratio `r = K₂₂ / K₁₁`.
    pub aspect: f64,
    /// Skew `s = K₁₂`.
    pub skew: f64,
    /// Principal point abscissa `u = K₁₃`.
    pub u: f64,
    /// Principal point ordinate `v = K₂₃`.
    pub v: f64,
}

impl NormalizedIntrinsics {
    /// Reads the five parameters from an upper-triangular `K` with `K₃₃ = 1`.
    pub fn from_k(k: &Matrix3<f64>) -> Self {
        let f = k[(0, 0)];
        Self {
            f,
            aspect: if f != 0.0 { k[(1, 1)] / f } else { 0.0 },
            skew: k[(0, 1)],
            u: k[(0, 2)],
            v: k[(1, 2)],
        }
    }

    /// The calibration matrix `K` of eq. 25.
    pub fn k(&self) -> Matrix3<f64> {
        Matrix3::new(
            self.f,
            self.skew,
            self.u,
            0.0,
            self.aspect * self.f,
            self.v,
            0.0,
            0.0,
            1.0,
        )
    }
}

/// Result of [`self_calibrate`].
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SelfCalibration {
    /// The upgrade `T` (metric from projective) with `diag(1, 1, 1, 0) = T Ω* Tᵀ`:
    /// `P_M = P T⁻¹`, `M_M = T M` (eq. 27). Its fourth row is the plane at infinity of the
    /// projective frame. Serialized as row-major nested arrays.
    #[serde(serialize_with = "serialize_matrix4")]
    pub t: Matrix4<f64>,
    /// `T⁻¹` (computed directly from the eigen-decomposition, not by inversion). Serialized as
    /// row-major nested arrays.
    #[serde(serialize_with = "serialize_matrix4")]
    pub t_inv: Matrix4<f64>,
    /// `Ω*` after the rank-3 enforcement, scaled to unit Frobenius norm, in the projective frame
    /// of the input cameras each scaled to unit Frobenius norm. Serialized as row-major nested arrays.
    #[serde(serialize_with = "serialize_matrix4")]
    pub omega: Matrix4<f64>,
    /// Number of linear solves performed (≤ `options.iterations`).
    pub iterations: usize,
    /// Singular values of the final weighted linear system (10 unknowns), descending. The ratio
    /// of the second-smallest to the largest tells how well `Ω*` is determined.
    pub singular_values: Vec<f64>,
    /// Second-smallest over largest singular value of the final system restricted to the aspect,
    /// skew and principal-point equations (the focal-prior equations left out): close to zero
    /// when the motion is critical (pure translation, pure rotation, too few cameras — fewer than
    /// three always give zero).
    pub critical_ratio: f64,
    /// Eigenvalues of the (sign-fixed, unit-Frobenius) `Ω*` before the rank-3 enforcement,
    /// descending.
    pub omega_eigenvalues: [f64; 4],
    /// Per-camera intrinsics in normalized units, from the RQ decomposition
    /// ([`decompose_camera`]) of each upgraded camera `P_M = P T⁻¹`. A camera whose upgraded left
    /// 3×3 block is singular gets all-zero intrinsics (and makes the result degenerate).
    pub per_camera: Vec<NormalizedIntrinsics>,
    /// `Some(reason)` when the motion is critical or the estimate is unreliable: the null space of
    /// the weighted system has dimension larger than one, `Ω*` is not semi-definite (its three
    /// largest-magnitude eigenvalues do not share a sign), `ω* = P Ω* Pᵀ` is not positive
    /// definite for most cameras, or an upgraded camera is singular. Pure rotation, pure
    /// translation and other critical motions end up here.
    pub degenerate: Option<String>,
}

impl SelfCalibration {
    /// Upgrades a projective camera (normalized, i.e. already multiplied by `K_N⁻¹`) to the
    /// metric frame: `P_M = P T⁻¹` (eq. 27).
    pub fn upgrade_camera(&self, p: &Matrix3x4<f64>) -> Matrix3x4<f64> {
        p * self.t_inv
    }

    /// Upgrades a homogeneous projective point to the metric frame: `M_M = T M` (eq. 27).
    pub fn upgrade_point(&self, m: &nalgebra::Vector4<f64>) -> nalgebra::Vector4<f64> {
        self.t * m
    }
}

fn serialize_matrix4<S: serde::Serializer>(m: &Matrix4<f64>, s: S) -> Result<S::Ok, S::Error> {
    let rows: [[f64; 4]; 4] = std::array::from_fn(|i| std::array::from_fn(|j| m[(i, j)]));
    rows.serialize(s)
}

/// Index pairs `(i, j)`, `i ≤ j`, of the 10 unknowns of the symmetric `Ω*`.
const SYM_INDEX: [(usize, usize); 10] = [
    (0, 0),
    (0, 1),
    (0, 2),
    (0, 3),
    (1, 1),
    (1, 2),
    (1, 3),
    (2, 2),
    (2, 3),
    (3, 3),
];

/// Coefficients `c` with `a Ω* bᵀ = c · q` where `q` holds the 10 unknowns in [`SYM_INDEX`] order.
fn bilinear_coefficients(a: &RowVector4<f64>, b: &RowVector4<f64>) -> [f64; 10] {
    std::array::from_fn(|k| {
        let (i, j) = SYM_INDEX[k];
        if i == j {
            a[i] * b[i]
        } else {
            a[i] * b[j] + a[j] * b[i]
        }
    })
}

fn symmetric_from_vector(q: &[f64]) -> Matrix4<f64> {
    let mut m = Matrix4::zeros();
    for (k, &(i, j)) in SYM_INDEX.iter().enumerate() {
        m[(i, j)] = q[k];
        m[(j, i)] = q[k];
    }
    m
}

/// The 6 unweighted linear forms of eq. 26 for one camera, as rows over the 10 unknowns:
/// `ω*₁₁ − ω*₃₃`, `ω*₂₂ − ω*₃₃`, `ω*₁₁ − ω*₂₂`, `ω*₁₂`, `ω*₁₃`, `ω*₂₃` (with `ω*ᵢⱼ = Pᵢ Ω* Pⱼᵀ`), and
/// the row of `ω*₃₃ = P₃ Ω* P₃ᵀ` used to shift the prior means.
struct CameraRows {
    forms: [[f64; 10]; 6],
    w33: [f64; 10],
}

fn camera_equations(p: &Matrix3x4<f64>) -> CameraRows {
    let r1 = p.row(0).into_owned();
    let r2 = p.row(1).into_owned();
    let r3 = p.row(2).into_owned();
    let c11 = bilinear_coefficients(&r1, &r1);
    let c22 = bilinear_coefficients(&r2, &r2);
    let c33 = bilinear_coefficients(&r3, &r3);
    let diff = |a: &[f64; 10], b: &[f64; 10]| -> [f64; 10] { std::array::from_fn(|k| a[k] - b[k]) };
    CameraRows {
        forms: [
            diff(&c11, &c33),
            diff(&c22, &c33),
            diff(&c11, &c22),
            bilinear_coefficients(&r1, &r2),
            bilinear_coefficients(&r1, &r3),
            bilinear_coefficients(&r2, &r3),
        ],
        w33: c33,
    }
}

/// The six linear forms of [`camera_equations`] evaluated on a 3×3 `ω*`.
fn forms_of(w: &Matrix3<f64>) -> [f64; 6] {
    [
        w[(0, 0)] - w[(2, 2)],
        w[(1, 1)] - w[(2, 2)],
        w[(0, 0)] - w[(1, 1)],
        w[(0, 1)],
        w[(0, 2)],
        w[(1, 2)],
    ]
}

/// Stacks the weighted equations `(formₑ − mₑ ω*₃₃) · wₑ / ν` of the selected kinds `e`.
fn build_system(
    rows: &[CameraRows],
    weights: &[f64; 6],
    centers: &[f64; 6],
    nu: &[f64],
    select: &[bool; 6],
) -> DMatrix<f64> {
    let kinds: Vec<usize> = (0..6).filter(|&e| select[e]).collect();
    let mut a = DMatrix::<f64>::zeros(kinds.len() * rows.len(), 10);
    for (c, cam) in rows.iter().enumerate() {
        for (slot, &e) in kinds.iter().enumerate() {
            let w = weights[e] / nu[c];
            for k in 0..10 {
                a[(kinds.len() * c + slot, k)] = w * (cam.forms[e][k] - centers[e] * cam.w33[k]);
            }
        }
    }
    a
}

fn svd_of(
    a: DMatrix<f64>,
    compute_v: bool,
) -> Result<SVD<f64, nalgebra::Dyn, nalgebra::Dyn>, SelfCalibrationError> {
    // nalgebra's sorted SVD panics on NaN singular values: refuse non-finite systems first.
    if a.iter().any(|v| !v.is_finite()) {
        return Err(SelfCalibrationError::Numerical(
            "the eq. 26 system has non-finite entries".into(),
        ));
    }
    SVD::try_new(a, false, compute_v, f64::EPSILON, 10_000).ok_or_else(|| {
        SelfCalibrationError::Numerical("SVD of the eq. 26 system did not converge".into())
    })
}

/// Stacks eq. 26 with the common means `μₑ` of the six normalized forms as six extra unknowns
/// (columns 10–15): `wₑ (formₑ(Ω*)/ν − μₑ) = 0` for every camera, plus `√λ wₑ μₑ = 0`, the
/// priors of eq. 25 acting as `λ` virtual cameras at the prior means.
fn build_joint_system(
    rows: &[CameraRows],
    weights: &[f64; 6],
    nu: &[f64],
    lambda: f64,
) -> DMatrix<f64> {
    let n = rows.len();
    let mut a = DMatrix::<f64>::zeros(6 * n + 6, 16);
    for (c, cam) in rows.iter().enumerate() {
        for e in 0..6 {
            let w = weights[e] / nu[c];
            for k in 0..10 {
                a[(6 * c + e, k)] = w * cam.forms[e][k];
            }
            a[(6 * c + e, 10 + e)] = -weights[e];
        }
    }
    for e in 0..6 {
        a[(6 * n + e, 10 + e)] = lambda.sqrt() * weights[e];
    }
    a
}

/// Medians over the cameras whose `ω*` is positive definite of the six forms normalized by
/// `ω*₃₃`; `None` unless most cameras qualify.
fn median_forms(omegas: &[Matrix3<f64>]) -> Option<[f64; 6]> {
    let valid: Vec<[f64; 6]> = omegas
        .iter()
        .filter(|w| w.cholesky().is_some())
        .map(|w| forms_of(&(w / w[(2, 2)])))
        .filter(|f| f.iter().all(|v| v.is_finite()))
        .collect();
    if 2 * valid.len() <= omegas.len() {
        return None;
    }
    let mut out = [0.0; 6];
    for (e, c) in out.iter_mut().enumerate() {
        let mut vals: Vec<f64> = valid.iter().map(|f| f[e]).collect();
        *c = median(&mut vals)?;
    }
    Some(out)
}

/// Median of the finite values, `None` when there are none.
fn median(values: &mut [f64]) -> Option<f64> {
    values.sort_by(f64::total_cmp);
    values.get(values.len() / 2).copied()
}

/// Scales a camera to unit Frobenius norm without overflow (divides by the largest entry first).
fn unit_frobenius(p: &Matrix3x4<f64>) -> Option<Matrix3x4<f64>> {
    let max = p.amax();
    if max == 0.0 || !max.is_finite() {
        return None;
    }
    let q = p / max;
    let n = q.norm();
    if n == 0.0 || !n.is_finite() {
        return None;
    }
    Some(q / n)
}

fn symmetric_eigen(
    m: Matrix4<f64>,
) -> Result<SymmetricEigen<f64, nalgebra::U4>, SelfCalibrationError> {
    SymmetricEigen::try_new(m, f64::EPSILON, 10_000).ok_or_else(|| {
        SelfCalibrationError::Numerical("eigen-decomposition of Ω* did not converge".into())
    })
}

/// Linear self-calibration with the dual absolute quadric (§3.4, eqs. 22–27).
///
/// `normalized_cameras` are projective cameras already multiplied by `K_N⁻¹` (eq. 24, see
/// [`normalization_matrix`]), so that the focal length is of the order of one and the principal
/// point near zero. Steps:
///
/// 1. every camera is scaled to unit Frobenius norm;
/// 2. for each camera the 6 equations of eq. 26 in the 10 coefficients of `Ω*` are stacked with
///    weights `1 / (σ ν)` (see [`SelfCalibrationOptions`]), `ν = 1` at first;
/// 3. `Ω*` is the right singular vector of the smallest singular value; its sign is fixed so that
///    it is positive semi-definite (the majority of its three largest-magnitude eigenvalues are
///    positive — the inertia is invariant under the projective ambiguity);
/// 4. `ν = |P₃ Ω* P₃ᵀ|` is recomputed and steps 2–3 repeated until the `ν` converge or
///    `options.iterations` solves were made; with
///    [`SelfCalibrationOptions::estimate_prior_means`] (default) these later solves also estimate
///    the common means of the six prior equations, which removes the bias of eq. 26 for
///    intrinsics away from the prior means;
/// 5. critical motion is judged from the equations without the focal prior (see
///    [`SelfCalibration::critical_ratio`]), and from the signs of the eigenvalues of `Ω*` and of
///    `ω* = P Ω* Pᵀ`;
/// 6. the rank 3 is enforced by zeroing the smallest-magnitude eigenvalue of
///    `Ω* = V diag(λ₁, λ₂, λ₃, λ₄) Vᵀ`, and `T⁻¹ = V diag(√λ₁, √λ₂, √λ₃, 1)`, so that
///    `Ω* = T⁻¹ diag(1, 1, 1, 0) T⁻ᵀ`, i.e. `diag(1, 1, 1, 0) = T Ω* Tᵀ`, and the upgraded cameras
///    `P_M = P T⁻¹` satisfy `P_M diag(1, 1, 1, 0) P_Mᵀ = P Ω* Pᵀ ∼ K Kᵀ` (eqs. 22, 23, 27).
///
/// The metric frame is defined up to a similarity, including a reflection: whether the scene lies
/// in front of the cameras has to be checked with the points (flip the sign of one axis of `T`).
///
/// Degenerate (critical) motions do not make this fail: they give `Ok` with
/// [`SelfCalibration::degenerate`] set and finite numbers (negative eigenvalues are clamped).
pub fn self_calibrate(
    normalized_cameras: &[Matrix3x4<f64>],
    options: &SelfCalibrationOptions,
) -> Result<SelfCalibration, SelfCalibrationError> {
    options.validate()?;
    let n = normalized_cameras.len();
    if n < 2 {
        return Err(SelfCalibrationError::TooFewCameras(n));
    }
    let mut cams = Vec::with_capacity(n);
    for (index, p) in normalized_cameras.iter().enumerate() {
        if p.iter().any(|v| !v.is_finite()) {
            return Err(SelfCalibrationError::NonFiniteCamera { index });
        }
        cams.push(unit_frobenius(p).ok_or(SelfCalibrationError::ZeroCamera { index })?);
    }

    let aspect_factor = if options.estimate_aspect {
        options.estimated_aspect_weight
    } else {
        1.0
    };
    let base_weights = [
        1.0 / options.sigma_focal_sq,
        1.0 / options.sigma_focal_sq,
        aspect_factor / options.sigma_aspect,
        1.0 / options.sigma_skew,
        1.0 / options.sigma_principal_point,
        1.0 / options.sigma_principal_point,
    ];
    let rows: Vec<CameraRows> = cams.iter().map(camera_equations).collect();
    let all = [true; 6];

    let mut nu = vec![1.0_f64; n];
    let mut centers = [0.0_f64; 6];
    let mut omega_raw = Matrix4::zeros();
    let mut iterations = 0;
    for it in 0..options.iterations {
        iterations = it + 1;
        // First solve: eq. 26 verbatim (ν = 1). Later ones: with ν of the previous estimate, and
        // optionally with the common means of the six forms as extra unknowns.
        let joint = options.estimate_prior_means && it > 0;
        let a = if joint {
            build_joint_system(&rows, &base_weights, &nu, options.prior_mean_weight)
        } else {
            build_system(&rows, &base_weights, &[0.0; 6], &nu, &all)
        };
        let svd = svd_of(a, true)?;
        let v_t = svd.v_t.ok_or_else(|| {
            SelfCalibrationError::Numerical("SVD returned no right singular vectors".into())
        })?;
        let q: Vec<f64> = v_t.row(v_t.nrows() - 1).iter().take(10).copied().collect();
        let mut omega = symmetric_from_vector(&q);
        let norm = omega.norm();
        if !(norm > 0.0 && norm.is_finite()) {
            return Err(SelfCalibrationError::Numerical(
                "the eq. 26 solution has no Ω* part".into(),
            ));
        }
        omega /= norm;
        if sign_of_quadric(&omega)? < 0.0 {
            omega = -omega;
        }
        omega_raw = omega;

        let omegas: Vec<Matrix3<f64>> = cams.iter().map(|p| p * omega * p.transpose()).collect();
        if joint {
            centers = median_forms(&omegas).unwrap_or(centers);
        }
        if it + 1 == options.iterations {
            break;
        }

        // ν = P₃ Ω* P₃ᵀ of this estimate, guarded against ~0 by a fraction of the median.
        let mut new_nu: Vec<f64> = omegas.iter().map(|w| w[(2, 2)].abs()).collect();
        let mut finite: Vec<f64> = new_nu.iter().copied().filter(|v| v.is_finite()).collect();
        match median(&mut finite) {
            // Cameras and Ω* have unit norm, so ν ≤ 1; a median below 1e-12 means Ω* is useless.
            Some(m) if m > 1e-12 && m.is_finite() && finite.len() == n => {
                for v in &mut new_nu {
                    *v = v.max(1e-3 * m);
                }
            }
            _ => new_nu = vec![1.0; n],
        }
        // ν only matters up to a common scale: compare the normalized factors.
        let scale_old = nu.iter().sum::<f64>() / n as f64;
        let scale_new = new_nu.iter().sum::<f64>() / n as f64;
        let nu_change = nu
            .iter()
            .zip(&new_nu)
            .map(|(o, m)| ((o / scale_old) - (m / scale_new)).abs() / (m / scale_new))
            .fold(0.0, f64::max);
        debug!(
            iteration = iterations,
            nu_change, "self-calibration ν re-weighting"
        );
        let converged = nu_change < 1e-12 && (joint || !options.estimate_prior_means);
        nu = new_nu;
        if converged {
            break;
        }
    }

    // The final system over the 10 unknowns of Ω*: eq. 26 with the last ν (and, when the means
    // are estimated, with the forms taken relative to their estimated common means).
    let final_svd = svd_of(
        build_system(&rows, &base_weights, &centers, &nu, &all),
        false,
    )?;
    let mut singular_values: Vec<f64> = final_svd.singular_values.iter().copied().collect();
    singular_values.resize(10, 0.0);

    let mut reasons: Vec<String> = Vec::new();

    // Critical motion: the equations that do not depend on the focal prior (aspect, skew,
    // principal point) must determine Ω* up to scale, i.e. have a null space of dimension one.
    let data_only = [false, false, true, true, true, true];
    let reduced = svd_of(
        build_system(&rows, &base_weights, &centers, &nu, &data_only),
        false,
    )?;
    let mut reduced_sv: Vec<f64> = reduced.singular_values.iter().copied().collect();
    reduced_sv.resize(10, 0.0);
    let critical_ratio = if reduced_sv[0] > 0.0 {
        reduced_sv[8] / reduced_sv[0]
    } else {
        0.0
    };
    if critical_ratio.is_nan() || critical_ratio < options.degenerate_singular_ratio {
        reasons.push(format!(
            "Ω* is not determined without the focal prior (critical motion): second-smallest / largest \
             singular value = {critical_ratio:.3e} < {:.1e}",
            options.degenerate_singular_ratio
        ));
    }

    // ω* = P Ω* Pᵀ must be positive definite (eq. 23).
    let pd_count = cams
        .iter()
        .filter(|p| {
            let w = *p * omega_raw * p.transpose();
            let w = (w + w.transpose()) * 0.5;
            w.cholesky().is_some()
        })
        .count();
    if 2 * pd_count <= n {
        reasons.push(format!(
            "ω* = P Ω* Pᵀ is positive definite for only {pd_count} of {n} cameras"
        ));
    }

    // Eigen-decomposition: order the three largest-magnitude eigenpairs first (descending), the
    // smallest-magnitude one (the plane at infinity) last.
    let eig = symmetric_eigen(omega_raw)?;
    let mut by_value: Vec<f64> = eig.eigenvalues.iter().copied().collect();
    by_value.sort_by(|a, b| b.total_cmp(a));
    let omega_eigenvalues = [by_value[0], by_value[1], by_value[2], by_value[3]];
    let mut order = [0usize, 1, 2, 3];
    order.sort_by(|&a, &b| {
        eig.eigenvalues[b]
            .abs()
            .total_cmp(&eig.eigenvalues[a].abs())
    });
    let mut top = [order[0], order[1], order[2]];
    top.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    let null = order[3];

    let lambda_max = eig.eigenvalues[top[0]].abs().max(f64::MIN_POSITIVE);
    let floor = 1e-6 * lambda_max;
    let mut lambdas = [0.0; 3];
    let mut clamped = false;
    for (slot, &idx) in top.iter().enumerate() {
        let l = eig.eigenvalues[idx];
        if l.is_finite() && l > floor {
            lambdas[slot] = l;
        } else {
            lambdas[slot] = floor;
            clamped = true;
        }
    }
    if clamped {
        reasons.push(format!(
            "Ω* is not positive semi-definite of rank 3 (eigenvalues {:.3e}, {:.3e}, {:.3e}, {:.3e}); clamped",
            omega_eigenvalues[0], omega_eigenvalues[1], omega_eigenvalues[2], omega_eigenvalues[3]
        ));
    }
    // Unit Frobenius norm of the rank-3 Ω*.
    let norm = (lambdas.iter().map(|l| l * l).sum::<f64>()).sqrt();
    for l in &mut lambdas {
        *l /= norm;
    }

    let mut v = Matrix4::zeros();
    for (col, &idx) in top.iter().chain(std::iter::once(&null)).enumerate() {
        v.set_column(col, &eig.eigenvectors.column(idx));
    }
    let s = Matrix4::from_diagonal(&nalgebra::Vector4::new(
        lambdas[0].sqrt(),
        lambdas[1].sqrt(),
        lambdas[2].sqrt(),
        1.0,
    ));
    let s_inv = Matrix4::from_diagonal(&nalgebra::Vector4::new(
        1.0 / lambdas[0].sqrt(),
        1.0 / lambdas[1].sqrt(),
        1.0 / lambdas[2].sqrt(),
        1.0,
    ));
    let t_inv = v * s;
    let t = s_inv * v.transpose();
    let omega =
        v * Matrix4::from_diagonal(&nalgebra::Vector4::new(
            lambdas[0], lambdas[1], lambdas[2], 0.0,
        )) * v.transpose();

    let mut failed = 0;
    let per_camera: Vec<NormalizedIntrinsics> = cams
        .iter()
        .map(|p| match decompose_camera(&(p * t_inv)) {
            Some((k, _, _)) => NormalizedIntrinsics::from_k(&k),
            None => {
                failed += 1;
                NormalizedIntrinsics {
                    f: 0.0,
                    aspect: 0.0,
                    skew: 0.0,
                    u: 0.0,
                    v: 0.0,
                }
            }
        })
        .collect();
    if failed > 0 {
        reasons.push(format!(
            "{failed} of {n} upgraded cameras have a singular left 3×3 block"
        ));
    }

    let degenerate = if reasons.is_empty() {
        None
    } else {
        Some(reasons.join("; "))
    };
    debug!(
        iterations,
        ?singular_values,
        ?omega_eigenvalues,
        ?degenerate,
        "linear self-calibration (eqs. 24-27)"
    );
    Ok(SelfCalibration {
        t,
        t_inv,
        omega,
        iterations,
        singular_values,
        critical_ratio,
        omega_eigenvalues,
        per_camera,
        degenerate,
    })
}

/// `+1` when the majority of the three largest-magnitude eigenvalues of `omega` are positive,
/// `-1` otherwise. Sylvester's law of inertia makes this independent of the projective frame.
fn sign_of_quadric(omega: &Matrix4<f64>) -> Result<f64, SelfCalibrationError> {
    let eig = symmetric_eigen(*omega)?;
    let mut vals: Vec<f64> = eig.eigenvalues.iter().copied().collect();
    vals.sort_by(|a, b| b.abs().total_cmp(&a.abs()));
    let positive = vals[..3].iter().filter(|v| **v > 0.0).count();
    Ok(if positive >= 2 { 1.0 } else { -1.0 })
}

/// RQ decomposition of the left 3×3 block of a (metric) camera: `P ∼ K [R | t]` with `K` upper
/// triangular with a positive diagonal and `K₃₃ = 1`, `R` a rotation (`det R = +1`; the sign of
/// `P` is flipped when needed, which does not change the projective camera). `t` is such that
/// `P ∼ K [R | t]` holds for `P` of any scale (the centre is `C = −Rᵀ t`).
///
/// Returns `None` for a non-finite camera or a (numerically) singular left block.
pub fn decompose_camera(p: &Matrix3x4<f64>) -> Option<(Matrix3<f64>, Matrix3<f64>, Vector3<f64>)> {
    if p.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let max = p.amax();
    if max == 0.0 {
        return None;
    }
    let p = p / max;
    let m: Matrix3<f64> = p.fixed_view::<3, 3>(0, 0).into_owned();
    let scale = m.norm();
    if scale.is_nan() || scale <= 0.0 || m.determinant().abs() <= 1e-12 * scale.powi(3) {
        return None;
    }
    // RQ through QR: with J the anti-identity, (J M)ᵀ = Q U  ⇒  M = (J Uᵀ J)(J Qᵀ),
    // J Uᵀ J upper triangular and J Qᵀ orthogonal.
    let j = Matrix3::new(0.0, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 0.0);
    let qr = (j * m).transpose().qr();
    let q = qr.q();
    let u = qr.r();
    let mut k = j * u.transpose() * j;
    let mut r = j * q.transpose();
    for i in 0..3 {
        if k[(i, i)] < 0.0 {
            for row in 0..3 {
                k[(row, i)] = -k[(row, i)];
            }
            for col in 0..3 {
                r[(i, col)] = -r[(i, col)];
            }
        }
    }
    let mut p4: Vector3<f64> = p.column(3).into_owned();
    if r.determinant() < 0.0 {
        // −P = [K(−R) | −p₄]
        r = -r;
        p4 = -p4;
    }
    let t = k.solve_upper_triangular(&p4)?;
    let k33 = k[(2, 2)];
    if k33.is_nan() || k33 <= 0.0 {
        return None;
    }
    let k = k / k33;
    if k.iter()
        .chain(r.iter())
        .chain(t.iter())
        .any(|v| !v.is_finite())
    {
        return None;
    }
    Some((k, r, t))
}

#[cfg(test)]
mod tests {
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
            let pi_inf =
                truth.h.try_inverse().unwrap().transpose() * Vector4::new(0.0, 0.0, 0.0, 1.0);
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
}
