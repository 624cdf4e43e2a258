//! Descriptor dot products in 8-bit integers, for brute-force matching.
//!
//! RootSIFT descriptors (unit L2 norm, components in [0, 1]) are quantised to `q = round(512 v)`,
//! clamped to 255, as COLMAP stores SIFT descriptors. Every product `qa · qb` is then an integer
//! below 2²⁰ (‖q‖² ≈ 512²), so it is exact in f32 as well: the scores are the same numbers whether
//! they come from the AVX-512 VNNI kernel here (`vpdpbusd`, 64 byte products per instruction,
//! four times the f32 FMA rate) or from the f32 GEMM on the quantised values, and the matches do
//! not depend on the machine.
//!
//! `vpdpbusd` multiplies unsigned by signed bytes, so the second operand is stored as `qb − 128`
//! (signed) and `qa · qb = qa · (qb − 128) + 128 Σ qa`.

/// The quantisation scale of [`quantize`].
pub const SCALE: f32 = 512.0;

/// Whether every value is in [0, 1], as RootSIFT's are (and not NaN): only such descriptors are
/// quantised. (A component above 255/512 is clamped, as COLMAP clamps; RootSIFT rarely has one.)
pub fn fits(data: &[f32]) -> bool {
    data.iter().all(|v| (0.0..=1.0).contains(v))
}

/// `round(SCALE · v)` clamped to [0, 255], row-major like the input.
pub fn quantize(data: &[f32]) -> Vec<u8> {
    data.iter()
        .map(|&v| (v * SCALE).round().clamp(0.0, 255.0) as u8)
        .collect()
}

/// The quantised values as f32 (exact), for the portable path.
pub fn dequantized(q: &[u8]) -> Vec<f32> {
    q.iter().map(|&v| f32::from(v)).collect()
}

/// Columns per kernel tile: one 512-bit register of i32 sums.
const TILE: usize = 16;

/// The second operand of [`scores_block`], packed once per descriptor set: for each tile of 16
/// descriptors and each group of 4 dimensions, 64 bytes `(qb − 128)` (descriptor-major within
/// the group), zero-padded to whole tiles and groups.
pub struct PackedB {
    data: Vec<i8>,
    groups: usize,
    len: usize,
}

impl PackedB {
    pub fn new(q: &[u8], dim: usize) -> Self {
        let len = q.len().checked_div(dim).unwrap_or(0);
        let groups = dim.div_ceil(4);
        let tiles = len.div_ceil(TILE);
        let mut data = vec![0i8; tiles * groups * TILE * 4];
        for j in 0..len {
            let (t, c) = (j / TILE, j % TILE);
            for k in 0..dim {
                let (g, b) = (k / 4, k % 4);
                data[((t * groups + g) * TILE + c) * 4 + b] =
                    (i16::from(q[j * dim + k]) - 128) as i8;
            }
        }
        Self { data, groups, len }
    }
}

/// The environment variable that picks the matching kernel: `avx2` runs the AVX2 path (the f32
/// product on the same integers, with the same matches) even where the CPU has AVX-512 VNNI, so
/// that both paths are measured on one machine; `auto` (or unset) takes the best the CPU has.
pub const SIMD_ENV: &str = "HANDHELD_SIMD";

/// The values [`SIMD_ENV`] takes.
pub const SIMD_VALUES: [&str; 2] = ["auto", "avx2"];

/// Whether [`SIMD_ENV`] asks for the AVX2 path. Any other value than [`SIMD_VALUES`] is `auto`
/// here; the CLI refuses it before any work ([`simd_env_error`]).
fn forced_avx2() -> bool {
    static FORCED: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *FORCED.get_or_init(|| {
        std::env::var(SIMD_ENV).is_ok_and(|v| v.trim().eq_ignore_ascii_case("avx2"))
    })
}

/// The error for a value of [`SIMD_ENV`] that is not one of [`SIMD_VALUES`].
pub fn simd_env_error() -> Option<String> {
    let v = std::env::var(SIMD_ENV).ok()?;
    let known = SIMD_VALUES.iter().any(|k| v.trim().eq_ignore_ascii_case(k));
    (!known).then(|| {
        format!(
            "{SIMD_ENV}={v:?} is not a kernel choice: use `avx2` (the AVX2 path on any CPU) or `auto` (the best this CPU has), or unset it"
        )
    })
}

/// The matching kernel that runs: `avx512-vnni` or `avx2` (printed by the benchmarks).
pub fn simd_path() -> &'static str {
    if have_vnni() {
        "avx512-vnni"
    } else {
        "avx2"
    }
}

/// Whether the matcher runs the VNNI kernel: the CPU has AVX-512 F, BW and VNNI, and [`SIMD_ENV`]
/// does not ask for the AVX2 path.
pub fn have_vnni() -> bool {
    cpu_has_vnni() && !forced_avx2()
}

/// Whether this CPU can run the VNNI kernel (AVX-512 F, BW and VNNI).
pub fn cpu_has_vnni() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx512f")
            && std::arch::is_x86_feature_detected!("avx512bw")
            && std::arch::is_x86_feature_detected!("avx512vnni")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// `out (rows × cols) = qa[i0..i0+rows] · qb[j0..j0+cols]ᵀ` as f32, for `qa` row-major with
