//! Brute-force descriptor matching by matrix product, with Lowe's ratio test and a mutual-best check.
//!
//! For descriptor sets A (n×d) and B (m×d) the squared distances are `‖a‖² + ‖b‖² − 2·A·Bᵀ`, so the
//! whole search is one matrix product done in cache-sized blocks, parallel over row blocks,
//! followed by a linear scan that keeps each row's two nearest neighbours and each column's
//! nearest. The product is over descriptors quantised to bytes ([`crate::quantized`]): an 8-bit
//! integer kernel (AVX-512 VNNI) where the CPU has one, else an f32 GEMM (`matrixmultiply`) on the
//! same integer values, with the same result. For RootSIFT (unit L2 norm) this is `2 − 2·s`, the
//! Hellinger distance of Arandjelović & Zisserman (CVPR 2012). The ratio test is Lowe (IJCV 2004,
//! §7.1): accept the nearest neighbour when `d₁ < ratio · d₂`.
//!
//! **Coarse to fine** (the default for quantised 128-dimensional descriptors and more than
//! [`COARSE_MIN_COLUMNS`] columns; issue #34): the products over all 128 dimensions are most of
//! brute force's cost, and without AVX-512 VNNI they run at the integer multipliers' limit. So each
//! row first scans every column on 32 bytes, its descriptor's projections on the first 32
//! principal axes of RootSIFT ([`quantized::coarse_codes`]: 85 % of the descriptors' variance), and
//! keeps per lane of 16 columns its two best (`nearest::RowLanes2`, 32 candidates); then each candidate
//! is ranked on the full quantised descriptors, with the keys and ties of the full search. A
//! projection on orthonormal axes only shortens distances, so a row's nearest columns by code are
//! close to its nearest by descriptor, and both of the ratio test's neighbours are among the 32
//! unless two nearer columns share their lane. A column's best row is taken over the rows that
//! have it as a candidate. On the ten real sets' pairs the matches are those of the full search
//! but for a few in a thousand (a second neighbour missed, so a ratio test passed); the
//! full search stays behind `coarse_to_fine: false`. Every kernel gives the same matches either
//! way.
//!
//! Also here, because they decide which pairs are matched: [`sequential_pairs`] for video-like input
//! and [`exhaustive_pairs`] for unordered sets, and [`match_pairs`], parallel over pairs.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::detector::{Descriptors, Features};
use crate::error::{check, FeatureError};
use crate::nearest::{scan_block, Best2, Block, RowLanes};
use crate::quantized;

mod coarse;
mod prepared;
mod twins;
use coarse::coarse_to_fine;
pub use prepared::{prepare, Prepared};
use prepared::{prepare_with, Layout};
pub use twins::{distinct, TwinCache, Twins, SAME_PLACE_PX};

/// A correspondence between descriptor `i` of the first set and descriptor `j` of the second.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Match {
    pub i: u32,
    pub j: u32,
    /// Euclidean descriptor distance.
    pub distance: f32,
}

/// Options of [`match_descriptors`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MatchOptions {
    /// Lowe's ratio on distances: keep the nearest neighbour when `d₁ < ratio·d₂` (default 0.8; 1 or
    /// more disables the test).
    pub ratio: f32,
    /// Keep only matches that are also the nearest neighbour in the other direction (default true).
    pub mutual: bool,
    /// Largest accepted descriptor distance (default `None`: no limit). For RootSIFT distances are in [0, √2].
    pub max_distance: Option<f32>,
    /// Coarse to fine (default true): each descriptor's 32 candidates are found on 32 principal
    /// components of RootSIFT ([`quantized::coarse_codes`]) and ranked on all 128 dimensions,
    /// instead of all 128 dimensions over every column. Only for quantised 128-dimensional
    /// descriptors, with more than [`COARSE_MIN_COLUMNS`] columns; see the module notes.
    #[serde(default = "yes")]
    pub coarse_to_fine: bool,
}

fn yes() -> bool {
    true
}

/// Fewer columns than this are searched on the full descriptors alone: the coarse pass would keep
/// most of them as candidates.
pub const COARSE_MIN_COLUMNS: usize = 64;

