//! Linearisation and the Schur complement (Triggs et al. 2000, §6.1 eqs. 6.1–6.3).
//!
//! With the normal equations `[[U, W], [Wᵀ, V]] [δc; δp] = [bc; bp]` (`b = −Jᵀr`), the point blocks
//! `V` are 3×3 block-diagonal, so `S = U − W V⁻¹ Wᵀ`, `S δc = bc − W V⁻¹ bp` and `δp = V⁻¹(bp − Wᵀδc)`.
//! `S` is stored as a lower triangle, column-major, dense or in sparse columns (one storage for the
//! dense and the sparse solver); `assembly.rs` fills it.

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

use crate::assembly::PointChunks;
use crate::loss::{Corrector, RobustLoss};
use crate::problem::{CameraModel, Problem};
use crate::residual::{metric_jacobian, projective_jacobian, NUM_INTRINSICS};
use crate::structure::{Structure, MAX_FULL_COLS, NONE};

/// Everything that depends on the linearisation point but not on the damping.
#[derive(Default)]
pub(crate) struct Linearization {
    pub cost: f64,
    /// Robust-corrected Jacobians per observation (`jstride` camera columns each).
    pub jc: Vec<[f64; 2]>,
    pub jp: Vec<[[f64; 2]; 3]>,
    pub v: Vec<Matrix3<f64>>,
    pub bp: Vec<Vector3<f64>>,
    pub w: Vec<f64>,
    /// `−gradient` and `diag(JᵀJ)` of the camera-side parameters (priors included).
    pub bc: Vec<f64>,
    pub dc: Vec<f64>,
    /// Prior contributions to the diagonal of `U`.
    pub prior_h: Vec<f64>,
    /// Scratch kept between linearisations: robust-corrected residuals, and each observation's
    /// cost (summed in order).
    res: Vec<[f64; 2]>,
    terms: Vec<f64>,
}

/// Splits `data` into consecutive mutable pieces of the given lengths.
pub(crate) fn split_by<T>(mut data: &mut [T], lens: impl Iterator<Item = usize>) -> Vec<&mut [T]> {
    let mut out = Vec::new();
    for l in lens {
        let (a, b) = std::mem::take(&mut data).split_at_mut(l);
        out.push(a);
        data = b;
    }
    out
}

pub(crate) fn js(st: &Structure) -> usize {
    st.jstride.max(1)
}

pub(crate) fn linearize(p: &Problem, st: &Structure, loss: &RobustLoss) -> Linearization {
    let mut lin = Linearization::default();
    linearize_into(p, st, loss, &mut lin);
    lin
}

/// Zeroes `v` to length `len`, keeping its allocation.
fn zeroed<T: Clone>(v: &mut Vec<T>, len: usize, zero: T) {
    v.clear();
    v.resize(len, zero);
}

