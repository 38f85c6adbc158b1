//! Radial basis function (RBF) interpolation and least-squares fitting with a polynomial tail.
//!
//! The model is thesis eq. 4.1 (bickel2009 eq. 8 is the special case without tail):
//!
//! ```text
//!   f(x) = Σ_{i=1..M} w_i φ(‖x − c_i‖) + q(x),     x ∈ ℝ^d,  w_i ∈ ℝ^m,
//! ```
//!
//! with kernel φ(r) = r (biharmonic in 3-D, bickel2009 §4.1) or φ(r) = r³ (triharmonic,
//! thesis §4.2.1), and q a vector-valued polynomial of degree ≤ 0/1/2 (none / linear /
//! quadratic tail; the thesis uses quadratic). With the tail, the weights satisfy the side
//! conditions Σ_i w_i p(c_i) = 0 for every tail monomial p (Carr et al. 2001), so that
//! [`Rbf::interpolate`] solves the symmetric saddle-point system
//!
//! ```text
//!   [ Φ   P ] [ W ]   [ F ]        Φ_ij = φ(‖c_i − c_j‖),  P_ij = p_j(c_i)
//!   [ Pᵀ  0 ] [ A ] = [ 0 ]
//! ```
//!
//! (dense, indefinite; solved with faer's partial-pivoting LU). Because of the tail the
//! interpolant reproduces every polynomial of the tail's degree exactly (thesis §4.2.1: "can
//! exactly reproduce affine motions").
//!
//! [`Rbf::fit_least_squares`] uses fewer centres than samples (bickel2009 §4.2, thesis PSD
//! ch. 5): it minimizes Σ_k ‖f(x_k) − y_k‖² over W, A subject to the same side conditions
//! Pᵀ_c W = 0, by writing W = Z V with Z an orthonormal null-space basis of Pᵀ_c and solving
//! the unconstrained problem min ‖[Φ_xc Z, P_x] [V; A] − Y‖ with Householder QR. With as
//! many centres as samples it coincides with interpolation.
//!
//! [`greedy_rbf`] grows the centre set as in bickel2009 §4.2 (after Carr et al. 2001): fit,
//! add the sample with the largest error as a centre, refit, until the error is below a
//! tolerance; it returns the error history (error against basis size).
//!
//! Inputs are shifted to their centroid and scaled to unit radius before solving. This does
//! not change the model: polynomials of degree ≤ 2 stay polynomials of the same degree under
//! affine maps and φ(s r) = s φ(r) or s³ φ(r), so the function space is identical; it only
//! improves the conditioning of the dense systems.

use faer::Mat;
use serde::{Deserialize, Serialize};

use crate::dense;
use crate::error::{CoreError, Result, check_finite, check_len};

/// Radial kernel φ(r).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum RbfKernel {
    /// φ(r) = r — biharmonic kernel of bickel2009 §4.1 (strain-space material).
    Linear,
    /// φ(r) = r³ — triharmonic kernel of thesis §4.2.1 (mocap→face correspondence).
    #[default]
    Cubic,
}

impl RbfKernel {
    /// φ(r).
    #[inline]
    pub fn phi(self, r: f64) -> f64 {
        match self {
            RbfKernel::Linear => r,
            RbfKernel::Cubic => r * r * r,
        }
    }

    /// φ'(r)/r, the factor that multiplies (x − c) in ∇ₓφ(‖x − c‖); 0 at r = 0 for φ(r) = r
    /// (the kernel is not differentiable at its centre; the subgradient 0 is used).
    #[inline]
    fn dphi_over_r(self, r: f64) -> f64 {
        match self {
            RbfKernel::Linear => {
                if r > 0.0 {
                    1.0 / r
                } else {
                    0.0
                }
            }
            RbfKernel::Cubic => 3.0 * r,
        }
    }

    /// Power k of φ(r) = r^k, used to undo the input scaling: φ(s r) = s^k φ(r).
    fn degree(self) -> i32 {
        match self {
            RbfKernel::Linear => 1,
            RbfKernel::Cubic => 3,
        }
    }
}

/// Polynomial tail q(x) of thesis eq. 4.1.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum PolynomialTail {
    /// No tail (bickel2009 eq. 8).
    None,
    /// 1, x₁ … x_d (reproduces affine maps).
    Linear,
    /// 1, x₁ … x_d, x_i x_j (i ≤ j) (thesis eq. 4.1, reproduces quadratics).
    #[default]
    Quadratic,
}

