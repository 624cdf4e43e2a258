//! Shared linear-algebra helpers for the DLT-style solvers: the right null space of a design matrix
//! through an SVD that keeps every right singular vector.

use nalgebra::{DMatrix, Matrix3};

/// Singular values (descending) and `Vᵀ` (all `ncols` rows) of `a`.
///
/// nalgebra's SVD is thin, so a matrix with fewer rows than columns would lose its null vectors;
/// such a matrix is padded with zero rows first (which does not change `AᵀA`).
pub(crate) fn full_right_svd(a: DMatrix<f64>) -> Option<(Vec<f64>, DMatrix<f64>)> {
    let (rows, cols) = a.shape();
    if a.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let a = if rows < cols {
        a.resize_vertically(cols, 0.0)
    } else {
        a
    };
    let svd = a.svd(false, true);
    let v_t = svd.v_t?;
    let mut sv: Vec<f64> = svd.singular_values.iter().copied().collect();
    sv.resize(cols, 0.0);
    Some((sv, v_t))
}

/// Row `r` of `Vᵀ` (a 9-vector) read row-major into a 3×3 matrix.
pub(crate) fn row_to_matrix3(v_t: &DMatrix<f64>, r: usize) -> Matrix3<f64> {
    Matrix3::from_fn(|i, j| v_t[(r, 3 * i + j)])
}
