//! Shared pieces of the nonlinear least-squares solvers ([`crate::levenberg_marquardt`](mod@crate::levenberg_marquardt),
//! [`crate::gauss_newton`](mod@crate::gauss_newton)): the problem trait, box bounds, finite-difference Jacobians, the
//! reported status and the report.
//!
//! All solvers minimize the cost F(p) = ½ ‖r(p)‖² over p ∈ ℝⁿ (optionally within a box
//! l ≤ p ≤ u) from the linearization r(p + h) ≈ r + J h, i.e. the normal equations
//! (JᵀJ) h = −Jᵀr with gradient g = Jᵀr.

use faer::linalg::matmul::matmul;
use faer::{Accum, Mat, MatRef};
use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};

use crate::error::{CoreError, Result, check_finite, check_len};

/// A nonlinear least-squares problem: residuals r(p) ∈ ℝᵐ of parameters p ∈ ℝⁿ.
///
/// Only [`residuals`](Self::residuals) is required. Derivatives are taken from the first of
/// these that the problem provides (returns `true`):
/// 1. [`normal_equations`](Self::normal_equations): JᵀJ and Jᵀr directly (e.g. an adjoint
///    method or a problem that assembles JᵀJ from sparse blocks without forming J);
/// 2. [`jacobian`](Self::jacobian): the dense m×n Jacobian;
/// 3. otherwise finite differences of `residuals` ([`FiniteDifference`]).
///
/// A residual evaluation that fails (e.g. a simulation that diverged) should write NaN: the
/// solvers treat non-finite residuals at a trial point as a rejected step and at the start
/// point as [`SolverStatus::NonFinite`]. Methods take `&mut self` so a problem may cache
/// (e.g. keep the last simulated state as a warm start).
pub trait LeastSquaresProblem {
    /// Number of parameters n.
    fn num_params(&self) -> usize;
    /// Number of residuals m.
    fn num_residuals(&self) -> usize;
    /// Write r(p) into `residuals` (length m).
    fn residuals(&mut self, params: &[f64], residuals: &mut [f64]);
    /// Write J(p) = ∂r/∂p (m×n) into `jacobian`; return `false` to request finite differences.
    fn jacobian(&mut self, params: &[f64], jacobian: &mut DMatrix<f64>) -> bool {
        let _ = (params, jacobian);
        false
    }
    /// Write JᵀJ (n×n, both triangles) into `jtj` and Jᵀr (n) into `jtr`, given r(p) in
    /// `residuals`; return `false` to fall back to [`jacobian`](Self::jacobian).
    fn normal_equations(
        &mut self,
        params: &[f64],
        residuals: &[f64],
        jtj: &mut Mat<f64>,
        jtr: &mut [f64],
    ) -> bool {
        let _ = (params, residuals, jtj, jtr);
        false
    }
}

/// Box bounds l ≤ p ≤ u (entries may be ±∞).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Bounds {
    /// Lower bounds l.
    pub lower: Vec<f64>,
    /// Upper bounds u.
    pub upper: Vec<f64>,
}

impl Bounds {
    /// Checked bounds: equal lengths, no NaN, l ≤ u.
    pub fn new(lower: Vec<f64>, upper: Vec<f64>) -> Result<Self> {
        check_len("upper bounds", lower.len(), upper.len())?;
        for (index, (&l, &u)) in lower.iter().zip(&upper).enumerate() {
            if l.is_nan() || u.is_nan() || l > u {
                return Err(CoreError::InvalidBounds {
                    index,
                    lower: l,
                    upper: u,
                });
            }
        }
        Ok(Self { lower, upper })
    }

    /// No bounds on `n` parameters.
    pub fn unbounded(n: usize) -> Self {
        Self {
            lower: vec![f64::NEG_INFINITY; n],
            upper: vec![f64::INFINITY; n],
        }
    }

    /// Number of parameters.
    pub fn len(&self) -> usize {
        self.lower.len()
    }

    /// True for zero parameters.
    pub fn is_empty(&self) -> bool {
        self.lower.is_empty()
    }

    /// Project `p` onto the box.
    pub fn clamp(&self, p: &mut [f64]) {
        for ((x, &l), &u) in p.iter_mut().zip(&self.lower).zip(&self.upper) {
            *x = x.clamp(l, u);
        }
    }

