//! Levenberg–Marquardt with box bounds (bickel2009 §4.1 fits (λ, α) per example with it).
//!
//! Each iteration solves the damped normal equations
//!
//! ```text
//!   (JᵀJ + μ D) h = −Jᵀr,        D = I (Levenberg) or D = diag(JᵀJ) running max (Marquardt/Moré)
//! ```
//!
//! with faer's dense Cholesky, and rates the step by the gain ratio
//! ρ = (F(p) − F(p + h)) / (L(0) − L(h)), L(h) = F + hᵀg + ½ hᵀJᵀJ h. Accepted steps update
//! μ ← μ · max(⅓, 1 − (2ρ − 1)³), rejected ones μ ← μ ν, ν ← 2ν (Madsen, Nielsen & Tingleff
//! 2004, "Methods for non-linear least squares problems", Alg. 3.16; Nielsen's damping update).
//!
//! **Bounds: projected active-set steps.** At each linearization the parameters sitting on a
//! bound whose descent direction −gᵢ points out of the box are held fixed (the active set); the
//! damped system is solved for the free parameters only, and the trial point is projected
//! (clamped) onto the box. The predicted reduction is computed for the projected step actually
//! taken, so ρ stays meaningful. Convergence on the gradient uses the projected gradient
//! p − P(p − g), which vanishes at a KKT point.

use faer::Mat;
use serde::{Deserialize, Serialize};

use crate::error::{CoreError, Result};
use crate::least_squares::{
    Bounds, ConvergenceReason, FiniteDifference, LeastSquaresProblem, LeastSquaresReport,
    Linearizer, SolverStatus, half_squared_norm, norm_inf, norm2, quadratic_form, setup,
    solve_damped,
};

/// Damping matrix D in (JᵀJ + μD) h = −g.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum DampingScaling {
    /// D = I (Levenberg).
    Identity,
    /// D = diag(JᵀJ), using the running maximum of each diagonal entry over the iterations
    /// (Marquardt 1963 with Moré's 1978 safeguard); invariant to parameter scaling.
    #[default]
    Diagonal,
}

/// Settings of [`levenberg_marquardt`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LevenbergMarquardtSettings {
    /// Iteration cap (rejected steps count).
    pub max_iterations: usize,
    /// Stop when ‖projected gradient‖∞ ≤ this.
    pub gradient_tolerance: f64,
    /// Stop when ‖h‖ ≤ this · (‖p‖ + this).
    pub step_tolerance: f64,
    /// Stop when F = ½‖r‖² ≤ this.
    pub cost_tolerance: f64,
    /// Stop when an accepted step lowers F by less than this · F.
    pub relative_cost_tolerance: f64,
    /// Stop, before simulating a trial, when the largest decrease of F that the Gauss–Newton
    /// model at the current linearization predicts — ½ gᵀ(JᵀJ)⁻¹g over the free parameters, the
    /// decrease of the undamped step — is at most this · F (0: off). For a least-squares fit
    /// of m residuals and n parameters, a Gauss–Newton step of δ standard deviations of the
    /// parameters (s² (JᵀJ)⁻¹, s² = 2F/(m − n)) predicts the decrease δ²/(m − n) · F, so
    /// δ²/(m − n) stops the iterations once the next step is below δ σ: finer steps are below
    /// what the data resolve.
    pub predicted_cost_tolerance: f64,
    /// τ: initial μ = τ · max diag(JᵀJ) for [`DampingScaling::Identity`], μ = τ for
    /// [`DampingScaling::Diagonal`].
    pub initial_damping: f64,
    /// Give up ([`SolverStatus::DampingOverflow`]) when μ exceeds this.
    pub max_damping: f64,
    /// Damping matrix D.
    pub scaling: DampingScaling,
    /// Scheme used when the problem provides no derivatives.
    pub finite_difference: FiniteDifference,
}

impl Default for LevenbergMarquardtSettings {
    fn default() -> Self {
        Self {
            max_iterations: 200,
            gradient_tolerance: 1e-12,
            step_tolerance: 1e-12,
            cost_tolerance: 0.0,
            relative_cost_tolerance: 1e-14,
            predicted_cost_tolerance: 0.0,
            initial_damping: 1e-3,
            max_damping: 1e32,
            scaling: DampingScaling::Diagonal,
            finite_difference: FiniteDifference::Central,
        }
    }
}

