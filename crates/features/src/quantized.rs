//! Descriptor dot products in 8-bit integers, for brute-force matching.
//!
//! RootSIFT descriptors (unit L2 norm, components in [0, 1]) are quantised to `q = round(512 v)`,
//! clamped to 255, as COLMAP stores SIFT descriptors. Every product `qa · qb` is then an integer
//! below 2²⁰ (‖q‖² ≈ 512²), so it is exact in f32 as well: the scores are the same numbers whether
//! they come from the AVX-512 VNNI kernel here (`vpdpbusd`, 64 byte products per instruction,
//! eight times an AVX2 f32 FMA's), from the AVX2 kernel (`vpmaddwd` on pairs of i16, 16 products
//! per instruction) or from the f32 GEMM on the quantised values, and the matches do not depend on
//! the machine.
//!
//! `vpdpbusd` multiplies unsigned by signed bytes, so the second operand is stored as `qb − 128`
//! (signed) and `qa · qb = qa · (qb − 128) + 128 Σ qa`.

use crate::nearest::{RowLanes, RowLanes2};

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
        let (data, groups, len) = pack_tiles(q, dim, TILE, 4, |v| (i16::from(v) - 128) as i8);
        Self { data, groups, len }
    }
}

/// The `q.len() / dim` vectors of `q` packed for a kernel that takes `tile` vectors at a time and
/// `per` dimensions per word: for each tile and each group of `per` dimensions, the tile's vectors'
/// `per` values in turn (vector-major), each made by `f`; zero past `dim` and past the last
/// vector. Returns the data, the groups per vector and the vectors.
pub(crate) fn pack_tiles<T: Copy + Default>(
    q: &[u8],
    dim: usize,
    tile: usize,
    per: usize,
    f: impl Fn(u8) -> T,
) -> (Vec<T>, usize, usize) {
    let len = q.len().checked_div(dim).unwrap_or(0);
    let groups = dim.div_ceil(per);
    let mut data = vec![T::default(); len.div_ceil(tile) * groups * tile * per];
    for j in 0..len {
        let (t, c) = (j / tile, j % tile);
        for k in 0..dim {
            let (g, b) = (k / per, k % per);
            data[((t * groups + g) * tile + c) * per + b] = f(q[j * dim + k]);
        }
    }
    (data, groups, len)
}

/// Each vector of `q` (`dim` values) as `dim.div_ceil(per)` words of `per` values, `32 / per` bits
/// each, the lowest first, zero past `dim`: the first operand's rows of the AVX2 kernels.
pub(crate) fn words_of(q: &[u8], dim: usize, per: usize) -> Vec<i32> {
    let (groups, bits) = (dim.div_ceil(per), 32 / per);
    q.chunks_exact(dim.max(1))
        .flat_map(|row| {
            (0..groups).map(move |g| {
                (0..per).fold(0u32, |w, k| {
                    w | row.get(per * g + k).map_or(0, |&v| u32::from(v)) << (bits * k)
                }) as i32
            })
        })
        .collect()
}

/// The environment variable that picks the matching kernel: `avx2` runs the AVX2 path (the same
/// integer products, with the same matches) and `avx-vnni` the 256-bit VNNI path, even where the
/// CPU has AVX-512 VNNI, so that every path is measured on one machine; `auto` (or unset) takes
/// the best the CPU has.
pub const SIMD_ENV: &str = "HANDHELD_SIMD";

/// The values [`SIMD_ENV`] takes.
pub const SIMD_VALUES: [&str; 3] = ["auto", "avx2", "avx-vnni"];

/// The brute-force kernels, fastest first.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kernel {
    /// AVX-512 F/BW/VNNI: `vpdpbusd` on 512-bit registers.
    Avx512Vnni,
    /// AVX-VNNI (Intel since Alder Lake, AMD since Zen 5): `vpdpbusd` on 256-bit registers.
    AvxVnni,
    /// AVX2: `vpmaddwd` on pairs of i16.
    Avx2,
    /// Anything else: the f32 GEMM on the quantised values.
    Portable,
}

impl Kernel {
    /// The name `bench` prints.
    pub fn name(self) -> &'static str {
        match self {
            Kernel::Avx512Vnni => "avx512-vnni",
            Kernel::AvxVnni => "avx-vnni",
            Kernel::Avx2 => "avx2",
            Kernel::Portable => "portable",
        }
    }
}

/// The value of [`SIMD_ENV`], lower-cased and trimmed (`auto` when unset).
fn simd_choice() -> &'static str {
    static CHOICE: std::sync::OnceLock<String> = std::sync::OnceLock::new();
    CHOICE.get_or_init(|| {
        std::env::var(SIMD_ENV)
            .map_or_else(|_| "auto".to_string(), |v| v.trim().to_ascii_lowercase())
    })
}