    /// Projected gradient p − P(p − g): zero exactly at a first-order (KKT) point of the
    /// bound-constrained problem.
    pub(crate) fn projected_gradient(&self, p: &[f64], g: &[f64]) -> Vec<f64> {
        (0..p.len())
            .map(|i| p[i] - (p[i] - g[i]).clamp(self.lower[i], self.upper[i]))
            .collect()
    }

    /// Free-variable mask for the active-set step: a parameter on a bound whose descent
    /// direction −g points out of the box is held fixed.
    pub(crate) fn free_mask(&self, p: &[f64], g: &[f64]) -> Vec<bool> {
        (0..p.len())
            .map(|i| {
                !((p[i] <= self.lower[i] && g[i] > 0.0) || (p[i] >= self.upper[i] && g[i] < 0.0))
            })
            .collect()
    }
}

/// Finite-difference scheme used when the problem provides no derivatives.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum FiniteDifference {
    /// (r(p + h eᵢ) − r(p)) / h with h = √ε · max(|pᵢ|, 1); n extra evaluations.
    Forward,
    /// (r(p + h eᵢ) − r(p − h eᵢ)) / 2h with h = ε^⅓ · max(|pᵢ|, 1); 2n extra evaluations.
    /// Falls back to a one-sided difference next to a bound.
    #[default]
    Central,
}

/// Why a solver reported convergence.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum ConvergenceReason {
    /// ‖projected gradient‖∞ ≤ `gradient_tolerance`.
    Gradient,
    /// ‖h‖ ≤ `step_tolerance` · (‖p‖ + `step_tolerance`).
    Step,
    /// F ≤ `cost_tolerance`.
    Cost,
    /// An accepted step reduced F by less than `relative_cost_tolerance` · F.
    RelativeCost,
    /// The largest decrease of F the Gauss–Newton model predicts, ½ gᵀ(JᵀJ)⁻¹g, is below
    /// `predicted_cost_tolerance` · F (Levenberg–Marquardt).
    PredictedCost,
    /// Nelder–Mead: the simplex shrank below `x_tolerance` and its values spread less than
    /// `f_tolerance`.
    SimplexSize,
}

/// Outcome of a least-squares or Nelder–Mead run. Never a panic: every way of stopping is here.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum SolverStatus {
    /// A convergence test passed.
    Converged {
        /// Which test.
        reason: ConvergenceReason,
    },
    /// The iteration cap was reached first.
    MaxIterations,
    /// The evaluation cap was reached first (Nelder–Mead).
    MaxEvaluations,
    /// Residuals, Jacobian or cost were NaN/∞ at the start point (or the derivative
    /// evaluation at an accepted point failed).
    NonFinite,
    /// LM damping grew past `max_damping` without finding a decrease (no progress possible
    /// in floating point — often already at the minimum to machine precision).
    DampingOverflow,
    /// Gauss–Newton step halving found no decrease.
    LineSearchFailed,
    /// The (regularized) normal equations could not be factorized.
    LinearSolveFailed,
}

impl SolverStatus {
    /// True for [`SolverStatus::Converged`].
    pub fn is_converged(&self) -> bool {
        matches!(self, SolverStatus::Converged { .. })
    }
}

/// Result of a least-squares solve.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LeastSquaresReport {
    /// Final parameters (the best accepted point).
    pub params: Vec<f64>,
    /// Residuals r at `params`.
    pub residuals: Vec<f64>,
    /// F = ½ ‖r‖² at `params`.
    pub cost: f64,
    /// ‖projected gradient‖∞ at the last linearization.
    pub gradient_norm: f64,
    /// Iterations taken (rejected LM steps included).
    pub iterations: usize,
    /// Residual evaluations (finite differences included).
    pub residual_evaluations: usize,
    /// Derivative evaluations (Jacobian, normal equations or finite-difference sweeps).
    pub jacobian_evaluations: usize,
    /// Cost after each iteration (index 0 is the start point).
    pub cost_history: Vec<f64>,
    /// Why the solver stopped.
    pub status: SolverStatus,
}

