//! Dense Gauss–Newton with step-halving line search (wherever the model is nearly linear in its
//! parameters and small enough for dense normal equations).
//!
//! Each iteration solves the normal equations (JᵀJ) h = −Jᵀr on the free parameters with
//! faer's Cholesky (a tiny ridge 10⁻¹² · max diag(JᵀJ) is added only if JᵀJ is singular) and
//! takes p ← P(p + α h), where P projects onto the bounds and α = 1, ½, ¼, … is the first
//! step length satisfying the Armijo condition F(p_new) ≤ F(p) + c · gᵀ(p_new − p),
//! c = `armijo`. Bounds are handled like [`crate::levenberg_marquardt`](mod@crate::levenberg_marquardt): parameters on a bound
//! whose descent direction points outward are held fixed, the trial point is clamped.

use faer::Mat;
use serde::{Deserialize, Serialize};

use crate::error::Result;
use crate::least_squares::{
    Bounds, ConvergenceReason, FiniteDifference, LeastSquaresProblem, LeastSquaresReport,
    Linearizer, SolverStatus, half_squared_norm, norm_inf, norm2, setup, solve_damped,
};

/// Settings of [`gauss_newton`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GaussNewtonSettings {
    /// Iteration cap.
    pub max_iterations: usize,
    /// Stop when ‖projected gradient‖∞ ≤ this.
    pub gradient_tolerance: f64,
    /// Stop when ‖h‖ ≤ this · (‖p‖ + this).
    pub step_tolerance: f64,
    /// Stop when F = ½‖r‖² ≤ this.
    pub cost_tolerance: f64,
    /// Stop when an accepted step lowers F by less than this · F.
    pub relative_cost_tolerance: f64,
    /// Maximum number of step halvings per iteration.
    pub max_halvings: usize,
    /// Armijo constant c in F(p_new) ≤ F + c gᵀΔp.
    pub armijo: f64,
    /// Scheme used when the problem provides no derivatives.
    pub finite_difference: FiniteDifference,
}

impl Default for GaussNewtonSettings {
    fn default() -> Self {
        Self {
            max_iterations: 100,
            gradient_tolerance: 1e-12,
            step_tolerance: 1e-12,
            cost_tolerance: 0.0,
            relative_cost_tolerance: 1e-14,
            max_halvings: 30,
            armijo: 1e-4,
            finite_difference: FiniteDifference::Central,
        }
    }
}

/// Minimize ½‖r(p)‖² by Gauss–Newton with step halving (see module docs).
///
/// Errors only on invalid input; non-convergence is reported in the status
/// ([`SolverStatus::LineSearchFailed`] when no halving decreases F,
/// [`SolverStatus::LinearSolveFailed`] when JᵀJ cannot be factorized even with the ridge).
pub fn gauss_newton<P: LeastSquaresProblem + ?Sized>(
    problem: &mut P,
    initial: &[f64],
    bounds: Option<&Bounds>,
    settings: &GaussNewtonSettings,
) -> Result<LeastSquaresReport> {
    let (n, m, bounds, mut p) = setup(problem, initial, bounds)?;
    let mut lin = Linearizer::new();
    let mut r = vec![0.0; m];
    let finite = lin.residuals(problem, &p, &mut r);
    let mut cost = half_squared_norm(&r);
    let mut history = vec![cost];
    let report = |p, r, cost, gnorm, it, lin: &Linearizer, history, status| {
        lin.report(p, r, cost, gnorm, it, history, status)
    };
    if !finite {
        return Ok(report(
            p,
            r,
            cost,
            f64::NAN,
            0,
            &lin,
            history,
            SolverStatus::NonFinite,
        ));
    }
    let mut a = Mat::<f64>::zeros(n, n);
    let mut g = vec![0.0; n];
    let ones = vec![1.0; n];
    let mut p_new = vec![0.0; n];
    let mut r_new = vec![0.0; m];
    let mut last_gnorm = f64::NAN;
    for it in 0..settings.max_iterations {
        if !lin.linearize(
            problem,
            &p,
            &r,
            &bounds,
            settings.finite_difference,
            &mut a,
            &mut g,
        ) {
            return Ok(report(
                p,
                r,
                cost,
                f64::NAN,
                it,
                &lin,
                history,
                SolverStatus::NonFinite,
            ));
        }
        let gnorm = norm_inf(&bounds.projected_gradient(&p, &g));
        last_gnorm = gnorm;
        if gnorm <= settings.gradient_tolerance {
            let status = SolverStatus::Converged {
                reason: ConvergenceReason::Gradient,
            };
            return Ok(report(p, r, cost, gnorm, it, &lin, history, status));
        }
        if cost <= settings.cost_tolerance {
            let status = SolverStatus::Converged {
                reason: ConvergenceReason::Cost,
            };
            return Ok(report(p, r, cost, gnorm, it, &lin, history, status));
        }
        let free = bounds.free_mask(&p, &g);
        let amax = (0..n).map(|i| a[(i, i)]).fold(0.0, f64::max);
        let h = match solve_damped(&a, &g, &free, 0.0, &ones) {
            Some(h) => h,
            None => match solve_damped(&a, &g, &free, 1e-12 * amax.max(f64::MIN_POSITIVE), &ones) {
                Some(h) => h,
                None => {
                    return Ok(report(
                        p,
                        r,
                        cost,
                        gnorm,
                        it,
                        &lin,
                        history,
                        SolverStatus::LinearSolveFailed,
                    ));
                }
            },
        };
        let mut alpha = 1.0;
        let mut accepted = false;
        for _ in 0..=settings.max_halvings {
            for i in 0..n {
                p_new[i] = p[i] + alpha * h[i];
            }
            bounds.clamp(&mut p_new);
            let slope: f64 = (0..n).map(|i| g[i] * (p_new[i] - p[i])).sum();
            let step_norm = (0..n)
                .map(|i| (p_new[i] - p[i]).powi(2))
                .sum::<f64>()
                .sqrt();
            // Step test on the full Gauss–Newton step only (halved steps are not convergence).
            if alpha == 1.0
                && step_norm <= settings.step_tolerance * (norm2(&p) + settings.step_tolerance)
            {
                let status = SolverStatus::Converged {
                    reason: ConvergenceReason::Step,
                };
                return Ok(report(p, r, cost, gnorm, it + 1, &lin, history, status));
            }
            if lin.residuals(problem, &p_new, &mut r_new) {
                let cost_new = half_squared_norm(&r_new);
                if cost_new <= cost + settings.armijo * slope && cost_new < cost {
                    accepted = true;
                    break;
                }
            }
            alpha *= 0.5;
        }
        if !accepted {
            return Ok(report(
                p,
                r,
                cost,
                gnorm,
                it + 1,
                &lin,
                history,
                SolverStatus::LineSearchFailed,
            ));
        }
        std::mem::swap(&mut p, &mut p_new);
        std::mem::swap(&mut r, &mut r_new);
        let old_cost = cost;
        cost = half_squared_norm(&r);
        history.push(cost);
        if old_cost - cost <= settings.relative_cost_tolerance * old_cost {
            let status = SolverStatus::Converged {
                reason: ConvergenceReason::RelativeCost,
            };
            let gn = norm_inf(&bounds.projected_gradient(&p, &g));
            return Ok(report(p, r, cost, gn, it + 1, &lin, history, status));
        }
    }
    Ok(report(
        p,
        r,
        cost,
        last_gnorm,
        settings.max_iterations,
        &lin,
        history,
        SolverStatus::MaxIterations,
    ))
}
