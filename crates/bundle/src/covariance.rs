//! Marginal covariances of the 3D points and camera centres at a bundle-adjustment optimum, from the
//! Schur system (Triggs et al. 2000, §2.2 and §6.1; Hartley & Zisserman 2004, §A6.4):
//! `Σc = S⁺` for the camera-side parameters and `Σp = V⁻¹ + V⁻¹ Wᵀ Σc W V⁻¹` for each point, all scaled by
//! the a-posteriori variance factor `σ̂² = Σ‖r‖² / (#residuals − #free parameters + gauge)`.
//!
//! Gauge: the first view is held fixed (as in [`crate::MetricBundleConfig`]); the remaining scale
//! freedom is removed by the pseudo-inverse of the Jacobi-scaled `S` (eigenvalues below `1e-9` of the
//! largest are dropped). This needs a dense `S`, so it is limited to a few thousand parameters.
//!
//! A point whose rays (nearly) coincide, such as one seen only by two shots from the same spot,
//! has a direction its observations do not constrain: its block `V` is singular. Its observations
//! say nothing along that direction (`W` vanishes there too), so `V` enters `S` through its
//! pseudo-inverse (eigenvalues below [`POINT_RCOND`] of its largest dropped) rather than an
//! inverse of roundoff, and the point gets no covariance: it is counted in
//! [`MetricUncertainty::undetermined_points`].

use std::collections::BTreeMap;

use handheld_core::{CameraId, ImageId, MetricReconstruction, PointId};
use nalgebra::{DMatrix, Matrix3, SymmetricEigen};
use rayon::prelude::*;

use crate::assembly::assemble;
use crate::metric::{metric_problem, MetricBundleConfig};
use crate::options::{BundleError, BundleOptions};
use crate::residual::NUM_INTRINSICS;
use crate::schur::{linearize, ReducedMatrix};
use crate::structure::Structure;

/// Largest reduced system for which covariances are computed.
pub const MAX_COVARIANCE_DIMENSION: usize = 4000;

/// Smallest ratio of a point block's eigenvalues to its largest that counts as information: below
/// it the direction is undetermined (in double precision, `1e-12` leaves six digits of the
/// inverse).
pub const POINT_RCOND: f64 = 1e-12;

/// A 3×3 covariance and its summary standard deviation `sqrt(trace/3)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PointUncertainty {
    pub covariance: Matrix3<f64>,
    pub sigma: f64,
}

impl PointUncertainty {
    fn new(covariance: Matrix3<f64>) -> Self {
        Self {
            covariance,
            sigma: (covariance.trace().max(0.0) / 3.0).sqrt(),
        }
    }

    /// Standard deviations along the axes.
    pub fn sigma_xyz(&self) -> [f64; 3] {
        [0, 1, 2].map(|i| self.covariance[(i, i)].max(0.0).sqrt())
    }
}

/// Uncertainty of a metric reconstruction.
#[derive(Clone, Debug, PartialEq)]
pub struct MetricUncertainty {
    pub points: BTreeMap<PointId, PointUncertainty>,
    /// Camera centres of the views whose pose is free.
    pub centers: BTreeMap<ImageId, PointUncertainty>,
    /// Standard deviation of every refined intrinsic of each group, in the order of
    /// [`crate::IntrinsicParam`] (`None` where the parameter is held constant).
    pub intrinsics: BTreeMap<CameraId, [Option<f64>; NUM_INTRINSICS]>,
    /// `σ̂²` in pixels² that scales every covariance.
    pub variance_factor: f64,
    /// Eigenvalues of the scaled `S` dropped as gauge freedoms.
    pub dropped_directions: usize,
    /// Points with a direction their observations do not constrain (no entry in `points`).
    pub undetermined_points: usize,
}