/// [`linearize`] into the buffers of an earlier linearisation of the same problem. Large buffers
/// allocated afresh at every iteration cost a page fault per 4 KiB on first write (with a TLB
/// shootdown to every core where the pages came from a freed arena): half the time of a 50-view
/// problem's iterations went to the kernel.
pub(crate) fn linearize_into(
    p: &Problem,
    st: &Structure,
    loss: &RobustLoss,
    lin: &mut Linearization,
) {
    let no = p.num_observations();
    let np = p.points.len();
    let js = js(st);
    let Linearization {
        cost,
        jc,
        jp,
        v,
        bp,
        w,
        bc,
        dc,
        prior_h,
        res,
        terms,
    } = lin;
    zeroed(res, no, [0.0; 2]);
    zeroed(jc, no * js, [0.0; 2]);
    zeroed(jp, no, [[0.0; 2]; 3]);
    let mut data_cost_terms = std::mem::take(terms);
    res.par_iter_mut()
        .zip(jc.par_chunks_mut(js))
        .zip(jp.par_iter_mut())
        .enumerate()
        .with_min_len(256)
        .map(|(o, ((r_out, jc_out), jp_out))| {
            let c = p.obs_camera[o] as usize;
            let x = &p.points[p.obs_point[o] as usize];
            let mut full = [[0.0; 2]; MAX_FULL_COLS];
            let r = match p.model {
                CameraModel::Metric => {
                    let mut jpose = [[0.0; 2]; 6];
                    let mut jintr = [[0.0; 2]; NUM_INTRINSICS];
                    let r = metric_jacobian(
                        &p.cameras[c],
                        &p.groups[p.camera_group[c]],
                        x,
                        p.obs_xy[o],
                        &p.motion(o),
                        &mut jpose,
                        &mut jintr,
                        jp_out,
                    );
                    full[..6].copy_from_slice(&jpose);
                    full[6..].copy_from_slice(&jintr);
                    r
                }
                CameraModel::Projective => {
                    let mut jcam = [[0.0; 2]; 11];
                    let r = projective_jacobian(&p.cameras[c], x, p.obs_xy[o], &mut jcam, jp_out);
                    full[..11].copy_from_slice(&jcam);
                    r
                }
            };
            // Per-observation σ (eq. 21's weights): scale the residual and both Jacobians by 1/σ.
            let wt = p.obs_weight(o);
            let r = if wt != 1.0 {
                for row in full.iter_mut().chain(jp_out.iter_mut()) {
                    row[0] *= wt;
                    row[1] *= wt;
                }
                [r[0] * wt, r[1] * wt]
            } else {
                r
            };
            for (k, m) in st.cam_colmap[c].iter().enumerate() {
                if *m != u8::MAX {
                    jc_out[*m as usize] = full[k];
                }
            }
            let s = r[0] * r[0] + r[1] * r[1];
            let corr = Corrector::new(loss, s);
            if !corr.is_identity() {
                let (own, sh) = st.cam_ncols[c];
                corr.correct_jacobian(r, &mut jc_out[..own + sh]);
                corr.correct_jacobian(r, jp_out);
                *r_out = corr.correct_residual(r);
            } else {
                *r_out = r;
            }
            loss.evaluate(s)[0]
        })
        // Collected, then summed in order: a parallel sum's grouping depends on work stealing,
        // and the last bits of the cost decide LM's accept/reject (same seed, same output).
        .collect_into_vec(&mut data_cost_terms);
    let data_cost: f64 = data_cost_terms.iter().sum();
    *terms = data_cost_terms;

    // Point blocks: V, bp and the W blocks of each incidence.
    zeroed(v, np, Matrix3::zeros());
    zeroed(bp, np, Vector3::zeros());
    zeroed(w, st.w_len, 0.0);
    let pi = &st.point_inc;
    let w_lens = (0..np).map(|pt| {
        let (a, b) = (pi.ptr[pt], pi.ptr[pt + 1]);
        if a == b {
            0
        } else {
            st.inc_woff[b - 1] + 3 * st.block_dim[pi.idx[b - 1] as usize] - st.inc_woff[a]
        }
    });
    let w_parts = split_by(w, w_lens);
    v.par_iter_mut()
        .zip(bp.par_iter_mut())
        .zip(w_parts.into_par_iter())
        .enumerate()
        .with_min_len(64)
        .for_each(|(pt, ((v, bp), wpt))| {
            let base = st.inc_woff.get(pi.ptr[pt]).copied().unwrap_or(0);
            for &o in st.point_obs.row(pt) {
                let o = o as usize;
                let (j, r) = (&jp[o], res[o]);
                for a in 0..3 {
                    bp[a] -= j[a][0] * r[0] + j[a][1] * r[1];
                    for b in a..3 {
                        v[(a, b)] += j[a][0] * j[b][0] + j[a][1] * j[b][1];
                    }
                }
                let c = p.obs_camera[o] as usize;
                let (own, sh) = st.cam_ncols[c];
                let cols = &jc[o * js..o * js + own + sh];
                for (slot, range) in [(0, 0..own), (1, own..own + sh)] {
                    let inc = st.obs_inc[o][slot];
                    if inc == NONE {
                        continue;
                    }
                    let off = st.inc_woff[inc as usize] - base;
                    let d = range.len();
                    for (row, k) in range.enumerate() {
                        for t in 0..3 {
                            wpt[off + t * d + row] += cols[k][0] * j[t][0] + cols[k][1] * j[t][1];
                        }
                    }
                }
            }
            for a in 0..3 {
                for b in 0..a {
                    v[(a, b)] = v[(b, a)];
                }
            }
        });

    // Camera side: gradient and diagonal, over fixed ranges of observations in storage order
    // (each range into its own pair of vectors, added in order: the same sums on any machine). By
    // block, the observations of a camera lie scattered through the Jacobians.
    let n = st.num_reduced;
    let ranges = (no / 8192).clamp(1, 16);
    let per = no.div_ceil(ranges);
    let partial: Vec<Vec<f64>> = (0..ranges)
        .into_par_iter()
        .map(|k| {
            let mut g = vec![0.0; 2 * n];
            let (gb, gd) = g.split_at_mut(n);
            for o in k * per..((k + 1) * per).min(no) {
                let c = p.obs_camera[o] as usize;
                let (own, sh) = st.cam_ncols[c];
                let r = res[o];
                for (k, col) in jc[o * js..o * js + own + sh].iter().enumerate() {
                    let i = st.reduced_index(c, k);
                    gb[i] -= col[0] * r[0] + col[1] * r[1];
                    gd[i] += col[0] * col[0] + col[1] * col[1];
                }
            }
            g
        })
        .collect();
    zeroed(bc, n, 0.0);
    zeroed(dc, n, 0.0);
    for g in &partial {
        for i in 0..n {
            bc[i] += g[i];
            dc[i] += g[n + i];
        }
    }
    zeroed(prior_h, n, 0.0);
    if p.model == CameraModel::Metric {
        for g in 0..p.groups.len() {
            for k in 0..NUM_INTRINSICS {
                if let (Some(i), Some(pr)) = (st.group_param_at[g][k], p.group_priors[g][k]) {
                    let is2 = 1.0 / (pr.sigma * pr.sigma);
                    bc[i] -= (p.groups[g][k] - pr.mean) * is2;
                    dc[i] += is2;
                    prior_h[i] += is2;
                }
            }
        }
    }
    *cost = 0.5 * data_cost + p.prior_cost();
}