impl PolynomialTail {
    /// Number of monomials in `dim` dimensions.
    pub fn num_terms(self, dim: usize) -> usize {
        match self {
            PolynomialTail::None => 0,
            PolynomialTail::Linear => 1 + dim,
            PolynomialTail::Quadratic => 1 + dim + dim * (dim + 1) / 2,
        }
    }

    /// Monomials evaluated at `x` (normalized coordinates), written into `out`.
    fn eval(self, x: &[f64], out: &mut [f64]) {
        if self == PolynomialTail::None {
            return;
        }
        let d = x.len();
        out[0] = 1.0;
        out[1..=d].copy_from_slice(x);
        if self == PolynomialTail::Quadratic {
            let mut k = 1 + d;
            for i in 0..d {
                for j in i..d {
                    out[k] = x[i] * x[j];
                    k += 1;
                }
            }
        }
    }

    /// Gradient of monomial `t` with respect to x, into `out` (length d).
    fn grad(self, x: &[f64], t: usize, out: &mut [f64]) {
        out.fill(0.0);
        let d = x.len();
        if t == 0 {
            return;
        }
        if t <= d {
            out[t - 1] = 1.0;
            return;
        }
        let mut k = 1 + d;
        for i in 0..d {
            for j in i..d {
                if k == t {
                    out[i] += x[j];
                    out[j] += x[i];
                    return;
                }
                k += 1;
            }
        }
    }
}

/// Settings of an RBF fit.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RbfSettings {
    /// Radial kernel φ.
    pub kernel: RbfKernel,
    /// Polynomial tail q.
    pub tail: PolynomialTail,
    /// Relative residual accepted from the dense interpolation solve before the system is
    /// declared singular (duplicate centres, centres not unisolvent for the tail).
    pub solve_residual_tolerance: f64,
}

impl Default for RbfSettings {
    fn default() -> Self {
        Self {
            kernel: RbfKernel::Cubic,
            tail: PolynomialTail::Quadratic,
            solve_residual_tolerance: 1e-8,
        }
    }
}

/// Scattered samples (x_k, y_k), x_k ∈ ℝ^d, y_k ∈ ℝ^m, stored row-major in flat slices.
#[derive(Clone, Copy, Debug)]
pub struct ScatteredData<'a> {
    points: &'a [f64],
    values: &'a [f64],
    dim: usize,
    out_dim: usize,
}

impl<'a> ScatteredData<'a> {
    /// `points` holds n·`dim` coordinates, `values` n·`out_dim` values, both row-major.
    pub fn new(points: &'a [f64], dim: usize, values: &'a [f64], out_dim: usize) -> Result<Self> {
        if dim == 0 {
            return Err(CoreError::InvalidSetting {
                field: "dim",
                reason: "must be ≥ 1".into(),
            });
        }
        if out_dim == 0 {
            return Err(CoreError::InvalidSetting {
                field: "out_dim",
                reason: "must be ≥ 1".into(),
            });
        }
        if !points.len().is_multiple_of(dim) {
            return Err(CoreError::DimensionMismatch {
                what: "points (multiple of dim)",
                expected: points.len() / dim * dim,
                got: points.len(),
            });
        }
        let n = points.len() / dim;
        check_len("values (n · out_dim)", n * out_dim, values.len())?;
        check_finite("points", points)?;
        check_finite("values", values)?;
        Ok(Self {
            points,
            values,
            dim,
            out_dim,
        })
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        self.points.len() / self.dim
    }

    /// True when there are no samples.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Input dimension d.
    pub fn dim(&self) -> usize {
        self.dim
    }

    /// Output dimension m.
    pub fn out_dim(&self) -> usize {
        self.out_dim
    }

    /// Sample point k.
    pub fn point(&self, k: usize) -> &'a [f64] {
        &self.points[k * self.dim..(k + 1) * self.dim]
    }

    /// Sample value k.
    pub fn value(&self, k: usize) -> &'a [f64] {
        &self.values[k * self.out_dim..(k + 1) * self.out_dim]
    }
}

