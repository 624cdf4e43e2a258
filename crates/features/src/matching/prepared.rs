//! Descriptor sets prepared once for the brute-force product ([`Prepared`]): quantised and normed,
//! with the kernel's layout made on first use. Split from `matching.rs`.

use std::sync::OnceLock;

use crate::detector::Descriptors;
use crate::quantized;

/// One descriptor set ready to be either operand of the brute-force product: quantised and
/// normed once ([`prepare`]), so that an image matched against many others pays for that once
/// (seeded matching matches each image's seeds against every other image's). The kernels' layouts
/// are made on first use and kept: a set that is only ever matched coarse to fine never makes the
/// full search's (a third of its memory; on the low-texture set the prepared images no longer
/// fill the CPU's last-level cache).
pub struct Prepared {
    pub(super) n: usize,
    pub(super) d: usize,
    /// Squared norms, in the units of the scores.
    pub(super) norms: Vec<f32>,
    /// Scores per unit of squared descriptor distance (`quantized::SCALE`, or 1 unquantised).
    pub(super) unit: f32,
    pub(super) kernel: quantized::Kernel,
    pub(super) rows: Rows,
    /// Every value below 128 (the coarse codes): the AVX2 path multiplies bytes
    /// ([`quantized::scores_block_avx2_bytes`]).
    pub(super) seven_bit: bool,
    /// The layout of the kernel, made on first use.
    pub(super) layout: OnceLock<Layout>,
    /// The coarse codes ([`quantized::coarse_codes`]), prepared alike (quantised 128-dimensional
    /// sets only).
    pub(super) coarse: Option<Box<Prepared>>,
}

/// The rows, row-major: quantised, with each row's `Σ q` (the VNNI kernels' correction), or the
/// raw values of descriptors that are not in [0, 1].
pub(super) enum Rows {
    Quantised { q: Vec<u8>, sums: Vec<i32> },
    Raw(Vec<f32>),
}

/// How the score blocks are computed: a VNNI kernel (512- or 256-bit, `wide`) on the quantised
/// first set (with its row sums) and the packed second set, the AVX2 kernel, or the f32 GEMM (on
/// the quantised values, the same numbers; see `quantized`), or on the raw values of descriptors
/// that are not in [0, 1] (`F32(None)`: the rows themselves).
pub(super) enum Layout {
    Vnni {
        /// Every row laid out for the AVX-512 VNNI kernel (`wide` only).
        rows: Option<quantized::RowGroups>,
        packed: quantized::PackedB,
        wide: bool,
    },
    /// Without VNNI: rows as pairs of i16 and the set packed ([`quantized::scores_block_avx2`]).
    Avx2(Vec<i32>, quantized::PackedI16),
    /// Without VNNI, values below 128: rows as groups of four bytes and the set packed
    /// ([`quantized::scores_block_avx2_bytes`]).
    Avx2Bytes(Vec<i32>, quantized::PackedBytes),
    F32(Option<Vec<f32>>),
}

impl Prepared {
    /// Number of descriptors.
    pub fn len(&self) -> usize {
        self.n
    }

    pub fn is_empty(&self) -> bool {
        self.n == 0
    }

    pub(super) fn quantised(&self) -> bool {
        matches!(self.rows, Rows::Quantised { .. })
    }

    /// Whether the two sets were prepared alike (the same kernel, both quantised or both raw), so
    /// that [`match_prepared`] can match them.
    pub fn alike(&self, other: &Prepared) -> bool {
        self.quantised() == other.quantised()
            && self.kernel == other.kernel
            && self.seven_bit == other.seven_bit
            && self.coarse.is_some() == other.coarse.is_some()
    }

    /// The quantised rows and their sums (empty for raw rows).
    pub(super) fn q(&self) -> (&[u8], &[i32]) {
        match &self.rows {
            Rows::Quantised { q, sums } => (q, sums),
            Rows::Raw(_) => (&[], &[]),
        }
    }

