//! Linearisation and the Schur complement (Triggs et al. 2000, §6.1 eqs. 6.1–6.3).
//!
//! With the normal equations `[[U, W], [Wᵀ, V]] [δc; δp] = [bc; bp]` (`b = −Jᵀr`), the point blocks
//! `V` are 3×3 block-diagonal, so `S = U − W V⁻¹ Wᵀ`, `S δc = bc − W V⁻¹ bp` and `δp = V⁻¹(bp − Wᵀδc)`.
//! `S` is assembled block row by block row in parallel (each worker owns whole rows, so no locks), in
//! lower-triangular column-major storage shared by the dense and the sparse solver.

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

use crate::loss::{Corrector, RobustLoss};
use crate::problem::{CameraModel, Problem};
use crate::residual::{metric_jacobian, projective_jacobian, NUM_INTRINSICS};
use crate::structure::{Structure, MAX_FULL_COLS, NONE};

/// Everything that depends on the linearisation point but not on the damping.
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
    let no = p.num_observations();
    let np = p.points.len();
    let js = js(st);
    let mut res = vec![[0.0; 2]; no];
    let mut jc = vec![[0.0; 2]; no * js];
    let mut jp = vec![[[0.0; 2]; 3]; no];
    let data_cost: f64 = res
        .par_iter_mut()
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
        .collect::<Vec<f64>>()
        .iter()
        .sum();

    // Point blocks: V, bp and the W blocks of each incidence.
    let mut v = vec![Matrix3::zeros(); np];
    let mut bp = vec![Vector3::zeros(); np];
    let mut w = vec![0.0; st.w_len];
    let pi = &st.point_inc;
    let w_lens = (0..np).map(|pt| {
        let (a, b) = (pi.ptr[pt], pi.ptr[pt + 1]);
        if a == b {
            0
        } else {
            st.inc_woff[b - 1] + 3 * st.block_dim[pi.idx[b - 1] as usize] - st.inc_woff[a]
        }
    });
    let w_parts = split_by(&mut w, w_lens);
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

    // Camera side: gradient and diagonal, block by block.
    let n = st.num_reduced;
    let mut bc = vec![0.0; n];
    let mut dc = vec![0.0; n];
    let bc_parts = split_by(&mut bc, st.block_dim.iter().copied());
    let dc_parts = split_by(&mut dc, st.block_dim.iter().copied());
    bc_parts
        .into_par_iter()
        .zip(dc_parts.into_par_iter())
        .enumerate()
        .for_each(|(b, (bcb, dcb))| {
            for &o in st.block_obs.row(b) {
                let o = o as usize;
                let c = p.obs_camera[o] as usize;
                let (own, sh) = st.cam_ncols[c];
                // Which of the camera's two blocks `b` is: its own (poses, unshared
                // intrinsics) or its group's shared intrinsics. A held camera has no own block
                // (`own` = 0), and its observations still count for the shared one.
                let (lo, d) = if st.cam_block[c] as usize == b {
                    (0, own)
                } else {
                    (own, sh)
                };
                let r = res[o];
                for k in 0..d {
                    let col = jc[o * js + lo + k];
                    bcb[k] -= col[0] * r[0] + col[1] * r[1];
                    dcb[k] += col[0] * col[0] + col[1] * col[1];
                }
            }
        });
    let mut prior_h = vec![0.0; n];
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
    Linearization {
        cost: 0.5 * data_cost + p.prior_cost(),
        jc,
        jp,
        v,
        bp,
        w,
        bc,
        dc,
        prior_h,
    }
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
    chunk_start: Vec<usize>,
    /// Per reduced column: chunk-local base of its off-diagonal rows and of its diagonal block.
    cb_off: Vec<usize>,
    cb_diag: Vec<usize>,
    /// Aligned with `block_cols.idx`: row offset of each coupled block within a column.
    rowoff: Vec<usize>,
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
        Self {
            dense,
            n,
            col_ptr,
            row_idx,
            values: vec![0.0; len],
            chunk_start,
            cb_off,
            cb_diag,
            rowoff,
        }
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

