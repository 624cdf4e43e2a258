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
                #[cfg(target_arch = "x86_64")]
                quantized::Kernel::Avx512Vnni if quantized::cpu_has_vnni() => {
                    let mut cols = mutual.then(|| ColBest::new(m));
                    // SAFETY: the CPU has AVX-512 VNNI (checked just above).
                    unsafe { ranking.run_vnni(&mut best, cols.as_mut()) };
                    if let Some(c) = cols {
                        col_best = c.key.into_iter().zip(c.row).collect();
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
    /// ([`quantized::dots16`]), and the offers without a branch on the data: a row's 32 keys
    /// reduced to its two best ([`offer32`]), and each candidate column's best row updated by a
    /// gather, a comparison and a masked scatter (a row's candidates are 32 distinct columns: one
    /// per lane and rank of [`RowLanes2`]). The same bests as [`Ranking::run`]'s, key for key.
    ///
    /// # Safety
    /// The CPU must have AVX-512 F/BW/VNNI.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx512bw,avx512vnni")]
    unsafe fn run_vnni(&self, best: &mut [Best2], mut cols: Option<&mut ColBest>) {
        use std::arch::x86_64::*;
        let d = self.a.d;
        let ((qa, sums), qb) = (self.a.q(), self.b.q().0);
        let (na, nb) = (&self.a.norms, &self.b.norms);
        let none = _mm512_set1_epi32(-1);
        let low = _mm512_set1_ps(f32::NEG_INFINITY);
        for (r, (ln, bst)) in self.lanes.iter().zip(best).enumerate() {
            let i = self.i0 + r;
            let row = &qa[i * d..(i + 1) * d];
            let mut keys = [low; 2];
            let mut jv = [none; 2];
            let mut valid = [0; 2];
            for (h, js) in [&ln.j1, &ln.j2].into_iter().enumerate() {
                // SAFETY: the CPU has AVX-512 VNNI (the caller's contract); `js` holds 16 u32, and
                // each gather and scatter reads or writes only the valid lanes, whose columns
                // (below `m`) index `nb` and the column bests.
                unsafe {
                    let s = quantized::dots16(row, sums[i], qb, js);
                    let j = _mm512_loadu_si512(js.as_ptr().cast());
                    let v = _mm512_cmpneq_epu32_mask(j, none);
                    let s = _mm512_cvtepi32_ps(_mm512_loadu_si512(s.as_ptr().cast()));
                    let twice = _mm512_add_ps(s, s);
                    let nbj = _mm512_mask_i32gather_ps::<4>(low, v, j, nb.as_ptr());
                    keys[h] = _mm512_mask_blend_ps(v, low, _mm512_sub_ps(twice, nbj));
                    jv[h] = j;
                    valid[h] = v;
                    if let Some(c) = cols.as_deref_mut() {
                        let key = _mm512_sub_ps(twice, _mm512_set1_ps(na[i]));
                        let cur = _mm512_mask_i32gather_ps::<4>(low, v, j, c.key.as_ptr());
                        let up = _mm512_mask_cmp_ps_mask::<_CMP_GT_OQ>(v, key, cur);
                        _mm512_mask_i32scatter_ps::<4>(c.key.as_mut_ptr(), up, j, key);
                        let iv = _mm512_set1_epi32(i as i32);
                        _mm512_mask_i32scatter_epi32::<4>(c.row.as_mut_ptr().cast(), up, j, iv);
                    }
                }
            }
            // SAFETY: the CPU has AVX-512 F (the caller's contract).
            let (k1, j1, k2) = unsafe { offer32(keys, jv, valid) };
            bst.offer_unordered(k1, j1);
            bst.offer_unordered(k2, u32::MAX);
        }
    }
}

/// Each column's best row so far, in two arrays (for the gathers and scatters of
/// [`Ranking::run_vnni`]).
#[cfg(target_arch = "x86_64")]
struct ColBest {
    key: Vec<f32>,
    row: Vec<u32>,
}

#[cfg(target_arch = "x86_64")]
impl ColBest {
    fn new(m: usize) -> Self {
        ColBest {
            key: vec![f32::NEG_INFINITY; m],
            row: vec![u32::MAX; m],
        }
    }
}

/// The two best of a row's 32 keys (invalid lanes at −∞), as [`Best2::offer_unordered`] leaves
/// them whatever the order: the largest key, the smallest column among the valid lanes that hold
/// it (`u32::MAX` if none), and the largest key of the others (the same value if it is held
/// twice).
///
/// # Safety
/// The CPU must have AVX-512 F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn offer32(
    keys: [std::arch::x86_64::__m512; 2],
    js: [std::arch::x86_64::__m512i; 2],
    valid: [std::arch::x86_64::__mmask16; 2],
) -> (f32, u32, f32) {
    use std::arch::x86_64::*;
    let k1 = _mm512_reduce_max_ps(_mm512_max_ps(keys[0], keys[1]));
    let top = |h: usize| _mm512_mask_cmpeq_ps_mask(valid[h], keys[h], _mm512_set1_ps(k1));
    let (t0, t1) = (top(0), top(1));
    let j1 = _mm512_mask_reduce_min_epu32(t0, js[0]).min(_mm512_mask_reduce_min_epu32(t1, js[1]));
    let rest = |h: usize, t: __mmask16| {
        let at = _mm512_mask_cmpeq_epi32_mask(t, js[h], _mm512_set1_epi32(j1 as i32));
        _mm512_mask_blend_ps(at, keys[h], _mm512_set1_ps(f32::NEG_INFINITY))
    };
    let k2 = _mm512_reduce_max_ps(_mm512_max_ps(rest(0, t0), rest(1, t1)));
    (k1, j1, k2)
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

#[cfg(all(test, target_arch = "x86_64"))]
mod tests {
    use super::*;
    use std::arch::x86_64::*;

    /// [`offer32`] leaves the same two best as offering the 32 keys one by one, with ties and
    /// invalid lanes.
    #[test]
    fn offer32_is_best2() {
        if !std::arch::is_x86_feature_detected!("avx512f") {
            eprintln!("skipped: no AVX-512 on this CPU");
            return;
        }
        let mut state = 0x2545_f491_4f6c_dd1d_u64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        for _ in 0..2000 {
            let mut keys = [[f32::NEG_INFINITY; 16]; 2];
            let mut js = [[u32::MAX; 16]; 2];
            let mut valid = [0u16; 2];
            let mut want = Best2::NONE;
            for h in 0..2 {
                for l in 0..16 {
                    if next() % 5 == 0 {
                        continue;
                    }
                    // Few distinct keys, so that ties are common.
                    let k = (next() % 6) as f32 - 3.0;
                    let j = (h * 16 + l) as u32 * 7 % 97 + (next() % 3) as u32 * 97;
                    keys[h][l] = k;
                    js[h][l] = j;
                    valid[h] |= 1 << l;
                    want.offer_unordered(k, j);
                }
            }
            // SAFETY: AVX-512 F is present (checked above); the arrays hold 16 lanes each.
            let got = unsafe {
                let kv = keys.map(|k| _mm512_loadu_ps(k.as_ptr()));
                let jv = js.map(|j| _mm512_loadu_si512(j.as_ptr().cast()));
                let (k1, j1, k2) = offer32(kv, jv, valid);
                let mut b = Best2::NONE;
                b.offer_unordered(k1, j1);
                b.offer_unordered(k2, u32::MAX);
                b
            };
            assert_eq!((got.s1, got.j1, got.s2), (want.s1, want.j1, want.s2));
        }
    }
}
