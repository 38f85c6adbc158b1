//! Thin wrappers over faer's dense factorizations used by the RBF, B-spline and optimizer
//! modules: partial-pivoting LU for square (possibly indefinite) systems, Cholesky for
//! symmetric positive definite ones, Householder QR for least squares. Each wrapper checks the
//! result for non-finite values so callers can turn a breakdown into a reported error.

use faer::linalg::solvers::{Solve, SolveLstsq};
use faer::{Mat, MatRef, Side};

/// Solve the square system `a x = b` with partial-pivoting LU. Returns `None` when the
/// solution is not finite or the relative residual ‖a x − b‖ / (‖a‖‖x‖ + ‖b‖) exceeds
/// `residual_tol` (a singular system factorized without error shows up here).
pub(crate) fn solve_lu(
    a: MatRef<'_, f64>,
    b: MatRef<'_, f64>,
    residual_tol: f64,
) -> Option<Mat<f64>> {
    let lu = a.partial_piv_lu();
    let x = lu.solve(b);
    if !all_finite(x.as_ref()) {
        return None;
    }
    let r = a * &x - b;
    let scale = a.norm_l2() * x.norm_l2() + b.norm_l2();
    if r.norm_l2() > residual_tol * scale.max(f64::MIN_POSITIVE) {
        return None;
    }
    Some(x)
}

/// Solve `a x = b` for symmetric positive definite `a` (lower triangle read) with Cholesky.
/// `None` if `a` is not numerically positive definite or the result is not finite.
pub(crate) fn solve_spd(a: MatRef<'_, f64>, b: MatRef<'_, f64>) -> Option<Mat<f64>> {
    let llt = a.llt(Side::Lower).ok()?;
    let x = llt.solve(b);
    all_finite(x.as_ref()).then_some(x)
}

/// Least-squares solution of `a x ≈ b` (`a` is m×n with m ≥ n) by Householder QR.
/// `None` if the result is not finite or `a` is numerically rank deficient (a diagonal entry
/// of R below `rank_tol · max|R_ii|`).
pub(crate) fn lstsq_qr(a: MatRef<'_, f64>, b: MatRef<'_, f64>, rank_tol: f64) -> Option<Mat<f64>> {
    let (m, n) = (a.nrows(), a.ncols());
    if m < n {
        return None;
    }
    if n == 0 {
        return Some(Mat::zeros(0, b.ncols()));
    }
    let qr = a.qr();
    let r = qr.thin_R();
    let rmax = (0..n).map(|i| r[(i, i)].abs()).fold(0.0, f64::max);
    if rmax.is_nan() || rmax <= 0.0 || (0..n).any(|i| r[(i, i)].abs() <= rank_tol * rmax) {
        return None;
    }
    let x = qr.solve_lstsq(b);
    all_finite(x.as_ref()).then_some(x)
}

/// Orthonormal basis of the null space of the k×m matrix `c` (k may be 0), as an m×(m−rank)
/// matrix; singular values below `tol · σ_max` count as zero.
pub(crate) fn null_space(c: MatRef<'_, f64>, tol: f64) -> Option<Mat<f64>> {
    let (k, m) = (c.nrows(), c.ncols());
    if k == 0 || m == 0 {
        return Some(Mat::identity(m, m));
    }
    let svd = c.svd().ok()?;
    let s = svd.S().column_vector();
    let smax = (0..s.nrows()).map(|i| s[i]).fold(0.0, f64::max);
    let rank = (0..s.nrows()).filter(|&i| s[i] > tol * smax).count();
    let v = svd.V();
    Some(Mat::from_fn(m, m - rank, |i, j| v[(i, rank + j)]))
}

pub(crate) fn all_finite(x: MatRef<'_, f64>) -> bool {
    (0..x.ncols()).all(|j| (0..x.nrows()).all(|i| x[(i, j)].is_finite()))
}