/// Storage of the reduced matrix (lower triangle, column-major), dense or compressed sparse columns.
pub(crate) struct ReducedMatrix {
    pub dense: bool,
    pub n: usize,
    /// Sparse pattern (lower triangle, CSC); empty when dense.
    pub col_ptr: Vec<usize>,
    pub row_idx: Vec<usize>,
    pub values: Vec<f64>,
    /// Start of each block's columns in `values` (`nb + 1` entries).
    pub(crate) chunk_start: Vec<usize>,
    /// Per reduced column: chunk-local base of its off-diagonal rows and of its diagonal block.
    pub(crate) cb_off: Vec<usize>,
    pub(crate) cb_diag: Vec<usize>,
    /// Aligned with `block_cols.idx`: row offset of each coupled block within a column.
    pub(crate) rowoff: Vec<usize>,
    /// The point ranges assembled point by point, each into its own accumulator.
    pub(crate) points: PointChunks,
}

impl ReducedMatrix {
    pub fn new(st: &Structure, dense: bool) -> Self {
        let n = st.num_reduced;
        let nb = st.num_blocks();
        let mut chunk_start = Vec::with_capacity(nb + 1);
        let mut cb_off = vec![0; n];
        let mut cb_diag = vec![0; n];
        let mut rowoff = vec![0; st.block_cols.idx.len()];
        let (mut col_ptr, mut row_idx) = (Vec::new(), Vec::new());
        if dense {
            for b in 0..nb {
                let off = st.block_offset[b];
                chunk_start.push(off * n);
                for jj in 0..st.block_dim[b] {
                    cb_off[off + jj] = jj * n;
                    cb_diag[off + jj] = jj * n + off;
                }
                for (q, b2) in st.block_cols.row(b).iter().enumerate() {
                    rowoff[st.block_cols.ptr[b] + q] = st.block_offset[*b2 as usize];
                }
            }
            chunk_start.push(n * n);
        } else {
            col_ptr.push(0);
            for b in 0..nb {
                let (off, d) = (st.block_offset[b], st.block_dim[b]);
                chunk_start.push(row_idx.len());
                let mut prefix = 0;
                for (q, b2) in st.block_cols.row(b).iter().enumerate() {
                    rowoff[st.block_cols.ptr[b] + q] = prefix;
                    prefix += st.block_dim[*b2 as usize];
                }
                for jj in 0..d {
                    let local = row_idx.len() - chunk_start[b];
                    cb_diag[off + jj] = local - jj;
                    cb_off[off + jj] = local + d - jj;
                    row_idx.extend(off + jj..off + d);
                    for b2 in st.block_cols.row(b) {
                        let o2 = st.block_offset[*b2 as usize];
                        row_idx.extend(o2..o2 + st.block_dim[*b2 as usize]);
                    }
                    col_ptr.push(row_idx.len());
                }
            }
            chunk_start.push(row_idx.len());
        }
        let len = *chunk_start.last().unwrap_or(&0);
        let mut m = Self {
            dense,
            n,
            col_ptr,
            row_idx,
            values: vec![0.0; len],
            chunk_start,
            cb_off,
            cb_diag,
            rowoff,
            points: PointChunks::default(),
        };
        m.points = PointChunks::new(st, &m);
        m
    }
}