/// The error for a value of [`SIMD_ENV`] that is not one of [`SIMD_VALUES`].
pub fn simd_env_error() -> Option<String> {
    let v = std::env::var(SIMD_ENV).ok()?;
    let known = SIMD_VALUES.iter().any(|k| v.trim().eq_ignore_ascii_case(k));
    (!known).then(|| {
        format!(
            "{SIMD_ENV}={v:?} is not a kernel choice: use `avx2` (the AVX2 path on any CPU with AVX2), `avx-vnni` (the 256-bit VNNI path, on a CPU with AVX-VNNI) or `auto` (the best this CPU has), or unset it"
        )
    })
}

/// The brute-force kernel that runs: the best this CPU has, or a slower one [`SIMD_ENV`] asks
/// for (a kernel the CPU lacks is never run: `avx-vnni` on a CPU without it is `auto`).
pub fn kernel() -> Kernel {
    let best = if cpu_has_vnni() {
        Kernel::Avx512Vnni
    } else if cpu_has_avx_vnni() {
        Kernel::AvxVnni
    } else if cpu_has_avx2() {
        Kernel::Avx2
    } else {
        Kernel::Portable
    };
    let asked = match simd_choice() {
        "avx2" if cpu_has_avx2() => Kernel::Avx2,
        "avx-vnni" if cpu_has_avx_vnni() => Kernel::AvxVnni,
        _ => best,
    };
    // Never faster than the CPU allows (the enum is ordered fastest first).
    if (asked as u8) < (best as u8) {
        best
    } else {
        asked
    }
}

/// The matching kernel that runs, by name (printed by the benchmarks).
pub fn simd_path() -> &'static str {
    kernel().name()
}

/// Whether the matcher runs the AVX-512 VNNI kernel.
pub fn have_vnni() -> bool {
    kernel() == Kernel::Avx512Vnni
}

/// Whether this CPU can run the AVX-VNNI kernel (AVX2 and AVX-VNNI).
pub fn cpu_has_avx_vnni() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2")
            && std::arch::is_x86_feature_detected!("avxvnni")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
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
/// `dim` columns, its row sums `suma`, and `b` packed by [`PackedB::new`], by the AVX-512 VNNI
/// kernel (`wide`) or the AVX-VNNI one (256-bit registers: each 64-byte group of `b` is two
/// registers of 8 columns). `j0` must be a multiple of 16. Only call when the CPU has the kernel
/// ([`cpu_has_vnni`], [`cpu_has_avx_vnni`]).
#[allow(clippy::too_many_arguments)]
pub fn scores_block(
    wide: bool,
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
    assert!(qa.len() >= (i0 + rows) * dim && dim.div_ceil(4) == b.groups);
    let abc = RowGroups::new(wide, qa, dim, i0, rows);
    scores_block_grouped(&abc, suma, b, j0, cols, out);
}

/// Rows `i0..i0 + rows` of the first operand laid out for a VNNI kernel (4-byte groups, broadcast
/// once per row chunk of the kernel's register tile): made once per row block and used for every
/// column block of it ([`scores_block_grouped`]).
pub struct RowGroups {
    abc: Vec<i32>,
    wide: bool,
    i0: usize,
    rows: usize,
    groups: usize,
}

impl RowGroups {
    /// The layout from row `i0` on, for the fused AVX-512 kernels over rows `i0..i0 + rows` (a
    /// whole number of row chunks after the layout's first row) and columns `j0..j0 + cols` of
    /// `b` (`j0` a multiple of the tile); asserts that the operands fit.
    fn wide_rows(
        &self,
        i0: usize,
        rows: usize,
        suma: &[i32],
        b: &PackedB,
        j0: usize,
        cols: usize,
    ) -> &[i32] {
        #[cfg(target_arch = "x86_64")]
        let per_chunk = vnni::ROWS;
        #[cfg(not(target_arch = "x86_64"))]
        let per_chunk = 8;
        assert!(
            i0 >= self.i0
                && (i0 - self.i0).is_multiple_of(per_chunk)
                && i0 + rows <= self.i0 + self.rows
        );
        assert!(j0.is_multiple_of(TILE) && j0 + cols <= b.len);
        assert!(suma.len() >= i0 + rows && self.groups == b.groups);
        &self.abc[(i0 - self.i0) / per_chunk * self.groups * per_chunk..]
    }

    /// Whether laid out for the AVX-512 VNNI kernel (else for AVX-VNNI).
    pub fn wide(&self) -> bool {
        self.wide
    }

