//! Assembly of the reduced camera system `S = U − W V⁻¹ Wᵀ` and `bc − W V⁻¹ bp` (Triggs et al.
//! 2000, §6.1 eqs. 6.1–6.3), into the storage of [`ReducedMatrix`].
//!
//! Point by point ([`assemble_by_points`]) where the points' products outweigh the accumulators:
//! each point's blocks are read once, in storage order, and summed into its range's accumulator;
//! block row by block row ([`assemble_by_rows`]) otherwise, each worker owning whole rows.

use nalgebra::Matrix3;
use rayon::prelude::*;

use crate::problem::Problem;
use crate::schur::{js, split_by, Linearization, ReducedMatrix};
use crate::structure::Structure;

/// The reduced matrix assembled point by point (see [`assemble_by_points`]): the points are cut
/// into ranges of about equal work, fixed by the problem alone (not by the thread count, so that
/// the sums, and with them the run, are the same on every machine); each range is summed into
/// its own accumulator, and the ranges are added in order.
#[derive(Default)]
pub(crate) struct PointChunks {
    /// `bounds[k]..bounds[k + 1]` are the points of range `k`; empty when fewer than two ranges
    /// would pay for their accumulators ([`assemble_by_rows`] then).
    pub(crate) bounds: Vec<usize>,
    /// Per reduced column `c` of block `b`: where row `off(b) + i` of its diagonal block sits in
    /// an accumulator, less `i`, and where the rows of a coupled block `b' > b` begin, less that
    /// block's base (`block_offset[b']` when dense, its [`ReducedMatrix::rowoff`] when sparse).
    col_diag: Vec<usize>,
    col_off: Vec<usize>,
    /// Length of the matrix part of an accumulator: the packed lower triangle when dense, the
    /// values when sparse. The right-hand side (`n`) follows it.
    len: usize,
    /// Per range: its accumulator.
    acc: Vec<Vec<f64>>,
}

/// A range's products (about `(Σ dims)²` per point) must outweigh zeroing and adding its
/// accumulator this many times over; a problem that cannot fill two such ranges (a long walk of
/// views that each see a few of the points: a large, mostly empty matrix) is assembled by rows.
const WORK_PER_VALUE: usize = 32;
/// At most this many ranges (parallelism of the assembly).
const MAX_RANGES: usize = 16;
/// The accumulators together stay under this many values (128 MB).
const MAX_ACCUMULATOR_VALUES: usize = 16 << 20;

impl PointChunks {
    pub(crate) fn new(st: &Structure, m: &ReducedMatrix) -> Self {
        let n = st.num_reduced;
        let nb = st.num_blocks();
        let (mut col_diag, mut col_off) = (vec![0; n], vec![0; n]);
        let len = if m.dense {
            // Packed lower triangle: column `c` holds rows `c..n` from `c n − c (c − 1) / 2`.
            for b in 0..nb {
                let off = st.block_offset[b];
                for jj in 0..st.block_dim[b] {
                    let c = off + jj;
                    let base = c * n - c * c.saturating_sub(1) / 2 - c;
                    col_diag[c] = base + off;
                    col_off[c] = base;
                }
            }
            n * (n + 1) / 2
        } else {
            for b in 0..nb {
                let off = st.block_offset[b];
                for jj in 0..st.block_dim[b] {
                    col_diag[off + jj] = m.chunk_start[b] + m.cb_diag[off + jj];
                    col_off[off + jj] = m.chunk_start[b] + m.cb_off[off + jj];
                }
            }
            m.values.len()
        };
        let np = st.point_inc.ptr.len().saturating_sub(1);
        // Work of a point: its incidence pairs, weighted by their block sizes.
        let work = |pt: usize| {
            let dims: usize = st
                .point_inc
                .row(pt)
                .iter()
                .map(|b| st.block_dim[*b as usize])
                .sum();
            dims * dims + 1
        };
        let total: usize = (0..np).map(work).sum();
        let size = (len + n).max(1);
        let ranges = (total / (WORK_PER_VALUE * size))
            .min(MAX_RANGES)
            .min(MAX_ACCUMULATOR_VALUES / size);
        let mut bounds = Vec::new();
        if ranges >= 2 {
            bounds.push(0);
            let mut acc = 0;
            for pt in 0..np {
                acc += work(pt);
                if acc * ranges >= total * bounds.len() && bounds.len() < ranges {
                    bounds.push(pt + 1);
                }
            }
            bounds.push(np);
            bounds.dedup();
        }
        Self {
            bounds,
            col_diag,
            col_off,
            len,
            acc: Vec::new(),
        }
    }
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
    if m.points.bounds.is_empty() {
        assemble_by_rows(p, st, lin, vinv, extra_diag, m, rhs);
    } else {
        assemble_by_points(p, st, lin, vinv, extra_diag, m, rhs);
    }
}