/// Inverts the damped point blocks `V + diag(μ_p)`; `None` entries mark singular blocks (zeroed).
pub(crate) fn invert_points(lin: &Linearization, mu_p: &[f64]) -> Vec<Matrix3<f64>> {
    lin.v
        .par_iter()
        .enumerate()
        .with_min_len(256)
        .map(|(pt, v)| {
            let mut m = *v;
            for a in 0..3 {
                m[(a, a)] += mu_p[3 * pt + a];
            }
            m.try_inverse().unwrap_or_else(Matrix3::zeros)
        })
        .collect()
}

/// Back-substitution `δp = V⁻¹ (bp − Wᵀ δc)` for every point.
pub(crate) fn back_substitute(
    st: &Structure,
    lin: &Linearization,
    vinv: &[Matrix3<f64>],
    dc: &[f64],
) -> Vec<f64> {
    let np = lin.v.len();
    let mut dp = vec![0.0; 3 * np];
    dp.par_chunks_mut(3)
        .enumerate()
        .with_min_len(256)
        .for_each(|(pt, out)| {
            let mut r = lin.bp[pt];
            for i in st.point_inc.ptr[pt]..st.point_inc.ptr[pt + 1] {
                let b = st.point_inc.idx[i] as usize;
                let (off, d) = (st.block_offset[b], st.block_dim[b]);
                let w = &lin.w[st.inc_woff[i]..st.inc_woff[i] + 3 * d];
                for t in 0..3 {
                    r[t] -= w[t * d..(t + 1) * d]
                        .iter()
                        .zip(&dc[off..off + d])
                        .map(|(a, b)| a * b)
                        .sum::<f64>();
                }
            }
            let x = vinv[pt] * r;
            out.copy_from_slice(x.as_slice());
        });
    dp
}

/// `‖J δ‖²` over all observations plus the prior terms (for the model cost decrease).
pub(crate) fn jacobian_step_norm2(
    p: &Problem,
    st: &Structure,
    lin: &Linearization,
    dc: &[f64],
    dp: &[f64],
) -> f64 {
    let js = js(st);
    let data: f64 = (0..p.num_observations())
        .into_par_iter()
        .with_min_len(1024)
        .map(|o| {
            let c = p.obs_camera[o] as usize;
            let pt = p.obs_point[o] as usize;
            let (own, sh) = st.cam_ncols[c];
            let mut e = [0.0; 2];
            for k in 0..own + sh {
                let col = lin.jc[o * js + k];
                let x = dc[st.reduced_index(c, k)];
                e[0] += col[0] * x;
                e[1] += col[1] * x;
            }
            for t in 0..3 {
                e[0] += lin.jp[o][t][0] * dp[3 * pt + t];
                e[1] += lin.jp[o][t][1] * dp[3 * pt + t];
            }
            e[0] * e[0] + e[1] * e[1]
        })
        // Summed in order, as in `linearize` (same seed, same output).
        .collect::<Vec<f64>>()
        .iter()
        .sum();
    data + lin
        .prior_h
        .iter()
        .zip(dc)
        .map(|(h, x)| h * x * x)
        .sum::<f64>()
}
