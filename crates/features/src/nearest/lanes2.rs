//! The coarse pass's scan of coarse-to-fine matching ([`crate::matching`]): each row's two best
//! columns per lane of 16, with both their columns, as candidates for the full descriptors.

use super::Block;
#[cfg(all(target_arch = "x86_64", target_feature = "avx2"))]
use std::arch::x86_64::*;

/// A row's coarse candidates (coarse-to-fine matching, [`crate::matching`]): per lane `l` of a
/// 16-column tile (the columns `j ≡ l (mod 16)`, offered in increasing order), the two best keys
/// and both their columns. The 32 columns are the row's candidates, ranked again on the full
/// descriptors: a row's nearest columns are found unless two nearer ones share their lane.
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C, align(64))]
pub(crate) struct RowLanes2 {
    pub b1: [f32; 16],
    pub b2: [f32; 16],
    pub j1: [u32; 16],
    pub j2: [u32; 16],
}

impl RowLanes2 {
    pub const NONE: RowLanes2 = RowLanes2 {
        b1: [f32::NEG_INFINITY; 16],
        b2: [f32::NEG_INFINITY; 16],
        j1: [u32::MAX; 16],
        j2: [u32::MAX; 16],
    };

    /// Offers column `j` with key `key` to lane `l`: strict `>`, so the first of equal keys stays.
    #[inline(always)]
    pub(crate) fn offer(&mut self, l: usize, key: f32, j: u32) {
        let (m1, m2) = (key > self.b1[l], key > self.b2[l]);
        let (b1, j1) = (self.b1[l], self.j1[l]);
        self.b2[l] = if m1 {
            b1
        } else if m2 {
            key
        } else {
            self.b2[l]
        };
        self.j2[l] = if m1 {
            j1
        } else if m2 {
            j
        } else {
            self.j2[l]
        };
        self.b1[l] = if m1 { key } else { b1 };
        self.j1[l] = if m1 { j } else { j1 };
    }
}

/// Offers every score of `block` to its row's lanes ([`RowLanes2`], one per row of the block):
/// key `2s − ‖b‖²`, column `j0 + c` to lane `c mod 16` (`j0` a multiple of 16).
pub(crate) fn scan_lanes2(block: &Block<'_>, lanes: &mut [RowLanes2]) {
    let Block {
        s,
        rows,
        cols,
        j0,
        nb,
        ..
    } = *block;
    assert!(s.len() >= rows * cols && lanes.len() >= rows && nb.len() >= cols);
    assert!(j0.is_multiple_of(16));
    let full = cols / 16 * 16;
    for (r, ln) in lanes[..rows].iter_mut().enumerate() {
        let row = &s[r * cols..(r + 1) * cols];
        // Whole tiles first, the row's lanes in registers along the row.
        #[cfg(all(target_arch = "x86_64", target_feature = "avx2"))]
        // SAFETY: AVX2 is enabled at compile time; `row` and `nb` hold `full` values.
        unsafe {
            lanes2_row(&row[..full], &nb[..full], j0 as u32, ln)
        };
        #[cfg(not(all(target_arch = "x86_64", target_feature = "avx2")))]
        for (t, (sc, nc)) in row[..full]
            .chunks_exact(16)
            .zip(nb[..full].chunks_exact(16))
            .enumerate()
        {
            let j = (j0 + 16 * t) as u32;
            for l in 0..16 {
                ln.offer(l, (sc[l] + sc[l]) - nc[l], j + l as u32);
            }
        }
        for c in full..cols {
            ln.offer(c % 16, (row[c] + row[c]) - nb[c], (j0 + c) as u32);
        }
    }
}

