//! The public types of self-calibration: options, result, per-camera intrinsics, errors, and K_N (eq. 24).

use nalgebra::{Matrix3, Matrix3x4, Matrix4};
use serde::Serialize;
use thiserror::Error;

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
    /// An option is out of its valid range; `option` is the field's name.
    #[error("invalid self-calibration option `{option}`: {reason}")]
    InvalidOption {
        option: &'static str,
        reason: String,
    },
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
#[derive(Clone, Debug, PartialEq, Serialize, serde::Deserialize)]
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
        let bad = |option: &'static str, reason: String| {
            Err(SelfCalibrationError::InvalidOption { option, reason })
        };
        if self.iterations == 0 || self.iterations > 1000 {
            return bad(
                "iterations",
                format!("must be in 1..=1000, got {}", self.iterations),
            );
        }
        for (option, value) in [
            ("sigma_focal_sq", self.sigma_focal_sq),
            ("sigma_aspect", self.sigma_aspect),
            ("sigma_principal_point", self.sigma_principal_point),
            ("sigma_skew", self.sigma_skew),
        ] {
            if !(value.is_finite() && (1e-12..=1e12).contains(&value)) {
                return bad(
                    option,
                    format!("must be a finite standard deviation in [1e-12, 1e12], got {value}"),
                );
            }
        }
        if !(self.estimated_aspect_weight > 0.0 && self.estimated_aspect_weight <= 1.0) {
            return bad(
                "estimated_aspect_weight",
                format!("must be in (0, 1], got {}", self.estimated_aspect_weight),
            );
        }
        if !(self.prior_mean_weight.is_finite() && (0.0..=1e6).contains(&self.prior_mean_weight)) {
            return bad(
                "prior_mean_weight",
                format!("must be in [0, 1e6], got {}", self.prior_mean_weight),
            );
        }
        if !(self.degenerate_singular_ratio >= 0.0 && self.degenerate_singular_ratio < 1.0) {
            return bad(
                "degenerate_singular_ratio",
                format!("must be in [0, 1), got {}", self.degenerate_singular_ratio),
            );
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
#[derive(Clone, Copy, Debug, PartialEq, Serialize, serde::Deserialize)]
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
#[derive(Clone, Debug, PartialEq, Serialize, serde::Deserialize)]
pub struct SelfCalibration {
    /// The upgrade `T` (metric from projective) with `diag(1, 1, 1, 0) = T Ω* Tᵀ`:
    /// `P_M = P T⁻¹`, `M_M = T M` (eq. 27). Its fourth row is the plane at infinity of the
    /// projective frame. Serialized as row-major nested arrays.
    #[serde(
        serialize_with = "serialize_matrix4",
        deserialize_with = "deserialize_matrix4"
    )]
    pub t: Matrix4<f64>,
    /// `T⁻¹` (computed directly from the eigen-decomposition, not by inversion). Serialized as
    /// row-major nested arrays.
    #[serde(
        serialize_with = "serialize_matrix4",
        deserialize_with = "deserialize_matrix4"
    )]
    pub t_inv: Matrix4<f64>,
    /// `Ω*` after the rank-3 enforcement, scaled to unit Frobenius norm, in the projective frame
    /// of the input cameras each scaled to unit Frobenius norm. Serialized as row-major nested arrays.
    #[serde(
        serialize_with = "serialize_matrix4",
        deserialize_with = "deserialize_matrix4"
    )]
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

fn deserialize_matrix4<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Matrix4<f64>, D::Error> {
    let rows = <[[f64; 4]; 4] as serde::Deserialize>::deserialize(d)?;
    Ok(Matrix4::from_fn(|i, j| rows[i][j]))
}