    pub fn new(wide: bool, qa: &[u8], dim: usize, i0: usize, rows: usize) -> Self {
        assert!(qa.len() >= (i0 + rows) * dim);
        let groups = dim.div_ceil(4);
        #[cfg(target_arch = "x86_64")]
        let per_chunk = if wide { vnni::ROWS } else { avx_vnni::ROWS };
        #[cfg(not(target_arch = "x86_64"))]
        let per_chunk = 8;
        Self {
            abc: vnni_row_groups(qa, dim, i0, rows, groups, per_chunk),
            wide,
            i0,
            rows,
            groups,
        }
    }
}

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
fn vnni_row_groups(
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

/// [`scores_block`] from the rows' [`RowGroups`] (the same scores).
pub fn scores_block_grouped(
    a: &RowGroups,
    suma: &[i32],
    b: &PackedB,
    j0: usize,
    cols: usize,
    out: &mut [f32],
) {
    let (i0, rows) = (a.i0, a.rows);
    assert!(j0.is_multiple_of(TILE) && j0 + cols <= b.len && out.len() >= rows * cols);
    assert!(suma.len() >= i0 + rows && a.groups == b.groups);
    assert!(if a.wide {
        cpu_has_vnni()
    } else {
        cpu_has_avx_vnni()
    });
    #[cfg(target_arch = "x86_64")]
    // SAFETY: the CPU has the kernel's instructions (asserted above); the asserted lengths cover
    // every element the kernels address (see `vnni::block`, `avx_vnni::block`), and `a` was laid
    // out for this kernel's row chunks.
    unsafe {
        if a.wide {
            vnni::block(&a.abc, suma, i0, rows, b, j0, cols, out)
        } else {
            avx_vnni::block(&a.abc, suma, i0, rows, b, j0, cols, out)
        }
    }
}

/// [`scores_block_grouped`] and [`crate::nearest::scan_block`] in one pass over the rows
/// `i0..i0 + rows` of `a` (laid out `wide`, for the AVX-512 VNNI kernel, from a row a whole number
/// of chunks of 8 before `i0`: a whole image's layout serves every row block of it): each
/// register tile is scanned while still in registers, and no score block is written. The same result as the two calls once each row's `lanes` are merged
/// ([`RowLanes::merge`]): `na` are the rows' squared norms (`a.rows` of them), `nb` the columns'
/// (`cols`), `lanes` one entry per row, `cols_best` one per column.
#[allow(clippy::too_many_arguments)]
pub(crate) fn scan_scores_grouped(
    a: &RowGroups,
    (i0, rows): (usize, usize),
    suma: &[i32],
    b: &PackedB,
    j0: usize,
    cols: usize,
    na: &[f32],
    nb: &[f32],
    lanes: &mut [RowLanes],
    cols_best: Option<(&mut [f32], &mut [u32])>,
) {
    let abc = a.wide_rows(i0, rows, suma, b, j0, cols);
    assert!(na.len() >= rows && nb.len() >= cols && lanes.len() >= rows);
    if let Some((v, k)) = &cols_best {
        assert!(v.len() >= cols && k.len() >= cols);
    }
    assert!(a.wide && cpu_has_vnni());
    #[cfg(target_arch = "x86_64")]
    // SAFETY: the CPU has AVX-512 VNNI (asserted above); the asserted lengths cover every element
    // the kernel addresses, and `a` was laid out for its row chunks.
    unsafe {
        vnni::block_scan(abc, suma, i0, rows, b, j0, cols, na, nb, lanes, cols_best)
    }
}

/// The coarse pass of coarse-to-fine matching over rows `i0..i0 + rows` of `a` (laid out as for
/// [`scan_scores_grouped`]) and columns `j0..j0 + cols`: each row's lanes keep their two best
/// keys and both columns ([`RowLanes2`]); the same lanes as [`scores_block_grouped`] followed by
/// [`crate::nearest::scan_lanes2`]. Only where the CPU has AVX-512 VNNI.
#[allow(clippy::too_many_arguments)]
pub(crate) fn scan_lanes2_grouped(
    a: &RowGroups,
    (i0, rows): (usize, usize),
    suma: &[i32],
    b: &PackedB,
    j0: usize,
    cols: usize,
    nb: &[f32],
    lanes: &mut [RowLanes2],
) {
    let abc = a.wide_rows(i0, rows, suma, b, j0, cols);
    assert!(nb.len() >= cols && lanes.len() >= rows);
    assert!(a.wide && cpu_has_vnni());
    #[cfg(target_arch = "x86_64")]
    // SAFETY: the CPU has AVX-512 VNNI (asserted above); the asserted lengths cover every element
    // the kernel addresses, and `a` was laid out for its row chunks.
    unsafe {
        vnni::block_scan2(abc, suma, i0, rows, b, j0, cols, nb, lanes)
    }
}

/// The exact products of one quantised 128-dimensional row `a` (`sum_a = Σ a`) with the 16 rows
/// `js` of `b` (row-major; `u32::MAX` reads row 0, to be ignored) by AVX-512 VNNI.
///
/// # Safety
/// The CPU must have AVX-512 F/BW/VNNI ([`cpu_has_vnni`]).
#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx512vnni")]
pub unsafe fn dots16(a: &[u8], sum_a: i32, b: &[u8], js: &[u32; 16]) -> [i32; 16] {
    assert!(a.len() == 128 && !b.is_empty() && b.len().is_multiple_of(128));
    assert!(js
        .iter()
        .all(|&j| j == u32::MAX || (j as usize + 1) * 128 <= b.len()));
    // SAFETY: the CPU has AVX-512 VNNI (the caller's contract); every row read is in `b`.
    unsafe { vnni::dots16(a, sum_a, b, js) }
}

/// Dimensions of the coarse codes ([`coarse_codes`]).
pub const COARSE_DIM: usize = 32;

/// The coarse codes of quantised 128-dimensional descriptors (`q`, row-major, from [`quantize`]):
/// each descriptor `q / 512` projected on the first [`COARSE_DIM`] principal axes of RootSIFT
/// (`pca.rs`, made by `scripts/sift_pca.py`) and stored as `round(s · y) + 64` in 7 bits, so that
/// the brute-force kernels rank descriptors by these codes exactly as they rank them by the full
/// descriptors, at a quarter of the products. A projection on orthonormal axes only shortens
/// distances, and 85 % of the descriptors' variance lies on these 32 axes, so a descriptor's nearest
/// neighbours are among the nearest by code ([`crate::matching`] keeps 32 of them per row and ranks
/// those on all 128 dimensions). The sums run in a fixed order in f32, so the codes are the same on
/// every machine. Seven bits (the projections at half the scale of `pca.rs`, 60 code units at its
/// 99.99th percentile) let the AVX2 path multiply the codes as bytes
/// ([`scores_block_avx2_bytes`]: monstree-phone's forced-AVX2 matches stage 5.23 → 4.65 s); the
/// ten sets' sparse models came out the same as with eight bits, within 0.03 AUC@1 points. `None`
/// for any other dimension.
pub fn coarse_codes(q: &[u8], dim: usize) -> Option<Vec<u8>> {
    if dim != pca::MEAN.len() {
        return None;
    }
    // The axes by dimension, so that the 32 projections of a row accumulate side by side (each
    // still over the dimensions in order: the same sums as one axis at a time).
    static BY_DIMENSION: std::sync::OnceLock<Vec<[f32; COARSE_DIM]>> = std::sync::OnceLock::new();
    let by_dimension = BY_DIMENSION.get_or_init(|| {
        (0..dim)
            .map(|k| std::array::from_fn(|c| pca::AXES[c][k]))
            .collect()
    });
    let mut out = vec![0u8; q.len() / dim * COARSE_DIM];
    for (row, code) in q.chunks_exact(dim).zip(out.chunks_exact_mut(COARSE_DIM)) {
        let mut y = [0f32; COARSE_DIM];
        for ((&v, m), axes) in row.iter().zip(&pca::MEAN).zip(by_dimension) {
            let x = f32::from(v) / SCALE - m;
            for (y, a) in y.iter_mut().zip(axes) {
                *y += a * x;
            }
        }
        for (c, y) in code.iter_mut().zip(y) {
            *c = ((y * coarse_scale()).round().clamp(-64.0, 63.0) + 64.0) as u8;
        }
    }
    Some(out)
}

/// Code units per unit of projection of [`coarse_codes`]: half of `pca::SCALE`, so that the
/// 99.99th percentile of a projection maps to 60 and every code fits in 7 bits.
pub fn coarse_scale() -> f32 {
    0.5 * pca::SCALE
}

#[rustfmt::skip]
mod pca;

mod packed;
use packed::TILE_I16;
pub use packed::{
    cpu_has_avx2, pairs_of, quads_of, scores_block_avx2, scores_block_avx2_bytes, PackedBytes,
    PackedI16,
};

#[cfg(target_arch = "x86_64")]
mod avx2;

#[cfg(target_arch = "x86_64")]
mod avx_vnni;

#[cfg(target_arch = "x86_64")]
mod vnni;

#[cfg(test)]
mod tests;