/// A fitted RBF f: ℝ^d → ℝ^m (thesis eq. 4.1). Serializable, so a fitted model can be stored.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Rbf {
    kernel: RbfKernel,
    tail: PolynomialTail,
    dim: usize,
    out_dim: usize,
    /// Centres c_i in input coordinates, row-major M×d.
    centers: Vec<f64>,
    /// Centres in normalized coordinates (x − shift)/scale.
    centers_normalized: Vec<f64>,
    shift: Vec<f64>,
    scale: f64,
    /// Weights in normalized coordinates, row-major M×m.
    weights: Vec<f64>,
    /// Tail coefficients in normalized coordinates, row-major q×m.
    tail_coefficients: Vec<f64>,
}

impl Rbf {
    /// Interpolate: centres are the sample points, f(x_k) = y_k exactly (thesis eq. 4.1 with
    /// c_i = m_i). Solves the saddle-point system of the module docs with faer LU.
    ///
    /// Errors: fewer samples than tail terms, or a singular system (duplicate centres,
    /// centres not unisolvent for the tail, e.g. coplanar points with a quadratic tail in 3-D).
    pub fn interpolate(data: &ScatteredData<'_>, settings: &RbfSettings) -> Result<Self> {
        let n = data.len();
        let q = settings.tail.num_terms(data.dim);
        if n < q.max(1) {
            return Err(CoreError::TooFewSamples {
                what: "RBF interpolation samples",
                needed: q.max(1),
                got: n,
            });
        }
        let (shift, scale) = normalization(data.points, data.dim);
        let centers_normalized = normalize(data.points, data.dim, &shift, scale);
        let size = n + q;
        let mut a = Mat::<f64>::zeros(size, size);
        let d = data.dim;
        for i in 0..n {
            let ci = &centers_normalized[i * d..(i + 1) * d];
            for j in 0..i {
                let cj = &centers_normalized[j * d..(j + 1) * d];
                let v = settings.kernel.phi(dist(ci, cj));
                a[(i, j)] = v;
                a[(j, i)] = v;
            }
        }
        let mut prow = vec![0.0; q];
        for i in 0..n {
            settings
                .tail
                .eval(&centers_normalized[i * d..(i + 1) * d], &mut prow);
            for t in 0..q {
                a[(i, n + t)] = prow[t];
                a[(n + t, i)] = prow[t];
            }
        }
        let m = data.out_dim;
        let b = Mat::<f64>::from_fn(
            size,
            m,
            |i, k| if i < n { data.values[i * m + k] } else { 0.0 },
        );
        let x = dense::solve_lu(a.as_ref(), b.as_ref(), settings.solve_residual_tolerance)
            .ok_or_else(|| CoreError::SingularSystem {
                what: "RBF interpolation",
                size,
                detail: "duplicate centres or centres not unisolvent for the polynomial tail"
                    .into(),
            })?;
        let weights = (0..n * m).map(|idx| x[(idx / m, idx % m)]).collect();
        let tail_coefficients = (0..q * m).map(|idx| x[(n + idx / m, idx % m)]).collect();
        Ok(Self {
            kernel: settings.kernel,
            tail: settings.tail,
            dim: d,
            out_dim: m,
            centers: data.points.to_vec(),
            centers_normalized,
            shift,
            scale,
            weights,
            tail_coefficients,
        })
    }

