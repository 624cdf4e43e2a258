//! The AVX-512 VNNI kernel of [`super::scores_block`]: `vpdpbusd` on 512-bit registers.

use super::{PackedB, TILE};
use crate::nearest::{RowLanes, RowLanes2};
use std::arch::x86_64::*;

/// Rows per register tile: 8 accumulators of 16 sums each.
pub(super) const ROWS: usize = 8;

/// The sums of one register tile: the row chunk's groups `chunk` (`ROWS` per group) against
/// one tile of B (`bt`, one run of 64 bytes per group). A constant trip count over the rows, so
/// the loop unrolls and the accumulators stay in registers.
///
/// # Safety
/// AVX-512 F/BW/VNNI must be available, and `bt` must hold a run of 64 bytes per group of `chunk`.
#[inline(always)]
unsafe fn tile_sums(chunk: &[i32], bt: &[i8]) -> [__m512i; ROWS] {
    let mut acc = [_mm512_setzero_si512(); ROWS];
    for (g, ag) in chunk.chunks_exact(ROWS).enumerate() {
        // SAFETY: `bt` holds a run of 64 bytes per group (the caller's contract).
        let bv = unsafe { _mm512_loadu_si512(bt.as_ptr().add(g * 64).cast()) };
        for (a, &w) in acc.iter_mut().zip(ag) {
            *a = _mm512_dpbusd_epi32(*a, _mm512_set1_epi32(w), bv);
        }
    }
    acc
}

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
            // SAFETY: VNNI is enabled here; `bt` holds `groups` runs of 64 bytes.
            let acc = unsafe { tile_sums(chunk, bt) };
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

/// [`block`] with the scan of [`crate::nearest::scan_block`] fused in: each register tile of
/// 8 rows × 16 columns is offered to the rows' two bests and the columns' bests while it is still
/// in registers, instead of being stored to a score block and read back (on the low-texture set
/// that round trip cost as much as the products). The same comparisons in the same order as
/// `scan_block` over the stored block (rows in increasing order down each column, columns in
/// increasing order along each row, strict `>`), so the same result, ties included. `na` are the
/// block's rows' squared norms (`rows`), `nb` its columns' (`cols`); `best` holds one entry per
/// row, `cols_best` (when the mutual check runs) one per column.
#[allow(clippy::too_many_arguments)]
#[target_feature(enable = "avx512f,avx512bw,avx512vnni")]
pub(super) unsafe fn block_scan(
    abc: &[i32],
    suma: &[i32],
    i0: usize,
    rows: usize,
    b: &PackedB,
    j0: usize,
    cols: usize,
    na: &[f32],
    nb: &[f32],
    lanes: &mut [RowLanes],
    mut cols_best: Option<(&mut [f32], &mut [u32])>,
) {
    let groups = b.groups;
    let t0 = j0 / TILE;
    let tiles = cols.div_ceil(TILE);
    let lane_index = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
    let mut r0 = 0;
    while r0 < rows {
        let nr = ROWS.min(rows - r0);
        let chunk = &abc[(r0 / ROWS) * groups * ROWS..(r0 / ROWS + 1) * groups * ROWS];
        for t in 0..tiles {
            let bt = &b.data[(t0 + t) * groups * TILE * 4..(t0 + t + 1) * groups * TILE * 4];
            // SAFETY: VNNI is enabled here; `bt` holds `groups` runs of 64 bytes.
            let acc = unsafe { tile_sums(chunk, bt) };
            let c0 = t * TILE;
            let nc = TILE.min(cols - c0);
            let mask: __mmask16 = if nc == TILE { 0xffff } else { (1u16 << nc) - 1 };
            let nbt = &nb[c0..c0 + nc];
            // SAFETY: the mask reads only the tile's `nc` norms.
            let nbv = unsafe { _mm512_maskz_loadu_ps(mask, nbt.as_ptr()) };
            let j = (j0 + c0) as u32;
            let (mut v, mut k) = match &cols_best {
                // SAFETY: the mask reads only the tile's `nc` columns (asserted by the caller).
                Some((cv, ck)) => unsafe {
                    (
                        _mm512_maskz_loadu_ps(mask, cv.as_ptr().add(c0)),
                        _mm512_maskz_loadu_epi32(mask, ck.as_ptr().add(c0).cast()),
                    )
                },
                None => (_mm512_setzero_ps(), _mm512_setzero_si512()),
            };
            for (r, a) in acc.iter().enumerate().take(nr) {
                let corr = _mm512_set1_epi32(128 * suma[i0 + r0 + r]);
                let s = _mm512_cvtepi32_ps(_mm512_add_epi32(*a, corr));
                let twice = _mm512_add_ps(s, s);
                // The row's lanes: a key above a lane's best moves the best to second; one above
                // its second only replaces it (`Best2::offer`, per lane, masked to the tile).
                let ln = &mut lanes[r0 + r];
                let rk = _mm512_sub_ps(twice, nbv);
                // SAFETY: `RowLanes` holds three runs of 16 lanes.
                unsafe {
                    let b1 = _mm512_loadu_ps(ln.b1.as_ptr());
                    let b2 = _mm512_loadu_ps(ln.b2.as_ptr());
                    let m1 = _mm512_mask_cmp_ps_mask::<_CMP_GT_OQ>(mask, rk, b1);
                    let m2 = _mm512_mask_cmp_ps_mask::<_CMP_GT_OQ>(mask, rk, b2);
                    let b2 = _mm512_mask_blend_ps(m1, _mm512_mask_blend_ps(m2, b2, rk), b1);
                    _mm512_storeu_ps(ln.b2.as_mut_ptr(), b2);
                    _mm512_storeu_ps(ln.b1.as_mut_ptr(), _mm512_mask_blend_ps(m1, b1, rk));
                    let jl = _mm512_add_epi32(_mm512_set1_epi32(j as i32), lane_index);
                    _mm512_mask_storeu_epi32(ln.j1.as_mut_ptr().cast(), m1, jl);
                }
                if cols_best.is_some() {
                    let key = _mm512_sub_ps(twice, _mm512_set1_ps(na[r0 + r]));
                    let g = _mm512_mask_cmp_ps_mask::<_CMP_GT_OQ>(mask, key, v);
                    v = _mm512_mask_blend_ps(g, v, key);
                    k = _mm512_mask_blend_epi32(g, k, _mm512_set1_epi32((i0 + r0 + r) as i32));
                }
            }
            if let Some((cv, ck)) = &mut cols_best {
                // SAFETY: the mask writes only the tile's `nc` columns.
                unsafe {
                    _mm512_mask_storeu_ps(cv.as_mut_ptr().add(c0), mask, v);
                    _mm512_mask_storeu_epi32(ck.as_mut_ptr().add(c0).cast(), mask, k);
                }
            }
        }
        r0 += nr;
    }
}

