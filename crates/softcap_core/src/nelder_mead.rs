//! Nelder–Mead downhill simplex (Wang 2015 fits material control points with it), with the
//! adaptive coefficients of Gao & Han (2012) and box bounds by projection.
//!
//! Lagarias et al. (1998) formulation: with vertices sorted f(x₀) ≤ … ≤ f(xₙ) and centroid c
//! of the best n, try reflection x_r = c + ρ(c − xₙ); expansion x_e = c + χ(x_r − c);
//! outside contraction c + γ(x_r − c) or inside contraction c − γ(c − xₙ); otherwise shrink
//! xᵢ ← x₀ + σ(xᵢ − x₀). Standard coefficients (ρ, χ, γ, σ) = (1, 2, ½, ½); adaptive ones
//! (1, 1 + 2/n, ¾ − 1/2n, 1 − 1/n) keep the method effective in higher dimension.
//!
//! **Bounds: clamping.** Every trial point is projected onto the box before it is evaluated,
//! so the objective is only ever evaluated inside the bounds. (The simplex may flatten against
//! a bound; that is the intended behaviour when the optimum lies on it.) A non-finite objective
//! value counts as +∞, i.e. the point is rejected.

use serde::{Deserialize, Serialize};

use crate::error::{CoreError, Result};
use crate::least_squares::{Bounds, ConvergenceReason, SolverStatus, setup_bounds};

/// Settings of [`nelder_mead`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NelderMeadSettings {
    /// Iteration cap.
    pub max_iterations: usize,
    /// Objective-evaluation cap.
    pub max_evaluations: usize,
    /// Converged when max |f(xᵢ) − f(x₀)| ≤ this …
    pub f_tolerance: f64,
    /// … and max ‖xᵢ − x₀‖∞ ≤ this.
    pub x_tolerance: f64,
    /// Initial simplex: vertex i moves parameter i by this fraction of |pᵢ| …
    pub initial_relative_step: f64,
    /// … or by this absolute amount where pᵢ = 0.
    pub initial_absolute_step: f64,
    /// Use the dimension-adaptive coefficients of Gao & Han (2012).
    pub adaptive: bool,
}

impl Default for NelderMeadSettings {
    fn default() -> Self {
        Self {
            max_iterations: 10_000,
            max_evaluations: 20_000,
            f_tolerance: 1e-12,
            x_tolerance: 1e-10,
            initial_relative_step: 0.05,
            initial_absolute_step: 0.00025,
            adaptive: true,
        }
    }
}

/// Result of [`nelder_mead`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct NelderMeadReport {
    /// Best vertex.
    pub params: Vec<f64>,
    /// Objective at `params`.
    pub value: f64,
    /// Iterations taken.
    pub iterations: usize,
    /// Objective evaluations.
    pub evaluations: usize,
    /// Why it stopped.
    pub status: SolverStatus,
}