/// Validated problem dimensions and bounds.
pub(crate) fn setup<P: LeastSquaresProblem + ?Sized>(
    problem: &P,
    initial: &[f64],
    bounds: Option<&Bounds>,
) -> Result<(usize, usize, Bounds, Vec<f64>)> {
    let n = problem.num_params();
    let m = problem.num_residuals();
    check_len("initial parameters", n, initial.len())?;
    let (bounds, p) = setup_bounds(initial, bounds)?;
    Ok((n, m, bounds, p))
}

pub(crate) fn setup_bounds(initial: &[f64], bounds: Option<&Bounds>) -> Result<(Bounds, Vec<f64>)> {
    let n = initial.len();
    check_finite("initial parameters", initial)?;
    let bounds = match bounds {
        Some(b) => {
            check_len("bounds", n, b.len())?;
            Bounds::new(b.lower.clone(), b.upper.clone())?
        }
        None => Bounds::unbounded(n),
    };
    let mut p = initial.to_vec();
    bounds.clamp(&mut p);
    Ok((bounds, p))
}

pub(crate) fn half_squared_norm(r: &[f64]) -> f64 {
    0.5 * r.iter().map(|v| v * v).sum::<f64>()
}

/// Evaluation counters and scratch for linearizations.
pub(crate) struct Linearizer {
    pub jacobian: Option<DMatrix<f64>>,
    pub residual_evaluations: usize,
    pub jacobian_evaluations: usize,
    scratch_plus: Vec<f64>,
    scratch_minus: Vec<f64>,
    scratch_p: Vec<f64>,
}

impl Linearizer {
    /// The report both least-squares solvers return, with this linearizer's evaluation counts.
    pub(crate) fn report(
        &self,
        params: Vec<f64>,
        residuals: Vec<f64>,
        cost: f64,
        gradient_norm: f64,
        iterations: usize,
        cost_history: Vec<f64>,
        status: SolverStatus,
    ) -> LeastSquaresReport {
        LeastSquaresReport {
            params,
            residuals,
            cost,
            gradient_norm,
            iterations,
            residual_evaluations: self.residual_evaluations,
            jacobian_evaluations: self.jacobian_evaluations,
            cost_history,
            status,
        }
    }

    pub fn new() -> Self {
        Self {
            jacobian: None,
            residual_evaluations: 0,
            jacobian_evaluations: 0,
            scratch_plus: Vec::new(),
            scratch_minus: Vec::new(),
            scratch_p: Vec::new(),
        }
    }

    pub fn residuals<P: LeastSquaresProblem + ?Sized>(
        &mut self,
        problem: &mut P,
        p: &[f64],
        r: &mut [f64],
    ) -> bool {
        self.residual_evaluations += 1;
        problem.residuals(p, r);
        r.iter().all(|v| v.is_finite())
    }

    /// Fill `a` = JᵀJ and `g` = Jᵀr at `p` (with residuals `r`). Returns false if anything
    /// is non-finite.
    pub fn linearize<P: LeastSquaresProblem + ?Sized>(
        &mut self,
        problem: &mut P,
        p: &[f64],
        r: &[f64],
        bounds: &Bounds,
        fd: FiniteDifference,
        a: &mut Mat<f64>,
        g: &mut [f64],
    ) -> bool {
        let n = p.len();
        let m = r.len();
        self.jacobian_evaluations += 1;
        if problem.normal_equations(p, r, a, g) {
            return a.nrows() == n
                && a.ncols() == n
                && crate::dense::all_finite(a.as_ref())
                && g.iter().all(|v| v.is_finite());
        }
        let mut jac = self.jacobian.take().unwrap_or_else(|| DMatrix::zeros(m, n));
        if jac.nrows() != m || jac.ncols() != n {
            jac = DMatrix::zeros(m, n);
        }
        let ok = if problem.jacobian(p, &mut jac) {
            jac.nrows() == m && jac.ncols() == n
        } else {
            self.finite_difference(problem, p, r, bounds, fd, &mut jac)
        };
        let ok = ok && jac.iter().all(|v| v.is_finite());
        if ok {
            let jv = MatRef::from_column_major_slice(jac.as_slice(), m, n);
            let rv = MatRef::from_column_major_slice(r, m, 1);
            matmul(
                a.as_mut(),
                Accum::Replace,
                jv.transpose(),
                jv,
                1.0,
                faer::get_global_parallelism(),
            );
            let mut gm = Mat::<f64>::zeros(n, 1);
            matmul(
                gm.as_mut(),
                Accum::Replace,
                jv.transpose(),
                rv,
                1.0,
                faer::get_global_parallelism(),
            );
            for i in 0..n {
                g[i] = gm[(i, 0)];
            }
        }
        self.jacobian = Some(jac);
        ok
    }