/// The coarse pass of coarse-to-fine matching (`crate::matching`): [`block`] with each register
/// tile offered to the rows' lanes while still in registers, keeping per lane the two best keys
/// and **both** their columns ([`RowLanes2`]), and no column bests. Per lane the same comparisons
/// in the same order as [`crate::nearest::scan_lanes2`] over the stored block (columns in
/// increasing order, strict `>`), so the same lanes.
#[allow(clippy::too_many_arguments)]
#[target_feature(enable = "avx512f,avx512bw,avx512vnni")]
pub(super) unsafe fn block_scan2(
    abc: &[i32],
    suma: &[i32],
    i0: usize,
    rows: usize,
    b: &PackedB,
    j0: usize,
    cols: usize,
    nb: &[f32],
    lanes: &mut [RowLanes2],
) {
    let groups = b.groups;
    let t0 = j0 / TILE;
    let tiles = cols.div_ceil(TILE);
    let lane_index = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
    let mut r0 = 0;
    while r0 < rows {
        let nr = ROWS.min(rows - r0);
        let chunk = &abc[(r0 / ROWS) * groups * ROWS..(r0 / ROWS + 1) * groups * ROWS];
        for t in 0..tiles {
            let bt = &b.data[(t0 + t) * groups * TILE * 4..(t0 + t + 1) * groups * TILE * 4];
            // SAFETY: VNNI is enabled here; `bt` holds `groups` runs of 64 bytes.
            let acc = unsafe { tile_sums(chunk, bt) };
            let c0 = t * TILE;
            let nc = TILE.min(cols - c0);
            let mask: __mmask16 = if nc == TILE { 0xffff } else { (1u16 << nc) - 1 };
            // SAFETY: the mask reads only the tile's `nc` norms.
            let nbv = unsafe { _mm512_maskz_loadu_ps(mask, nb[c0..c0 + nc].as_ptr()) };
            let jl = _mm512_add_epi32(_mm512_set1_epi32((j0 + c0) as i32), lane_index);
            for (r, a) in acc.iter().enumerate().take(nr) {
                let corr = _mm512_set1_epi32(128 * suma[i0 + r0 + r]);
                let s = _mm512_cvtepi32_ps(_mm512_add_epi32(*a, corr));
                let rk = _mm512_sub_ps(_mm512_add_ps(s, s), nbv);
                let ln = &mut lanes[r0 + r];
                // SAFETY: `RowLanes2` holds four runs of 16 lanes.
                unsafe {
                    let b1 = _mm512_loadu_ps(ln.b1.as_ptr());
                    let b2 = _mm512_loadu_ps(ln.b2.as_ptr());
                    let m1 = _mm512_mask_cmp_ps_mask::<_CMP_GT_OQ>(mask, rk, b1);
                    let m2 = _mm512_mask_cmp_ps_mask::<_CMP_GT_OQ>(mask, rk, b2);
                    let j1 = _mm512_loadu_si512(ln.j1.as_ptr().cast());
                    let j2 = _mm512_loadu_si512(ln.j2.as_ptr().cast());
                    let b2 = _mm512_mask_blend_ps(m1, _mm512_mask_blend_ps(m2, b2, rk), b1);
                    let j2 = _mm512_mask_blend_epi32(m1, _mm512_mask_blend_epi32(m2, j2, jl), j1);
                    _mm512_storeu_ps(ln.b2.as_mut_ptr(), b2);
                    _mm512_storeu_si512(ln.j2.as_mut_ptr().cast(), j2);
                    _mm512_storeu_ps(ln.b1.as_mut_ptr(), _mm512_mask_blend_ps(m1, b1, rk));
                    _mm512_mask_storeu_epi32(ln.j1.as_mut_ptr().cast(), m1, jl);
                }
            }
        }
        r0 += nr;
    }
}