    /// Least-squares fit with given centres (row-major M×d, usually M < n samples;
    /// bickel2009 §4.2): minimizes Σ_k ‖f(x_k) − y_k‖² subject to the tail side conditions
    /// (see module docs).
    ///
    /// Errors: centre dimension mismatch, fewer samples than unknowns, or a rank-deficient
    /// design matrix.
    pub fn fit_least_squares(
        data: &ScatteredData<'_>,
        centers: &[f64],
        settings: &RbfSettings,
    ) -> Result<Self> {
        let d = data.dim;
        let m = data.out_dim;
        let n = data.len();
        if !centers.len().is_multiple_of(d) {
            return Err(CoreError::DimensionMismatch {
                what: "centers (multiple of dim)",
                expected: centers.len() / d * d,
                got: centers.len(),
            });
        }
        check_finite("centers", centers)?;
        let nc = centers.len() / d;
        let q = settings.tail.num_terms(d);
        let (shift, scale) = normalization(data.points, d);
        let centers_normalized = normalize(centers, d, &shift, scale);
        let samples_normalized = normalize(data.points, d, &shift, scale);

        // Null space Z of P_cᵀ (q × M): weights W = Z V satisfy the side conditions.
        let mut pc = Mat::<f64>::zeros(q, nc);
        let mut prow = vec![0.0; q];
        for i in 0..nc {
            settings
                .tail
                .eval(&centers_normalized[i * d..(i + 1) * d], &mut prow);
            for t in 0..q {
                pc[(t, i)] = prow[t];
            }
        }
        let z = dense::null_space(pc.as_ref(), 1e-12).ok_or_else(|| CoreError::SingularSystem {
            what: "RBF side conditions",
            size: nc,
            detail: "SVD of the tail matrix failed".into(),
        })?;
        let nv = z.ncols();
        let unknowns = nv + q;
        if n < unknowns {
            return Err(CoreError::TooFewSamples {
                what: "RBF least-squares samples",
                needed: unknowns,
                got: n,
            });
        }
        let mut phi = Mat::<f64>::zeros(n, nc);
        for k in 0..n {
            let xk = &samples_normalized[k * d..(k + 1) * d];
            for i in 0..nc {
                phi[(k, i)] = settings
                    .kernel
                    .phi(dist(xk, &centers_normalized[i * d..(i + 1) * d]));
            }
        }
        let phiz = &phi * &z;
        let mut a = Mat::<f64>::zeros(n, unknowns);
        for k in 0..n {
            for j in 0..nv {
                a[(k, j)] = phiz[(k, j)];
            }
            settings
                .tail
                .eval(&samples_normalized[k * d..(k + 1) * d], &mut prow);
            for t in 0..q {
                a[(k, nv + t)] = prow[t];
            }
        }
        let b = Mat::<f64>::from_fn(n, m, |k, j| data.values[k * m + j]);
        let sol = dense::lstsq_qr(a.as_ref(), b.as_ref(), 1e-14).ok_or_else(|| CoreError::SingularSystem {
            what: "RBF least squares",
            size: unknowns,
            detail: "design matrix is rank deficient (duplicate centres or samples not unisolvent for the tail)".into(),
        })?;
        let v = Mat::<f64>::from_fn(nv, m, |i, j| sol[(i, j)]);
        let w = &z * &v;
        let weights = (0..nc * m).map(|idx| w[(idx / m, idx % m)]).collect();
        let tail_coefficients = (0..q * m).map(|idx| sol[(nv + idx / m, idx % m)]).collect();
        Ok(Self {
            kernel: settings.kernel,
            tail: settings.tail,
            dim: d,
            out_dim: m,
            centers: centers.to_vec(),
            centers_normalized,
            shift,
            scale,
            weights,
            tail_coefficients,
        })
    }

    /// Input dimension d.
    pub fn dim(&self) -> usize {
        self.dim
    }

    /// Output dimension m.
    pub fn out_dim(&self) -> usize {
        self.out_dim
    }

    /// Number of centres M.
    pub fn num_centers(&self) -> usize {
        self.centers.len() / self.dim
    }

    /// Centres c_i, row-major M×d, in input coordinates.
    pub fn centers(&self) -> &[f64] {
        &self.centers
    }

    /// Kernel φ.
    pub fn kernel(&self) -> RbfKernel {
        self.kernel
    }

    /// Polynomial tail.
    pub fn tail(&self) -> PolynomialTail {
        self.tail
    }

    /// Weights w_i of thesis eq. 4.1 in input coordinates (row-major M×m):
    /// w_i = s^{−k} ŵ_i for φ(r) = r^k and input scale s.
    pub fn weights(&self) -> Vec<f64> {
        let f = self.scale.powi(-self.kernel.degree());
        self.weights.iter().map(|w| w * f).collect()
    }

    /// f(x) into `out` (length m). Errors on a wrong slice length.
    pub fn evaluate_into(&self, x: &[f64], out: &mut [f64]) -> Result<()> {
        check_len("RBF evaluation point", self.dim, x.len())?;
        check_len("RBF evaluation output", self.out_dim, out.len())?;
        let xn: Vec<f64> = (0..self.dim)
            .map(|i| (x[i] - self.shift[i]) / self.scale)
            .collect();
        self.evaluate_normalized(&xn, out);
        Ok(())
    }

