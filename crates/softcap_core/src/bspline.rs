//! Uniform cubic B-spline curves v: [t₀, t₁] → ℝᵐ and their weighted least-squares fit
//! (thesis §4.3.1 eq. 4.2: wrinkle valleys are fitted with 5–12 control points minimizing
//! E = Σᵢ wᵢ ‖pᵢ − v(xᵢ)‖²).
//!
//! With n ≥ 4 control points P₀ … P_{n−1} the curve has n − 3 uniform spans on [t₀, t₁]. For
//! u = (t − t₀)/(t₁ − t₀) · (n − 3), span s = ⌊u⌋ (clamped to 0 … n − 4) and τ = u − s,
//!
//! ```text
//!   v(t) = Σ_{k=0..3} B_k(τ) P_{s+k},   B₀ = (1−τ)³/6,  B₁ = (3τ³ − 6τ² + 4)/6,
//!                                       B₂ = (−3τ³ + 3τ² + 3τ + 1)/6,  B₃ = τ³/6.
//! ```
//!
//! The spline space contains every cubic polynomial on [t₀, t₁], so a cubic is fitted exactly.
//! Outside [t₀, t₁] the end spans' polynomials are extended.
//!
//! The fit solves the weighted least-squares problem with Householder QR on the √w-scaled
//! design matrix (better conditioned than the normal equations), optionally with a smoothing
//! term λ Σᵢ ‖P_{i+1} − 2Pᵢ + P_{i−1}‖² that keeps spans without samples well defined.

use faer::Mat;
use serde::{Deserialize, Serialize};

use crate::dense;
use crate::error::{CoreError, Result, check_finite, check_len};

/// A uniform cubic B-spline curve in ℝ^`dim`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct UniformCubicBSpline {
    /// Control points, row-major n×dim.
    control_points: Vec<f64>,
    dim: usize,
    t_min: f64,
    t_max: f64,
}

/// Uniform cubic basis functions B₀…B₃ at τ and their first and second derivatives.
fn basis(tau: f64) -> ([f64; 4], [f64; 4], [f64; 4]) {
    let t2 = tau * tau;
    let t3 = t2 * tau;
    let s = 1.0 - tau;
    let b = [
        s * s * s / 6.0,
        (3.0 * t3 - 6.0 * t2 + 4.0) / 6.0,
        (-3.0 * t3 + 3.0 * t2 + 3.0 * tau + 1.0) / 6.0,
        t3 / 6.0,
    ];
    let db = [
        -s * s / 2.0,
        (3.0 * t2 - 4.0 * tau) / 2.0,
        (-3.0 * t2 + 2.0 * tau + 1.0) / 2.0,
        t2 / 2.0,
    ];
    let ddb = [s, 3.0 * tau - 2.0, -3.0 * tau + 1.0, tau];
    (b, db, ddb)
}

impl UniformCubicBSpline {
    /// Spline from control points (row-major n×`dim`, n ≥ 4) on the parameter interval
    /// [`t_min`, `t_max`] (t_min < t_max).
    pub fn new(control_points: Vec<f64>, dim: usize, t_min: f64, t_max: f64) -> Result<Self> {
        if dim == 0 || !control_points.len().is_multiple_of(dim) {
            return Err(CoreError::DimensionMismatch {
                what: "control points (multiple of dim)",
                expected: control_points.len().checked_div(dim).unwrap_or(0) * dim,
                got: control_points.len(),
            });
        }
        let n = control_points.len() / dim;
        if n < 4 {
            return Err(CoreError::TooFewSamples {
                what: "cubic B-spline control points",
                needed: 4,
                got: n,
            });
        }
        check_finite("control points", &control_points)?;
        if !(t_min.is_finite() && t_max.is_finite() && t_min < t_max) {
            return Err(CoreError::InvalidSetting {
                field: "t_min/t_max",
                reason: format!("need finite t_min < t_max, got [{t_min}, {t_max}]"),
            });
        }
        Ok(Self {
            control_points,
            dim,
            t_min,
            t_max,
        })
    }

    /// Number of control points n.
    pub fn num_control_points(&self) -> usize {
        self.control_points.len() / self.dim
    }

    /// Output dimension m.
    pub fn dim(&self) -> usize {
        self.dim
    }

    /// Control points, row-major n×m.
    pub fn control_points(&self) -> &[f64] {
        &self.control_points
    }

    /// Parameter interval [t₀, t₁].
    pub fn domain(&self) -> (f64, f64) {
        (self.t_min, self.t_max)
    }

    /// Span index s, local τ, and du/dt.
    fn locate(&self, t: f64) -> (usize, f64, f64) {
        let spans = (self.num_control_points() - 3) as f64;
        let dudt = spans / (self.t_max - self.t_min);
        let u = (t - self.t_min) * dudt;
        let s = u.floor().clamp(0.0, spans - 1.0);
        (s as usize, u - s, dudt)
    }

    fn combine(&self, s: usize, w: &[f64; 4], scale: f64, out: &mut [f64]) {
        out.fill(0.0);
        for k in 0..4 {
            let p = &self.control_points[(s + k) * self.dim..(s + k + 1) * self.dim];
            for j in 0..self.dim {
                out[j] += w[k] * scale * p[j];
            }
        }
    }

    /// v(t) into `out` (length m).
    pub fn evaluate_into(&self, t: f64, out: &mut [f64]) -> Result<()> {
        check_len("B-spline output", self.dim, out.len())?;
        let (s, tau, _) = self.locate(t);
        self.combine(s, &basis(tau).0, 1.0, out);
        Ok(())
    }

