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
            let lanes = candidate_lanes(xa, xb, i0, rows);
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
                #[cfg(all(target_arch = "x86_64", target_feature = "avx2"))]
                _ if a.d == 128 => {
                    let mut cols = mutual.then(|| ColBest::new(m));
                    ranking.run_avx2(&mut best, cols.as_mut());
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

/// The coarse pass for rows `i0..i0 + rows` of the coarse codes `xa` against every column of
/// `xb`: each row's 32 candidates (two per lane of 16 columns).
pub(super) fn candidate_lanes(
    xa: &Prepared,
    xb: &Prepared,
    i0: usize,
    rows: usize,
) -> Vec<RowLanes2> {
    let m = xb.n;
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
    lanes
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

    /// [`Ranking::run`] on AVX2 (the CPUs without AVX-512): eight candidates' exact products at a
    /// time ([`dots8`], on the row widened to 16 bits once), and the offers reduced as in
    /// [`Ranking::run_vnni`], the column bests by a gather and a comparison, then a store per
    /// improved column. The same bests as [`Ranking::run`]'s, key for key.
    #[cfg(all(target_arch = "x86_64", target_feature = "avx2"))]
    fn run_avx2(&self, best: &mut [Best2], mut cols: Option<&mut ColBest>) {
        use std::arch::x86_64::*;
        let d = self.a.d;
        assert_eq!(d, 128);
        let (qa, qb) = (self.a.q().0, self.b.q().0);
        let (na, nb) = (&self.a.norms, &self.b.norms);
        assert!(self
            .lanes
            .iter()
            .flat_map(|ln| ln.j1.iter().chain(&ln.j2))
            .all(
                |&j| j == u32::MAX || ((j as usize) < nb.len() && (j as usize + 1) * d <= qb.len())
            ));
        assert!(cols
            .as_ref()
            .is_none_or(|c| c.key.len() >= nb.len() && c.row.len() >= nb.len()));
        // SAFETY: AVX2 is enabled at compile time; every row read is in `qa` or `qb` and every
        // gathered or stored column below `nb.len()` (asserted above); invalid lanes are masked.
        unsafe {
            let none = _mm256_set1_epi32(-1);
            let low = _mm256_set1_ps(f32::NEG_INFINITY);
            for (r, (ln, bst)) in self.lanes.iter().zip(best).enumerate() {
                let i = self.i0 + r;
                let wide: [__m256i; 8] = std::array::from_fn(|k| {
                    _mm256_cvtepu8_epi16(_mm_loadu_si128(qa.as_ptr().add(i * d + 16 * k).cast()))
                });
                let mut keys = [low; 4];
                let mut jv = [none; 4];
                for (h, js) in ln
                    .j1
                    .chunks_exact(8)
                    .chain(ln.j2.chunks_exact(8))
                    .enumerate()
                {
                    let j = _mm256_loadu_si256(js.as_ptr().cast());
                    let v = _mm256_xor_si256(_mm256_cmpeq_epi32(j, none), none);
                    let s = _mm256_cvtepi32_ps(dots8(&wide, qb, js));
                    let twice = _mm256_add_ps(s, s);
                    let vf = _mm256_castsi256_ps(v);
                    let nbj = _mm256_mask_i32gather_ps::<4>(low, nb.as_ptr(), j, vf);
                    keys[h] = _mm256_blendv_ps(low, _mm256_sub_ps(twice, nbj), vf);
                    jv[h] = j;
                    if let Some(c) = cols.as_deref_mut() {
                        let key = _mm256_sub_ps(twice, _mm256_set1_ps(na[i]));
                        let cur = _mm256_mask_i32gather_ps::<4>(low, c.key.as_ptr(), j, vf);
                        let up = _mm256_and_ps(_mm256_cmp_ps::<_CMP_GT_OQ>(key, cur), vf);
                        let mut bits = _mm256_movemask_ps(up) as u32;
                        if bits != 0 {
                            let mut kk = [0f32; 8];
                            _mm256_storeu_ps(kk.as_mut_ptr(), key);
                            while bits != 0 {
                                let l = bits.trailing_zeros() as usize;
                                bits &= bits - 1;
                                let jj = js[l] as usize;
                                *c.key.get_unchecked_mut(jj) = kk[l];
                                *c.row.get_unchecked_mut(jj) = i as u32;
                            }
                        }
                    }
                }
                let (k1, j1, k2) = offer32_avx2(keys, jv);
                bst.offer_unordered(k1, j1);
                bst.offer_unordered(k2, u32::MAX);
            }
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

/// The exact products of one row (its 128 bytes widened to 16 bits: `wide`) with the eight rows
/// `js` of `b` (128 bytes a row; a `u32::MAX` reads row 0, whose lane the caller ignores), lane `k`
/// for `js[k]`: `vpmaddwd` on 16-bit pairs, exact in i32 (128 · 255² < 2³¹), the eight sums
/// reduced together by a tree of horizontal adds.
///
/// # Safety
/// Every row `js` names must lie inside `b`.
#[cfg(all(target_arch = "x86_64", target_feature = "avx2"))]
#[inline(always)]
unsafe fn dots8(
    wide: &[std::arch::x86_64::__m256i; 8],
    b: &[u8],
    js: &[u32],
) -> std::arch::x86_64::__m256i {
    use std::arch::x86_64::*;
    // SAFETY: the rows read are inside `b` (the caller's contract); AVX2 is enabled.
    unsafe {
        let acc: [__m256i; 8] = std::array::from_fn(|k| {
            let j = js[k];
            let row = b
                .as_ptr()
                .add(if j == u32::MAX { 0 } else { j as usize * 128 });
            let mut v = _mm256_setzero_si256();
            for (t, w) in wide.iter().enumerate() {
                let x = _mm256_cvtepu8_epi16(_mm_loadu_si128(row.add(16 * t).cast()));
                v = _mm256_add_epi32(v, _mm256_madd_epi16(x, *w));
            }
            v
        });
        // [a0+a1, a2+a3, b0+b1, b2+b3 | a4+a5, a6+a7, b4+b5, b6+b7] and so on, then the halves.
        let p = |x: usize| _mm256_hadd_epi32(acc[x], acc[x + 1]);
        let (p0, p1, p2, p3) = (p(0), p(2), p(4), p(6));
        let q0 = _mm256_hadd_epi32(p0, p1);
        let q1 = _mm256_hadd_epi32(p2, p3);
        // q0 lanes: [r0, r1, r2, r3 | r0', r1', r2', r3'] (the two 128-bit halves' partial sums).
        let lo = _mm256_permute2x128_si256::<0x20>(q0, q1);
        let hi = _mm256_permute2x128_si256::<0x31>(q0, q1);
        _mm256_add_epi32(lo, hi)
    }
}

/// [`offer32`] on AVX2: the two best of a row's 32 keys (invalid lanes at −∞, in four registers
/// of eight), as [`Best2::offer_unordered`] leaves them whatever the order.
#[cfg(all(target_arch = "x86_64", target_feature = "avx2"))]
#[inline(always)]
fn offer32_avx2(
    keys: [std::arch::x86_64::__m256; 4],
    js: [std::arch::x86_64::__m256i; 4],
) -> (f32, u32, f32) {
    use std::arch::x86_64::*;
    // SAFETY: AVX2 is enabled at compile time.
    unsafe {
        let hmax = |v: __m256| {
            let m = _mm_max_ps(_mm256_castps256_ps128(v), _mm256_extractf128_ps::<1>(v));
            let m = _mm_max_ps(m, _mm_movehl_ps(m, m));
            _mm_cvtss_f32(_mm_max_ss(m, _mm_shuffle_ps::<0b01>(m, m)))
        };
        let hmin_u = |v: __m256i| {
            let m = _mm_min_epu32(_mm256_castsi256_si128(v), _mm256_extracti128_si256::<1>(v));
            let m = _mm_min_epu32(m, _mm_shuffle_epi32::<0b01_00_11_10>(m));
            _mm_cvtsi128_si32(_mm_min_epu32(m, _mm_shuffle_epi32::<0b10_11_00_01>(m))) as u32
        };
        let all = _mm256_max_ps(
            _mm256_max_ps(keys[0], keys[1]),
            _mm256_max_ps(keys[2], keys[3]),
        );
        let k1 = hmax(all);
        let k1v = _mm256_set1_ps(k1);
        // Lanes holding the best key (a valid one: −∞ only in invalid lanes when any is valid).
        let top: [__m256i; 4] =
            std::array::from_fn(|h| _mm256_castps_si256(_mm256_cmp_ps::<_CMP_EQ_OQ>(keys[h], k1v)));
        let none = _mm256_set1_epi32(-1);
        let cand: [__m256i; 4] = std::array::from_fn(|h| _mm256_blendv_epi8(none, js[h], top[h]));
        let j1 = if k1 == f32::NEG_INFINITY {
            u32::MAX
        } else {
            hmin_u(_mm256_min_epu32(
                _mm256_min_epu32(cand[0], cand[1]),
                _mm256_min_epu32(cand[2], cand[3]),
            ))
        };
        let j1v = _mm256_set1_epi32(j1 as i32);
        let rest: [__m256; 4] = std::array::from_fn(|h| {
            let at = _mm256_and_si256(top[h], _mm256_cmpeq_epi32(js[h], j1v));
            _mm256_blendv_ps(
                keys[h],
                _mm256_set1_ps(f32::NEG_INFINITY),
                _mm256_castsi256_ps(at),
            )
        });
        let k2 = hmax(_mm256_max_ps(
            _mm256_max_ps(rest[0], rest[1]),
            _mm256_max_ps(rest[2], rest[3]),
        ));
        (k1, j1, k2)
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
            #[cfg(target_feature = "avx2")]
            {
                // SAFETY: AVX2 is enabled at compile time; the arrays hold 8 lanes a half.
                let (k1, j1, k2) = unsafe {
                    let kv: [__m256; 4] = std::array::from_fn(|q| {
                        _mm256_loadu_ps(keys[q / 2][8 * (q % 2)..].as_ptr())
                    });
                    let jv: [__m256i; 4] = std::array::from_fn(|q| {
                        _mm256_loadu_si256(js[q / 2][8 * (q % 2)..].as_ptr().cast())
                    });
                    offer32_avx2(kv, jv)
                };
                let mut b = Best2::NONE;
                b.offer_unordered(k1, j1);
                b.offer_unordered(k2, u32::MAX);
                assert_eq!((b.s1, b.j1, b.s2), (want.s1, want.j1, want.s2));
            }
        }
    }

    /// [`dots8`] gives the exact products of [`dot_u8`], extreme bytes included.
    #[cfg(target_feature = "avx2")]
    #[test]
    fn dots8_is_exact() {
        let mut state = 0x9e37_79b9_7f4a_7c15_u64;
        let mut byte = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            [0u8, 255, (state >> 32) as u8][(state % 3) as usize]
        };
        let b: Vec<u8> = (0..20 * 128).map(|_| byte()).collect();
        let a: Vec<u8> = (0..128).map(|_| byte()).collect();
        let js = [3u32, 0, 19, u32::MAX, 7, 7, 12, 1];
        // SAFETY: AVX2 is enabled at compile time; every row named is inside `b`.
        let got = unsafe {
            let wide: [__m256i; 8] = std::array::from_fn(|k| {
                _mm256_cvtepu8_epi16(_mm_loadu_si128(a[16 * k..].as_ptr().cast()))
            });
            let mut out = [0i32; 8];
            _mm256_storeu_si256(out.as_mut_ptr().cast(), dots8(&wide, &b, &js));
            out
        };
        for (k, &j) in js.iter().enumerate() {
            let j = if j == u32::MAX { 0 } else { j as usize };
            assert_eq!(
                got[k] as u32,
                dot_u8(&a, &b[j * 128..(j + 1) * 128]),
                "lane {k}"
            );
        }
    }
}
