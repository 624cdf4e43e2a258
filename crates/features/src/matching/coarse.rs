//! The coarse-to-fine search of [`super::match_prepared`] (see the module notes of
//! [`crate::matching`]): each row's 32 candidates found on the coarse codes, then ranked on the
//! full quantised descriptors.

use rayon::prelude::*;

use super::{BlockResult, Layout, Prepared, Scorer, COL_BLOCK, ROW_BLOCK};
use crate::nearest::{scan_lanes2, Best2, Block, RowLanes2};
use crate::quantized;

/// Coarse to fine: per row block, every row's 32 candidates by the coarse codes ([`RowLanes2`]),
/// then each candidate's key on the full quantised descriptors, offered in increasing column order
/// to the row's two best and (`mutual`) to the column's best row, as the exact search offers them,
/// so a candidate's key and the ties are the exact search's. A column's best row is taken over the
/// rows that have it as a candidate.
pub(super) fn coarse_to_fine(
    a: &Prepared,
    b: &Prepared,
    xa: &Prepared,
    xb: &Prepared,
    mutual: bool,
) -> Vec<BlockResult> {
    let (n, m, d) = (a.n, b.n, a.d);
    (0..n.div_ceil(ROW_BLOCK))
        .into_par_iter()
        .map(|blk| {
            let i0 = blk * ROW_BLOCK;
            let rows = ROW_BLOCK.min(n - i0);
            let mut lanes = vec![RowLanes2::NONE; rows];
            if let (Layout::Vnni { rows: Some(g), .. }, Layout::Vnni { packed, .. }) =
                (xa.layout(), xb.layout())
            {
                let sums = xa.q().1;
                for j0 in (0..m).step_by(COL_BLOCK) {
                    let cols = COL_BLOCK.min(m - j0);
                    quantized::scan_lanes2_grouped(
                        g,
                        (i0, rows),
                        sums,
                        packed,
                        j0,
                        cols,
                        &xb.norms[j0..j0 + cols],
                        &mut lanes,
                    );
                }
            } else {
                let mut scorer = Scorer::new(xa, xb, i0, rows);
                for j0 in (0..m).step_by(COL_BLOCK) {
                    let cols = COL_BLOCK.min(m - j0);
                    let block = Block {
                        s: scorer.scores(j0, cols),
                        rows,
                        cols,
                        i0,
                        j0,
                        na: &xa.norms[i0..i0 + rows],
                        nb: &xb.norms[j0..j0 + cols],
                    };
                    scan_lanes2(&block, &mut lanes);
                }
            }
            let mut best = vec![Best2::NONE; rows];
            let mut col_best = vec![(f32::NEG_INFINITY, u32::MAX); if mutual { m } else { 0 }];
            let ranking = Ranking {
                a,
                b,
                i0,
                lanes: &lanes,
            };
            match a.kernel {
                quantized::Kernel::Avx512Vnni if quantized::cpu_has_vnni() => {
                    // SAFETY: the CPU has AVX-512 VNNI (checked just above).
                    #[cfg(target_arch = "x86_64")]
                    unsafe {
                        ranking.run_vnni(&mut best, mutual.then_some(&mut col_best[..]))
                    }
                }
                _ => {
                    let (qa, qb) = (a.q().0, b.q().0);
                    ranking.run(&mut best, mutual.then_some(&mut col_best[..]), |i, j| {
                        dot_u8(&qa[i * d..(i + 1) * d], &qb[j * d..(j + 1) * d])
                    })
                }
            }
            (best, col_best)
        })
        .collect()
}

/// The fine pass of coarse-to-fine matching over one row block: every row's candidates
/// ([`RowLanes2`]) ranked on the full quantised descriptors.
struct Ranking<'a> {
    a: &'a Prepared,
    b: &'a Prepared,
    i0: usize,
    lanes: &'a [RowLanes2],
}

