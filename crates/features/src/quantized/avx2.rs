//! The AVX2 kernel of [`super::scores_block_avx2`]: `vpmaddwd` on pairs of i16, i32 sums.

use super::{PackedBytes, PackedI16, TILE_I16};
use std::arch::x86_64::*;

/// Rows per register tile: 6 rows × 2 registers of 8 sums, 12 accumulators (of 16 registers).
const ROWS: usize = 6;

#[target_feature(enable = "avx2")]
pub(super) unsafe fn block(
    pa: &[i32],
    i0: usize,
    rows: usize,
    b: &PackedI16,
    j0: usize,
    cols: usize,
    out: &mut [f32],
) {
    let pairs = b.pairs;
    let t0 = j0 / TILE_I16;
    let tiles = cols.div_ceil(TILE_I16);
    let tile_len = pairs * TILE_I16 * 2;
    let mut r0 = 0;
    while r0 < rows {
        let nr = ROWS.min(rows - r0);
        // Rows past the block repeat its last row: read, summed, not stored.
        let arow: [&[i32]; ROWS] = std::array::from_fn(|r| {
            let i = i0 + r0 + r.min(nr - 1);
            &pa[i * pairs..(i + 1) * pairs]
        });
        for t in 0..tiles {
            let bt = &b.data[(t0 + t) * tile_len..(t0 + t + 1) * tile_len];
            let mut lo = [_mm256_setzero_si256(); ROWS];
            let mut hi = [_mm256_setzero_si256(); ROWS];
            for (g, bg) in bt.chunks_exact(TILE_I16 * 2).enumerate() {
                // SAFETY: `bg` holds 32 i16 (64 bytes).
                let (b0, b1) = unsafe {
                    (
                        _mm256_loadu_si256(bg.as_ptr().cast()),
                        _mm256_loadu_si256(bg.as_ptr().add(16).cast()),
                    )
                };
                for r in 0..ROWS {
                    // SAFETY: every row slice has `pairs` words and g < pairs.
                    let a = _mm256_set1_epi32(unsafe { *arow[r].get_unchecked(g) });
                    lo[r] = _mm256_add_epi32(lo[r], _mm256_madd_epi16(a, b0));
                    hi[r] = _mm256_add_epi32(hi[r], _mm256_madd_epi16(a, b1));
                }
            }
            let c0 = t * TILE_I16;
            let nc = TILE_I16.min(cols - c0);
            for r in 0..nr {
                let at = (r0 + r) * cols + c0;
                store_tile(lo[r], hi[r], &mut out[at..at + nc]);
            }
        }
        r0 += nr;
    }
}

/// Rows per register tile of [`block_bytes`]: 4 rows × 2 registers of 8 sums.
const ROWS_BYTES: usize = 4;

