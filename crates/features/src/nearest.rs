//! The scan of one block of brute-force scores ([`crate::matching`]): each row's two nearest
//! columns (for Lowe's ratio test) and each column's nearest row (for the mutual check), in one
//! pass over the block.
//!
//! A score `s = a·b` ranks the columns of a row by the key `2s − ‖b‖²` and the rows of a column by
//! `2s − ‖a‖²` (the squared distance is `‖a‖² + ‖b‖² − 2s`; larger keys are nearer). The block is
//! walked in tiles of [`TILE`] columns, each tile down all its rows, so that the tile's column
//! bests live in registers for the whole block instead of being loaded and stored once per row
//! (that streaming made the mutual check cost more than the products themselves: 25 % of
//! fountain-P11's matches stage in `perf`, against 18 % for the VNNI kernel). Every row still
//! sees its columns in increasing order and every column its rows, so ties resolve as a plain scan
//! resolves them: the first column, and the first row, win.
//!
//! Where brute force runs its AVX-512 VNNI kernel, the kernel does this scan itself on each
//! register tile before it leaves the registers (`quantized::scan_scores_grouped`), and a row's
//! two best are kept per lane of the tile ([`RowLanes`]) instead of behind a branch on the
//! row's second best: the low-texture set's matches stage 0.75 → 0.60 s. This module's scan
//! remains the AVX2, AVX-VNNI and portable paths' (on eight lanes the fused scan gained nothing).

/// The two nearest neighbours of a row, as keys `2·a·b − ‖b‖²` (larger is nearer).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Best2 {
    pub s1: f32,
    pub j1: u32,
    pub s2: f32,
}

impl Best2 {
    pub const NONE: Best2 = Best2 {
        s1: f32::NEG_INFINITY,
        j1: u32::MAX,
        s2: f32::NEG_INFINITY,
    };

    /// Offers column `j` with key `key`, in any order of columns: the same two best as
    /// [`Best2::offer`] given the same columns in increasing order (the first column of the
    /// largest key, and the second largest key).
    #[inline]
    pub(crate) fn offer_unordered(&mut self, key: f32, j: u32) {
        if key > self.s1 || (key == self.s1 && j < self.j1) {
            self.s2 = self.s1;
            self.s1 = key;
            self.j1 = j;
        } else if key > self.s2 {
            self.s2 = key;
        }
    }

    /// Offers column `j` with key `key`.
    #[inline]
    pub(crate) fn offer(&mut self, key: f32, j: u32) {
        if key > self.s2 {
            if key > self.s1 {
                self.s2 = self.s1;
                self.s1 = key;
                self.j1 = j;
            } else {
                self.s2 = key;
            }
        }
    }
}

/// A row's two nearest neighbours kept per lane of a 16-column tile: lane `l` sees the columns
/// `j ≡ l (mod 16)` in increasing order and keeps their two best keys and the first column of
/// the best ([`Best2::offer`] per lane), without a branch on the data. [`RowLanes::merge`] gives
/// the row's [`Best2`] over all its columns: the same as offering them in order to one `Best2`.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(64))]
pub(crate) struct RowLanes {
    pub b1: [f32; 16],
    pub b2: [f32; 16],
    pub j1: [u32; 16],
}

impl RowLanes {
    pub const NONE: RowLanes = RowLanes {
        b1: [f32::NEG_INFINITY; 16],
        b2: [f32::NEG_INFINITY; 16],
        j1: [u32::MAX; 16],
    };

    /// The row's two best over every lane: the largest key, the first column that has it (the
    /// smallest of the lanes' first columns with that key), and the second largest of all the
    /// keys offered (equal to the largest when two columns share it). The lanes' two best hold
    /// the two largest keys of the whole row, so this is what one `Best2` fed every column in
    /// order holds.
    pub fn merge(&self) -> Best2 {
        let mut out = Best2::NONE;
        let mut at = usize::MAX;
        for l in 0..16 {
            let (b1, j1) = (self.b1[l], self.j1[l]);
            if j1 == u32::MAX {
                continue;
            }
            if b1 > out.s1 || (b1 == out.s1 && j1 < out.j1) {
                out.s1 = b1;
                out.j1 = j1;
                at = l;
            }
        }
        if at == usize::MAX {
            return Best2::NONE;
        }
        let mut s2 = f32::NEG_INFINITY;
        for l in 0..16 {
            if self.j1[l] == u32::MAX {
                continue;
            }
            if l != at {
                s2 = s2.max(self.b1[l]);
            }
            s2 = s2.max(self.b2[l]);
        }
        out.s2 = s2;
        out
    }
}

