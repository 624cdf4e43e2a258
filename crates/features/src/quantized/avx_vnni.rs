//! The AVX-VNNI kernel of [`super::scores_block`]: `vpdpbusd` on 256-bit registers.

use super::{PackedB, TILE};
use std::arch::x86_64::*;

/// Rows per register tile: 6 rows × 2 registers of 8 sums, 12 accumulators (of 16 registers).
pub(super) const ROWS: usize = 6;

/// The block's scores from its rows' groups `abc` (`super::RowGroups`, [`ROWS`] per chunk,
/// for rows `i0..i0 + rows`).
#[allow(clippy::too_many_arguments)]
#[target_feature(enable = "avx2,avxvnni")]
pub(super) unsafe fn block(
    abc: &[i32],
    suma: &[i32],
    i0: usize,
    rows: usize,
    b: &PackedB,
    j0: usize,
    cols: usize,
    out: &mut [f32],
) {
    let groups = b.groups;
    let t0 = j0 / TILE;
    let tiles = cols.div_ceil(TILE);
    let mut r0 = 0;
    while r0 < rows {
        let nr = ROWS.min(rows - r0);
        let chunk = &abc[(r0 / ROWS) * groups * ROWS..(r0 / ROWS + 1) * groups * ROWS];
        for t in 0..tiles {
            let bt = &b.data[(t0 + t) * groups * TILE * 4..(t0 + t + 1) * groups * TILE * 4];
            let mut lo = [_mm256_setzero_si256(); ROWS];
            let mut hi = [_mm256_setzero_si256(); ROWS];
            for (g, ag) in chunk.chunks_exact(ROWS).enumerate() {
                // SAFETY: `bt` holds `groups` runs of 64 bytes.
                let (b0, b1) = unsafe {
                    (
                        _mm256_loadu_si256(bt.as_ptr().add(g * 64).cast()),
                        _mm256_loadu_si256(bt.as_ptr().add(g * 64 + 32).cast()),
                    )
                };
                for r in 0..ROWS {
                    let a = _mm256_set1_epi32(ag[r]);
                    lo[r] = _mm256_dpbusd_avx_epi32(lo[r], a, b0);
                    hi[r] = _mm256_dpbusd_avx_epi32(hi[r], a, b1);
                }
            }
            let c0 = t * TILE;
            let nc = TILE.min(cols - c0);
            for r in 0..nr {
                let corr = _mm256_set1_epi32(128 * suma[i0 + r0 + r]);
                let l = _mm256_cvtepi32_ps(_mm256_add_epi32(lo[r], corr));
                let h = _mm256_cvtepi32_ps(_mm256_add_epi32(hi[r], corr));
                let mut tile = [0f32; TILE];
                // SAFETY: `tile` holds 16 floats.
                unsafe {
                    _mm256_storeu_ps(tile.as_mut_ptr(), l);
                    _mm256_storeu_ps(tile.as_mut_ptr().add(8), h);
                }
                let at = (r0 + r) * cols + c0;
                out[at..at + nc].copy_from_slice(&tile[..nc]);
            }
        }
        r0 += nr;
    }
}