impl Default for MatchOptions {
    fn default() -> Self {
        Self {
            ratio: 0.8,
            mutual: true,
            max_distance: None,
            coarse_to_fine: true,
        }
    }
}

impl MatchOptions {
    /// Checks the ratio and the distance limit; the error names the offending option.
    pub fn validate(&self) -> Result<(), FeatureError> {
        check(self.ratio.is_finite() && self.ratio > 0.0, "ratio", || {
            format!("must be positive and finite, got {}", self.ratio)
        })?;
        if let Some(d) = self.max_distance {
            check(d.is_finite() && d >= 0.0, "max_distance", || {
                format!("must be finite and ≥ 0, got {d}")
            })?;
        }
        Ok(())
    }
}

/// Rows of A per parallel task.
const ROW_BLOCK: usize = 256;
/// Columns of B per kernel call: the score block is `ROW_BLOCK × COL_BLOCK` floats, 256 KiB, so
/// that the scan reads it from the core's L2 cache (1 MiB blocks came from L3: fountain-P11's
/// matches stage 1.89 → 1.81 s, the low-texture set's 1.73 → 1.59 ms per pair; the scan's ties
/// resolve to the smallest index whatever the blocks, so the matches are the same).
const COL_BLOCK: usize = 256;

/// One row block's result: each row's two best, and each column's best `(score, row)` over the block.
type BlockResult = (Vec<Best2>, Vec<(f32, u32)>);

/// Matches every descriptor of `a` to its nearest neighbour in `b`, filtered by the ratio test, the
/// mutual check and `max_distance`. Returns matches sorted by `i`. Mismatched dimensions or invalid
/// options give no matches (with a warning).
pub fn match_descriptors(a: &Descriptors, b: &Descriptors, opts: &MatchOptions) -> Vec<Match> {
    match_with(a, b, opts, quantized::kernel())
}

/// [`match_descriptors`] with the given brute-force kernel (one the CPU has).
fn match_with(
    a: &Descriptors,
    b: &Descriptors,
    opts: &MatchOptions,
    kernel: quantized::Kernel,
) -> Vec<Match> {
    if a.dim != b.dim || a.dim == 0 || a.is_empty() || b.is_empty() {
        if a.dim != b.dim {
            tracing::warn!("descriptor dimensions differ: {} vs {}", a.dim, b.dim);
        }
        return Vec::new();
    }
    // Both quantised, or both raw when either does not fit.
    let quantise =
        quantized::fits(&a.data[..a.len() * a.dim]) && quantized::fits(&b.data[..b.len() * b.dim]);
    match_prepared(
        &prepare_with(a, kernel, quantise),
        &prepare_with(b, kernel, quantise),
        opts,
    )
}

