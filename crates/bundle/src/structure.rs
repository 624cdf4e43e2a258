//! The block layout of the reduced camera system, computed once per solve.
//!
//! Camera-side parameters are grouped in *blocks*: one per camera holding its free pose parameters
//! plus the free intrinsics of its group when no other camera uses that group (BAL's layout), and one
//! per shared intrinsics group with free parameters. Shared blocks come last so that their (dense)
//! rows of the reduced matrix are short. Each observation touches at most two blocks (its camera's and
//! its shared group's) and one point; a point's *incidences* are the distinct blocks its observations
//! touch, each carrying one `W` block of the Schur complement (Triggs et al. 2000, §6.1).

use crate::problem::{CameraModel, Problem};
use crate::residual::NUM_INTRINSICS;

pub(crate) const NONE: u32 = u32::MAX;
/// Columns of a camera's full Jacobian: metric 6 pose + the intrinsics, projective 11.
pub(crate) const MAX_FULL_COLS: usize = 6 + NUM_INTRINSICS;

/// Compressed rows: `ptr[i]..ptr[i + 1]` indexes `idx`.
#[derive(Clone, Debug, Default)]
pub(crate) struct Csr {
    pub ptr: Vec<usize>,
    pub idx: Vec<u32>,
}

impl Csr {
    #[inline]
    pub fn row(&self, i: usize) -> &[u32] {
        &self.idx[self.ptr[i]..self.ptr[i + 1]]
    }

    /// Groups `items` (row, value) by row, keeping their order within a row.
    fn from_pairs(rows: usize, items: impl Iterator<Item = (usize, u32)> + Clone) -> Self {
        let mut ptr = vec![0usize; rows + 1];
        for (r, _) in items.clone() {
            ptr[r + 1] += 1;
        }
        for i in 0..rows {
            ptr[i + 1] += ptr[i];
        }
        let mut fill = ptr.clone();
        let mut idx = vec![0u32; ptr[rows]];
        for (r, v) in items {
            idx[fill[r]] = v;
            fill[r] += 1;
        }
        Self { ptr, idx }
    }
}

#[derive(Clone, Debug)]
pub(crate) struct Structure {
    pub block_dim: Vec<usize>,
    /// First reduced index of each block; `num_reduced` in all.
    pub block_offset: Vec<usize>,
    pub num_reduced: usize,
    /// Per camera: its own block (or `NONE`), and the shared block of its group (or `NONE`).
    pub cam_block: Vec<u32>,
    pub cam_shared: Vec<u32>,
    /// Per camera: number of Jacobian columns in its own block and in the shared block.
    pub cam_ncols: Vec<(usize, usize)>,
    /// Per camera: full Jacobian column → compact column (`u8::MAX` when held constant).
    pub cam_colmap: Vec<[u8; MAX_FULL_COLS]>,
    /// Per camera: reduced index of its first pose parameter.
    pub cam_pose_at: Vec<Option<usize>>,
    /// Per group: reduced index of each free intrinsic parameter.
    pub group_param_at: Vec<[Option<usize>; NUM_INTRINSICS]>,
    /// Compact Jacobian columns stored per observation (the maximum over cameras).
    pub jstride: usize,
    /// Observations of each point.
    pub point_obs: Csr,
    /// Incidences of each point (values: block ids, sorted); the incidence index is the position in `idx`.
    pub point_inc: Csr,
    /// Per incidence: its point and the offset of its `W` block (`dim × 3`, column-major) in the W buffer.
    pub inc_point: Vec<u32>,
    pub inc_woff: Vec<usize>,
    pub w_len: usize,
    /// Per observation: incidence of its own block and of its shared block (`NONE` when absent).
    pub obs_inc: Vec<[u32; 2]>,
    /// Per block: the incidences that touch it (row assembly of the Schur complement).
    pub block_inc: Csr,
    /// Per block: observations whose camera-side Jacobian touches it.
    pub block_obs: Csr,
    /// Per block `b`: the blocks `b' > b` coupled to it in the reduced matrix, sorted.
    pub block_cols: Csr,
}