    /// f(x).
    pub fn evaluate(&self, x: &[f64]) -> Result<Vec<f64>> {
        let mut out = vec![0.0; self.out_dim];
        self.evaluate_into(x, &mut out)?;
        Ok(out)
    }

    /// f at a batch of points (row-major B×d) → row-major B×m.
    pub fn evaluate_batch(&self, points: &[f64]) -> Result<Vec<f64>> {
        if !points.len().is_multiple_of(self.dim) {
            return Err(CoreError::DimensionMismatch {
                what: "batch points (multiple of dim)",
                expected: points.len() / self.dim * self.dim,
                got: points.len(),
            });
        }
        let nb = points.len() / self.dim;
        let mut out = vec![0.0; nb * self.out_dim];
        let mut xn = vec![0.0; self.dim];
        for b in 0..nb {
            for i in 0..self.dim {
                xn[i] = (points[b * self.dim + i] - self.shift[i]) / self.scale;
            }
            self.evaluate_normalized(&xn, &mut out[b * self.out_dim..(b + 1) * self.out_dim]);
        }
        Ok(out)
    }

    /// Jacobian ∂f/∂x at x, row-major m×d, into `out`.
    ///
    /// ∂f/∂x = Σ_i w_i φ'(r_i)/r_i (x − c_i)ᵀ + ∂q/∂x; for φ(r) = r the (undefined) gradient
    /// at a centre is taken as 0.
    pub fn jacobian_into(&self, x: &[f64], out: &mut [f64]) -> Result<()> {
        let (d, m) = (self.dim, self.out_dim);
        check_len("RBF jacobian point", d, x.len())?;
        check_len("RBF jacobian output (m·d)", m * d, out.len())?;
        let xn: Vec<f64> = (0..d)
            .map(|i| (x[i] - self.shift[i]) / self.scale)
            .collect();
        out.fill(0.0);
        for c in 0..self.num_centers() {
            let cn = &self.centers_normalized[c * d..(c + 1) * d];
            let f = self.kernel.dphi_over_r(dist(&xn, cn));
            for k in 0..m {
                let wk = self.weights[c * m + k] * f;
                for i in 0..d {
                    out[k * d + i] += wk * (xn[i] - cn[i]);
                }
            }
        }
        let q = self.tail.num_terms(d);
        let mut g = vec![0.0; d];
        for t in 0..q {
            self.tail.grad(&xn, t, &mut g);
            for k in 0..m {
                let a = self.tail_coefficients[t * m + k];
                for i in 0..d {
                    out[k * d + i] += a * g[i];
                }
            }
        }
        // Chain rule through the normalization x̂ = (x − shift)/scale.
        for v in out.iter_mut() {
            *v /= self.scale;
        }
        Ok(())
    }

    fn evaluate_normalized(&self, xn: &[f64], out: &mut [f64]) {
        let (d, m) = (self.dim, self.out_dim);
        out.fill(0.0);
        for c in 0..self.num_centers() {
            let phi = self
                .kernel
                .phi(dist(xn, &self.centers_normalized[c * d..(c + 1) * d]));
            let w = &self.weights[c * m..(c + 1) * m];
            for k in 0..m {
                out[k] += w[k] * phi;
            }
        }
        let q = self.tail.num_terms(d);
        if q > 0 {
            let mut p = [0.0; 64];
            let mut heap;
            let prow: &mut [f64] = if q <= p.len() {
                &mut p[..q]
            } else {
                heap = vec![0.0; q];
                &mut heap
            };
            self.tail.eval(xn, prow);
            for t in 0..q {
                let a = &self.tail_coefficients[t * m..(t + 1) * m];
                for k in 0..m {
                    out[k] += a[k] * prow[t];
                }
            }
        }
    }
}

/// Which error measure [`greedy_rbf`] compares with its tolerance.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum GreedyErrorMeasure {
    /// max_k ‖f(x_k) − y_k‖.
    #[default]
    Max,
    /// sqrt(mean_k ‖f(x_k) − y_k‖²).
    Rms,
}