/// [`match_descriptors`] on prepared sets (the same matches).
pub fn match_prepared(a: &Prepared, b: &Prepared, opts: &MatchOptions) -> Vec<Match> {
    if let Err(e) = opts.validate() {
        tracing::warn!("invalid match options: {e}");
        return Vec::new();
    }
    if a.d != b.d || a.d == 0 || a.is_empty() || b.is_empty() {
        if a.d != b.d {
            tracing::warn!("descriptor dimensions differ: {} vs {}", a.d, b.d);
        }
        return Vec::new();
    }
    if !a.alike(b) {
        // Prepared for different kernels (or one set not quantisable): both as raw f32 would
        // change the numbers, so this is a caller's error.
        tracing::warn!("descriptor sets prepared differently: no matches");
        return Vec::new();
    }
    if opts.coarse_to_fine && b.n > COARSE_MIN_COLUMNS {
        if let (Some(ca), Some(cb)) = (&a.coarse, &b.coarse) {
            let blocks = coarse_to_fine(a, b, ca, cb, opts.mutual);
            return select(a, b, &blocks, opts);
        }
    }
    let (n, m) = (a.n, b.n);
    let (na, nb) = (&a.norms, &b.norms);

    // Per row block: the rows' two best and, for the mutual check, each column's best row in this block.
    let blocks: Vec<BlockResult> = (0..n.div_ceil(ROW_BLOCK))
        .into_par_iter()
        .map(|blk| {
            let i0 = blk * ROW_BLOCK;
            let rows = ROW_BLOCK.min(n - i0);
            let mut best = vec![Best2::NONE; rows];
            let mcols = if opts.mutual { m } else { 0 };
            let (mut col_val, mut col_row) =
                (vec![f32::NEG_INFINITY; mcols], vec![u32::MAX; mcols]);
            // The AVX-512 VNNI kernel scans its register tiles itself: no score block.
            if let (Layout::Vnni { rows: Some(g), .. }, Layout::Vnni { packed, .. }) =
                (a.layout(), b.layout())
            {
                let sums = a.q().1;
                let mut lanes = vec![RowLanes::NONE; rows];
                for j0 in (0..m).step_by(COL_BLOCK) {
                    let cols = COL_BLOCK.min(m - j0);
                    let cols_best = opts
                        .mutual
                        .then(|| (&mut col_val[j0..j0 + cols], &mut col_row[j0..j0 + cols]));
                    quantized::scan_scores_grouped(
                        g,
                        (i0, rows),
                        sums,
                        packed,
                        j0,
                        cols,
                        &na[i0..i0 + rows],
                        &nb[j0..j0 + cols],
                        &mut lanes,
                        cols_best,
                    );
                }
                let best = lanes.iter().map(RowLanes::merge).collect();
                let col_best = col_val.into_iter().zip(col_row).collect();
                return (best, col_best);
            }
            let mut scorer = Scorer::new(a, b, i0, rows);
            for j0 in (0..m).step_by(COL_BLOCK) {
                let cols = COL_BLOCK.min(m - j0);
                let s = scorer.scores(j0, cols);
                let block = Block {
                    s,
                    rows,
                    cols,
                    i0,
                    j0,
                    na: &na[i0..i0 + rows],
                    nb: &nb[j0..j0 + cols],
                };
                let cols_best = opts
                    .mutual
                    .then(|| (&mut col_val[j0..j0 + cols], &mut col_row[j0..j0 + cols]));
                scan_block(&block, &mut best, cols_best);
            }
            let col_best = col_val.into_iter().zip(col_row).collect();
            (best, col_best)
        })
        .collect();
    select(a, b, &blocks, opts)
}

/// The score blocks of one row block (rows `i0..i0 + rows` of `a`) against column blocks of `b`,
/// by the kernel both were prepared for, for the paths that store a block before scanning it.
struct Scorer<'a> {
    a: &'a Prepared,
    b: &'a Prepared,
    i0: usize,
    rows: usize,
    /// The rows' layout for the AVX-VNNI kernel, made once for every column block.
    groups: Option<quantized::RowGroups>,
    scores: Vec<f32>,
}

impl<'a> Scorer<'a> {
    fn new(a: &'a Prepared, b: &'a Prepared, i0: usize, rows: usize) -> Self {
        let groups = match a.layout() {
            Layout::Vnni { wide, .. } => {
                Some(quantized::RowGroups::new(*wide, a.q().0, a.d, i0, rows))
            }
            _ => None,
        };
        Self {
            a,
            b,
            i0,
            rows,
            groups,
            scores: vec![0f32; rows * COL_BLOCK.min(b.n)],
        }
    }

    /// The `rows × cols` scores against columns `j0..j0 + cols` (`cols ≤ COL_BLOCK`), row-major.
    fn scores(&mut self, j0: usize, cols: usize) -> &[f32] {
        let (i0, rows, d) = (self.i0, self.rows, self.a.d);
        let s = &mut self.scores[..rows * cols];
        match (self.a.layout(), self.b.layout()) {
            (Layout::Vnni { .. }, Layout::Vnni { packed, .. }) => {
                if let Some(g) = &self.groups {
                    quantized::scores_block_grouped(g, self.a.q().1, packed, j0, cols, s)
                }
            }
            (Layout::Avx2(pa, _), Layout::Avx2(_, packed)) => {
                quantized::scores_block_avx2(pa, d, i0, rows, packed, j0, cols, s)
            }
            (Layout::Avx2Bytes(pa, _), Layout::Avx2Bytes(_, packed)) => {
                quantized::scores_block_avx2_bytes(
                    pa,
                    self.a.q().1,
                    d,
                    i0,
                    rows,
                    packed,
                    j0,
                    cols,
                    s,
                )
            }
            (Layout::F32(_), Layout::F32(_)) => gemm_abt(
                &self.a.f32_rows()[i0 * d..(i0 + rows) * d],
                &self.b.f32_rows()[j0 * d..(j0 + cols) * d],
                rows,
                cols,
                d,
                s,
            ),
            _ => unreachable!("checked by the caller: both sets prepared alike"),
        }
        s
    }
}