impl Ranking<'_> {
    /// Offers every row's candidates, with their keys on the full descriptors (`dot(i, j)`, the
    /// exact integer product), to the row's two best in any order ([`Best2::offer_unordered`]:
    /// the same two best as the exact search's, given the same columns) and (`col_best`) to each
    /// candidate column's best row, rows in increasing order with strict `>` as the exact search
    /// offers them, so the first of equal rows stays.
    #[inline(always)]
    fn run(
        &self,
        best: &mut [Best2],
        mut col_best: Option<&mut [(f32, u32)]>,
        dot: impl Fn(usize, usize) -> u32,
    ) {
        let (na, nb) = (&self.a.norms, &self.b.norms);
        for (r, (ln, bst)) in self.lanes.iter().zip(best).enumerate() {
            let i = self.i0 + r;
            for &j in ln.j1.iter().chain(&ln.j2) {
                if j == u32::MAX {
                    continue;
                }
                let jj = j as usize;
                let twice = 2.0 * dot(i, jj) as f32;
                bst.offer_unordered(twice - nb[jj], j);
                if let Some(cb) = col_best.as_deref_mut() {
                    let key = twice - na[i];
                    let c = &mut cb[jj];
                    *c = if key > c.0 { (key, i as u32) } else { *c };
                }
            }
        }
    }

    /// [`Ranking::run`] with the products by AVX-512 VNNI, sixteen candidates at a time
    /// ([`quantized::dots16`]).
    ///
    /// # Safety
    /// The CPU must have AVX-512 F/BW/VNNI.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx512bw,avx512vnni")]
    unsafe fn run_vnni(&self, best: &mut [Best2], mut col_best: Option<&mut [(f32, u32)]>) {
        let d = self.a.d;
        let ((qa, sums), qb) = (self.a.q(), self.b.q().0);
        let (na, nb) = (&self.a.norms, &self.b.norms);
        for (r, (ln, bst)) in self.lanes.iter().zip(best).enumerate() {
            let i = self.i0 + r;
            let row = &qa[i * d..(i + 1) * d];
            // SAFETY: the CPU has AVX-512 VNNI (the caller's contract).
            let (s1, s2) = unsafe {
                (
                    quantized::dots16(row, sums[i], qb, &ln.j1),
                    quantized::dots16(row, sums[i], qb, &ln.j2),
                )
            };
            for (&j, &s) in ln.j1.iter().chain(&ln.j2).zip(s1.iter().chain(&s2)) {
                if j == u32::MAX {
                    continue;
                }
                let jj = j as usize;
                let twice = 2.0 * s as f32;
                bst.offer_unordered(twice - nb[jj], j);
                if let Some(cb) = col_best.as_deref_mut() {
                    let key = twice - na[i];
                    let c = &mut cb[jj];
                    *c = if key > c.0 { (key, i as u32) } else { *c };
                }
            }
        }
    }
}

/// `a · b` of two byte vectors, exact (128 · 255² < 2²⁴, so exact in f32 as well).
#[inline]
fn dot_u8(a: &[u8], b: &[u8]) -> u32 {
    #[cfg(all(target_arch = "x86_64", target_feature = "avx2"))]
    if a.len() == b.len() && a.len().is_multiple_of(16) {
        use std::arch::x86_64::*;
        // SAFETY: AVX2 is enabled at compile time; every load reads 16 bytes inside `a` and `b`
        // (equal lengths, a multiple of 16).
        unsafe {
            let mut acc = _mm256_setzero_si256();
            for k in (0..a.len()).step_by(16) {
                let x = _mm256_cvtepu8_epi16(_mm_loadu_si128(a.as_ptr().add(k).cast()));
                let y = _mm256_cvtepu8_epi16(_mm_loadu_si128(b.as_ptr().add(k).cast()));
                acc = _mm256_add_epi32(acc, _mm256_madd_epi16(x, y));
            }
            let h = _mm_add_epi32(
                _mm256_castsi256_si128(acc),
                _mm256_extracti128_si256(acc, 1),
            );
            let h = _mm_add_epi32(h, _mm_shuffle_epi32(h, 0b01_00_11_10));
            let h = _mm_add_epi32(h, _mm_shuffle_epi32(h, 0b10_11_00_01));
            return _mm_cvtsi128_si32(h) as u32;
        }
    }
    a.iter()
        .zip(b)
        .map(|(&x, &y)| u32::from(x) * u32::from(y))
        .sum()
}