/// `dim` columns, its row sums `suma`, and `b` packed by [`PackedB::new`]. `j0` must be a
/// multiple of 16. Only call when [`cpu_has_vnni`] is true.
#[allow(clippy::too_many_arguments)]
pub fn scores_block(
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
    assert!(j0.is_multiple_of(TILE) && j0 + cols <= b.len && out.len() >= rows * cols);
    assert!(
        qa.len() >= (i0 + rows) * dim && suma.len() >= i0 + rows && dim.div_ceil(4) == b.groups
    );
    assert!(cpu_has_vnni());
    #[cfg(target_arch = "x86_64")]
    // SAFETY: the CPU has AVX-512 F/BW/VNNI (asserted above); the asserted lengths cover every
    // element the kernel addresses (see `vnni::block`).
    unsafe {
        vnni::block(qa, suma, dim, i0, rows, b, j0, cols, out)
    }
}

/// Columns per tile of the AVX2 kernel: two 256-bit registers of f32 sums.
const TILE_F32: usize = 16;

/// The second operand of [`scores_block_avx2`], packed once per descriptor set: for each tile of
/// 16 descriptors and each dimension, the 16 values as f32 (exact integers), zero-padded.
pub struct PackedF32 {
    data: Vec<f32>,
    dim: usize,
    len: usize,
}

impl PackedF32 {
    pub fn new(q: &[u8], dim: usize) -> Self {
        let len = q.len().checked_div(dim).unwrap_or(0);
        let tiles = len.div_ceil(TILE_F32);
        let mut data = vec![0f32; tiles * dim * TILE_F32];
        for j in 0..len {
            let (t, c) = (j / TILE_F32, j % TILE_F32);
            for k in 0..dim {
                data[(t * dim + k) * TILE_F32 + c] = f32::from(q[j * dim + k]);
            }
        }
        Self { data, dim, len }
    }
}

/// Whether this CPU runs the AVX2 kernel (AVX2 and FMA).
pub fn cpu_has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// [`scores_block`] for CPUs without VNNI: the same products, as f32 FMAs on the quantised values
/// (`fa` = [`dequantized`] rows of A, row-major), with `b` packed once per pair instead of the
/// general GEMM's packing on every call. Every product is an integer below 2²⁴, so the sums are
/// exact in any order: the scores are the VNNI kernel's. `j0` must be a multiple of 16. Only
/// call when [`cpu_has_avx2`] is true.
#[allow(clippy::too_many_arguments)]
pub fn scores_block_avx2(
    fa: &[f32],
    dim: usize,
    i0: usize,
    rows: usize,
    b: &PackedF32,
    j0: usize,
    cols: usize,
    out: &mut [f32],
) {
    assert!(j0.is_multiple_of(TILE_F32) && j0 + cols <= b.len && out.len() >= rows * cols);
    assert!(rows > 0 && fa.len() >= (i0 + rows) * dim && dim == b.dim);
    assert!(cpu_has_avx2());
    #[cfg(target_arch = "x86_64")]
    // SAFETY: the CPU has AVX2 and FMA (asserted above); the asserted lengths cover every element
    // the kernel addresses (see `avx2::block`).
    unsafe {
        avx2::block(fa, dim, i0, rows, b, j0, cols, out)
    }
}

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::{PackedF32, TILE_F32};
    use std::arch::x86_64::*;

    /// Rows per register tile: 6 rows × 2 registers of 8 sums, 12 accumulators (of 16 registers).
    const ROWS: usize = 6;

    #[allow(clippy::too_many_arguments)]
    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn block(
        fa: &[f32],
        dim: usize,
        i0: usize,
        rows: usize,
        b: &PackedF32,
        j0: usize,
        cols: usize,
        out: &mut [f32],
    ) {
        let t0 = j0 / TILE_F32;
        let tiles = cols.div_ceil(TILE_F32);
        let mut r0 = 0;
        while r0 < rows {
            let nr = ROWS.min(rows - r0);
            // Rows past the block repeat its last row: read, summed, not stored.
            let arow: [&[f32]; ROWS] = std::array::from_fn(|r| {
                let i = i0 + r0 + r.min(nr - 1);
                &fa[i * dim..(i + 1) * dim]
            });
            for t in 0..tiles {
                let bt = &b.data[(t0 + t) * dim * TILE_F32..(t0 + t + 1) * dim * TILE_F32];
                let mut lo = [_mm256_setzero_ps(); ROWS];
                let mut hi = [_mm256_setzero_ps(); ROWS];
                for (k, bk) in bt.chunks_exact(TILE_F32).enumerate() {
                    // SAFETY: `bk` holds 16 floats.
                    let (b0, b1) = unsafe {
                        (
                            _mm256_loadu_ps(bk.as_ptr()),
                            _mm256_loadu_ps(bk.as_ptr().add(8)),
                        )
                    };
                    for r in 0..ROWS {
                        // SAFETY: every row slice has `dim` floats and k < dim.
                        let a = _mm256_set1_ps(unsafe { *arow[r].get_unchecked(k) });
                        lo[r] = _mm256_fmadd_ps(a, b0, lo[r]);
                        hi[r] = _mm256_fmadd_ps(a, b1, hi[r]);
                    }
                }
                let c0 = t * TILE_F32;
                let nc = TILE_F32.min(cols - c0);
                for r in 0..nr {
                    let at = (r0 + r) * cols + c0;
                    let dst = &mut out[at..at + nc];
                    if nc == TILE_F32 {
                        // SAFETY: `dst` holds 16 floats.
                        unsafe {
                            _mm256_storeu_ps(dst.as_mut_ptr(), lo[r]);
                            _mm256_storeu_ps(dst.as_mut_ptr().add(8), hi[r]);
                        }
                    } else {
                        let mut tile = [0f32; TILE_F32];
                        // SAFETY: `tile` holds 16 floats.
                        unsafe {
                            _mm256_storeu_ps(tile.as_mut_ptr(), lo[r]);
                            _mm256_storeu_ps(tile.as_mut_ptr().add(8), hi[r]);
                        }
                        dst.copy_from_slice(&tile[..nc]);
                    }
                }
            }
            r0 += nr;
        }
    }
}