/// Assembles `S = U + diag(extra) − W V⁻¹ Wᵀ` into `m.values` and `rhs = bc − W V⁻¹ bp`.
pub(crate) fn assemble(
    p: &Problem,
    st: &Structure,
    lin: &Linearization,
    vinv: &[Matrix3<f64>],
    extra_diag: &[f64],
    m: &mut ReducedMatrix,
    rhs: &mut [f64],
) {
    let nb = st.num_blocks();
    let js = js(st);
    let chunk_lens = (0..nb).map(|b| m.chunk_start[b + 1] - m.chunk_start[b]);
    let chunks = split_by(&mut m.values, chunk_lens);
    let rhs_parts = split_by(rhs, st.block_dim.iter().copied());
    let (cb_off, cb_diag, rowoff) = (&m.cb_off, &m.cb_diag, &m.rowoff);
    chunks
        .into_par_iter()
        .zip(rhs_parts.into_par_iter())
        .enumerate()
        .for_each_init(
            || (vec![0usize; nb], Vec::<f64>::new()),
            |(pos, y), (b, (vals, rb))| {
                let (off, d) = (st.block_offset[b], st.block_dim[b]);
                for (q, b2) in st.block_cols.row(b).iter().enumerate() {
                    pos[*b2 as usize] = rowoff[st.block_cols.ptr[b] + q];
                }
                let cbo = &cb_off[off..off + d];
                let cbd = &cb_diag[off..off + d];
                vals.fill(0.0);
                rb.copy_from_slice(&lin.bc[off..off + d]);
                // U = Σ Jcᵀ Jc over the observations touching this block row.
                for &o in st.block_obs.row(b) {
                    let o = o as usize;
                    let c = p.obs_camera[o] as usize;
                    let (own, sh) = st.cam_ncols[c];
                    let cols = &lin.jc[o * js..o * js + own + sh];
                    let own_row = st.cam_block[c] as usize == b;
                    let (lo, hi) = if own_row { (0, own) } else { (own, own + sh) };
                    for jj in lo..hi {
                        let cj = cols[jj];
                        let base = cbd[jj - lo];
                        for ii in jj..hi {
                            vals[base + ii - lo] += cj[0] * cols[ii][0] + cj[1] * cols[ii][1];
                        }
                    }
                    if own_row && sh > 0 {
                        let ro = pos[st.cam_shared[c] as usize];
                        for jj in 0..own {
                            let cj = cols[jj];
                            let base = cbo[jj] + ro;
                            for ii in 0..sh {
                                vals[base + ii] +=
                                    cj[0] * cols[own + ii][0] + cj[1] * cols[own + ii][1];
                            }
                        }
                    }
                }
                // − W V⁻¹ Wᵀ and − W V⁻¹ bp over the points seen through this block. W blocks are stored
                // column-major (`d × 3`), so each row of the update is three contiguous AXPYs.
                y.resize(3 * d, 0.0);
                for &i in st.block_inc.row(b) {
                    let i = i as usize;
                    let pt = st.inc_point[i] as usize;
                    let vi = &vinv[pt];
                    let wi = &lin.w[st.inc_woff[i]..st.inc_woff[i] + 3 * d];
                    let (w0, w1, w2) = (&wi[..d], &wi[d..2 * d], &wi[2 * d..]);
                    let bpp = &lin.bp[pt];
                    for jj in 0..d {
                        for t in 0..3 {
                            y[3 * jj + t] =
                                w0[jj] * vi[(0, t)] + w1[jj] * vi[(1, t)] + w2[jj] * vi[(2, t)];
                        }
                        rb[jj] -=
                            y[3 * jj] * bpp[0] + y[3 * jj + 1] * bpp[1] + y[3 * jj + 2] * bpp[2];
                    }
                    for i2 in i..st.point_inc.ptr[pt + 1] {
                        let b2 = st.point_inc.idx[i2] as usize;
                        let d2 = st.block_dim[b2];
                        let wj = &lin.w[st.inc_woff[i2]..st.inc_woff[i2] + 3 * d2];
                        let (v0, v1, v2) = (&wj[..d2], &wj[d2..2 * d2], &wj[2 * d2..]);
                        if b2 != b {
                            let ro = pos[b2];
                            match d2 {
                                3 => sub_rows::<3>(vals, cbo, ro, &y[..3 * d], wj),
                                6 => sub_rows::<6>(vals, cbo, ro, &y[..3 * d], wj),
                                9 => sub_rows::<9>(vals, cbo, ro, &y[..3 * d], wj),
                                11 => sub_rows::<11>(vals, cbo, ro, &y[..3 * d], wj),
                                _ => {
                                    for jj in 0..d {
                                        let start = cbo[jj] + ro;
                                        axpy3(
                                            &mut vals[start..start + d2],
                                            &y[3 * jj..3 * jj + 3],
                                            v0,
                                            v1,
                                            v2,
                                        );
                                    }
                                }
                            }
                            continue;
                        }
                        for jj in 0..d {
                            let start = cbd[jj] + jj;
                            axpy3(
                                &mut vals[start..start + d2 - jj],
                                &y[3 * jj..3 * jj + 3],
                                &v0[jj..],
                                &v1[jj..],
                                &v2[jj..],
                            );
                        }
                    }
                }
                for jj in 0..d {
                    vals[cbd[jj] + jj] += extra_diag[off + jj];
                }
            },
        );
}

/// `dst −= y₀ v₀ + y₁ v₁ + y₂ v₂` (one row of `−Y Wᵀ`).
#[inline(always)]
fn axpy3(dst: &mut [f64], y: &[f64], v0: &[f64], v1: &[f64], v2: &[f64]) {
    let (y0, y1, y2) = (y[0], y[1], y[2]);
    for (s, ((a0, a1), a2)) in dst.iter_mut().zip(v0.iter().zip(v1).zip(v2)) {
        *s -= y0 * a0 + y1 * a1 + y2 * a2;
    }
}

/// `−Y Wᵀ` for an off-diagonal block whose column block has the fixed size `D2` (unrolled).
#[inline(always)]
fn sub_rows<const D2: usize>(vals: &mut [f64], cbo: &[usize], ro: usize, y: &[f64], w: &[f64]) {
    let (v0, v1, v2): (&[f64; D2], &[f64; D2], &[f64; D2]) = match (
        w[..D2].try_into(),
        w[D2..2 * D2].try_into(),
        w[2 * D2..3 * D2].try_into(),
    ) {
        (Ok(a), Ok(b), Ok(c)) => (a, b, c),
        _ => return,
    };
    for (jj, yr) in y.chunks_exact(3).enumerate() {
        let start = cbo[jj] + ro;
        let Some(dst) = vals.get_mut(start..start + D2) else {
            continue;
        };
        let (y0, y1, y2) = (yr[0], yr[1], yr[2]);
        for ii in 0..D2 {
            dst[ii] -= y0 * v0[ii] + y1 * v1[ii] + y2 * v2[ii];
        }
    }
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