    /// v(t).
    pub fn evaluate(&self, t: f64) -> Vec<f64> {
        let mut out = vec![0.0; self.dim];
        let (s, tau, _) = self.locate(t);
        self.combine(s, &basis(tau).0, 1.0, &mut out);
        out
    }

    /// dv/dt(t).
    pub fn derivative(&self, t: f64) -> Vec<f64> {
        let mut out = vec![0.0; self.dim];
        let (s, tau, dudt) = self.locate(t);
        self.combine(s, &basis(tau).1, dudt, &mut out);
        out
    }

    /// d²v/dt²(t).
    pub fn second_derivative(&self, t: f64) -> Vec<f64> {
        let mut out = vec![0.0; self.dim];
        let (s, tau, dudt) = self.locate(t);
        self.combine(s, &basis(tau).2, dudt * dudt, &mut out);
        out
    }
}

/// Settings of [`fit_uniform_cubic_bspline`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BSplineFitSettings {
    /// Number of control points n ≥ 4 (thesis §4.3.1 uses 5–12).
    pub num_control_points: usize,
    /// λ ≥ 0 of the second-difference smoothing term (0: pure eq. 4.2).
    pub smoothing: f64,
    /// Parameter interval; None: [min tᵢ, max tᵢ] of the samples.
    pub domain: Option<(f64, f64)>,
}

impl Default for BSplineFitSettings {
    fn default() -> Self {
        Self {
            num_control_points: 8,
            smoothing: 0.0,
            domain: None,
        }
    }
}

/// Weighted least-squares uniform cubic B-spline through samples (tᵢ, pᵢ), pᵢ ∈ ℝ^`dim`
/// (row-major in `values`), minimizing thesis eq. 4.2 Σ wᵢ ‖pᵢ − v(tᵢ)‖² (+ λ smoothing).
/// `weights` None means all 1; weights must be ≥ 0.
///
/// Errors: mismatched lengths, negative/non-finite weights, a degenerate parameter range, or a
/// rank-deficient fit (too few samples per span and λ = 0).
pub fn fit_uniform_cubic_bspline(
    params: &[f64],
    values: &[f64],
    dim: usize,
    weights: Option<&[f64]>,
    settings: &BSplineFitSettings,
) -> Result<UniformCubicBSpline> {
    let ns = params.len();
    if dim == 0 {
        return Err(CoreError::InvalidSetting {
            field: "dim",
            reason: "must be ≥ 1".into(),
        });
    }
    check_len(
        "B-spline sample values (samples · dim)",
        ns * dim,
        values.len(),
    )?;
    check_finite("B-spline sample parameters", params)?;
    check_finite("B-spline sample values", values)?;
    if let Some(w) = weights {
        check_len("B-spline weights", ns, w.len())?;
        if let Some(index) = w.iter().position(|v| !v.is_finite() || *v < 0.0) {
            return Err(CoreError::NonFiniteInput {
                what: "B-spline weights (must be finite and ≥ 0)",
                index,
            });
        }
    }
    let n = settings.num_control_points;
    if n < 4 {
        return Err(CoreError::InvalidSetting {
            field: "num_control_points",
            reason: format!("need ≥ 4, got {n}"),
        });
    }
    if settings.smoothing.is_nan() || settings.smoothing < 0.0 {
        return Err(CoreError::InvalidSetting {
            field: "smoothing",
            reason: "must be ≥ 0".into(),
        });
    }
    let (t_min, t_max) = match settings.domain {
        Some(d) => d,
        None => (
            params.iter().copied().fold(f64::INFINITY, f64::min),
            params.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        ),
    };
    // Knot geometry only matters through `locate`: a zero-coefficient curve on the same domain gives it.
    let mut curve = UniformCubicBSpline::new(vec![0.0; n * dim], dim, t_min, t_max)?;
    let n_smooth = if settings.smoothing > 0.0 { n - 2 } else { 0 };
    let rows = ns + n_smooth;
    if rows < n {
        return Err(CoreError::TooFewSamples {
            what: "B-spline fit samples",
            needed: n,
            got: ns,
        });
    }
    let mut a = Mat::<f64>::zeros(rows, n);
    let mut b = Mat::<f64>::zeros(rows, dim);
    for i in 0..ns {
        let sw = weights.map_or(1.0, |w| w[i].sqrt());
        let (s, tau, _) = curve.locate(params[i]);
        let (bk, _, _) = basis(tau);
        for k in 0..4 {
            a[(i, s + k)] += sw * bk[k];
        }
        for j in 0..dim {
            b[(i, j)] = sw * values[i * dim + j];
        }
    }
    let sl = settings.smoothing.sqrt();
    for r in 0..n_smooth {
        a[(ns + r, r)] = sl;
        a[(ns + r, r + 1)] = -2.0 * sl;
        a[(ns + r, r + 2)] = sl;
    }
    let x = dense::lstsq_qr(a.as_ref(), b.as_ref(), 1e-12).ok_or_else(|| CoreError::SingularSystem {
        what: "B-spline least squares",
        size: n,
        detail: "not enough (weighted) samples in every span; add samples, reduce control points or set smoothing > 0"
            .into(),
    })?;
    for i in 0..n {
        for j in 0..dim {
            curve.control_points[i * dim + j] = x[(i, j)];
        }
    }
    Ok(curve)
}