/// Pseudo-inverse of a symmetric positive semi-definite 3×3 block, and how many directions it
/// dropped (eigenvalues below [`POINT_RCOND`] of the largest, or not positive).
fn pseudo_inverse3(v: &Matrix3<f64>) -> (Matrix3<f64>, usize) {
    let eig = SymmetricEigen::new(*v);
    let top = eig.eigenvalues.max();
    if !top.is_finite() || top <= 0.0 {
        return (Matrix3::zeros(), 3);
    }
    let mut dropped = 0;
    let inv = nalgebra::Vector3::from_fn(|i, _| {
        let l = eig.eigenvalues[i];
        if l > POINT_RCOND * top {
            1.0 / l
        } else {
            dropped += 1;
            0.0
        }
    });
    let q = eig.eigenvectors;
    (q * Matrix3::from_diagonal(&inv) * q.transpose(), dropped)
}

/// Covariances at the current estimate of `rec` (normally right after [`crate::bundle_adjust_metric`]
/// with the same config); `options` supplies the loss and the thread count.
pub fn metric_uncertainty(
    rec: &MetricReconstruction,
    config: &MetricBundleConfig,
    options: &BundleOptions,
) -> Result<MetricUncertainty, BundleError> {
    options.validate()?;
    let (p, index) = metric_problem(rec, config)?;
    p.validate()?;
    let st = Structure::new(&p);
    let n = st.num_reduced;
    if n > MAX_COVARIANCE_DIMENSION {
        return Err(BundleError::TooLarge {
            what: "covariance estimation",
            dimension: n,
            limit: MAX_COVARIANCE_DIMENSION,
        });
    }
    let lin = linearize(&p, &st, &options.loss);
    let (vinv, point_dropped): (Vec<Matrix3<f64>>, Vec<usize>) =
        lin.v.iter().map(pseudo_inverse3).unzip();
    let mut m = ReducedMatrix::new(&st, true);
    let mut rhs = vec![0.0; n];
    assemble(&p, &st, &lin, &vinv, &lin.prior_h, &mut m, &mut rhs);
    let mut s = DMatrix::from_column_slice(n, n, &m.values);
    for j in 0..n {
        for i in 0..j {
            s[(i, j)] = s[(j, i)];
        }
    }
    // Pseudo-inverse of the Jacobi-scaled matrix: faer's blocked, parallel eigensolver and product
    // (nalgebra's unblocked ones took 7 s of a 400-view walk's sparse stage, n = 2 400).
    let d: Vec<f64> = (0..n).map(|i| 1.0 / s[(i, i)].max(1e-300).sqrt()).collect();
    let scaled = faer::Mat::<f64>::from_fn(n, n, |i, j| s[(i, j)] * d[i] * d[j]);
    drop(s);
    let eig = scaled
        .self_adjoint_eigen(faer::Side::Lower)
        .map_err(|e| BundleError::Linear(format!("eigendecomposition of the covariance: {e:?}")))?;
    let eigenvalues = eig.S().column_vector();
    let top = (0..n).fold(0.0f64, |a, i| a.max(eigenvalues[i]));
    if !top.is_finite() || top <= 0.0 {
        return Err(BundleError::Linear(format!(
            "the reduced camera system of the covariance has no positive eigenvalue (largest {top:e})"
        )));
    }
    let mut dropped = 0;
    let inv_vals: Vec<f64> = (0..n)
        .map(|i| {
            let v = eigenvalues[i];
            if v > 1e-9 * top {
                1.0 / v
            } else {
                dropped += 1;
                0.0
            }
        })
        .collect();
    let u = eig.U();
    let u_scaled = faer::Mat::<f64>::from_fn(n, n, |i, k| u[(i, k)] * inv_vals[k]);
    let product = &u_scaled * u.transpose();
    let cov = DMatrix::from_fn(n, n, |i, j| product[(i, j)] * d[i] * d[j]);
    drop(product);
    let free_point_params = 3 * p.points.len() - point_dropped.iter().sum::<usize>();
    let dof = (2 * p.num_observations()) as f64 - (n + free_point_params) as f64 + dropped as f64;
    let sum_sq: f64 = (0..p.num_observations())
        .map(|o| p.weighted_residual(o))
        .map(|r| r[0] * r[0] + r[1] * r[1])
        .sum();
    let variance_factor = if dof > 0.0 { sum_sq / dof } else { 1.0 };

    // Σp = V⁻¹ + Σᵢⱼ Yᵢᵀ Σc[bᵢ, bⱼ] Yⱼ with Yᵢ = Wᵢ V⁻¹ (dᵢ × 3), point by point in parallel.
    let points: BTreeMap<PointId, PointUncertainty> = index
        .points
        .par_iter()
        .enumerate()
        .with_min_len(64)
        .filter(|(pt, _)| point_dropped[*pt] == 0)
        .map(|(pt, id)| {
            let vi = vinv[pt];
            let mut c = vi;
            let range = st.point_inc.ptr[pt]..st.point_inc.ptr[pt + 1];
            // Each Yᵢ column-major in one buffer, with its block's offset and dimension.
            let mut ys: Vec<(usize, usize, usize)> = Vec::with_capacity(range.len());
            let mut buf: Vec<f64> = Vec::new();
            for i in range {
                let b = st.point_inc.idx[i] as usize;
                let dim = st.block_dim[b];
                let w = &lin.w[st.inc_woff[i]..st.inc_woff[i] + 3 * dim];
                let at = buf.len();
                for t in 0..3 {
                    for r in 0..dim {
                        buf.push(
                            w[r] * vi[(0, t)]
                                + w[dim + r] * vi[(1, t)]
                                + w[2 * dim + r] * vi[(2, t)],
                        );
                    }
                }
                ys.push((st.block_offset[b], dim, at));
            }
            let mut tmp = Vec::new();
            for &(oi, di, ai) in &ys {
                let yi = &buf[ai..ai + 3 * di];
                for &(oj, dj, aj) in &ys {
                    let yj = &buf[aj..aj + 3 * dj];
                    // tmp = Σc[bᵢ, bⱼ] Yⱼ (dᵢ × 3).
                    tmp.clear();
                    tmp.resize(3 * di, 0.0);
                    for b in 0..3 {
                        for (col, &y) in yj[b * dj..(b + 1) * dj].iter().enumerate() {
                            if y == 0.0 {
                                continue;
                            }
                            for r in 0..di {
                                tmp[b * di + r] += cov[(oi + r, oj + col)] * y;
                            }
                        }
                    }
                    for a in 0..3 {
                        for b in 0..3 {
                            let mut acc = 0.0;
                            for r in 0..di {
                                acc += yi[a * di + r] * tmp[b * di + r];
                            }
                            c[(a, b)] += acc;
                        }
                    }
                }
            }
            (*id, PointUncertainty::new(c * variance_factor))
        })
        .collect();
    let mut centers = BTreeMap::new();
    for (i, id) in index.views.iter().enumerate() {
        let Some(at) = st.cam_pose_at[i] else {
            continue;
        };
        let b = &p.cameras[i];
        let rt = Matrix3::new(b[0], b[3], b[6], b[1], b[4], b[7], b[2], b[5], b[8]);
        let tx = Matrix3::new(0.0, -b[11], b[10], b[11], 0.0, -b[9], -b[10], b[9], 0.0);
        // C = −Rᵀt: ∂C/∂δ = −Rᵀ[t]×, ∂C/∂t = −Rᵀ.
        let mut j = DMatrix::zeros(3, 6);
        j.view_mut((0, 0), (3, 3)).copy_from(&(-rt * tx));
        j.view_mut((0, 3), (3, 3)).copy_from(&(-rt));
        let sub = cov.view((at, at), (6, 6));
        let c = &j * sub * j.transpose();
        centers.insert(
            *id,
            PointUncertainty::new(Matrix3::from_fn(|a, b| c[(a, b)]) * variance_factor),
        );
    }
    let intrinsics = index
        .cameras
        .iter()
        .enumerate()
        .map(|(g, id)| {
            let sd = st.group_param_at[g]
                .map(|at| at.map(|k| (cov[(k, k)] * variance_factor).max(0.0).sqrt()));
            (*id, sd)
        })
        .collect();
    Ok(MetricUncertainty {
        points,
        centers,
        intrinsics,
        variance_factor,
        dropped_directions: dropped,
        undetermined_points: point_dropped.iter().filter(|d| **d > 0).count(),
    })
}