/// The matches from the row blocks' two bests and column bests: Lowe's ratio test, the mutual
/// check and the distance limit.
fn select(a: &Prepared, b: &Prepared, blocks: &[BlockResult], opts: &MatchOptions) -> Vec<Match> {
    let (na, unit) = (&a.norms, a.unit);
    let mut col_best = vec![(f32::NEG_INFINITY, u32::MAX); if opts.mutual { b.n } else { 0 }];
    for (_, cb) in blocks {
        // Blocks come in increasing row order, so strict `>` keeps the smallest row among ties.
        for (acc, &v) in col_best.iter_mut().zip(cb) {
            if v.0 > acc.0 {
                *acc = v;
            }
        }
    }
    let ratio2 = opts.ratio * opts.ratio;
    let mut out = Vec::new();
    for (blk, (best, _)) in blocks.iter().enumerate() {
        for (r, bst) in best.iter().enumerate() {
            let i = blk * ROW_BLOCK + r;
            if bst.j1 == u32::MAX {
                continue;
            }
            let d1 = (na[i] - bst.s1).max(0.0);
            if opts.ratio < 1.0 && bst.s2.is_finite() {
                let d2 = (na[i] - bst.s2).max(0.0);
                if d1 >= ratio2 * d2 {
                    continue;
                }
            }
            if opts.mutual && col_best[bst.j1 as usize].1 != i as u32 {
                continue;
            }
            let distance = d1.sqrt() / unit;
            if opts.max_distance.is_some_and(|t| distance > t) {
                continue;
            }
            out.push(Match {
                i: i as u32,
                j: bst.j1,
                distance,
            });
        }
    }
    out
}

/// `c (rows × cols) = a (rows × d) · bᵀ` for row-major `a`, `b` (cols × d) and `c`.
fn gemm_abt(a: &[f32], b: &[f32], rows: usize, cols: usize, d: usize, c: &mut [f32]) {
    assert!(a.len() >= rows * d && b.len() >= cols * d && c.len() >= rows * cols);
    // SAFETY: the asserted lengths cover every element addressed by the given shapes and strides
    // (a: rows×d with strides (d, 1); bᵀ: d×cols with strides (1, d); c: rows×cols with strides (cols, 1)),
    // and `c` is an exclusive borrow that does not alias `a` or `b`.
    unsafe {
        matrixmultiply::sgemm(
            rows,
            d,
            cols,
            1.0,
            a.as_ptr(),
            d as isize,
            1,
            b.as_ptr(),
            1,
            d as isize,
            0.0,
            c.as_mut_ptr(),
            cols as isize,
            1,
        );
    }
}

/// Matches the descriptors of each `(first, second)` pair of images, in parallel over pairs.
/// A pair naming a missing image gets no matches.
pub fn match_pairs(
    features: &[Features],
    pairs: &[(usize, usize)],
    opts: &MatchOptions,
) -> Vec<Vec<Match>> {
    pairs
        .par_iter()
        .map(|&(p, q)| match (features.get(p), features.get(q)) {
            (Some(fa), Some(fb)) => match_descriptors(&fa.descriptors, &fb.descriptors, opts),
            _ => Vec::new(),
        })
        .collect()
}

/// Pairs `(i, j)` with `i < j ≤ i + window` among `n` images in sequence order.
pub fn sequential_pairs(n: usize, window: usize) -> Vec<(usize, usize)> {
    (0..n)
        .flat_map(|i| {
            (i + 1..n.min(i.saturating_add(window).saturating_add(1))).map(move |j| (i, j))
        })
        .collect()
}

