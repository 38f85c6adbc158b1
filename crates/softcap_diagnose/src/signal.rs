//! Small time-series kernels on non-uniformly sampled traces (frame times), used by the hypothesis
//! extensions: first-order low-pass, derivatives, time shift, the median frame interval.

use nalgebra::Vector3;

/// Weights of the exact first-order lag over one interval: y' = (f − y)/τ started at y₀ under
/// the linear input f(σ) = f₀ + (f₁ − f₀) σ/Δ has, at σ = s ∈ [0, Δ],
/// y(s) = w₀ f₀ + w₁ f₁ + w_y y₀ with (slope c = (f₁ − f₀)/Δ, E = e^{−s/τ})
/// y(s) = f₀ + c s − cτ + (y₀ − f₀ + cτ) E, i.e.
/// w₀ = 1 − (s − τ)/Δ − (1 + τ/Δ) E, w₁ = (s − τ)/Δ + (τ/Δ) E, w_y = E (they sum to 1).
/// The one kernel of the lag: [`low_pass`] and the FSR chain ([`crate::sensor`]) both use it.
pub fn lag_weights(dt: f64, tau_s: f64, s: f64) -> [f64; 3] {
    let dt = dt.max(1e-12);
    let e = (-s / tau_s).exp();
    let w1 = (s - tau_s) / dt + tau_s / dt * e;
    [1.0 - w1 - e, w1, e]
}

/// First-order low-pass y' = (f − y)/τ with y(t₀) = f(t₀), integrated exactly for a piecewise
/// linear input ([`lag_weights`] at s = Δ): with slope s = (f_k − f_{k−1})/Δ,
/// y_k = f_k − sτ + (y_{k−1} − f_{k−1} + sτ) e^{−Δ/τ}.
pub fn low_pass(t: &[f64], f: &[Vector3<f64>], tau_s: f64) -> Vec<Vector3<f64>> {
    let mut y = Vec::with_capacity(f.len());
    if f.is_empty() {
        return y;
    }
    y.push(f[0]);
    for k in 1..f.len() {
        let dt = t[k] - t[k - 1];
        let [w0, w1, wy] = lag_weights(dt, tau_s, dt.max(1e-12));
        let prev = y[k - 1];
        y.push(f[k - 1] * w0 + f[k] * w1 + prev * wy);
    }
    y
}

/// Time derivative by central differences (one-sided at the ends), of vectors or scalars.
pub fn derivative<V>(t: &[f64], f: &[V]) -> Vec<V>
where
    V: Copy
        + std::ops::Sub<Output = V>
        + std::ops::Mul<f64, Output = V>
        + std::ops::Div<f64, Output = V>,
{
    let n = f.len();
    (0..n)
        .map(|k| {
            if n < 2 {
                return f[k] * 0.0;
            }
            let (a, b) = if k == 0 {
                (0, 1)
            } else if k == n - 1 {
                (n - 2, n - 1)
            } else {
                (k - 1, k + 1)
            };
            (f[b] - f[a]) / (t[b] - t[a]).max(1e-12)
        })
        .collect()
}

/// Linear interpolation of the trace at `tq` (clamped to the ends).
pub fn sample(t: &[f64], f: &[Vector3<f64>], tq: f64) -> Vector3<f64> {
    let n = t.len();
    if n == 0 {
        return Vector3::zeros();
    }
    if tq <= t[0] {
        return f[0];
    }
    if tq >= t[n - 1] {
        return f[n - 1];
    }
    let k = t.partition_point(|&x| x <= tq).clamp(1, n - 1);
    let w = (tq - t[k - 1]) / (t[k] - t[k - 1]);
    f[k - 1] * (1.0 - w) + f[k] * w
}

/// Time at which a scalar trace first crosses `level` upwards within `range` (linear interpolation).
pub fn crossing_time(
    t: &[f64],
    v: &[f64],
    level: f64,
    range: std::ops::Range<usize>,
) -> Option<f64> {
    let s = range.start.max(1);
    for k in s..range.end.min(v.len()) {
        if v[k - 1] < level && v[k] >= level {
            let w = (level - v[k - 1]) / (v[k] - v[k - 1]);
            return Some(t[k - 1] + w * (t[k] - t[k - 1]));
        }
    }
    None
}

/// Median frame interval of the times `t`, s (0.05 s for fewer than two frames, at least 1 ms).
pub fn median_dt(t: &[f64]) -> f64 {
    let mut d: Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).collect();
    d.sort_by(f64::total_cmp);
    d.get(d.len() / 2).copied().unwrap_or(0.05).max(1e-3)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn low_pass_of_a_ramp_matches_the_analytic_solution() {
        // y' = (t − y)/τ, y(0)=0 → y = t − τ(1 − e^{−t/τ}); exact for a linear input.
        let tau = 0.3;
        let t: Vec<f64> = (0..50).map(|k| 0.037 * k as f64).collect();
        let f: Vec<_> = t.iter().map(|&x| Vector3::new(x, 0.0, 0.0)).collect();
        let y = low_pass(&t, &f, tau);
        for (k, &tk) in t.iter().enumerate() {
            let exact = tk - tau * (1.0 - (-tk / tau).exp());
            assert!((y[k].x - exact).abs() < 1e-12, "{k}: {} vs {exact}", y[k].x);
        }
    }

    #[test]
    fn sample_and_derivative_of_a_quadratic() {
        let t: Vec<f64> = (0..20).map(|k| 0.1 * k as f64).collect();
        let f: Vec<_> = t.iter().map(|&x| Vector3::new(x * x, 0.0, 0.0)).collect();
        let d = derivative(&t, &f);
        // Central differences are exact for quadratics.
        assert!((d[7].x - 2.0 * t[7]).abs() < 1e-12);
        assert!((sample(&t, &f, 0.55).x - 0.5 * (0.25 + 0.36)).abs() < 1e-12);
        let v: Vec<f64> = f.iter().map(|p| p.x).collect();
        let tc = crossing_time(&t, &v, 1.0, 0..20).unwrap();
        assert!((tc - (0.9 + (1.0 - 0.81) / (1.0 - 0.81) * 0.1)).abs() < 1e-12);
    }
}