#[cfg(target_arch = "x86_64")]
mod vnni {
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
        // Row groups, broadcast once per row block, laid out [row chunk of ROWS][group][row in
        // chunk] so that one group's ROWS broadcasts read consecutive words; rows past the block
        // are zero (their sums are computed and not stored).
        let chunks = rows.div_ceil(ROWS);
        let mut abc = vec![0i32; chunks * groups * ROWS];
        for r in 0..rows {
            for g in 0..groups {
                abc[((r / ROWS) * groups + g) * ROWS + r % ROWS] = group(qa, dim, i0 + r, g);
            }
        }
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
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A seeded linear congruential generator of 31-bit values.
    fn lcg(mut s: u64) -> impl FnMut() -> u32 {
        move || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 33) as u32
        }
    }

    /// Every score of the block `(i0, rows, j0, cols)` equals the exact integer product.
    fn assert_exact(
        qa: &[u8],
        qb: &[u8],
        dim: usize,
        block: (usize, usize, usize, usize),
        out: &[f32],
    ) {
        let (i0, rows, j0, cols) = block;
        for r in 0..rows {
            for c in 0..cols {
                let (i, j) = (i0 + r, j0 + c);
                let exact: i64 = (0..dim)
                    .map(|k| i64::from(qa[i * dim + k]) * i64::from(qb[j * dim + k]))
                    .sum();
                assert_eq!(out[r * cols + c] as i64, exact, "({i}, {j})");
            }
        }
    }

    #[test]
    #[cfg_attr(
        not(has_vnni),
        ignore = "needs a CPU with AVX-512 VNNI (this one has none)"
    )]
    fn vnni_scores_equal_the_exact_integer_products() {
        assert!(cpu_has_vnni(), "this CPU has no AVX-512 VNNI");
        let mut rnd = lcg(7);
        for &(n, m, dim) in &[(37usize, 53usize, 128usize), (8, 16, 128), (5, 21, 10)] {
            let qa: Vec<u8> = (0..n * dim).map(|_| rnd() as u8).collect();
            let qb: Vec<u8> = (0..m * dim).map(|_| rnd() as u8).collect();
            let suma: Vec<i32> = qa
                .chunks_exact(dim)
                .map(|r| r.iter().map(|&v| i32::from(v)).sum())
                .collect();
            let packed = PackedB::new(&qb, dim);
            let (i0, rows, j0, cols) = (1, n - 2, 16, m - 16);
            let mut out = vec![0f32; rows * cols];
            scores_block(&qa, &suma, dim, i0, rows, &packed, j0, cols, &mut out);
            assert_exact(&qa, &qb, dim, (i0, rows, j0, cols), &out);
        }
    }

    #[test]
    fn avx2_scores_equal_the_exact_integer_products() {
        if !cpu_has_avx2() {
            eprintln!("skipped: this CPU has no AVX2/FMA");
            return;
        }
        let mut rnd = lcg(11);
        // Sizes that leave partial row groups (of 6) and partial tiles (of 16); 255s everywhere in
        // the last case, the largest sums (128 · 255², below 2²⁴).
        for &(n, m, dim, full) in &[
            (37usize, 53usize, 128usize, false),
            (8, 16, 128, false),
            (5, 37, 10, false),
            (9, 40, 128, true),
        ] {
            let mut draw = || if full { 255u8 } else { rnd() as u8 };
            let qa: Vec<u8> = (0..n * dim).map(|_| draw()).collect();
            let qb: Vec<u8> = (0..m * dim).map(|_| draw()).collect();
            let packed = PackedF32::new(&qb, dim);
            let fa = dequantized(&qa);
            let (i0, rows, j0, cols) = (1, n - 2, 16, m - 16);
            let mut out = vec![0f32; rows * cols];
            scores_block_avx2(&fa, dim, i0, rows, &packed, j0, cols, &mut out);
            assert_exact(&qa, &qb, dim, (i0, rows, j0, cols), &out);
        }
    }
}
