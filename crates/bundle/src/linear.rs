//! Cholesky solvers for the reduced camera system (faer): dense blocked `LLᵀ` for small systems, sparse
//! supernodal `LLᵀ` with an AMD fill-reducing ordering for large ones. The sparse symbolic factorisation
//! depends only on the pattern, so it is computed once and reused at every iteration.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt;
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, CholeskySymbolicParams, LltRef, SymbolicCholesky,
    SymbolicCholeskyRaw, SymmetricOrdering,
};
use faer::sparse::linalg::SupernodalThreshold;
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, MatRef, Par, Side};

use crate::options::BundleError;
use crate::schur::ReducedMatrix;

/// The symbolic analysis of the sparse pattern of `m` (lower triangle): AMD ordering,
/// supernodal factor.
pub(crate) fn analyse(m: &ReducedMatrix) -> Result<SymbolicCholesky<usize>, BundleError> {
    let sym = SymbolicSparseColMatRef::new_checked(m.n, m.n, &m.col_ptr, None, &m.row_idx);
    let params = CholeskySymbolicParams {
        supernodal_flop_ratio_threshold: SupernodalThreshold::FORCE_SUPERNODAL,
        ..Default::default()
    };
    factorize_symbolic_cholesky(sym, Side::Lower, SymmetricOrdering::Amd, params)
        .map_err(|e| BundleError::Linear(format!("{e:?}")))
}

/// The sparse factorisation's work over the dense one's: `Σ c_j²` over the factor's columns
/// (`c_j` the column's entries on and below the diagonal, the usual count of a column's flops)
/// against the same sum for a full lower triangle (`Σ k²`, k = 1..n, about n³/3). A supernode of
/// `w` columns with `r` rows below its diagonal block has columns of `w + r, w − 1 + r, …, 1 + r`
/// entries.
pub(crate) fn flop_ratio(symbolic: &SymbolicCholesky<usize>, n: usize) -> f64 {
    let nf = n as f64;
    let dense = nf * (nf + 1.0) * (2.0 * nf + 1.0) / 6.0;
    let sparse: f64 = match symbolic.raw() {
        SymbolicCholeskyRaw::Supernodal(sn) => {
            let (begin, end, rows) = (
                sn.supernode_begin(),
                sn.supernode_end(),
                sn.col_ptr_for_row_idx(),
            );
            (0..sn.n_supernodes())
                .map(|s| {
                    let w = end[s] - begin[s];
                    let r = rows[s + 1] - rows[s];
                    (1..=w).map(|k| ((k + r) as f64).powi(2)).sum::<f64>()
                })
                .sum()
        }
        SymbolicCholeskyRaw::Simplicial(sp) => sp
            .col_ptr()
            .windows(2)
            .map(|c| ((c[1] - c[0]) as f64).powi(2))
            .sum(),
    };
    if dense > 0.0 {
        sparse / dense
    } else {
        1.0
    }
}

pub(crate) enum Factorizer {
    Dense,
    Sparse {
        symbolic: Box<SymbolicCholesky<usize>>,
        l_values: Vec<f64>,
        buffer: MemBuffer,
    },
}

impl Factorizer {
    /// Prepares a solver for the pattern of `m` (the symbolic analysis for the sparse case).
    pub fn new(m: &ReducedMatrix) -> Result<Self, BundleError> {
        if m.dense {
            return Ok(Factorizer::Dense);
        }
        Self::sparse(analyse(m)?)
    }

    /// The sparse solver of an analysed pattern ([`analyse`]): its factor's storage and scratch.
    pub fn sparse(symbolic: SymbolicCholesky<usize>) -> Result<Self, BundleError> {
        let req = symbolic
            .factorize_numeric_llt_scratch::<f64>(Par::Seq, Default::default())
            .or(symbolic.solve_in_place_scratch::<f64>(1, Par::Seq));
        let buffer =
            MemBuffer::try_new(req).map_err(|_| BundleError::Linear("out of memory".into()))?;
        let l_values = vec![0.0; symbolic.len_val()];
        Ok(Factorizer::Sparse {
            symbolic: Box::new(symbolic),
            l_values,
            buffer,
        })
    }

    /// Factorises `m` (destroying its values when dense) and solves `m x = rhs` in place. Returns
    /// `false` when the matrix is not numerically positive definite.
    pub fn solve(&mut self, m: &mut ReducedMatrix, rhs: &mut [f64]) -> bool {
        let n = m.n;
        if n == 0 {
            return true;
        }
        match self {
            Factorizer::Dense => {
                let mut a = MatMut::from_column_major_slice_mut(&mut m.values, n, n);
                let req =
                    llt::factor::cholesky_in_place_scratch::<f64>(n, Par::Seq, Default::default())
                        .or(llt::solve::solve_in_place_scratch::<f64>(n, 1, Par::Seq));
                let Ok(mut buf) = MemBuffer::try_new(req) else {
                    return false;
                };
                let stack = MemStack::new(&mut buf);
                if llt::factor::cholesky_in_place(
                    a.as_mut(),
                    Default::default(),
                    Par::Seq,
                    stack,
                    Default::default(),
                )
                .is_err()
                {
                    return false;
                }
                let l = MatRef::from_column_major_slice(&m.values, n, n);
                llt::solve::solve_in_place_with_conj(
                    l,
                    Conj::No,
                    MatMut::from_column_major_slice_mut(rhs, n, 1),
                    Par::Seq,
                    stack,
                );
            }
            Factorizer::Sparse {
                symbolic,
                l_values,
                buffer,
            } => {
                let sym = SymbolicSparseColMatRef::new_checked(n, n, &m.col_ptr, None, &m.row_idx);
                let a = SparseColMatRef::new(sym, &m.values);
                let stack = MemStack::new(buffer);
                let Ok(llt) = symbolic.factorize_numeric_llt::<f64>(
                    l_values,
                    a,
                    Side::Lower,
                    Default::default(),
                    Par::Seq,
                    stack,
                    Default::default(),
                ) else {
                    return false;
                };
                let llt: LltRef<'_, usize, f64> = llt;
                llt.solve_in_place_with_conj(
                    Conj::No,
                    MatMut::from_column_major_slice_mut(rhs, n, 1),
                    Par::Seq,
                    stack,
                );
            }
        }
        rhs.iter().all(|v| v.is_finite())
    }
}
