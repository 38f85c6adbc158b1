//! Brent's derivative-free minimization of a function of one variable on a bounded interval
//! (Brent 1973, *Algorithms for Minimization without Derivatives*, ch. 5; Press et al. 2007,
//! *Numerical Recipes* §10.3): golden-section steps, replaced by parabolic interpolation through
//! the three best points whenever the parabola's minimum falls inside the interval and the steps
//! shrink. Used as the line search of the saito-barbic Gauss–Newton iteration (§3.4), whose
//! objective along the search direction is only available by re-solving an equilibrium.
//!
//! A non-finite function value counts as +∞ (the point is worse than any finite one).

use serde::{Deserialize, Serialize};

/// Settings of [`minimize_bounded`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BrentSettings {
    /// Absolute tolerance on the abscissa.
    pub x_tolerance: f64,
    /// Budget of function evaluations.
    pub max_evaluations: usize,
}

impl Default for BrentSettings {
    fn default() -> Self {
        Self {
            x_tolerance: 1e-3,
            max_evaluations: 30,
        }
    }
}

/// Outcome of [`minimize_bounded`]: the best point evaluated.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BrentMinimum {
    /// Abscissa of the lowest value found.
    pub x: f64,
    /// The lowest value found (+∞ if every value was non-finite).
    pub f: f64,
    /// Function evaluations spent.
    pub evaluations: usize,
    /// True if the interval shrank below the tolerance (false: evaluation budget exhausted).
    pub converged: bool,
}

fn finite_or_inf(v: f64) -> f64 {
    if v.is_finite() { v } else { f64::INFINITY }
}

/// Minimizes `f` over the open interval (`lo`, `hi`) by Brent's method. The end points are never
/// evaluated (a caller that knows f there compares itself).
pub fn minimize_bounded(
    mut f: impl FnMut(f64) -> f64,
    lo: f64,
    hi: f64,
    settings: &BrentSettings,
) -> BrentMinimum {
    let golden = 0.5 * (3.0 - 5f64.sqrt());
    let (mut a, mut b) = if lo <= hi { (lo, hi) } else { (hi, lo) };
    let mut x = a + golden * (b - a);
    let (mut w, mut v) = (x, x);
    let mut fx = finite_or_inf(f(x));
    let (mut fw, mut fv) = (fx, fx);
    let mut evaluations = 1;
    let (mut d, mut e) = (0.0f64, 0.0f64);
    let eps = f64::EPSILON.sqrt();
    loop {
        let xm = 0.5 * (a + b);
        let tol1 = eps * x.abs() + settings.x_tolerance / 3.0;
        let tol2 = 2.0 * tol1;
        if (x - xm).abs() <= tol2 - 0.5 * (b - a) {
            return BrentMinimum {
                x,
                f: fx,
                evaluations,
                converged: true,
            };
        }
        if evaluations >= settings.max_evaluations {
            return BrentMinimum {
                x,
                f: fx,
                evaluations,
                converged: false,
            };
        }
        let mut golden_step = true;
        if e.abs() > tol1 && fx.is_finite() && fw.is_finite() && fv.is_finite() {
            // Parabola through (v, fv), (w, fw), (x, fx).
            let r = (x - w) * (fx - fv);
            let mut q = (x - v) * (fx - fw);
            let mut p = (x - v) * q - (x - w) * r;
            q = 2.0 * (q - r);
            if q > 0.0 {
                p = -p;
            } else {
                q = -q;
            }
            let e_prev = e;
            if p.abs() < (0.5 * q * e_prev).abs() && p > q * (a - x) && p < q * (b - x) {
                e = d;
                d = p / q;
                let u = x + d;
                if u - a < tol2 || b - u < tol2 {
                    d = tol1.copysign(xm - x);
                }
                golden_step = false;
            }
        }
        if golden_step {
            e = if x >= xm { a - x } else { b - x };
            d = golden * e;
        }
        let u = if d.abs() >= tol1 {
            x + d
        } else {
            x + tol1.copysign(d)
        };
        let fu = finite_or_inf(f(u));
        evaluations += 1;
        if fu <= fx {
            if u >= x {
                a = x;
            } else {
                b = x;
            }
            (v, fv) = (w, fw);
            (w, fw) = (x, fx);
            (x, fx) = (u, fu);
        } else {
            if u < x {
                a = u;
            } else {
                b = u;
            }
            if fu <= fw || w == x {
                (v, fv) = (w, fw);
                (w, fw) = (u, fu);
            } else if fu <= fv || v == x || v == w {
                (v, fv) = (u, fu);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_the_minimum_of_a_smooth_function_in_few_evaluations() {
        // f(x) = (x − 0.3)² + 0.1 (x − 0.3)⁴: minimum at 0.3.
        let m = minimize_bounded(
            |x| (x - 0.3).powi(2) + 0.1 * (x - 0.3).powi(4),
            0.0,
            1.0,
            &BrentSettings {
                x_tolerance: 1e-6,
                max_evaluations: 50,
            },
        );
        assert!(m.converged && (m.x - 0.3).abs() < 1e-5, "{m:?}");
        assert!(m.evaluations < 15, "{m:?}");
    }

    #[test]
    fn non_finite_values_are_avoided() {
        // Undefined (NaN) beyond 0.6, minimum of the defined part at 0.5.
        let m = minimize_bounded(
            |x| if x > 0.6 { f64::NAN } else { (x - 0.5).powi(2) },
            0.0,
            1.0,
            &BrentSettings::default(),
        );
        assert!((m.x - 0.5).abs() < 2e-3 && m.f.is_finite(), "{m:?}");
    }

    #[test]
    fn a_minimum_at_the_boundary_is_approached() {
        let m = minimize_bounded(|x| x, 0.0, 1.0, &BrentSettings::default());
        assert!(m.x < 2e-3, "{m:?}");
    }
}
