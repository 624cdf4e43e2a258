//! Shared linear-algebra helpers for the DLT-style solvers: the right null space of a design matrix
//! through an SVD that keeps every right singular vector, and, for the minimal solvers' short design
//! matrices (7 × 9, 8 × 9), by Gaussian elimination on the stack.

use nalgebra::{DMatrix, Matrix3, SVector};

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

/// Relative size (of a singular value of the design matrix, so its square for an eigenvalue of the
/// normal matrix) below which the normal equations cannot tell the null space from roundoff, and
/// the SVD of the design matrix decides instead.
const NORMAL_RANK_TOL: f64 = 1e-6;

/// The least-squares null vector of a design matrix `A` with 9 columns, given by its rows, as the
/// eigenvector of the smallest eigenvalue of `AᵀA` (9 × 9, accumulated row by row without forming
/// `A`): the same vector as the SVD's last right singular vector (H&Z §A5.3), and on
/// Hartley-normalised points (entries of order 1) squaring the condition number costs nothing
/// that matters in double precision. `None` when the second-smallest eigenvalue is within roundoff
/// of zero (a null space of two or more dimensions, or nearly so): the caller's SVD then decides.
pub(crate) fn normal_equations_null_vector(
    rows: impl IntoIterator<Item = [f64; 9]>,
) -> Option<SVector<f64, 9>> {
    let mut m = nalgebra::SMatrix::<f64, 9, 9>::zeros();
    for r in rows {
        for i in 0..9 {
            for j in i..9 {
                m[(i, j)] += r[i] * r[j];
            }
        }
    }
    for i in 0..9 {
        for j in 0..i {
            m[(i, j)] = m[(j, i)];
        }
    }
    if m.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let eig = m.symmetric_eigen();
    let mut order: [usize; 9] = std::array::from_fn(|i| i);
    order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    let largest = eig.eigenvalues[order[8]];
    let second = eig.eigenvalues[order[1]].max(0.0);
    if largest.is_nan() || largest <= 0.0 || second <= NORMAL_RANK_TOL * NORMAL_RANK_TOL * largest {
        return None;
    }
    Some(eig.eigenvectors.column(order[0]).into_owned())
}

/// Row `r` of `Vᵀ` (a 9-vector) read row-major into a 3×3 matrix.
pub(crate) fn row_to_matrix3(v_t: &DMatrix<f64>, r: usize) -> Matrix3<f64> {
    Matrix3::from_fn(|i, j| v_t[(r, 3 * i + j)])
}

/// The right null space of an `m × 9` matrix with `m < 9` rows (a minimal solver's design matrix:
/// the 4-point homography's 8 × 9), by Gauss–Jordan elimination with
/// complete pivoting (Golub & Van Loan §3.4.8): the `m` pivot columns are solved for in terms of the
/// `9 − m` free ones, each free one set to 1 in turn. Returns the unit null vectors and the ratio of
/// the smallest to the largest pivot, which is zero for a matrix of rank below `m` and, like the
/// singular values' ratio it stands in for, small for a nearly rank-deficient one. About 300
/// multiply-adds on the stack, where an SVD of the same matrix costs a few microseconds and a heap
/// allocation; the RANSAC loops call this once per sample. `None` for a non-finite entry or
/// `m ≥ 9`.
///
/// The 7-point solver used the SVD until the twenty-eighth session: the elimination's rounding moved
/// a few weak pairs by an inlier or two, and templeSparseRing's model once followed its one
/// marginal pair (AUC@1 77.19 → 15.79, `docs/benchmarks.md`, #34). It no longer does (the same
/// set without that pair: 76.82); what the change does to each set over several RANSAC seeds is
/// in `docs/benchmarks.md`.
pub(crate) fn null_space_short(rows: &[[f64; 9]]) -> Option<(Vec<SVector<f64, 9>>, f64)> {
    let m = rows.len();
    if m >= 9 || rows.iter().flatten().any(|v| !v.is_finite()) {
        return None;
    }
    let mut a = [[0.0f64; 9]; 8];
    a[..m].copy_from_slice(rows);
    // cols[k]: the original column now in position k.
    let mut cols: [usize; 9] = std::array::from_fn(|k| k);
    let (mut largest, mut smallest) = (0.0f64, f64::INFINITY);
    for k in 0..m {
        let (mut pr, mut pc, mut best) = (k, k, 0.0f64);
        for (r, row) in a.iter().enumerate().take(m).skip(k) {
            for (c, v) in row.iter().enumerate().skip(k) {
                if v.abs() > best {
                    (pr, pc, best) = (r, c, v.abs());
                }
            }
        }
        if best == 0.0 {
            return Some((Vec::new(), 0.0));
        }
        a.swap(k, pr);
        if pc != k {
            for row in a.iter_mut().take(m) {
                row.swap(k, pc);
            }
            cols.swap(k, pc);
        }
        largest = largest.max(best);
        smallest = smallest.min(best);
        let pivot = a[k];
        for (r, row) in a.iter_mut().enumerate().take(m) {
            if r == k || row[k] == 0.0 {
                continue;
            }
            let f = row[k] / pivot[k];
            for c in k..9 {
                row[c] -= f * pivot[c];
            }
        }
    }
    let vectors = (m..9)
        .map(|free| {
            let mut x = SVector::<f64, 9>::zeros();
            x[cols[free]] = 1.0;
            for (k, row) in a.iter().enumerate().take(m) {
                x[cols[k]] = -row[free] / row[k];
            }
            x.normalize()
        })
        .collect();
    Some((vectors, smallest / largest))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn short_null_space_agrees_with_the_svd() {
        // A 7 × 9 matrix with entries of mixed size, and its null space by both routes.
        let rows: Vec<[f64; 9]> = (0..7)
            .map(|r| {
                std::array::from_fn(|c| {
                    (((r * 9 + c) as f64).powi(2) * 0.37).sin() * (1.0 + c as f64)
                })
            })
            .collect();
        let (vs, ratio) = null_space_short(&rows).expect("finite");
        assert_eq!(vs.len(), 2);
        assert!(ratio > 1e-6);
        let a = DMatrix::from_fn(7, 9, |r, c| rows[r][c]);
        for v in &vs {
            assert!((&a * v).norm() < 1e-12, "{}", (&a * v).norm());
        }
        // The two vectors span the SVD's null space.
        let (_, v_t) = full_right_svd(a).expect("finite");
        for v in &vs {
            let inside: f64 = (7..9).map(|r| v_t.row(r).transpose().dot(v).powi(2)).sum();
            assert!((inside - 1.0).abs() < 1e-10);
        }
        // A repeated row: rank 6, reported by a zero (or tiny) pivot ratio.
        let mut deficient = rows.clone();
        deficient[6] = deficient[2];
        let (_, ratio) = null_space_short(&deficient).expect("finite");
        assert!(ratio < 1e-12);
        assert!(null_space_short(&[[f64::NAN; 9]]).is_none());
    }
}
