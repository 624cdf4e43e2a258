//! The AVX-512 VNNI kernel of [`super::scores_block`]: `vpdpbusd` on 512-bit registers.

use super::{PackedB, TILE};
use std::arch::x86_64::*;

/// Rows per register tile: 8 accumulators of 16 sums each.
const ROWS: usize = 8;

/// The 4 bytes of row `i`, dimensions `4g..4g+4`, as one i32 (zero past `dim`).
#[inline(always)]
fn group(qa: &[u8], dim: usize, i: usize, g: usize) -> i32 {
    let row = &qa[i * dim..(i + 1) * dim];
    let k = 4 * g;
    if k + 4 <= dim {
        i32::from_le_bytes([row[k], row[k + 1], row[k + 2], row[k + 3]])
    } else {
        let mut v = [0u8; 4];
        for (t, x) in v.iter_mut().enumerate() {
            *x = row.get(k + t).copied().unwrap_or(0);
        }
        i32::from_le_bytes(v)
    }
}

/// Rows `i0..i0 + rows` of A as 4-byte groups, broadcast once per row block, laid out
/// `[row chunk of per_chunk][group][row in chunk]` so that one group's broadcasts read consecutive
/// words; rows past the block are zero (their sums are computed and not stored).
pub(super) fn row_groups(
    qa: &[u8],
    dim: usize,
    i0: usize,
    rows: usize,
    groups: usize,
    per_chunk: usize,
) -> Vec<i32> {
    let chunks = rows.div_ceil(per_chunk);
    let mut abc = vec![0i32; chunks * groups * per_chunk];
    for r in 0..rows {
        for g in 0..groups {
            abc[((r / per_chunk) * groups + g) * per_chunk + r % per_chunk] =
                group(qa, dim, i0 + r, g);
        }
    }
    abc
}

#[allow(clippy::too_many_arguments)]
#[target_feature(enable = "avx512f,avx512bw,avx512vnni")]
pub(super) unsafe fn block(
    qa: &[u8],
    suma: &[i32],
    dim: usize,
    i0: usize,
    rows: usize,
    b: &PackedB,
    j0: usize,
    cols: usize,
    out: &mut [f32],
) {
    let groups = b.groups;
    let abc = row_groups(qa, dim, i0, rows, groups, ROWS);
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