    fn finite_difference<P: LeastSquaresProblem + ?Sized>(
        &mut self,
        problem: &mut P,
        p: &[f64],
        r: &[f64],
        bounds: &Bounds,
        fd: FiniteDifference,
        jac: &mut DMatrix<f64>,
    ) -> bool {
        let n = p.len();
        let m = r.len();
        self.scratch_plus.resize(m, 0.0);
        self.scratch_minus.resize(m, 0.0);
        self.scratch_p.clear();
        self.scratch_p.extend_from_slice(p);
        for i in 0..n {
            let scale = p[i].abs().max(1.0);
            let (lo, hi) = (bounds.lower[i], bounds.upper[i]);
            let central = fd == FiniteDifference::Central;
            let h = if central {
                f64::EPSILON.cbrt() * scale
            } else {
                f64::EPSILON.sqrt() * scale
            };
            let can_plus = p[i] + h <= hi;
            let can_minus = p[i] - h >= lo;
            if central && can_plus && can_minus {
                self.scratch_p[i] = p[i] + h;
                let hp = self.scratch_p[i] - p[i];
                self.residual_evaluations += 1;
                problem.residuals(&self.scratch_p, &mut self.scratch_plus);
                self.scratch_p[i] = p[i] - h;
                let hm = p[i] - self.scratch_p[i];
                self.residual_evaluations += 1;
                problem.residuals(&self.scratch_p, &mut self.scratch_minus);
                for k in 0..m {
                    jac[(k, i)] = (self.scratch_plus[k] - self.scratch_minus[k]) / (hp + hm);
                }
            } else {
                // One-sided: forward if room above the point, else backward.
                let step = if can_plus || !can_minus { h } else { -h };
                self.scratch_p[i] = p[i] + step;
                let hs = self.scratch_p[i] - p[i];
                if hs == 0.0 {
                    // Degenerate box lo == hi: the parameter is fixed.
                    for k in 0..m {
                        jac[(k, i)] = 0.0;
                    }
                    continue;
                }
                self.residual_evaluations += 1;
                problem.residuals(&self.scratch_p, &mut self.scratch_plus);
                for k in 0..m {
                    jac[(k, i)] = (self.scratch_plus[k] - r[k]) / hs;
                }
            }
            self.scratch_p[i] = p[i];
        }
        true
    }
}

/// Solve (A_ff + μ D_ff) h_f = −g_f on the free variables (D diagonal, Cholesky via faer);
/// fixed variables get h = 0. `None` if the matrix is not numerically positive definite.
pub(crate) fn solve_damped(
    a: &Mat<f64>,
    g: &[f64],
    free: &[bool],
    mu: f64,
    d: &[f64],
) -> Option<Vec<f64>> {
    let idx: Vec<usize> = (0..g.len()).filter(|&i| free[i]).collect();
    let nf = idx.len();
    let mut h = vec![0.0; g.len()];
    if nf == 0 {
        return Some(h);
    }
    let mut af = Mat::<f64>::from_fn(nf, nf, |i, j| a[(idx[i], idx[j])]);
    for i in 0..nf {
        af[(i, i)] += mu * d[idx[i]];
    }
    let b = Mat::<f64>::from_fn(nf, 1, |i, _| -g[idx[i]]);
    let x = crate::dense::solve_spd(af.as_ref(), b.as_ref())?;
    for (k, &i) in idx.iter().enumerate() {
        h[i] = x[(k, 0)];
    }
    Some(h)
}

/// hᵀ A h.
pub(crate) fn quadratic_form(a: &Mat<f64>, h: &[f64]) -> f64 {
    let n = h.len();
    let mut s = 0.0;
    for j in 0..n {
        if h[j] == 0.0 {
            continue;
        }
        let mut col = 0.0;
        for i in 0..n {
            col += a[(i, j)] * h[i];
        }
        s += col * h[j];
    }
    s
}

pub(crate) fn norm2(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}

pub(crate) fn norm_inf(v: &[f64]) -> f64 {
    v.iter().fold(0.0, |acc, x| acc.max(x.abs()))
}