/// All pairs `(i, j)` with `i < j < n`.
pub fn exhaustive_pairs(n: usize) -> Vec<(usize, usize)> {
    sequential_pairs(n, n)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pair_helpers() {
        assert_eq!(
            sequential_pairs(4, 2),
            vec![(0, 1), (0, 2), (1, 2), (1, 3), (2, 3)]
        );
        assert_eq!(exhaustive_pairs(3), vec![(0, 1), (0, 2), (1, 2)]);
        assert!(sequential_pairs(1, 5).is_empty());
        assert_eq!(sequential_pairs(3, usize::MAX).len(), 3);
    }

    #[test]
    fn options_validate() {
        assert!(MatchOptions::default().validate().is_ok());
        assert!(MatchOptions {
            ratio: 0.0,
            ..Default::default()
        }
        .validate()
        .is_err());
        assert!(MatchOptions {
            max_distance: Some(-1.0),
            ..Default::default()
        }
        .validate()
        .is_err());
    }

    #[test]
    #[cfg_attr(
        not(has_vnni),
        ignore = "needs a CPU with AVX-512 VNNI (this one has none)"
    )]
    fn every_kernel_gives_the_same_matches() {
        assert!(quantized::cpu_has_vnni(), "this CPU has no AVX-512 VNNI");
        let (a, b) = planted();
        let o = MatchOptions::default();
        let x = match_with(&a, &b, &o, quantized::Kernel::Avx512Vnni);
        assert!(x.len() >= 250, "{} matches", x.len());
        let mut others = vec![quantized::Kernel::Portable];
        if quantized::cpu_has_avx2() {
            others.push(quantized::Kernel::Avx2);
        }
        if quantized::cpu_has_avx_vnni() {
            others.push(quantized::Kernel::AvxVnni);
        }
        let exact = MatchOptions {
            coarse_to_fine: false,
            ..o.clone()
        };
        let y = match_with(&a, &b, &exact, quantized::Kernel::Avx512Vnni);
        for k in others {
            assert_eq!(x, match_with(&a, &b, &o, k), "{k:?}, coarse to fine");
            assert_eq!(y, match_with(&a, &b, &exact, k), "{k:?}, full search");
        }
    }

    /// RootSIFT-like descriptors (non-negative, unit norm): 700 in `a`, 1 100 in `b`, of which the
    /// first 300 are noisy copies of `a`'s.
    fn planted() -> (Descriptors, Descriptors) {
        let mut s = 11u64;
        let mut rnd = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 40) as f32 / (1u64 << 24) as f32
        };
        let mut unit = |base: Option<&[f32]>| {
            let v: Vec<f32> = (0..128)
                .map(|k| {
                    base.map_or(0.0, |b| b[k]) + rnd() * if base.is_some() { 0.03 } else { 1.0 }
                })
                .collect();
            let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
            v.into_iter().map(|x| x / n).collect::<Vec<_>>()
        };
        let a: Vec<Vec<f32>> = (0..700).map(|_| unit(None)).collect();
        let b: Vec<Vec<f32>> = (0..1100)
            .map(|j| {
                if j < 300 {
                    unit(Some(&a[j]))
                } else {
                    unit(None)
                }
            })
            .collect();
        let flat = |v: &[Vec<f32>]| Descriptors {
            dim: 128,
            data: v.concat(),
        };
        (flat(&a), flat(&b))
    }

    /// Coarse to fine finds every planted match the full search finds, and nothing else here;
    /// below `COARSE_MIN_COLUMNS` columns the full search runs.
    #[test]
    fn coarse_to_fine_finds_what_the_full_search_finds() {
        let (a, b) = planted();
        let kernel = quantized::kernel();
        let full = MatchOptions {
            coarse_to_fine: false,
            ..Default::default()
        };
        let want = match_with(&a, &b, &full, kernel);
        let got = match_with(&a, &b, &MatchOptions::default(), kernel);
        let planted = |m: &[Match]| m.iter().filter(|m| m.i == m.j && m.i < 300).count();
        assert!(planted(&want) >= 290, "{} of 300", planted(&want));
        assert_eq!(got, want);
        let small = Descriptors {
            dim: 128,
            data: b.data[..40 * 128].to_vec(),
        };
        assert_eq!(
            match_with(&a, &small, &MatchOptions::default(), kernel),
            match_with(&a, &small, &full, kernel)
        );
    }
}