/// Columns per tile: two AVX2 registers of keys and two of row indices, held across the rows.
const TILE: usize = 16;

/// One block of scores: `s` holds `rows × cols` scores row-major, for the rows `i0..i0 + rows`
/// (whose squared norms are `na`) and the columns `j0..j0 + cols` (squared norms `nb`).
pub(crate) struct Block<'a> {
    pub s: &'a [f32],
    pub rows: usize,
    pub cols: usize,
    pub i0: usize,
    pub j0: usize,
    pub na: &'a [f32],
    pub nb: &'a [f32],
}

/// Updates every row's two best (`best`, one per row of the block) and, when `cols_best` is given,
/// every column's best `(key, row)` so far (`cols_best.0[c]`, `cols_best.1[c]` for column
/// `j0 + c`), over `block`.
pub(crate) fn scan_block(
    block: &Block<'_>,
    best: &mut [Best2],
    mut cols_best: Option<(&mut [f32], &mut [u32])>,
) {
    let Block {
        s,
        rows,
        cols,
        i0,
        j0,
        na,
        nb,
    } = *block;
    assert!(s.len() >= rows * cols && best.len() >= rows && na.len() >= rows && nb.len() >= cols);
    if let Some((v, k)) = &cols_best {
        assert!(v.len() >= cols && k.len() >= cols);
    }
    let mut c0 = 0;
    while c0 < cols {
        let width = TILE.min(cols - c0);
        if width == TILE {
            let (cv, ci) = match &mut cols_best {
                Some((v, k)) => (Some(&mut v[c0..c0 + TILE]), Some(&mut k[c0..c0 + TILE])),
                None => (None, None),
            };
            let tile = Tile {
                s: &s[c0..],
                cols,
                nb: nb[c0..c0 + TILE].try_into().expect("a tile"),
                j: (j0 + c0) as u32,
            };
            scan_tile(&tile, &mut best[..rows], na, i0 as u32, cv.zip(ci));
        } else {
            for (r, bst) in best[..rows].iter_mut().enumerate() {
                let sr = &s[r * cols + c0..r * cols + c0 + width];
                for (c, (&sv, &nj)) in sr.iter().zip(&nb[c0..c0 + width]).enumerate() {
                    bst.offer(2.0 * sv - nj, (j0 + c0 + c) as u32);
                }
                if let Some((v, k)) = &mut cols_best {
                    let (ni, i) = (na[r], (i0 + r) as u32);
                    for (c, &sv) in sr.iter().enumerate() {
                        let key = 2.0 * sv - ni;
                        if key > v[c0 + c] {
                            v[c0 + c] = key;
                            k[c0 + c] = i;
                        }
                    }
                }
            }
        }
        c0 += width;
    }
}

/// One tile of [`TILE`] columns down the rows of a block: `s` starts at the tile's first column
/// of the first row (rows `cols` apart), `nb` are its columns' squared norms, `j` its first
/// column's index.
struct Tile<'a> {
    s: &'a [f32],
    cols: usize,
    nb: &'a [f32; TILE],
    j: u32,
}

impl Tile<'_> {
    /// Offers a row's `TILE` scores of this tile to its two bests, column by column.
    #[inline]
    fn offer_row(&self, bst: &mut Best2, scores: &[f32]) {
        for (c, (&sv, &nj)) in scores.iter().zip(self.nb).enumerate() {
            bst.offer(2.0 * sv - nj, self.j + c as u32);
        }
    }
}

/// [`scan_block`] over one full tile; `cols_best` the tile's column bests, updated.
#[inline]
fn scan_tile(
    tile: &Tile<'_>,
    best: &mut [Best2],
    na: &[f32],
    i0: u32,
    cols_best: Option<(&mut [f32], &mut [u32])>,
) {
    let rows = best.len();
    assert!(na.len() >= rows && (rows == 0 || tile.s.len() >= (rows - 1) * tile.cols + TILE));
    if let Some((v, k)) = &cols_best {
        assert!(v.len() >= TILE && k.len() >= TILE);
    }
    #[cfg(all(target_arch = "x86_64", target_feature = "avx2"))]
    if wide() {
        // SAFETY: `wide` holds only where the CPU has AVX-512 F; the asserts above cover every
        // load and store.
        unsafe { avx512::scan_tile(tile, best, na, i0, cols_best) }
    } else {
        // SAFETY: AVX2 is enabled at compile time; the asserts above cover every load and store.
        unsafe { avx2::scan_tile(tile, best, na, i0, cols_best) }
    }
    #[cfg(not(all(target_arch = "x86_64", target_feature = "avx2")))]
    portable_tile(tile, best, na, i0, cols_best)
}

