//! The AVX-512 VNNI kernel of [`super::scores_block`]: `vpdpbusd` on 512-bit registers.

use super::{PackedB, TILE};
use std::arch::x86_64::*;

/// Rows per register tile: 8 accumulators of 16 sums each.
pub(super) const ROWS: usize = 8;

/// The block's scores from its rows' groups `abc` (`super::RowGroups`, [`ROWS`] per chunk, for
/// rows `i0..i0 + rows`).
#[allow(clippy::too_many_arguments)]
#[target_feature(enable = "avx512f,avx512bw,avx512vnni")]
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
            // A constant trip count over the rows, so the loop unrolls and the accumulators
            // stay in registers.
            let mut acc = [_mm512_setzero_si512(); ROWS];
            for (g, ag) in chunk.chunks_exact(ROWS).enumerate() {
                // SAFETY: `bt` holds `groups` runs of 64 bytes.
                let bv = unsafe { _mm512_loadu_si512(bt.as_ptr().add(g * 64).cast()) };
                for (a, &w) in acc.iter_mut().zip(ag) {
                    *a = _mm512_dpbusd_epi32(*a, _mm512_set1_epi32(w), bv);
                }
            }
            let c0 = t * TILE;
            let nc = TILE.min(cols - c0);
            let mask: __mmask16 = if nc == TILE { 0xffff } else { (1u16 << nc) - 1 };
            for (r, a) in acc.iter().enumerate().take(nr) {
                let corr = _mm512_set1_epi32(128 * suma[i0 + r0 + r]);
                let s = _mm512_cvtepi32_ps(_mm512_add_epi32(*a, corr));
                let dst = &mut out[(r0 + r) * cols + c0..(r0 + r) * cols + c0 + nc];
                // SAFETY: `dst` has `nc` floats and the mask writes only those.
                unsafe { _mm512_mask_storeu_ps(dst.as_mut_ptr(), mask, s) };
            }
        }
        r0 += nr;
    }
}
