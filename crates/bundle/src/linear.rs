//! Cholesky solvers for the reduced camera system (faer): dense blocked `LLᵀ` for small systems, sparse
//! supernodal `LLᵀ` with an AMD fill-reducing ordering for large ones. The sparse symbolic factorisation
//! depends only on the pattern, so it is computed once and reused at every iteration.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt;
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, CholeskySymbolicParams, LltRef, SymbolicCholesky,
    SymmetricOrdering,
};
use faer::sparse::linalg::SupernodalThreshold;
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, MatRef, Par, Side};

use crate::options::BundleError;
use crate::schur::ReducedMatrix;

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
        let sym = SymbolicSparseColMatRef::new_checked(m.n, m.n, &m.col_ptr, None, &m.row_idx);
        let params = CholeskySymbolicParams {
            supernodal_flop_ratio_threshold: SupernodalThreshold::FORCE_SUPERNODAL,
            ..Default::default()
        };
        let symbolic =
            factorize_symbolic_cholesky(sym, Side::Lower, SymmetricOrdering::Amd, params)
                .map_err(|e| BundleError::Linear(format!("{e:?}")))?;
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

    /// The share of the `n × n` storage the factor fills (`1` when dense): the supernodal factor's
    /// entries over `n²` (each supernode stores its whole diagonal block, so a full pattern comes
    /// to about 1).
    pub fn fill(&self, n: usize) -> f64 {
        match self {
            Factorizer::Dense => 1.0,
            Factorizer::Sparse { symbolic, .. } => {
                symbolic.len_val() as f64 / (n * n).max(1) as f64
            }
        }
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