/// `S` point by point. Each point's `W` blocks and `V⁻¹` are read once, in storage order, and its
/// whole `W V⁻¹ Wᵀ` is added to its range's accumulator. The block-row order of
/// [`assemble_by_rows`] reads every point once per camera that sees it, from wherever its blocks
/// lie, and spent most of its time waiting on memory.
fn assemble_by_points(
    p: &Problem,
    st: &Structure,
    lin: &Linearization,
    vinv: &[Matrix3<f64>],
    extra_diag: &[f64],
    m: &mut ReducedMatrix,
    rhs: &mut [f64],
) {
    let n = m.n;
    let dense = m.dense;
    let pc = &mut m.points;
    let len = pc.len;
    let ranges = pc.bounds.len().saturating_sub(1);
    pc.acc.resize_with(ranges, Vec::new);
    let js = js(st);
    let (col_diag, col_off, bounds) = (&pc.col_diag, &pc.col_off, &pc.bounds);
    let (rowoff, block_cols) = (&m.rowoff, &st.block_cols);
    // Where the rows of block `b2 > b` begin in the columns of block `b` (less `col_off`).
    let row_base = |b: usize, b2: usize| -> usize {
        if dense {
            return st.block_offset[b2];
        }
        let row = block_cols.row(b);
        match row.binary_search(&(b2 as u32)) {
            Ok(q) => rowoff[block_cols.ptr[b] + q],
            Err(_) => usize::MAX,
        }
    };
    pc.acc.par_iter_mut().enumerate().for_each(|(k, acc)| {
        acc.clear();
        acc.resize(len + n, 0.0);
        let (s_acc, r_acc) = acc.split_at_mut(len);
        let mut y: Vec<f64> = Vec::new();
        let range = bounds[k]..bounds[k + 1];
        for (pt, (vi, bpp)) in range
            .clone()
            .zip(vinv[range.clone()].iter().zip(&lin.bp[range]))
        {
            // U = Σ Jcᵀ Jc over the point's observations (each camera's own block, its shared
            // block, and the shared rows against the own columns: shared blocks come last).
            for &o in st.point_obs.row(pt) {
                let o = o as usize;
                let c = p.obs_camera[o] as usize;
                let (own, sh) = st.cam_ncols[c];
                let cols = &lin.jc[o * js..o * js + own + sh];
                let ob = (own > 0).then(|| st.cam_block[c] as usize);
                let sb = (sh > 0).then(|| st.cam_shared[c] as usize);
                for (lo, hi, blk) in [(0, own, ob), (own, own + sh, sb)] {
                    let Some(blk) = blk else { continue };
                    let off = st.block_offset[blk];
                    for jj in lo..hi {
                        let base = col_diag[off + jj - lo];
                        let cj = cols[jj];
                        for ii in jj..hi {
                            s_acc[base + ii - lo] += cj[0] * cols[ii][0] + cj[1] * cols[ii][1];
                        }
                    }
                }
                if let (Some(ob), Some(sb)) = (ob, sb) {
                    let (off, rb) = (st.block_offset[ob], row_base(ob, sb));
                    for jj in 0..own {
                        let base = col_off[off + jj] + rb;
                        let cj = cols[jj];
                        for ii in 0..sh {
                            s_acc[base + ii] +=
                                cj[0] * cols[own + ii][0] + cj[1] * cols[own + ii][1];
                        }
                    }
                }
            }
            // − W V⁻¹ Wᵀ and − W V⁻¹ bp: Y = W V⁻¹ for every incidence, then every pair.
            let incs = st.point_inc.ptr[pt]..st.point_inc.ptr[pt + 1];
            if incs.is_empty() {
                continue;
            }
            let last = st.point_inc.idx[incs.end - 1] as usize;
            let w0 = st.inc_woff[incs.start];
            let wlen = st.inc_woff[incs.end - 1] + 3 * st.block_dim[last] - w0;
            let wpt = &lin.w[w0..w0 + wlen];
            y.clear();
            y.resize(wlen, 0.0);
            for i in incs.clone() {
                let b = st.point_inc.idx[i] as usize;
                let (off, d) = (st.block_offset[b], st.block_dim[b]);
                let at = st.inc_woff[i] - w0;
                let wi = &wpt[at..at + 3 * d];
                let yi = &mut y[at..at + 3 * d];
                for jj in 0..d {
                    let (a0, a1, a2) = (wi[jj], wi[d + jj], wi[2 * d + jj]);
                    let mut yr = [0.0; 3];
                    for (t, v) in yr.iter_mut().enumerate() {
                        *v = a0 * vi[(0, t)] + a1 * vi[(1, t)] + a2 * vi[(2, t)];
                    }
                    yi[3 * jj..3 * jj + 3].copy_from_slice(&yr);
                    r_acc[off + jj] -= yr[0] * bpp[0] + yr[1] * bpp[1] + yr[2] * bpp[2];
                }
            }
            for i in incs.clone() {
                let b = st.point_inc.idx[i] as usize;
                let (off, d) = (st.block_offset[b], st.block_dim[b]);
                let at = st.inc_woff[i] - w0;
                let yi = &y[at..at + 3 * d];
                let wi = &wpt[at..at + 3 * d];
                let diag = &col_diag[off..off + d];
                match d {
                    6 => sub_diag::<6>(s_acc, diag, yi, wi),
                    9 => sub_diag::<9>(s_acc, diag, yi, wi),
                    11 => sub_diag::<11>(s_acc, diag, yi, wi),
                    _ => {
                        for jj in 0..d {
                            let start = diag[jj] + jj;
                            axpy3(
                                &mut s_acc[start..start + d - jj],
                                &yi[3 * jj..3 * jj + 3],
                                &wi[jj..d],
                                &wi[d + jj..2 * d],
                                &wi[2 * d + jj..],
                            );
                        }
                    }
                }
                for i2 in i + 1..incs.end {
                    let b2 = st.point_inc.idx[i2] as usize;
                    let d2 = st.block_dim[b2];
                    let at2 = st.inc_woff[i2] - w0;
                    let wj = &wpt[at2..at2 + 3 * d2];
                    let rb = row_base(b, b2);
                    let cols = &col_off[off..off + d];
                    match (d, d2) {
                        (6, 6) => sub_square::<6>(s_acc, cols, rb, yi, wj),
                        (9, 9) => sub_square::<9>(s_acc, cols, rb, yi, wj),
                        (11, 11) => sub_square::<11>(s_acc, cols, rb, yi, wj),
                        (_, 6) => sub_block::<6>(s_acc, cols, rb, yi, wj),
                        (_, 9) => sub_block::<9>(s_acc, cols, rb, yi, wj),
                        (_, 11) => sub_block::<11>(s_acc, cols, rb, yi, wj),
                        _ => {
                            let (v0, v1, v2) = (&wj[..d2], &wj[d2..2 * d2], &wj[2 * d2..]);
                            for (jj, col) in cols.iter().enumerate() {
                                let Some(dst) = s_acc.get_mut(col + rb..col + rb + d2) else {
                                    continue;
                                };
                                axpy3(dst, &yi[3 * jj..3 * jj + 3], v0, v1, v2);
                            }
                        }
                    }
                }
            }
        }
    });
    // The ranges added in order.
    let accs = &pc.acc;
    if dense {
        // Unpacked column by column; the upper triangle is left at zero.
        m.values
            .par_chunks_mut(n.max(1))
            .enumerate()
            .for_each(|(c, col)| {
                col[..c].fill(0.0);
                for (r, v) in col.iter_mut().enumerate().skip(c) {
                    *v = accs.iter().map(|a| a[col_off[c] + r]).sum();
                }
            });
    } else {
        m.values
            .par_chunks_mut(4096)
            .enumerate()
            .for_each(|(q, vals)| {
                let start = q * 4096;
                for (k, v) in vals.iter_mut().enumerate() {
                    *v = accs.iter().map(|a| a[start + k]).sum();
                }
            });
    }
    for b in 0..st.num_blocks() {
        let off = st.block_offset[b];
        for jj in 0..st.block_dim[b] {
            let c = off + jj;
            let at = if dense { c * n + c } else { col_diag[c] + jj };
            m.values[at] += extra_diag[c];
        }
    }
    for (k, r) in rhs.iter_mut().enumerate() {
        *r = lin.bc[k] + accs.iter().map(|a| a[len + k]).sum::<f64>();
    }
}