#[cfg(all(target_arch = "x86_64", target_feature = "avx2"))]
/// [`scan_lanes2`]'s whole tiles of one row on AVX2 registers: the row's lanes
/// (`ln`, two best keys and columns per lane, 8 registers) are loaded once, offered the row's
/// scores `s` (whole tiles of 16; columns `j0..`, squared norms `nb`) and stored back. The
/// same comparisons as [`RowLanes2::offer`] in the same order.
///
/// # Safety
/// AVX2 must be available; `s` and `nb` must have the same length, a multiple of 16.
#[inline]
unsafe fn lanes2_row(s: &[f32], nb: &[f32], j0: u32, ln: &mut RowLanes2) {
    debug_assert!(s.len() == nb.len() && s.len().is_multiple_of(16));
    // SAFETY: `RowLanes2` holds four runs of 16 lanes; every load below reads 8 values of
    // `s` or `nb` inside their common length (the caller's contract).
    unsafe {
        let mut b1 = [
            _mm256_loadu_ps(ln.b1.as_ptr()),
            _mm256_loadu_ps(ln.b1.as_ptr().add(8)),
        ];
        let mut b2 = [
            _mm256_loadu_ps(ln.b2.as_ptr()),
            _mm256_loadu_ps(ln.b2.as_ptr().add(8)),
        ];
        let ld = |p: *const u32| _mm256_castsi256_ps(_mm256_loadu_si256(p.cast()));
        let mut j1 = [ld(ln.j1.as_ptr()), ld(ln.j1.as_ptr().add(8))];
        let mut j2 = [ld(ln.j2.as_ptr()), ld(ln.j2.as_ptr().add(8))];
        let mut jl = [
            _mm256_add_epi32(
                _mm256_set1_epi32(j0 as i32),
                _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7),
            ),
            _mm256_add_epi32(
                _mm256_set1_epi32(j0 as i32),
                _mm256_setr_epi32(8, 9, 10, 11, 12, 13, 14, 15),
            ),
        ];
        let step = _mm256_set1_epi32(16);
        for c in (0..s.len()).step_by(16) {
            for h in 0..2 {
                let sv = _mm256_loadu_ps(s.as_ptr().add(c + 8 * h));
                let rk = _mm256_sub_ps(
                    _mm256_add_ps(sv, sv),
                    _mm256_loadu_ps(nb.as_ptr().add(c + 8 * h)),
                );
                let m1 = _mm256_cmp_ps::<_CMP_GT_OQ>(rk, b1[h]);
                let m2 = _mm256_cmp_ps::<_CMP_GT_OQ>(rk, b2[h]);
                let jv = _mm256_castsi256_ps(jl[h]);
                b2[h] = _mm256_blendv_ps(_mm256_blendv_ps(b2[h], rk, m2), b1[h], m1);
                j2[h] = _mm256_blendv_ps(_mm256_blendv_ps(j2[h], jv, m2), j1[h], m1);
                b1[h] = _mm256_blendv_ps(b1[h], rk, m1);
                j1[h] = _mm256_blendv_ps(j1[h], jv, m1);
                jl[h] = _mm256_add_epi32(jl[h], step);
            }
        }
        for h in 0..2 {
            _mm256_storeu_ps(ln.b1.as_mut_ptr().add(8 * h), b1[h]);
            _mm256_storeu_ps(ln.b2.as_mut_ptr().add(8 * h), b2[h]);
            _mm256_storeu_si256(
                ln.j1.as_mut_ptr().add(8 * h).cast(),
                _mm256_castps_si256(j1[h]),
            );
            _mm256_storeu_si256(
                ln.j2.as_mut_ptr().add(8 * h).cast(),
                _mm256_castps_si256(j2[h]),
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nearest::Best2;

    /// Per lane, the two best keys and their columns, offered in increasing column order with
    /// strict `>` (the first of equal keys stays), and the block scan gives the same.
    #[test]
    fn the_lane_scan_keeps_each_lanes_first_two_best_ties_included() {
        let mut s = 5u64;
        let mut rnd = move || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 33) as u32
        };
        let (rows, cols, j0) = (9usize, 70usize, 32usize);
        let scores: Vec<f32> = (0..rows * cols).map(|_| (rnd() % 4) as f32).collect();
        let nb: Vec<f32> = (0..cols).map(|_| (rnd() % 3) as f32).collect();
        let na = vec![0f32; rows];
        let block = Block {
            s: &scores,
            rows,
            cols,
            i0: 0,
            j0,
            na: &na,
            nb: &nb,
        };
        let mut lanes = vec![RowLanes2::NONE; rows];
        scan_lanes2(&block, &mut lanes);
        for r in 0..rows {
            for l in 0..16 {
                // The lane's columns, by key descending then column ascending.
                let mut cand: Vec<(f32, u32)> = (0..cols)
                    .filter(|c| (j0 + c) % 16 == l)
                    .map(|c| (2.0 * scores[r * cols + c] - nb[c], (j0 + c) as u32))
                    .collect();
                cand.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
                let ln = &lanes[r];
                assert_eq!((ln.b1[l], ln.j1[l]), cand[0], "row {r} lane {l}");
                assert_eq!((ln.b2[l], ln.j2[l]), cand[1], "row {r} lane {l}");
            }
        }
    }

    /// Offered in any order, the two best are those of the columns offered in increasing order.
    #[test]
    fn unordered_offers_give_the_ordered_two_best() {
        let mut s = 9u64;
        let mut rnd = move || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 33) as u32
        };
        for _ in 0..500 {
            let keys: Vec<f32> = (0..12).map(|_| (rnd() % 5) as f32).collect();
            let mut ordered = Best2::NONE;
            for (j, &k) in keys.iter().enumerate() {
                ordered.offer(k, j as u32);
            }
            let mut order: Vec<usize> = (0..keys.len()).collect();
            for i in (1..order.len()).rev() {
                order.swap(i, rnd() as usize % (i + 1));
            }
            let mut any = Best2::NONE;
            for j in order {
                any.offer_unordered(keys[j], j as u32);
            }
            assert_eq!(any, ordered, "{keys:?}");
        }
    }
}
