//! The parameters of the next tracking pass of the tracking ↔ estimation loop (wang2015 §7):
//! each pass tracks with a material, the fit of those tracks proposes the next one, x ↦ g(x). The
//! plain loop tracks with g(x) and converges linearly where the tracker's pull toward its own
//! material is strong (bar8ab's E6: ×0.72 a pass). [`anderson_next`] accelerates the fixed-point
//! iteration with the earlier passes (Anderson acceleration).

use nalgebra::{DMatrix, DVector};

/// Earlier passes Anderson mixes at most (its depth m: m + 1 passes, the current one included).
pub const ANDERSON_DEPTH: usize = 2;

/// The smallest relative 1-σ a parameter's residual is weighted by in [`anderson_next`] (0.1 %).
pub const ANDERSON_SIGMA_FLOOR: f64 = 1e-3;

/// One pass of the loop: (E per control point, Pa; α, 1/s; β, s).
#[derive(Clone, Debug, PartialEq)]
pub struct LoopPass {
    /// What the pass tracked with (x).
    pub tracked_with: Vec<f64>,
    /// What its fit proposes for the next pass, g(x): the fit's values, a control point at an E
    /// bound given its nearest free neighbour's ([`super::young_for_tracking`]).
    pub proposed: Vec<f64>,
}

/// Anderson acceleration (type II, Walker & Ni 2011, SIAM J. Numer. Anal. 49(4)) of the loop's
/// fixed-point iteration x ↦ g(x), on the logarithms of the parameters (all positive; E moves
/// by factors): with the last m + 1 ≤ [`ANDERSON_DEPTH`] + 1 passes (oldest first, the current
/// one last), residuals f = g(x) − x, ΔF and ΔG their and g's differences between consecutive
/// passes, γ minimizes ‖W (f_k − ΔF γ)‖ and the next x is g(x_k) − ΔG γ, clamped to
/// `lower`…`upper`. W weighs each parameter's residual by 1 / its relative 1-σ in the current
/// fit (`sigma`, at least [`ANDERSON_SIGMA_FLOOR`]; a non-finite σ weighs 0): the least squares
/// are those of the parameters the data determine, a barely strained tip's E does not steer γ.
/// With one pass, or differences of rank 0, it is the plain iteration g(x_k).
pub fn anderson_next(passes: &[LoopPass], sigma: &[f64], lower: &[f64], upper: &[f64]) -> Vec<f64> {
    let Some(current) = passes.last() else {
        return Vec::new();
    };
    let n = current.proposed.len();
    let clamp = |v: Vec<f64>| -> Vec<f64> {
        v.into_iter()
            .enumerate()
            .map(|(i, x)| {
                let lo = lower.get(i).copied().unwrap_or(0.0);
                x.clamp(lo, upper.get(i).copied().unwrap_or(f64::INFINITY))
            })
            .collect()
    };
    let used = &passes[passes.len().saturating_sub(ANDERSON_DEPTH + 1)..];
    let m = used.len() - 1;
    if m == 0 {
        return clamp(current.proposed.clone());
    }
    let ln = |v: &[f64]| v.iter().map(|x| x.ln()).collect::<Vec<_>>();
    let g: Vec<Vec<f64>> = used.iter().map(|p| ln(&p.proposed)).collect();
    let f: Vec<Vec<f64>> = used
        .iter()
        .zip(&g)
        .map(|(p, g)| {
            g.iter()
                .zip(ln(&p.tracked_with))
                .map(|(g, x)| g - x)
                .collect()
        })
        .collect();
    let w: Vec<f64> = (0..n)
        .map(|i| {
            let s = sigma.get(i).copied().unwrap_or(f64::INFINITY);
            if s.is_finite() {
                1.0 / s.max(ANDERSON_SIGMA_FLOOR)
            } else {
                0.0
            }
        })
        .collect();
    let df = DMatrix::from_fn(n, m, |r, c| w[r] * (f[c + 1][r] - f[c][r]));
    let rhs = DVector::from_fn(n, |r, _| w[r] * f[m][r]);
    let svd = df.svd(true, true);
    let tol = 1e-10 * svd.singular_values.max();
    let Ok(gamma) = svd.solve(&rhs, tol) else {
        return clamp(current.proposed.clone());
    };
    clamp(
        (0..n)
            .map(|r| {
                let step: f64 = (0..m).map(|c| gamma[c] * (g[c + 1][r] - g[c][r])).sum();
                (g[m][r] - step).exp()
            })
            .collect(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A linear contraction toward a fixed point in log space, x ↦ x* + A (x − x*): E0 and E1
    /// coupled with a slow eigenvalue (≈ 0.8, as the loop's tip pair), E2 on its own. Three passes
    /// give E0 and E1 exactly (two differences span their plane: Anderson is then GMRES on it)
    /// where the plain iteration is still percents off; E2, weighed 0 (σ not finite), does not
    /// steer γ.
    #[test]
    fn anderson_reaches_the_fixed_point_of_a_linear_contraction_in_log_space() {
        let star = [8e5_f64, 4e5, 3.5e5];
        let a = [[0.5, 0.2, 0.0], [0.1, 0.75, 0.0], [0.0, 0.0, 0.9]];
        let g = |x: &[f64]| -> Vec<f64> {
            (0..3)
                .map(|i| {
                    let d: f64 = (0..3).map(|j| a[i][j] * (x[j] / star[j]).ln()).sum();
                    star[i] * d.exp()
                })
                .collect()
        };
        let mut x = vec![1e5, 1e5, 1e5];
        let mut passes = Vec::new();
        for _ in 0..3 {
            let p = LoopPass {
                tracked_with: x.clone(),
                proposed: g(&x),
            };
            x = p.proposed.clone();
            passes.push(p);
        }
        let rel = |v: f64, i: usize| (v / star[i] - 1.0).abs();
        let plain = &passes[2].proposed;
        let next = anderson_next(&passes, &[0.01, 0.01, f64::INFINITY], &[1e2; 3], &[1e10; 3]);
        for i in 0..2 {
            assert!(rel(plain[i], i) > 0.05, "plain {i}: {}", plain[i]);
            assert!(rel(next[i], i) < 1e-9, "{i}: {} vs {}", next[i], star[i]);
        }
        // Weighed like the others, E2's residual takes a share of γ: E0 and E1 no longer exact.
        let all = anderson_next(&passes, &[0.01; 3], &[1e2; 3], &[1e10; 3]);
        assert!(rel(all[1], 1) > 1e-6, "{}", all[1]);
        // Depth: a fourth pass drops the first.
        passes.insert(0, passes[0].clone());
        assert_eq!(
            anderson_next(&passes, &[0.01, 0.01, f64::INFINITY], &[1e2; 3], &[1e10; 3]),
            next
        );
    }

    /// One pass: the plain iteration, clamped to the bounds.
    #[test]
    fn one_pass_is_the_plain_iteration_within_the_bounds() {
        let p = LoopPass {
            tracked_with: vec![1e5, 0.5],
            proposed: vec![3e5, 5e3],
        };
        assert_eq!(
            anderson_next(&[p], &[0.01, 0.01], &[1e2, 1e-4], &[1e10, 1e3]),
            [3e5, 1e3]
        );
    }
}