/// Minimize `f` from `initial` within `bounds` (None: unbounded) by Nelder–Mead (module docs).
///
/// Errors only on invalid input; non-convergence is a status
/// ([`SolverStatus::MaxIterations`], [`SolverStatus::MaxEvaluations`], or
/// [`SolverStatus::NonFinite`] when the objective is not finite anywhere on the initial simplex).
pub fn nelder_mead<F: FnMut(&[f64]) -> f64>(
    mut f: F,
    initial: &[f64],
    bounds: Option<&Bounds>,
    settings: &NelderMeadSettings,
) -> Result<NelderMeadReport> {
    let n = initial.len();
    if n == 0 {
        return Err(CoreError::TooFewSamples {
            what: "Nelder–Mead parameters",
            needed: 1,
            got: 0,
        });
    }
    let (bounds, x0) = setup_bounds(initial, bounds)?;
    let (rho, chi, gamma, sigma) = if settings.adaptive && n > 1 {
        let nf = n as f64;
        (1.0, 1.0 + 2.0 / nf, 0.75 - 0.5 / nf, 1.0 - 1.0 / nf)
    } else {
        (1.0, 2.0, 0.5, 0.5)
    };
    let mut evaluations = 0usize;
    let mut eval = |x: &[f64], evaluations: &mut usize| {
        *evaluations += 1;
        let v = f(x);
        if v.is_finite() { v } else { f64::INFINITY }
    };
    // Initial simplex (McKinnon/fminsearch style), each vertex projected onto the box; if
    // the projection collapses a vertex onto x0 the step is taken in the other direction.
    let mut simplex: Vec<Vec<f64>> = vec![x0.clone()];
    for i in 0..n {
        let mut v = x0.clone();
        let step = if x0[i] != 0.0 {
            settings.initial_relative_step * x0[i]
        } else {
            settings.initial_absolute_step
        };
        v[i] = x0[i] + step;
        bounds.clamp(&mut v);
        if v[i] == x0[i] {
            v[i] = x0[i] - step;
            bounds.clamp(&mut v);
        }
        simplex.push(v);
    }
    let mut values: Vec<f64> = simplex.iter().map(|x| eval(x, &mut evaluations)).collect();
    if values.iter().all(|v| !v.is_finite()) {
        return Ok(NelderMeadReport {
            params: x0,
            value: f64::NAN,
            iterations: 0,
            evaluations,
            status: SolverStatus::NonFinite,
        });
    }
    let mut order: Vec<usize> = (0..=n).collect();
    let mut centroid = vec![0.0; n];
    let mut trial = vec![0.0; n];
    let mut trial2 = vec![0.0; n];
    let mut iterations = 0;
    let status = loop {
        // Stable sort by value, ties by vertex index, so runs are deterministic.
        order.sort_by(|&a, &b| values[a].total_cmp(&values[b]).then(a.cmp(&b)));
        let best = order[0];
        let worst = order[n];
        let second_worst = order[n - 1];
        let fspread = order
            .iter()
            .map(|&i| (values[i] - values[best]).abs())
            .fold(0.0, f64::max);
        let xspread = order
            .iter()
            .map(|&i| {
                simplex[i]
                    .iter()
                    .zip(&simplex[best])
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0, f64::max)
            })
            .fold(0.0, f64::max);
        if fspread <= settings.f_tolerance && xspread <= settings.x_tolerance {
            break SolverStatus::Converged {
                reason: ConvergenceReason::SimplexSize,
            };
        }
        if iterations >= settings.max_iterations {
            break SolverStatus::MaxIterations;
        }
        if evaluations >= settings.max_evaluations {
            break SolverStatus::MaxEvaluations;
        }
        iterations += 1;
        centroid.fill(0.0);
        for &i in &order[..n] {
            for (c, x) in centroid.iter_mut().zip(&simplex[i]) {
                *c += x / n as f64;
            }
        }
        let along = |t: f64, from: &[f64], out: &mut Vec<f64>| {
            // out = c + t (from − c), projected
            for j in 0..n {
                out[j] = centroid[j] + t * (from[j] - centroid[j]);
            }
            bounds.clamp(out);
        };
        along(-rho, &simplex[worst], &mut trial);
        let fr = eval(&trial, &mut evaluations);
        if fr < values[best] {
            along(-rho * chi, &simplex[worst], &mut trial2);
            let fe = eval(&trial2, &mut evaluations);
            if fe < fr {
                simplex[worst].copy_from_slice(&trial2);
                values[worst] = fe;
            } else {
                simplex[worst].copy_from_slice(&trial);
                values[worst] = fr;
            }
            continue;
        }
        if fr < values[second_worst] {
            simplex[worst].copy_from_slice(&trial);
            values[worst] = fr;
            continue;
        }
        let (t, accept_if) = if fr < values[worst] {
            (-rho * gamma, fr)
        } else {
            (gamma, values[worst])
        };
        along(t, &simplex[worst], &mut trial2);
        let fc = eval(&trial2, &mut evaluations);
        let contracted = if fr < values[worst] {
            fc <= accept_if
        } else {
            fc < accept_if
        };
        if contracted {
            simplex[worst].copy_from_slice(&trial2);
            values[worst] = fc;
            continue;
        }
        // Shrink towards the best vertex.
        let xb = simplex[best].clone();
        for &i in &order[1..] {
            for j in 0..n {
                simplex[i][j] = xb[j] + sigma * (simplex[i][j] - xb[j]);
            }
            bounds.clamp(&mut simplex[i]);
            values[i] = eval(&simplex[i], &mut evaluations);
        }
    };
    order.sort_by(|&a, &b| values[a].total_cmp(&values[b]).then(a.cmp(&b)));
    let best = order[0];
    Ok(NelderMeadReport {
        params: simplex[best].clone(),
        value: values[best],
        iterations,
        evaluations,
        status,
    })
}