/// Minimize ½‖r(p)‖² from `initial` within `bounds` (None: unbounded) by Levenberg–Marquardt
/// (see module docs). `initial` is projected onto the box first.
///
/// Errors only on invalid input (dimensions, bounds, settings); non-convergence is reported
/// in [`LeastSquaresReport::status`].
pub fn levenberg_marquardt<P: LeastSquaresProblem + ?Sized>(
    problem: &mut P,
    initial: &[f64],
    bounds: Option<&Bounds>,
    settings: &LevenbergMarquardtSettings,
) -> Result<LeastSquaresReport> {
    if settings.initial_damping.is_nan() || settings.initial_damping <= 0.0 {
        return Err(CoreError::InvalidSetting {
            field: "initial_damping",
            reason: "must be > 0".into(),
        });
    }
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
            0,
            &lin,
            history,
            SolverStatus::NonFinite,
        ));
    }
    let mut d = vec![1.0; n];
    let update_scaling = |d: &mut [f64], a: &Mat<f64>| {
        if settings.scaling == DampingScaling::Diagonal {
            let amax = (0..n).map(|i| a[(i, i)]).fold(0.0, f64::max);
            let floor = if amax > 0.0 { amax * 1e-12 } else { 1.0 };
            for i in 0..n {
                d[i] = d[i].max(a[(i, i)]).max(floor);
            }
        }
    };
    if settings.scaling == DampingScaling::Diagonal {
        d.fill(0.0);
    }
    update_scaling(&mut d, &a);
    let mut mu = match settings.scaling {
        DampingScaling::Identity => {
            let amax = (0..n).map(|i| a[(i, i)]).fold(0.0, f64::max);
            settings.initial_damping * if amax > 0.0 { amax } else { 1.0 }
        }
        DampingScaling::Diagonal => settings.initial_damping,
    };
    let mut nu = 2.0;
    let mut p_new = vec![0.0; n];
    let mut r_new = vec![0.0; m];
    let mut gnorm = norm_inf(&bounds.projected_gradient(&p, &g));
    for it in 0..settings.max_iterations {
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
        if settings.predicted_cost_tolerance > 0.0
            && let Some(h) = solve_damped(&a, &g, &free, 0.0, &d)
        {
            // ½ gᵀ(JᵀJ)⁻¹g = −½ hᵀg for the Gauss–Newton step h = −(JᵀJ)⁻¹g.
            let largest = -0.5 * h.iter().zip(&g).map(|(s, gi)| s * gi).sum::<f64>();
            if largest <= settings.predicted_cost_tolerance * cost {
                let status = SolverStatus::Converged {
                    reason: ConvergenceReason::PredictedCost,
                };
                return Ok(report(p, r, cost, gnorm, it, &lin, history, status));
            }
        }
        let Some(h) = solve_damped(&a, &g, &free, mu, &d) else {
            // Not positive definite at this damping: damp harder.
            mu *= nu;
            nu *= 2.0;
            if mu.is_nan() || mu > settings.max_damping {
                return Ok(report(
                    p,
                    r,
                    cost,
                    gnorm,
                    it + 1,
                    &lin,
                    history,
                    SolverStatus::DampingOverflow,
                ));
            }
            history.push(cost);
            continue;
        };
        for i in 0..n {
            p_new[i] = p[i] + h[i];
        }
        bounds.clamp(&mut p_new);
        let step: Vec<f64> = (0..n).map(|i| p_new[i] - p[i]).collect();
        let step_norm = norm2(&step);
        if step_norm <= settings.step_tolerance * (norm2(&p) + settings.step_tolerance) {
            let status = SolverStatus::Converged {
                reason: ConvergenceReason::Step,
            };
            return Ok(report(p, r, cost, gnorm, it + 1, &lin, history, status));
        }
        let predicted = -step.iter().zip(&g).map(|(s, gi)| s * gi).sum::<f64>()
            - 0.5 * quadratic_form(&a, &step);
        let trial_finite = lin.residuals(problem, &p_new, &mut r_new);
        let cost_new = if trial_finite {
            half_squared_norm(&r_new)
        } else {
            f64::INFINITY
        };
        let actual = cost - cost_new;
        let rho = if predicted > 0.0 {
            actual / predicted
        } else {
            -1.0
        };
        if trial_finite && rho > 0.0 && actual > 0.0 {
            std::mem::swap(&mut p, &mut p_new);
            std::mem::swap(&mut r, &mut r_new);
            let old_cost = cost;
            cost = cost_new;
            history.push(cost);
            mu *= (1.0 / 3.0f64).max(1.0 - (2.0 * rho - 1.0).powi(3));
            nu = 2.0;
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
                    it + 1,
                    &lin,
                    history,
                    SolverStatus::NonFinite,
                ));
            }
            update_scaling(&mut d, &a);
            gnorm = norm_inf(&bounds.projected_gradient(&p, &g));
            if old_cost - cost <= settings.relative_cost_tolerance * old_cost {
                let status = SolverStatus::Converged {
                    reason: ConvergenceReason::RelativeCost,
                };
                return Ok(report(p, r, cost, gnorm, it + 1, &lin, history, status));
            }
        } else {
            history.push(cost);
            mu *= nu;
            nu *= 2.0;
            if mu.is_nan() || mu > settings.max_damping {
                return Ok(report(
                    p,
                    r,
                    cost,
                    gnorm,
                    it + 1,
                    &lin,
                    history,
                    SolverStatus::DampingOverflow,
                ));
            }
        }
    }
    if gnorm <= settings.gradient_tolerance {
        let status = SolverStatus::Converged {
            reason: ConvergenceReason::Gradient,
        };
        return Ok(report(
            p,
            r,
            cost,
            gnorm,
            settings.max_iterations,
            &lin,
            history,
            status,
        ));
    }
    Ok(report(
        p,
        r,
        cost,
        gnorm,
        settings.max_iterations,
        &lin,
        history,
        SolverStatus::MaxIterations,
    ))
}
