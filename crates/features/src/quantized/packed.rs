//! The AVX2 path's layouts and entry points ([`scores_block_avx2`] on pairs of i16,
//! [`scores_block_avx2_bytes`] on 7-bit vectors), for CPUs without VNNI; the kernels are in
//! `avx2.rs`. Split from `quantized.rs`.

#[cfg(target_arch = "x86_64")]
use super::avx2;

/// Columns per tile of the AVX2 kernel: two 256-bit registers of i32 sums.
pub(super) const TILE_I16: usize = 16;

/// The second operand of [`scores_block_avx2`], packed once per descriptor set: for each tile of
/// 16 descriptors and each pair of dimensions `(2g, 2g + 1)`, the 16 descriptors' two values as
/// i16 (descriptor-major: 32 values, 64 bytes), zero-padded to whole tiles and pairs.
pub struct PackedI16 {
    pub(super) data: Vec<i16>,
    pub(super) pairs: usize,
    pub(super) len: usize,
}

impl PackedI16 {
    pub fn new(q: &[u8], dim: usize) -> Self {
        let (data, pairs, len) = super::pack_tiles(q, dim, TILE_I16, 2, i16::from);
        Self { data, pairs, len }
    }
}

/// The rows of A for [`scores_block_avx2`]: row `i`'s dimensions `(2g, 2g + 1)` as two i16 in one
/// i32 (low half first), `dim.div_ceil(2)` words per row, zero past `dim`.
pub fn pairs_of(q: &[u8], dim: usize) -> Vec<i32> {
    super::words_of(q, dim, 2)
}

/// Whether this CPU runs the AVX2 kernel.
pub fn cpu_has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// [`super::scores_block`] for CPUs without VNNI: the same integer products, two dimensions at a time by
/// `vpmaddwd` (16 products per instruction, twice an f32 FMA's 8, on half the bytes of B), summed
/// in i32. `pa` holds A's rows by [`pairs_of`] and `b` is packed once per pair of images. The sums
/// are exact (below 128 · 255² < 2²⁴), so the scores are the VNNI kernel's. `j0` must be a multiple
/// of 16. Only call when [`cpu_has_avx2`] is true.
#[allow(clippy::too_many_arguments)]
pub fn scores_block_avx2(
    pa: &[i32],
    dim: usize,
    i0: usize,
    rows: usize,
    b: &PackedI16,
    j0: usize,
    cols: usize,
    out: &mut [f32],
) {
    let pairs = dim.div_ceil(2);
    assert!(j0.is_multiple_of(TILE_I16) && j0 + cols <= b.len && out.len() >= rows * cols);
    assert!(rows > 0 && pa.len() >= (i0 + rows) * pairs && pairs == b.pairs);
    assert!(cpu_has_avx2());
    #[cfg(target_arch = "x86_64")]
    // SAFETY: the CPU has AVX2 (asserted above); the asserted lengths cover every element the
    // kernel addresses (see `avx2::block`).
    unsafe {
        avx2::block(pa, i0, rows, b, j0, cols, out)
    }
}

/// The second operand of [`scores_block_avx2_bytes`], packed once per set of 7-bit vectors: for
/// each tile of 16 vectors and each group of four dimensions, the 16 vectors' four values less 64
/// as i8 (vector-major: 64 bytes), zero-padded to whole tiles and groups.
pub struct PackedBytes {
    pub(super) data: Vec<i8>,
    pub(super) groups: usize,
    pub(super) len: usize,
}

impl PackedBytes {
    /// `q` holds vectors of `dim` values below 128 (checked).
    pub fn new(q: &[u8], dim: usize) -> Self {
        assert!(q.iter().all(|&v| v < 128), "values of 7 bits");
        let (data, groups, len) = super::pack_tiles(q, dim, TILE_I16, 4, |v| v as i8 - 64);
        Self { data, groups, len }
    }
}

/// The rows of A for [`scores_block_avx2_bytes`]: row `i`'s dimensions `4g..4g + 4` as four bytes
/// of one i32 (the lowest first), `dim.div_ceil(4)` words per row, zero past `dim`.
pub fn quads_of(q: &[u8], dim: usize) -> Vec<i32> {
    super::words_of(q, dim, 4)
}

/// [`scores_block_avx2`] for vectors of values below 128 (the coarse codes, [`super::coarse_codes`]):
/// `vpmaddubsw` multiplies 32 byte pairs an instruction where `vpmaddwd` multiplies 16 pairs of
/// i16, and its pair sums stay exact when one side is unsigned below 128 and the other signed
/// within ±64 (the set's values less 64; the rows' `64 · Σ u`, `sums`, is added back). The same
/// integer scores. `j0` must be a multiple of 16. Only call when [`cpu_has_avx2`] is true.
#[allow(clippy::too_many_arguments)]
pub fn scores_block_avx2_bytes(
    pa: &[i32],
    sums: &[i32],
    dim: usize,
    i0: usize,
    rows: usize,
    b: &PackedBytes,
    j0: usize,
    cols: usize,
    out: &mut [f32],
) {
    let groups = dim.div_ceil(4);
    assert!(j0.is_multiple_of(TILE_I16) && j0 + cols <= b.len && out.len() >= rows * cols);
    assert!(rows > 0 && pa.len() >= (i0 + rows) * groups && groups == b.groups);
    assert!(sums.len() >= i0 + rows);
    assert!(cpu_has_avx2());
    #[cfg(target_arch = "x86_64")]
    // SAFETY: the CPU has AVX2 (asserted above); the asserted lengths cover every element the
    // kernel addresses (see `avx2::block_bytes`).
    unsafe {
        avx2::block_bytes(pa, sums, i0, rows, b, j0, cols, out)
    }
}