/// Whether the scan runs on 512-bit registers: where brute force runs its AVX-512 VNNI kernel
/// (so `HANDHELD_SIMD=avx2` keeps the scan on AVX2 too). Decided once.
#[cfg(all(target_arch = "x86_64", target_feature = "avx2"))]
fn wide() -> bool {
    static WIDE: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *WIDE.get_or_init(|| crate::quantized::kernel() == crate::quantized::Kernel::Avx512Vnni)
}

/// [`scan_tile`] in plain Rust: the reference, and the path for CPUs built without AVX2.
#[cfg_attr(all(target_arch = "x86_64", target_feature = "avx2"), allow(dead_code))]
fn portable_tile(
    tile: &Tile<'_>,
    best: &mut [Best2],
    na: &[f32],
    i0: u32,
    mut cols_best: Option<(&mut [f32], &mut [u32])>,
) {
    for (r, bst) in best.iter_mut().enumerate() {
        let sr = &tile.s[r * tile.cols..r * tile.cols + TILE];
        // An OR of comparisons: most tiles hold nothing better than the row's second best.
        let s2 = bst.s2;
        let any = sr
            .iter()
            .zip(tile.nb)
            .fold(false, |a, (&sv, &nj)| a | (2.0 * sv - nj > s2));
        if any {
            for (c, (&sv, &nj)) in sr.iter().zip(tile.nb).enumerate() {
                bst.offer(2.0 * sv - nj, tile.j + c as u32);
            }
        }
        if let Some((v, k)) = &mut cols_best {
            let (ni, i) = (na[r], i0 + r as u32);
            for ((v, k), &sv) in v.iter_mut().zip(k.iter_mut()).zip(sr) {
                let key = 2.0 * sv - ni;
                if key > *v {
                    *v = key;
                    *k = i;
                }
            }
        }
    }
}

#[cfg(all(target_arch = "x86_64", target_feature = "avx2"))]
mod avx2 {
    use super::{Best2, Tile, TILE};
    use std::arch::x86_64::*;

    /// [`super::portable_tile`] on two registers of keys and two of row indices, held across
    /// the rows. `2s` is `s + s` (exact), and a row's test takes the larger of its two halves'
    /// keys (the scores and norms are finite, so `max(a, b) > t` is `a > t || b > t`).
    ///
    /// # Safety
    /// AVX2 must be available, and the lengths checked by [`super::scan_tile`] must hold.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn scan_tile(
        tile: &Tile<'_>,
        best: &mut [Best2],
        na: &[f32],
        i0: u32,
        cols_best: Option<(&mut [f32], &mut [u32])>,
    ) {
        let nb0 = _mm256_loadu_ps(tile.nb.as_ptr());
        let nb1 = _mm256_loadu_ps(tile.nb.as_ptr().add(8));
        let mutual = cols_best.is_some();
        let (mut v0, mut v1, mut k0, mut k1) = match &cols_best {
            Some((v, k)) => (
                _mm256_loadu_ps(v.as_ptr()),
                _mm256_loadu_ps(v.as_ptr().add(8)),
                _mm256_loadu_ps(k.as_ptr().cast()),
                _mm256_loadu_ps(k.as_ptr().add(8).cast()),
            ),
            None => (
                _mm256_setzero_ps(),
                _mm256_setzero_ps(),
                _mm256_setzero_ps(),
                _mm256_setzero_ps(),
            ),
        };
        let base = tile.s.as_ptr();
        for (r, bst) in best.iter_mut().enumerate() {
            let p = base.add(r * tile.cols);
            let x0 = _mm256_loadu_ps(p);
            let x1 = _mm256_loadu_ps(p.add(8));
            let t0 = _mm256_add_ps(x0, x0);
            let t1 = _mm256_add_ps(x1, x1);
            let rk = _mm256_max_ps(_mm256_sub_ps(t0, nb0), _mm256_sub_ps(t1, nb1));
            let gt = _mm256_cmp_ps::<_CMP_GT_OQ>(rk, _mm256_set1_ps(bst.s2));
            if _mm256_movemask_ps(gt) != 0 {
                tile.offer_row(bst, std::slice::from_raw_parts(p, TILE));
            }
            if mutual {
                let ni = _mm256_set1_ps(*na.get_unchecked(r));
                let idx = _mm256_castsi256_ps(_mm256_set1_epi32((i0 + r as u32) as i32));
                let c0 = _mm256_sub_ps(t0, ni);
                let c1 = _mm256_sub_ps(t1, ni);
                let g0 = _mm256_cmp_ps::<_CMP_GT_OQ>(c0, v0);
                let g1 = _mm256_cmp_ps::<_CMP_GT_OQ>(c1, v1);
                v0 = _mm256_blendv_ps(v0, c0, g0);
                v1 = _mm256_blendv_ps(v1, c1, g1);
                k0 = _mm256_blendv_ps(k0, idx, g0);
                k1 = _mm256_blendv_ps(k1, idx, g1);
            }
        }
        if let Some((v, k)) = cols_best {
            _mm256_storeu_ps(v.as_mut_ptr(), v0);
            _mm256_storeu_ps(v.as_mut_ptr().add(8), v1);
            _mm256_storeu_ps(k.as_mut_ptr().cast(), k0);
            _mm256_storeu_ps(k.as_mut_ptr().add(8).cast(), k1);
        }
    }
}