/// The exact products `a · b_k` of one row `a` (128 bytes, `sum_a = Σ a`) with the 16 rows
/// `js[k]` of `b` (row-major, 128 bytes a row), lane `k` of the result for `js[k]`; a `js[k]` of
/// `u32::MAX` reads row 0 (the caller ignores that lane). Each product is two `vpdpbusd` on `a`
/// and `b − 128` plus `128 Σ a`, and the 16 accumulators are summed across their lanes together
/// (a transpose-and-add tree: 45 instructions for the 16 sums instead of a reduction each).
///
/// # Safety
/// AVX-512 F/BW/VNNI must be available; `a` must hold 128 bytes and `b` every row `js` names.
#[target_feature(enable = "avx512f,avx512bw,avx512vnni")]
pub(super) unsafe fn dots16(a: &[u8], sum_a: i32, b: &[u8], js: &[u32; 16]) -> [i32; 16] {
    let top = _mm512_set1_epi8(-128);
    let mut acc = [_mm512_setzero_si512(); 16];
    // SAFETY: `a` holds 128 bytes and every row read is inside `b` (the caller's contract).
    unsafe {
        let a0 = _mm512_loadu_si512(a.as_ptr().cast());
        let a1 = _mm512_loadu_si512(a.as_ptr().add(64).cast());
        for (v, &j) in acc.iter_mut().zip(js) {
            let row = b
                .as_ptr()
                .add(if j == u32::MAX { 0 } else { j as usize * 128 });
            let b0 = _mm512_xor_si512(_mm512_loadu_si512(row.cast()), top);
            let b1 = _mm512_xor_si512(_mm512_loadu_si512(row.add(64).cast()), top);
            *v = _mm512_dpbusd_epi32(_mm512_dpbusd_epi32(*v, a0, b0), a1, b1);
        }
    }
    // Pairs of rows: within each 128-bit lane, [k0+k2, k'0+k'2, k1+k3, k'1+k'3].
    let w: [__m512i; 8] = std::array::from_fn(|p| {
        let (x, y) = (acc[2 * p], acc[2 * p + 1]);
        _mm512_add_epi32(_mm512_unpacklo_epi32(x, y), _mm512_unpackhi_epi32(x, y))
    });
    // Quads: within each 128-bit lane, the four rows' sums over that lane.
    let x: [__m512i; 4] = std::array::from_fn(|q| {
        let (u, v) = (w[2 * q], w[2 * q + 1]);
        _mm512_add_epi32(_mm512_unpacklo_epi64(u, v), _mm512_unpackhi_epi64(u, v))
    });
    // Across the 128-bit lanes: lanes (0 + 1, 2 + 3) of each quad, then of each pair of quads.
    let fold = |u: __m512i, v: __m512i| {
        _mm512_add_epi32(
            _mm512_shuffle_i32x4::<0b10_00_10_00>(u, v),
            _mm512_shuffle_i32x4::<0b11_01_11_01>(u, v),
        )
    };
    let (y, z) = (fold(x[0], x[1]), fold(x[2], x[3]));
    let sums = _mm512_add_epi32(fold(y, z), _mm512_set1_epi32(128 * sum_a));
    let mut out = [0i32; 16];
    // SAFETY: `out` holds 16 i32.
    unsafe { _mm512_storeu_si512(out.as_mut_ptr().cast(), sums) };
    out
}