/// Settings of [`greedy_rbf`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GreedyRbfSettings {
    /// Kernel and tail of the fitted RBF.
    pub rbf: RbfSettings,
    /// Stop when the chosen error measure is ≤ this (in output units).
    pub tolerance: f64,
    /// Error measure compared with `tolerance`.
    pub measure: GreedyErrorMeasure,
    /// Stop after this many centres.
    pub max_centers: usize,
    /// Sample indices to start with (bickel2009 §4.2 starts with the zero-strain sample).
    /// Empty: start with the sample closest to the centroid of all sample points.
    pub initial_centers: Vec<usize>,
}

impl Default for GreedyRbfSettings {
    fn default() -> Self {
        Self {
            rbf: RbfSettings::default(),
            tolerance: 1e-6,
            measure: GreedyErrorMeasure::Max,
            max_centers: 200,
            initial_centers: Vec::new(),
        }
    }
}

/// One step of the greedy selection.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct GreedyStep {
    /// Number of centres in this fit.
    pub num_centers: usize,
    /// max_k ‖f(x_k) − y_k‖ over all samples (not only centres).
    pub max_error: f64,
    /// sqrt(mean_k ‖f(x_k) − y_k‖²) over all samples.
    pub rms_error: f64,
    /// The sample with the largest error (the next centre, unless the run stopped).
    pub worst_sample: usize,
}

/// Why [`greedy_rbf`] stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum GreedyStatus {
    /// The error measure fell below the tolerance.
    ToleranceReached,
    /// `max_centers` centres were used without reaching the tolerance.
    MaxCenters,
    /// Every sample is a centre (interpolation) and the tolerance is still not met
    /// (only possible through round-off or a tolerance below solver accuracy).
    AllSamplesUsed,
    /// Adding a centre made the least-squares system singular; the last good fit is returned.
    SingularFit,
}

/// Result of [`greedy_rbf`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GreedyRbfReport {
    /// The final RBF (least-squares fit over all samples with the selected centres).
    pub rbf: Rbf,
    /// Indices of the selected centres into the samples, in the order they were added.
    pub centers: Vec<usize>,
    /// Error after each fit: error against basis size (bickel2009 Fig. 5).
    pub history: Vec<GreedyStep>,
    /// Why the selection stopped.
    pub status: GreedyStatus,
}

