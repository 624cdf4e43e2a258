//! The AVX2 kernel of [`super::scores_block_avx2`]: `vpmaddwd` on pairs of i16, i32 sums.

use super::{PackedI16, TILE_I16};
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
                let dst = &mut out[at..at + nc];
                let (l, h) = (_mm256_cvtepi32_ps(lo[r]), _mm256_cvtepi32_ps(hi[r]));
                if nc == TILE_I16 {
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
                    dst.copy_from_slice(&tile[..nc]);
                }
            }
        }
        r0 += nr;
    }
}