/// `−Y Wᵀ` for a `D × D` block (both sizes known: unrolled, in registers).
#[inline(always)]
fn sub_square<const D: usize>(acc: &mut [f64], cols: &[usize], rb: usize, y: &[f64], w: &[f64]) {
    let (Some(cols), Some(y), Some(w)) = (cols.get(..D), y.get(..3 * D), w.get(..3 * D)) else {
        return;
    };
    let (v0, v1, v2) = (&w[..D], &w[D..2 * D], &w[2 * D..]);
    for jj in 0..D {
        let start = cols[jj] + rb;
        let Some(dst) = acc.get_mut(start..start + D) else {
            continue;
        };
        let (y0, y1, y2) = (y[3 * jj], y[3 * jj + 1], y[3 * jj + 2]);
        for ii in 0..D {
            dst[ii] -= y0 * v0[ii] + y1 * v1[ii] + y2 * v2[ii];
        }
    }
}

/// The lower triangle of `−Y Wᵀ` for a diagonal `D × D` block whose columns' diagonal-block rows
/// start at `diag`.
#[inline(always)]
fn sub_diag<const D: usize>(acc: &mut [f64], diag: &[usize], y: &[f64], w: &[f64]) {
    let (Some(diag), Some(y), Some(w)) = (diag.get(..D), y.get(..3 * D), w.get(..3 * D)) else {
        return;
    };
    let (v0, v1, v2) = (&w[..D], &w[D..2 * D], &w[2 * D..]);
    for jj in 0..D {
        let Some(dst) = acc.get_mut(diag[jj]..diag[jj] + D) else {
            continue;
        };
        let (y0, y1, y2) = (y[3 * jj], y[3 * jj + 1], y[3 * jj + 2]);
        for ii in jj..D {
            dst[ii] -= y0 * v0[ii] + y1 * v1[ii] + y2 * v2[ii];
        }
    }
}