/// Greedy centre selection (bickel2009 §4.2 after Carr et al. 2001): start from the initial
/// centres, fit the RBF to *all* samples in the least-squares sense ([`Rbf::fit_least_squares`]),
/// add the sample with the largest error ‖f(x_k) − y_k‖ as a new centre, and repeat until the
/// error measure is ≤ `tolerance` or `max_centers` is reached.
pub fn greedy_rbf(
    data: &ScatteredData<'_>,
    settings: &GreedyRbfSettings,
) -> Result<GreedyRbfReport> {
    let n = data.len();
    let d = data.dim;
    if n == 0 {
        return Err(CoreError::TooFewSamples {
            what: "greedy RBF samples",
            needed: 1,
            got: 0,
        });
    }
    if settings.tolerance.is_nan() || settings.tolerance < 0.0 {
        return Err(CoreError::InvalidSetting {
            field: "tolerance",
            reason: "must be ≥ 0".into(),
        });
    }
    if settings.max_centers == 0 {
        return Err(CoreError::InvalidSetting {
            field: "max_centers",
            reason: "must be ≥ 1".into(),
        });
    }
    let mut centers: Vec<usize> = Vec::new();
    for &i in &settings.initial_centers {
        if i >= n {
            return Err(CoreError::IndexOutOfRange {
                what: "initial_centers",
                index: i,
                len: n,
            });
        }
        if !centers.contains(&i) {
            centers.push(i);
        }
    }
    if centers.is_empty() {
        let mut mean = vec![0.0; d];
        for k in 0..n {
            for i in 0..d {
                mean[i] += data.point(k)[i] / n as f64;
            }
        }
        let first = (0..n)
            .map(|k| (k, dist(data.point(k), &mean)))
            .fold(
                (0, f64::INFINITY),
                |acc, (k, r)| if r < acc.1 { (k, r) } else { acc },
            )
            .0;
        centers.push(first);
    }
    let mut is_center = vec![false; n];
    for &c in &centers {
        is_center[c] = true;
    }
    let mut history = Vec::new();
    let mut best: Option<Rbf> = None;
    let mut best_centers = centers.clone();
    let mut errors = vec![0.0; n];
    let mut pred = vec![0.0; data.out_dim];
    loop {
        let cpts: Vec<f64> = centers
            .iter()
            .flat_map(|&c| data.point(c).iter().copied())
            .collect();
        let rbf = match Rbf::fit_least_squares(data, &cpts, &settings.rbf) {
            Ok(r) => r,
            Err(e) => {
                return match best {
                    Some(rbf) => Ok(GreedyRbfReport {
                        rbf,
                        centers: best_centers,
                        history,
                        status: GreedyStatus::SingularFit,
                    }),
                    None => Err(e),
                };
            }
        };
        let mut sum2 = 0.0;
        for k in 0..n {
            rbf.evaluate_into(data.point(k), &mut pred)?;
            let e2: f64 = pred
                .iter()
                .zip(data.value(k))
                .map(|(p, y)| (p - y) * (p - y))
                .sum();
            errors[k] = e2.sqrt();
            sum2 += e2;
        }
        // Worst sample among non-centres (centres can carry error in least squares too, but
        // adding one twice would make the system singular).
        let (worst, worst_err) = (0..n)
            .filter(|&k| !is_center[k])
            .map(|k| (k, errors[k]))
            .fold(
                (usize::MAX, -1.0),
                |acc, (k, e)| if e > acc.1 { (k, e) } else { acc },
            );
        let max_error = errors.iter().copied().fold(0.0, f64::max);
        let rms_error = (sum2 / n as f64).sqrt();
        history.push(GreedyStep {
            num_centers: centers.len(),
            max_error,
            rms_error,
            worst_sample: worst,
        });
        best = Some(rbf);
        best_centers = centers.clone();
        let measured = match settings.measure {
            GreedyErrorMeasure::Max => max_error,
            GreedyErrorMeasure::Rms => rms_error,
        };
        let status = if measured <= settings.tolerance {
            Some(GreedyStatus::ToleranceReached)
        } else if worst == usize::MAX || worst_err < 0.0 {
            Some(GreedyStatus::AllSamplesUsed)
        } else if centers.len() >= settings.max_centers {
            Some(GreedyStatus::MaxCenters)
        } else {
            None
        };
        if let Some(status) = status {
            let rbf = best.take().expect("set just above");
            return Ok(GreedyRbfReport {
                rbf,
                centers,
                history,
                status,
            });
        }
        centers.push(worst);
        is_center[worst] = true;
    }
}

fn dist(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y) * (x - y))
        .sum::<f64>()
        .sqrt()
}

/// Centroid and radius (max distance from the centroid; 1 if all points coincide).
fn normalization(points: &[f64], d: usize) -> (Vec<f64>, f64) {
    let n = points.len() / d;
    let mut shift = vec![0.0; d];
    if n == 0 {
        return (shift, 1.0);
    }
    for k in 0..n {
        for i in 0..d {
            shift[i] += points[k * d + i];
        }
    }
    for s in &mut shift {
        *s /= n as f64;
    }
    let r = (0..n)
        .map(|k| dist(&points[k * d..(k + 1) * d], &shift))
        .fold(0.0, f64::max);
    (shift, if r > 0.0 { r } else { 1.0 })
}

fn normalize(points: &[f64], d: usize, shift: &[f64], scale: f64) -> Vec<f64> {
    points
        .iter()
        .enumerate()
        .map(|(idx, &x)| (x - shift[idx % d]) / scale)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quadratic_monomial_gradients_match_finite_differences() {
        let x = [0.3, -0.7, 1.1];
        let tail = PolynomialTail::Quadratic;
        let q = tail.num_terms(3);
        let mut p0 = vec![0.0; q];
        let mut p1 = vec![0.0; q];
        let mut g = vec![0.0; 3];
        let h = 1e-6;
        for t in 0..q {
            tail.grad(&x, t, &mut g);
            for i in 0..3 {
                let mut xp = x;
                let mut xm = x;
                xp[i] += h;
                xm[i] -= h;
                tail.eval(&xp, &mut p0);
                tail.eval(&xm, &mut p1);
                let fd = (p0[t] - p1[t]) / (2.0 * h);
                assert!(
                    (fd - g[i]).abs() < 1e-8,
                    "term {t} dir {i}: {fd} vs {}",
                    g[i]
                );
            }
        }
    }
}