#[cfg(all(target_arch = "x86_64", target_feature = "avx2"))]
mod avx512 {
    use super::{Best2, Tile, TILE};
    use std::arch::x86_64::*;

    /// [`super::avx2::scan_tile`] on one 512-bit register of keys and one of row indices: the
    /// same comparisons in the same order (a row's test is any of its 16 keys above the second
    /// best; a column takes a row whose key is strictly larger), so the same result.
    ///
    /// # Safety
    /// AVX-512 F must be available, and the lengths checked by [`super::scan_tile`] must hold.
    #[target_feature(enable = "avx512f")]
    pub(super) unsafe fn scan_tile(
        tile: &Tile<'_>,
        best: &mut [Best2],
        na: &[f32],
        i0: u32,
        cols_best: Option<(&mut [f32], &mut [u32])>,
    ) {
        let nb = _mm512_loadu_ps(tile.nb.as_ptr());
        let mutual = cols_best.is_some();
        let (mut v, mut k) = match &cols_best {
            Some((v, k)) => (
                _mm512_loadu_ps(v.as_ptr()),
                _mm512_loadu_si512(k.as_ptr().cast()),
            ),
            None => (_mm512_setzero_ps(), _mm512_setzero_si512()),
        };
        let base = tile.s.as_ptr();
        for (r, bst) in best.iter_mut().enumerate() {
            let p = base.add(r * tile.cols);
            let x = _mm512_loadu_ps(p);
            let t = _mm512_add_ps(x, x);
            let rk = _mm512_sub_ps(t, nb);
            if _mm512_cmp_ps_mask::<_CMP_GT_OQ>(rk, _mm512_set1_ps(bst.s2)) != 0 {
                tile.offer_row(bst, std::slice::from_raw_parts(p, TILE));
            }
            if mutual {
                let c = _mm512_sub_ps(t, _mm512_set1_ps(*na.get_unchecked(r)));
                let g = _mm512_cmp_ps_mask::<_CMP_GT_OQ>(c, v);
                v = _mm512_mask_blend_ps(g, v, c);
                k = _mm512_mask_blend_epi32(g, k, _mm512_set1_epi32((i0 + r as u32) as i32));
            }
        }
        if let Some((vs, ks)) = cols_best {
            _mm512_storeu_ps(vs.as_mut_ptr(), v);
            _mm512_storeu_si512(ks.as_mut_ptr().cast(), k);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The plain scan: row by row, column by column.
    #[allow(clippy::needless_range_loop)]
    fn reference(block: &Block<'_>, best: &mut [Best2], cv: &mut [f32], ci: &mut [u32]) {
        for r in 0..block.rows {
            for c in 0..block.cols {
                let sv = block.s[r * block.cols + c];
                best[r].offer(2.0 * sv - block.nb[c], (block.j0 + c) as u32);
                let key = 2.0 * sv - block.na[r];
                if key > cv[c] {
                    cv[c] = key;
                    ci[c] = (block.i0 + r) as u32;
                }
            }
        }
    }

    #[test]
    fn the_tiled_scan_equals_the_plain_scan_ties_included() {
        let mut state = 7u64;
        let mut next = |m: u64| {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 33) % m
        };
        // Small integer scores and norms: many exact ties, as the quantised kernels give.
        for &(rows, cols) in &[(37, 53), (5, 16), (64, 96), (3, 7), (20, 33)] {
            let s: Vec<f32> = (0..rows * cols).map(|_| next(9) as f32).collect();
            let na: Vec<f32> = (0..rows).map(|_| next(4) as f32).collect();
            let nb: Vec<f32> = (0..cols).map(|_| next(4) as f32).collect();
            let block = Block {
                s: &s,
                rows,
                cols,
                i0: 100,
                j0: 2000,
                na: &na,
                nb: &nb,
            };
            // Carried in from an earlier block: some columns already hold a better row.
            let cv0: Vec<f32> = (0..cols)
                .map(|_| {
                    if next(3) == 0 {
                        17.0
                    } else {
                        f32::NEG_INFINITY
                    }
                })
                .collect();
            let ci0: Vec<u32> = cv0
                .iter()
                .map(|v| if v.is_finite() { 3 } else { u32::MAX })
                .collect();
            let best0: Vec<Best2> = (0..rows)
                .map(|_| Best2 {
                    s1: 12.0,
                    j1: 1,
                    s2: 11.0,
                })
                .collect();
            let (mut b1, mut v1, mut k1) = (best0.clone(), cv0.clone(), ci0.clone());
            reference(&block, &mut b1, &mut v1, &mut k1);
            let (mut b2, mut v2, mut k2) = (best0.clone(), cv0.clone(), ci0.clone());
            scan_block(&block, &mut b2, Some((&mut v2, &mut k2)));
            assert_eq!(b1, b2, "{rows}×{cols}");
            assert_eq!((v1, k1), (v2, k2), "{rows}×{cols}");
            // Without the mutual check, the rows alone.
            let mut b3 = best0.clone();
            scan_block(&block, &mut b3, None);
            assert_eq!(b1, b3);
            // Fresh rows pick up the block's own bests.
            let mut fresh = vec![Best2::NONE; rows];
            let (mut v4, mut k4) = (vec![f32::NEG_INFINITY; cols], vec![u32::MAX; cols]);
            let mut fresh_ref = fresh.clone();
            let (mut v5, mut k5) = (v4.clone(), k4.clone());
            reference(&block, &mut fresh_ref, &mut v5, &mut k5);
            scan_block(&block, &mut fresh, Some((&mut v4, &mut k4)));
            assert_eq!(fresh, fresh_ref);
            assert_eq!((v4, k4), (v5, k5));
        }
    }

    #[test]
    fn the_portable_tile_equals_the_vector_tile() {
        let (rows, cols) = (40, 48);
        let s: Vec<f32> = (0..rows * cols).map(|k| ((k * 7919) % 13) as f32).collect();
        let na: Vec<f32> = (0..rows).map(|r| (r % 5) as f32).collect();
        let nb: Vec<f32> = (0..cols).map(|c| (c % 3) as f32).collect();
        for c0 in (0..cols).step_by(TILE) {
            let tile = Tile {
                s: &s[c0..],
                cols,
                nb: nb[c0..c0 + TILE].try_into().unwrap(),
                j: c0 as u32,
            };
            let (mut b1, mut v1, mut k1) = (
                vec![Best2::NONE; rows],
                vec![f32::NEG_INFINITY; TILE],
                vec![u32::MAX; TILE],
            );
            let (mut b2, mut v2, mut k2) = (b1.clone(), v1.clone(), k1.clone());
            portable_tile(&tile, &mut b1, &na, 5, Some((&mut v1, &mut k1)));
            scan_tile(&tile, &mut b2, &na, 5, Some((&mut v2, &mut k2)));
            assert_eq!((&b1, &v1, &k1), (&b2, &v2, &k2));
            // Each vector tile the CPU has, whichever `scan_tile` chose.
            #[cfg(all(target_arch = "x86_64", target_feature = "avx2"))]
            {
                let (mut b3, mut v3, mut k3) = (
                    vec![Best2::NONE; rows],
                    vec![f32::NEG_INFINITY; TILE],
                    vec![u32::MAX; TILE],
                );
                // SAFETY: AVX2 is enabled at compile time; the tile covers `rows` rows of `cols`.
                unsafe { avx2::scan_tile(&tile, &mut b3, &na, 5, Some((&mut v3, &mut k3))) };
                assert_eq!((&b1, &v1, &k1), (&b3, &v3, &k3));
                if std::arch::is_x86_feature_detected!("avx512f") {
                    let (mut b4, mut v4, mut k4) = (
                        vec![Best2::NONE; rows],
                        vec![f32::NEG_INFINITY; TILE],
                        vec![u32::MAX; TILE],
                    );
                    // SAFETY: the CPU has AVX-512 F (checked); the same tile.
                    unsafe { avx512::scan_tile(&tile, &mut b4, &na, 5, Some((&mut v4, &mut k4))) };
                    assert_eq!((&b1, &v1, &k1), (&b4, &v4, &k4));
                }
            }
        }
    }
}

mod lanes2;
pub(crate) use lanes2::{scan_lanes2, RowLanes2};