/// `−Y Wᵀ` into an accumulator for a block of `D2` rows, under the columns whose row starts are
/// `cols` (plus `rb`).
#[inline(always)]
fn sub_block<const D2: usize>(acc: &mut [f64], cols: &[usize], rb: usize, y: &[f64], w: &[f64]) {
    let (v0, v1, v2): (&[f64; D2], &[f64; D2], &[f64; D2]) = match (
        w[..D2].try_into(),
        w[D2..2 * D2].try_into(),
        w[2 * D2..3 * D2].try_into(),
    ) {
        (Ok(a), Ok(b), Ok(c)) => (a, b, c),
        _ => return,
    };
    for (yr, col) in y.chunks_exact(3).zip(cols) {
        let Some(dst) = acc.get_mut(col + rb..col + rb + D2) else {
            continue;
        };
        let (y0, y1, y2) = (yr[0], yr[1], yr[2]);
        for ii in 0..D2 {
            dst[ii] -= y0 * v0[ii] + y1 * v1[ii] + y2 * v2[ii];
        }
    }
}

/// The reduced matrix block row by block row: each worker owns whole rows, so no accumulators
/// (the sparse pattern, whose copies per worker could be large).
fn assemble_by_rows(
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
                                3 => sub_block::<3>(vals, cbo, ro, &y[..3 * d], wj),
                                6 => sub_block::<6>(vals, cbo, ro, &y[..3 * d], wj),
                                9 => sub_block::<9>(vals, cbo, ro, &y[..3 * d], wj),
                                11 => sub_block::<11>(vals, cbo, ro, &y[..3 * d], wj),
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::loss::RobustLoss;
    use crate::metric::{metric_problem, IntrinsicsMask, MetricBundleConfig};
    use crate::schur::{invert_points, linearize};
    use handheld_testkit::multiview::{multi_view_set, MultiViewOptions};

    /// The point-by-point assembly gives the block-row one's matrix and right-hand side, with
    /// shared intrinsics, per-camera intrinsics and a held view, under a robust loss.
    #[test]
    fn point_and_row_assembly_agree() {
        for shared in [true, false] {
            let set = multi_view_set(&MultiViewOptions {
                num_views: 9,
                num_points: 3000,
                noise_px: 0.5,
                outlier_fraction: 0.05,
                radial_distortion: true,
                shared_intrinsics: shared,
                seed: 3,
                ..Default::default()
            })
            .expect("valid options");
            let config = MetricBundleConfig {
                refine: IntrinsicsMask::focal_and_radial(),
                ..Default::default()
            };
            let (p, _) = metric_problem(&set.reconstruction, &config).expect("a problem");
            let st = Structure::new(&p);
            let lin = linearize(&p, &st, &RobustLoss::Huber(1.0));
            let mu_p = vec![1e-3; 3 * lin.v.len()];
            let vinv = invert_points(&lin, &mu_p);
            let extra: Vec<f64> = (0..st.num_reduced).map(|k| 1e-2 * (k + 1) as f64).collect();
            for dense in [true, false] {
                let mut by_points = ReducedMatrix::new(&st, dense);
                let mut by_rows = ReducedMatrix::new(&st, dense);
                assert!(by_points.points.bounds.len() > 2, "more than one range");
                let (mut r1, mut r2) = (vec![0.0; st.num_reduced], vec![0.0; st.num_reduced]);
                assemble_by_points(&p, &st, &lin, &vinv, &extra, &mut by_points, &mut r1);
                assemble_by_rows(&p, &st, &lin, &vinv, &extra, &mut by_rows, &mut r2);
                let scale = by_rows.values.iter().fold(0.0f64, |a, v| a.max(v.abs()));
                let n = st.num_reduced;
                for (k, (a, b)) in by_points.values.iter().zip(&by_rows.values).enumerate() {
                    // Dense: the lower triangle (the row order leaves the upper one as it was).
                    if dense && k % n < k / n {
                        continue;
                    }
                    assert!(
                        (a - b).abs() <= 1e-12 * scale,
                        "S[{k}] ({dense}): {a} against {b}"
                    );
                }
                let rscale = r2.iter().fold(0.0f64, |a, v| a.max(v.abs()));
                for (a, b) in r1.iter().zip(&r2) {
                    assert!((a - b).abs() <= 1e-12 * rscale, "rhs: {a} against {b}");
                }
            }
        }
    }
}