/// The AVX2 kernel of [`super::scores_block_avx2_bytes`]: `vpmaddubsw` on four dimensions at a
/// time (the row's bytes, unsigned, against the set's, signed and less 64), two groups' pair sums
/// added in i16 (at most 4 · 127 · 64 < 2¹⁵), widened by `vpmaddwd` against ones, and the row's
/// `64 · Σ u` added back.
#[target_feature(enable = "avx2")]
#[allow(clippy::too_many_arguments)]
pub(super) unsafe fn block_bytes(
    pa: &[i32],
    sums: &[i32],
    i0: usize,
    rows: usize,
    b: &PackedBytes,
    j0: usize,
    cols: usize,
    out: &mut [f32],
) {
    let groups = b.groups;
    let t0 = j0 / TILE_I16;
    let tiles = cols.div_ceil(TILE_I16);
    let tile_len = groups * TILE_I16 * 4;
    let ones = _mm256_set1_epi16(1);
    let mut r0 = 0;
    while r0 < rows {
        let nr = ROWS_BYTES.min(rows - r0);
        // Rows past the block repeat its last row: read, summed, not stored.
        let row = |r: usize| i0 + r0 + r.min(nr - 1);
        let arow: [&[i32]; ROWS_BYTES] =
            std::array::from_fn(|r| &pa[row(r) * groups..(row(r) + 1) * groups]);
        for t in 0..tiles {
            let bt = &b.data[(t0 + t) * tile_len..(t0 + t + 1) * tile_len];
            let mut lo = [_mm256_setzero_si256(); ROWS_BYTES];
            let mut hi = [_mm256_setzero_si256(); ROWS_BYTES];
            // SAFETY (every load below): group g's 16 columns are bytes 64g..64g + 64 of `bt`,
            // and g < groups.
            let load = |g: usize, half: usize| unsafe {
                _mm256_loadu_si256(bt.as_ptr().add(g * 64 + half * 32).cast())
            };
            let mut g = 0;
            while g + 1 < groups {
                let (b0l, b0h, b1l, b1h) = (load(g, 0), load(g, 1), load(g + 1, 0), load(g + 1, 1));
                for r in 0..ROWS_BYTES {
                    // SAFETY: every row slice has `groups` words and g + 1 < groups.
                    let (a0, a1) = unsafe {
                        (
                            _mm256_set1_epi32(*arow[r].get_unchecked(g)),
                            _mm256_set1_epi32(*arow[r].get_unchecked(g + 1)),
                        )
                    };
                    let sl = _mm256_add_epi16(
                        _mm256_maddubs_epi16(a0, b0l),
                        _mm256_maddubs_epi16(a1, b1l),
                    );
                    let sh = _mm256_add_epi16(
                        _mm256_maddubs_epi16(a0, b0h),
                        _mm256_maddubs_epi16(a1, b1h),
                    );
                    lo[r] = _mm256_add_epi32(lo[r], _mm256_madd_epi16(sl, ones));
                    hi[r] = _mm256_add_epi32(hi[r], _mm256_madd_epi16(sh, ones));
                }
                g += 2;
            }
            if g < groups {
                let (bl, bh) = (load(g, 0), load(g, 1));
                for r in 0..ROWS_BYTES {
                    // SAFETY: g < groups.
                    let a = _mm256_set1_epi32(unsafe { *arow[r].get_unchecked(g) });
                    lo[r] = _mm256_add_epi32(
                        lo[r],
                        _mm256_madd_epi16(_mm256_maddubs_epi16(a, bl), ones),
                    );
                    hi[r] = _mm256_add_epi32(
                        hi[r],
                        _mm256_madd_epi16(_mm256_maddubs_epi16(a, bh), ones),
                    );
                }
            }
            let c0 = t * TILE_I16;
            let nc = TILE_I16.min(cols - c0);
            for r in 0..nr {
                let back = _mm256_set1_epi32(64 * sums[i0 + r0 + r]);
                let at = (r0 + r) * cols + c0;
                store_tile(
                    _mm256_add_epi32(lo[r], back),
                    _mm256_add_epi32(hi[r], back),
                    &mut out[at..at + nc],
                );
            }
        }
        r0 += nr;
    }
}

/// A row's 16 sums (`lo`, `hi`) as floats into `dst` (at most 16 long; a partial tile's first).
#[target_feature(enable = "avx2")]
#[inline]
fn store_tile(lo: __m256i, hi: __m256i, dst: &mut [f32]) {
    let (l, h) = (_mm256_cvtepi32_ps(lo), _mm256_cvtepi32_ps(hi));
    if dst.len() == TILE_I16 {
        // SAFETY: `dst` holds 16 floats.
        unsafe {
            _mm256_storeu_ps(dst.as_mut_ptr(), l);
            _mm256_storeu_ps(dst.as_mut_ptr().add(8), h);
        }
    } else {
        let mut tile = [0f32; TILE_I16];
        // SAFETY: `tile` holds 16 floats.
        unsafe {
            _mm256_storeu_ps(tile.as_mut_ptr(), l);
            _mm256_storeu_ps(tile.as_mut_ptr().add(8), h);
        }
        dst.copy_from_slice(&tile[..dst.len()]);
    }
}