impl Structure {
    pub fn new(p: &Problem) -> Self {
        let nc = p.cameras.len();
        let metric = p.model == CameraModel::Metric;
        let ng = if metric { p.groups.len() } else { 0 };
        let mut group_users = vec![0usize; ng];
        if metric {
            for c in 0..nc {
                group_users[p.camera_group[c]] += 1;
            }
        }
        let nfree = |g: usize| p.group_free[g].iter().filter(|f| **f).count();
        let pose_cols = if metric { 6 } else { 11 };
        let mut block_dim = Vec::new();
        let mut cam_block = vec![NONE; nc];
        let mut cam_ncols = vec![(0, 0); nc];
        let mut cam_colmap = vec![[u8::MAX; MAX_FULL_COLS]; nc];
        let mut cam_pose_at = vec![None; nc];
        let mut group_param_at = vec![[None; NUM_INTRINSICS]; ng];
        // Own blocks first, in camera order.
        let mut offset = 0;
        for c in 0..nc {
            let mut cols = 0;
            if !p.camera_constant[c] {
                for (k, m) in cam_colmap[c].iter_mut().enumerate().take(pose_cols) {
                    *m = k as u8;
                }
                cam_pose_at[c] = Some(offset);
                cols = pose_cols;
            }
            if metric && group_users[p.camera_group[c]] == 1 {
                let g = p.camera_group[c];
                for k in 0..NUM_INTRINSICS {
                    if p.group_free[g][k] {
                        cam_colmap[c][6 + k] = cols as u8;
                        group_param_at[g][k] = Some(offset + cols);
                        cols += 1;
                    }
                }
            }
            if cols > 0 {
                cam_block[c] = block_dim.len() as u32;
                block_dim.push(cols);
                offset += cols;
            }
            cam_ncols[c].0 = cols;
        }
        // Shared intrinsics blocks last.
        let mut group_block = vec![NONE; ng];
        for g in 0..ng {
            if group_users[g] > 1 && nfree(g) > 0 {
                let mut cols = 0;
                for (at, &free) in group_param_at[g].iter_mut().zip(&p.group_free[g]) {
                    if free {
                        *at = Some(offset + cols);
                        cols += 1;
                    }
                }
                group_block[g] = block_dim.len() as u32;
                block_dim.push(cols);
                offset += cols;
            }
        }
        let mut cam_shared = vec![NONE; nc];
        if metric {
            for c in 0..nc {
                let g = p.camera_group[c];
                if group_block[g] != NONE {
                    cam_shared[c] = group_block[g];
                    let base = cam_ncols[c].0;
                    let mut cols = 0;
                    for k in 0..NUM_INTRINSICS {
                        if p.group_free[g][k] {
                            cam_colmap[c][6 + k] = (base + cols) as u8;
                            cols += 1;
                        }
                    }
                    cam_ncols[c].1 = cols;
                }
            }
        }
        let mut block_offset = Vec::with_capacity(block_dim.len());
        let mut acc = 0;
        for d in &block_dim {
            block_offset.push(acc);
            acc += d;
        }
        let nb = block_dim.len();
        let jstride = cam_ncols.iter().map(|(a, b)| a + b).max().unwrap_or(0);

        let no = p.num_observations();
        let np = p.points.len();
        let point_obs = Csr::from_pairs(np, (0..no).map(|o| (p.obs_point[o] as usize, o as u32)));
        // Incidences: distinct blocks per point, sorted.
        let mut inc_ptr = vec![0usize; np + 1];
        let mut inc_idx = Vec::new();
        let mut inc_point = Vec::new();
        let mut obs_inc = vec![[NONE; 2]; no];
        let mut scratch: Vec<u32> = Vec::new();
        for pt in 0..np {
            scratch.clear();
            for &o in point_obs.row(pt) {
                let c = p.obs_camera[o as usize] as usize;
                for b in [cam_block[c], cam_shared[c]] {
                    if b != NONE {
                        scratch.push(b);
                    }
                }
            }
            scratch.sort_unstable();
            scratch.dedup();
            let base = inc_idx.len();
            inc_idx.extend_from_slice(&scratch);
            inc_point.extend(std::iter::repeat_n(pt as u32, scratch.len()));
            inc_ptr[pt + 1] = inc_idx.len();
            for &o in point_obs.row(pt) {
                let c = p.obs_camera[o as usize] as usize;
                for (slot, b) in [cam_block[c], cam_shared[c]].into_iter().enumerate() {
                    if b != NONE {
                        let k = scratch.binary_search(&b).unwrap_or(0);
                        obs_inc[o as usize][slot] = (base + k) as u32;
                    }
                }
            }
        }
        let mut inc_woff = Vec::with_capacity(inc_idx.len());
        let mut w_len = 0;
        for &b in &inc_idx {
            inc_woff.push(w_len);
            w_len += 3 * block_dim[b as usize];
        }
        let point_inc = Csr {
            ptr: inc_ptr,
            idx: inc_idx,
        };
        let block_inc = Csr::from_pairs(
            nb,
            point_inc
                .idx
                .iter()
                .enumerate()
                .map(|(i, b)| (*b as usize, i as u32)),
        );
        let block_obs = Csr::from_pairs(
            nb,
            (0..no).flat_map(|o| {
                let c = p.obs_camera[o] as usize;
                [cam_block[c], cam_shared[c]]
                    .into_iter()
                    .filter(|b| *b != NONE)
                    .map(move |b| (b as usize, o as u32))
            }),
        );
        // Coupled blocks b' > b of each block row.
        let mut cols_ptr = vec![0usize; nb + 1];
        let mut cols_idx = Vec::new();
        let mut mark = vec![NONE; nb];
        for b in 0..nb {
            let start = cols_idx.len();
            for &i in block_inc.row(b) {
                let pt = inc_point[i as usize] as usize;
                for &b2 in point_inc.row(pt) {
                    if b2 as usize > b && mark[b2 as usize] != b as u32 {
                        mark[b2 as usize] = b as u32;
                        cols_idx.push(b2);
                    }
                }
            }
            cols_idx[start..].sort_unstable();
            cols_ptr[b + 1] = cols_idx.len();
        }
        Self {
            block_dim,
            block_offset,
            num_reduced: acc,
            cam_block,
            cam_shared,
            cam_ncols,
            cam_colmap,
            cam_pose_at,
            group_param_at,
            jstride,
            point_obs,
            point_inc,
            inc_point,
            inc_woff,
            w_len,
            obs_inc,
            block_inc,
            block_obs,
            block_cols: Csr {
                ptr: cols_ptr,
                idx: cols_idx,
            },
        }
    }

    pub fn num_blocks(&self) -> usize {
        self.block_dim.len()
    }

    /// Reduced index of compact Jacobian column `k` of an observation of camera `c`.
    #[inline]
    pub fn reduced_index(&self, c: usize, k: usize) -> usize {
        let (own, _) = self.cam_ncols[c];
        if k < own {
            self.block_offset[self.cam_block[c] as usize] + k
        } else {
            self.block_offset[self.cam_shared[c] as usize] + k - own
        }
    }
}