    /// The kernel's layout, made on first use.
    pub(super) fn layout(&self) -> &Layout {
        use quantized::Kernel;
        self.layout.get_or_init(|| {
            let d = self.d;
            match (&self.rows, self.kernel) {
                (Rows::Raw(_), _) => Layout::F32(None),
                (Rows::Quantised { q, .. }, Kernel::Avx512Vnni | Kernel::AvxVnni) => {
                    let wide = self.kernel == Kernel::Avx512Vnni;
                    Layout::Vnni {
                        // The AVX-512 kernel's row layout, made once for every pair and row block.
                        rows: wide.then(|| quantized::RowGroups::new(true, q, d, 0, self.n)),
                        packed: quantized::PackedB::new(q, d),
                        wide,
                    }
                }
                (Rows::Quantised { q, .. }, Kernel::Avx2) if self.seven_bit => {
                    Layout::Avx2Bytes(quantized::quads_of(q, d), quantized::PackedBytes::new(q, d))
                }
                (Rows::Quantised { q, .. }, Kernel::Avx2) => {
                    Layout::Avx2(quantized::pairs_of(q, d), quantized::PackedI16::new(q, d))
                }
                (Rows::Quantised { q, .. }, Kernel::Portable) => {
                    Layout::F32(Some(quantized::dequantized(q)))
                }
            }
        })
    }

    /// The rows as f32 for the portable path.
    pub(super) fn f32_rows(&self) -> &[f32] {
        match (self.layout(), &self.rows) {
            (Layout::F32(Some(v)), _) => v,
            (_, Rows::Raw(v)) => v,
            _ => &[],
        }
    }
}

/// Prepares `a` for [`match_prepared`] with the best kernel the CPU has ([`quantized::kernel`]).
pub fn prepare(a: &Descriptors) -> Prepared {
    let quantise = quantized::fits(&a.data[..a.len() * a.dim]);
    prepare_with(a, quantized::kernel(), quantise)
}

/// [`prepare`] with the given kernel: quantised when `quantise` (the caller has checked that the
/// values fit, [`quantized::fits`]), else the raw f32 values.
pub(super) fn prepare_with(a: &Descriptors, kernel: quantized::Kernel, quantise: bool) -> Prepared {
    let (n, d) = (a.len(), a.dim);
    let data = &a.data[..n * d];
    if quantise {
        let q = quantized::quantize(data);
        let coarse = quantized::coarse_codes(&q, d)
            .map(|codes| Box::new(prepare_codes(codes, n, quantized::COARSE_DIM, kernel, true)));
        Prepared {
            coarse,
            ..prepare_codes(q, n, d, kernel, false)
        }
    } else {
        let sq = |v: &[f32]| v.iter().map(|x| x * x).sum::<f32>();
        Prepared {
            n,
            d,
            norms: data.chunks_exact(d.max(1)).map(sq).collect(),
            unit: 1.0,
            kernel,
            rows: Rows::Raw(data.to_vec()),
            seven_bit: false,
            layout: OnceLock::new(),
            coarse: None,
        }
    }
}

/// `n` byte vectors of `d` dimensions (`q`, row-major) prepared for `kernel`; `seven_bit` when
/// every value is below 128 by construction (the coarse codes).
pub(super) fn prepare_codes(
    q: Vec<u8>,
    n: usize,
    d: usize,
    kernel: quantized::Kernel,
    seven_bit: bool,
) -> Prepared {
    debug_assert!(!seven_bit || q.iter().all(|&v| v < 128));
    let sq = |v: &[u8]| v.iter().map(|&x| u32::from(x) * u32::from(x)).sum::<u32>() as f32;
    let norms: Vec<f32> = q.chunks_exact(d.max(1)).map(sq).collect();
    let sums = q
        .chunks_exact(d.max(1))
        .map(|r| r.iter().map(|&v| i32::from(v)).sum())
        .collect();
    Prepared {
        n,
        d,
        norms,
        unit: quantized::SCALE,
        kernel,
        rows: Rows::Quantised { q, sums },
        seven_bit,
        layout: OnceLock::new(),
        coarse: None,
    }
}
