//! Base-material models of thesis §8.2: a locally linear corotational material whose
//! stress–strain matrix E is a non-linear function of the local strain, E(p(ε)).
//!
//! - [`InvariantMaterial`]: isotropic, p = (λ, μ) Lamé (thesis eq. 8.1) as an RBF over the strain
//!   invariants (I₁, I₂, I₃) (thesis eq. 8.2), projected to physically valid (E, ν) (§8.3).
//! - [`TransverseMaterial`]: transversely isotropic about z, p = (E11, E12, E13, E33, E44)
//!   (thesis eq. 8.5) as an RBF over the 6-D strain, kept positive definite by the spectral
//!   projection [`project_transverse`] (Rebonato & Jäckel 1999 eigenvalue clipping, §8.3).
//!
//! Both RBFs have the form of thesis eq. 8.2 plus a constant term,
//! p(ε) = p₀ + Σᵢ wᵢ φ(‖q(ε) − qᵢ‖) with φ(r) = r (the biharmonic kernel of bickel2009 §4.1):
//! p₀ is the homogeneous linear pre-fit of §8.3 and the sum models the non-linearity around it,
//! so that far from the sampled strains the material falls back towards the linear fit rather
//! than towards zero. q(ε) are the strain coordinates scaled per component (invariants differ by
//! orders of magnitude: I₁ ~ ε, I₂ ~ ε², I₃ ~ ε³), the scales taken from the pre-fit strains.

use nalgebra::{Matrix2, Matrix3, Matrix6, Vector6};
use serde::{Deserialize, Serialize};
use softcap_core::RbfKernel;

/// Strain tensor from the corotated Voigt strain (ε_xx, ε_yy, ε_zz, γ_xy, γ_xz, γ_yz) of
/// [`softcap_fem::strain_voigt`] (engineering shears γ = 2ε).
pub fn strain_tensor(eps: &Vector6<f64>) -> Matrix3<f64> {
    let (xy, xz, yz) = (0.5 * eps[3], 0.5 * eps[4], 0.5 * eps[5]);
    Matrix3::new(eps[0], xy, xz, xy, eps[1], yz, xz, yz, eps[2])
}

/// The three invariants of the symmetric strain tensor (thesis §8.2):
/// I₁ = tr ε, I₂ = ½((tr ε)² − tr ε²), I₃ = det ε.
pub fn strain_invariants(eps: &Vector6<f64>) -> [f64; 3] {
    let e = strain_tensor(eps);
    let tr = e.trace();
    let tr2 = (e * e).trace();
    [tr, 0.5 * (tr * tr - tr2), e.determinant()]
}

/// Stress–strain matrix of an isotropic material with Lamé (λ, μ) (thesis eq. 8.1,
/// σ = 2με + λ tr(ε) I) acting on Voigt strains with engineering shears.
pub fn isotropic_matrix(lame_lambda: f64, mu: f64) -> Matrix6<f64> {
    let mut e = Matrix6::zeros();
    for i in 0..3 {
        for j in 0..3 {
            e[(i, j)] = lame_lambda;
        }
        e[(i, i)] += 2.0 * mu;
        e[(i + 3, i + 3)] = mu;
    }
    e
}

/// Physically valid range of an isotropic material (thesis §8.3: "bound Lamé's parameters by
/// computing the Young modulus and Poisson ratio and projecting these to physically valid values").
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct IsotropicBounds {
    /// Smallest Young's modulus \[Pa\].
    pub young_min_pa: f64,
    /// Poisson ratio range.
    pub nu_min: f64,
    /// Poisson ratio range (below 0.5: incompressible is excluded).
    pub nu_max: f64,
}

impl Default for IsotropicBounds {
    fn default() -> Self {
        Self {
            young_min_pa: 100.0,
            nu_min: 0.0,
            nu_max: 0.49,
        }
    }
}

/// Projects Lamé (λ, μ) onto the valid set: E = μ(3λ + 2μ)/(λ + μ), ν = λ/(2(λ + μ)) are clamped
/// to `bounds` and mapped back, μ = E/(2(1 + ν)), λ = Eν/((1 + ν)(1 − 2ν)) (thesis §8.3). A pair
/// with λ + μ ≤ 0 or μ ≤ 0 (no valid (E, ν)) keeps its shear modulus (at least the bound) at ν_min.
pub fn project_lame(lame_lambda: f64, mu: f64, bounds: &IsotropicBounds) -> (f64, f64) {
    let e_min = bounds.young_min_pa;
    let (young, nu) = if mu > 0.0 && lame_lambda + mu > 0.0 && lame_lambda.is_finite() {
        (
            mu * (3.0 * lame_lambda + 2.0 * mu) / (lame_lambda + mu),
            lame_lambda / (2.0 * (lame_lambda + mu)),
        )
    } else {
        let m = if mu.is_finite() { mu.max(0.0) } else { 0.0 };
        (2.0 * m * (1.0 + bounds.nu_min), bounds.nu_min)
    };
    let nu = nu.clamp(bounds.nu_min, bounds.nu_max);
    let young = if young.is_finite() {
        young.max(e_min)
    } else {
        e_min
    };
    (
        young * nu / ((1.0 + nu) * (1.0 - 2.0 * nu)),
        young / (2.0 * (1.0 + nu)),
    )
}

/// p(q) = p₀ + Σᵢ wᵢ φ(‖q − qᵢ‖) with φ(r) = r, for `D`-dimensional q and `K` outputs
/// (thesis eq. 8.2 plus the constant p₀, see module docs).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StrainRbf {
    /// Constant part p₀ (the homogeneous linear fit).
    pub constant: Vec<f64>,
    /// Per-coordinate scales s: q = raw / s.
    pub scale: Vec<f64>,
    /// Centres qᵢ (scaled coordinates), one row each.
    pub centres: Vec<Vec<f64>>,
    /// Weights wᵢ, one row of K per centre.
    pub weights: Vec<Vec<f64>>,
}

impl StrainRbf {
    /// A constant function (the linear material).
    pub fn constant(p0: Vec<f64>, dim: usize) -> Self {
        Self {
            constant: p0,
            scale: vec![1.0; dim],
            centres: Vec::new(),
            weights: Vec::new(),
        }
    }

    /// Number of free parameters |p|·(P + 1) as laid out by [`Self::parameters`].
    pub fn num_parameters(&self) -> usize {
        self.constant.len() * (self.centres.len() + 1)
    }

    /// Flat parameters (p₀, w₁, …, w_P).
    pub fn parameters(&self) -> Vec<f64> {
        let mut out = self.constant.clone();
        for w in &self.weights {
            out.extend_from_slice(w);
        }
        out
    }

    /// Sets the flat parameters of [`Self::parameters`].
    pub fn set_parameters(&mut self, theta: &[f64]) {
        let k = self.constant.len();
        self.constant.copy_from_slice(&theta[..k]);
        for (i, w) in self.weights.iter_mut().enumerate() {
            w.copy_from_slice(&theta[k * (i + 1)..k * (i + 2)]);
        }
    }

    /// Evaluates p at raw (unscaled) coordinates.
    pub fn evaluate(&self, raw: &[f64], out: &mut [f64]) {
        out.copy_from_slice(&self.constant);
        for (c, w) in self.centres.iter().zip(&self.weights) {
            let r2: f64 = raw
                .iter()
                .zip(&self.scale)
                .zip(c)
                .map(|((x, s), ci)| {
                    let d = x / s - ci;
                    d * d
                })
                .sum();
            let phi = RbfKernel::Linear.phi(r2.sqrt());
            for (o, wk) in out.iter_mut().zip(w) {
                *o += wk * phi;
            }
        }
    }
}

impl StrainRbf {
    /// Evaluates p at raw coordinates together with its gradient ∂p_k/∂raw_d, written
    /// row-major into `grad` (K × D): ∂p/∂raw = Σᵢ wᵢ (q − qᵢ)ᵀ / (‖q − qᵢ‖ s) for φ(r) = r
    /// (thesis eq. 8.2). At a centre (r = 0) the kernel is not differentiable and the
    /// subgradient 0 is used, as `softcap_core::RbfKernel` does.
    pub fn evaluate_with_gradient(&self, raw: &[f64], out: &mut [f64], grad: &mut [f64]) {
        let dim = raw.len();
        out.copy_from_slice(&self.constant);
        grad.fill(0.0);
        let mut diff = [0.0f64; 6];
        for (c, w) in self.centres.iter().zip(&self.weights) {
            let mut r2 = 0.0;
            for d in 0..dim {
                let v = raw[d] / self.scale[d] - c[d];
                diff[d] = v;
                r2 += v * v;
            }
            let r = r2.sqrt();
            let phi = RbfKernel::Linear.phi(r);
            for (k, (o, wk)) in out.iter_mut().zip(w).enumerate() {
                *o += wk * phi;
                if r > 0.0 {
                    for d in 0..dim {
                        grad[k * dim + d] += wk * diff[d] / (r * self.scale[d]);
                    }
                }
            }
        }
    }
}

/// Gradient of the invariants of [`strain_invariants`] with respect to the Voigt strain
/// (ε_xx, ε_yy, ε_zz, γ_xy, γ_xz, γ_yz), rows I₁, I₂, I₃:
/// ∂I₁ = (1, 1, 1, 0, 0, 0); with I₂ = ε_xx ε_yy + ε_yy ε_zz + ε_zz ε_xx − (γ_xy² + γ_xz² + γ_yz²)/4,
/// ∂I₂ = (ε_yy + ε_zz, ε_xx + ε_zz, ε_xx + ε_yy, −γ_xy/2, −γ_xz/2, −γ_yz/2); ∂I₃ = the cofactors of ε
/// (∂ det ε / ∂ε = cof ε; an engineering shear γ = 2ε_ij enters two entries with weight ½ each).
pub fn strain_invariant_gradient(eps: &Vector6<f64>) -> [[f64; 6]; 3] {
    let [xx, yy, zz, gxy, gxz, gyz] = [eps[0], eps[1], eps[2], eps[3], eps[4], eps[5]];
    [
        [1.0, 1.0, 1.0, 0.0, 0.0, 0.0],
        [
            yy + zz,
            xx + zz,
            xx + yy,
            -0.5 * gxy,
            -0.5 * gxz,
            -0.5 * gyz,
        ],
        [
            yy * zz - 0.25 * gyz * gyz,
            xx * zz - 0.25 * gxz * gxz,
            xx * yy - 0.25 * gxy * gxy,
            0.25 * gxz * gyz - 0.5 * zz * gxy,
            0.25 * gxy * gyz - 0.5 * yy * gxz,
            0.25 * gxy * gxz - 0.5 * xx * gyz,
        ],
    ]
}

/// [`project_lame`] and its Jacobian ∂(λ′, μ′)/∂(λ, μ) (row-major 2×2), by the chain rule
/// through (λ, μ) → (E, ν) → clamp → (λ′, μ′) of thesis §8.3: E = μ(3λ + 2μ)/(λ + μ),
/// ν = λ/(2(λ + μ)); ∂E/∂λ = μ²/(λ + μ)², ∂E/∂μ = (3λ² + 4λμ + 2μ²)/(λ + μ)²,
/// ∂ν/∂λ = μ/(2(λ + μ)²), ∂ν/∂μ = −λ/(2(λ + μ)²); an active clamp zeroes its row;
/// λ′ = Eν/((1 + ν)(1 − 2ν)), μ′ = E/(2(1 + ν)) with ∂λ′/∂ν = E(1 + 2ν²)/((1 + ν)(1 − 2ν))².
/// Inside the valid set the Jacobian is the identity (to rounding).
pub fn project_lame_jacobian(
    lame_lambda: f64,
    mu: f64,
    bounds: &IsotropicBounds,
) -> ((f64, f64), [[f64; 2]; 2]) {
    let e_min = bounds.young_min_pa;
    // (E, ν) and their derivatives w.r.t. (λ, μ).
    let (young, nu, d_young, d_nu) =
        if mu > 0.0 && lame_lambda + mu > 0.0 && lame_lambda.is_finite() {
            let s = lame_lambda + mu;
            let (l, m) = (lame_lambda, mu);
            (
                m * (3.0 * l + 2.0 * m) / s,
                l / (2.0 * s),
                [
                    m * m / (s * s),
                    (3.0 * l * l + 4.0 * l * m + 2.0 * m * m) / (s * s),
                ],
                [m / (2.0 * s * s), -l / (2.0 * s * s)],
            )
        } else {
            let (m, dm) = if mu.is_finite() && mu > 0.0 {
                (mu, 1.0)
            } else {
                (0.0, 0.0)
            };
            let k = 2.0 * (1.0 + bounds.nu_min);
            (k * m, bounds.nu_min, [0.0, k * dm], [0.0, 0.0])
        };
    let (nu, d_nu) = if nu < bounds.nu_min {
        (bounds.nu_min, [0.0; 2])
    } else if nu > bounds.nu_max {
        (bounds.nu_max, [0.0; 2])
    } else {
        (nu, d_nu)
    };
    let (young, d_young) = if young.is_finite() && young >= e_min {
        (young, d_young)
    } else {
        (
            if young.is_finite() {
                young.max(e_min)
            } else {
                e_min
            },
            [0.0; 2],
        )
    };
    let g = (1.0 + nu) * (1.0 - 2.0 * nu);
    let lambda_p = young * nu / g;
    let mu_p = young / (2.0 * (1.0 + nu));
    let dl_de = nu / g;
    let dl_dnu = young * (1.0 + 2.0 * nu * nu) / (g * g);
    let dm_de = 1.0 / (2.0 * (1.0 + nu));
    let dm_dnu = -young / (2.0 * (1.0 + nu) * (1.0 + nu));
    let mut jac = [[0.0; 2]; 2];
    for c in 0..2 {
        jac[0][c] = dl_de * d_young[c] + dl_dnu * d_nu[c];
        jac[1][c] = dm_de * d_young[c] + dm_dnu * d_nu[c];
    }
    ((lambda_p, mu_p), jac)
}

/// Isotropic non-linear base material: (λ, μ) = p(I₁, I₂, I₃) (thesis eq. 8.1–8.2).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct InvariantMaterial {
    /// p(I) → (λ \[Pa\], μ \[Pa\]).
    pub rbf: StrainRbf,
    /// Valid range enforced on every evaluation.
    pub bounds: IsotropicBounds,
}

impl InvariantMaterial {
    /// Linear material with Lamé (λ, μ).
    pub fn linear(lame_lambda: f64, mu: f64) -> Self {
        Self {
            rbf: StrainRbf::constant(vec![lame_lambda, mu], 3),
            bounds: IsotropicBounds::default(),
        }
    }

    /// Linear material from Young's modulus and Poisson ratio.
    pub fn from_young_poisson(young_pa: f64, nu: f64) -> Self {
        Self::linear(
            young_pa * nu / ((1.0 + nu) * (1.0 - 2.0 * nu)),
            young_pa / (2.0 * (1.0 + nu)),
        )
    }

    /// Projected Lamé (λ, μ) at strain ε.
    pub fn lame_at(&self, eps: &Vector6<f64>) -> (f64, f64) {
        let inv = strain_invariants(eps);
        let mut p = [0.0; 2];
        self.rbf.evaluate(&inv, &mut p);
        project_lame(p[0], p[1], &self.bounds)
    }
}

/// Valid range of a transversely isotropic material: every eigenvalue of the Mandel-form
/// stiffness at least `eigen_min_pa`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TransverseBounds {
    /// Smallest eigenvalue of the Mandel stiffness \[Pa\].
    pub eigen_min_pa: f64,
}

impl Default for TransverseBounds {
    fn default() -> Self {
        Self {
            eigen_min_pa: 100.0,
        }
    }
}

/// The five parameters of thesis eq. 8.5 (transverse isotropy about z).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct TransverseParams {
    /// E11 = E22 \[Pa\]
    pub e11: f64,
    /// E12 \[Pa\]
    pub e12: f64,
    /// E13 = E23 \[Pa\]
    pub e13: f64,
    /// E33 \[Pa\]
    pub e33: f64,
    /// E44 = E55: out-of-plane shear (γ_xz, γ_yz) \[Pa\]
    pub e44: f64,
}

impl TransverseParams {
    /// From a 5-vector (E11, E12, E13, E33, E44).
    pub fn from_slice(p: &[f64]) -> Self {
        Self {
            e11: p[0],
            e12: p[1],
            e13: p[2],
            e33: p[3],
            e44: p[4],
        }
    }

    /// The isotropic material with Lamé (λ, μ) written in these parameters.
    pub fn isotropic(lame_lambda: f64, mu: f64) -> Self {
        Self {
            e11: lame_lambda + 2.0 * mu,
            e12: lame_lambda,
            e13: lame_lambda,
            e33: lame_lambda + 2.0 * mu,
            e44: mu,
        }
    }

    /// The 6×6 matrix of thesis eq. 8.5 in the Voigt order (xx, yy, zz, xy, xz, yz) with
    /// engineering shears. The in-plane shear stiffness (E11 − E12)/2 sits at the xy entry: the
    /// thesis prints it in the last diagonal slot, but with the tubes along z the plane of
    /// isotropy is x–y, and only G_xy = (E11 − E12)/2 makes the matrix invariant under rotations
    /// about z (checked in the tests).
    pub fn matrix(&self) -> Matrix6<f64> {
        let mut e = Matrix6::zeros();
        e[(0, 0)] = self.e11;
        e[(1, 1)] = self.e11;
        e[(2, 2)] = self.e33;
        e[(0, 1)] = self.e12;
        e[(1, 0)] = self.e12;
        e[(0, 2)] = self.e13;
        e[(2, 0)] = self.e13;
        e[(1, 2)] = self.e13;
        e[(2, 1)] = self.e13;
        e[(3, 3)] = 0.5 * (self.e11 - self.e12);
        e[(4, 4)] = self.e44;
        e[(5, 5)] = self.e44;
        e
    }
}

/// Nearest positive-definite transversely isotropic parameters (thesis §8.3, "we make sure that
/// the stiffness matrix is positive definite using the technique of [Rebonato and Jäckel, 1999]").
///
/// Rebonato–Jäckel's spectral method clips the eigenvalues of the symmetric matrix; in the
/// Mandel basis (shears scaled by √2, so the Frobenius norm is the tensor norm) this is the
/// Frobenius-nearest matrix with eigenvalues ≥ δ (Higham 1988). Transverse isotropy
/// block-diagonalizes the Mandel matrix into the modes (1, −1, 0, 0, 0, 0)/√2 and γ_xy with
/// eigenvalue E11 − E12, γ_xz and γ_yz with 2 E44, and the 2×2 block
/// [[E11 + E12, √2 E13], [√2 E13, E33]] on span{(1, 1, 0)/√2, e_z}. The clipped matrix commutes
/// with the same symmetry group, so it is itself transversely isotropic: clipping these four
/// closed-form spectra *is* the projection onto {TI and PD} — exact and cheap enough to run per
/// element per equilibrium iteration, which is why a conic solve (clarabel's PSD cone) is not used.
pub fn project_transverse(p: &TransverseParams, bounds: &TransverseBounds) -> TransverseParams {
    let d = bounds.eigen_min_pa;
    let a = (p.e11 - p.e12).max(d);
    let e44 = p.e44.max(0.5 * d);
    let s2 = std::f64::consts::SQRT_2;
    let b = Matrix2::new(p.e11 + p.e12, s2 * p.e13, s2 * p.e13, p.e33);
    let eig = b.symmetric_eigen();
    let lam = eig.eigenvalues.map(|v| v.max(d));
    let bp = eig.eigenvectors * Matrix2::from_diagonal(&lam) * eig.eigenvectors.transpose();
    let sum = bp[(0, 0)];
    TransverseParams {
        e11: 0.5 * (sum + a),
        e12: 0.5 * (sum - a),
        e13: bp[(0, 1)] / s2,
        e33: bp[(1, 1)],
        e44,
    }
}

/// Unit parameter vectors (E11, E12, E13, E33, E44): E is linear in them (thesis eq. 8.5).
const TRANSVERSE_UNITS: [[f64; 5]; 5] = [
    [1.0, 0.0, 0.0, 0.0, 0.0],
    [0.0, 1.0, 0.0, 0.0, 0.0],
    [0.0, 0.0, 1.0, 0.0, 0.0],
    [0.0, 0.0, 0.0, 1.0, 0.0],
    [0.0, 0.0, 0.0, 0.0, 1.0],
];

/// Jacobian ∂p′/∂p (row-major 5 × 5) of [`project_transverse`] at `raw` (projected: `projected`):
/// the identity when no spectrum is clipped (then p′ = p on a neighbourhood), otherwise central
/// differences of the projection (a closed form of five scalars and one 2×2 eigen-decomposition,
/// so 10 cheap evaluations), step 10⁻⁷ × the largest parameter.
fn transverse_projection_jacobian(
    raw: &TransverseParams,
    projected: &TransverseParams,
    bounds: &TransverseBounds,
) -> [[f64; 5]; 5] {
    let v = [raw.e11, raw.e12, raw.e13, raw.e33, raw.e44];
    let w = [
        projected.e11,
        projected.e12,
        projected.e13,
        projected.e33,
        projected.e44,
    ];
    let scale = v.iter().fold(0.0f64, |m, x| m.max(x.abs())).max(1.0);
    let mut jac = [[0.0; 5]; 5];
    let unchanged = v
        .iter()
        .zip(&w)
        .all(|(a, b)| (a - b).abs() <= 1e-12 * scale);
    // Clipping is inactive with a margin: the projection is the identity around `raw`.
    let d = bounds.eigen_min_pa;
    let s2 = std::f64::consts::SQRT_2;
    let b = Matrix2::new(raw.e11 + raw.e12, s2 * raw.e13, s2 * raw.e13, raw.e33);
    let interior = unchanged
        && raw.e11 - raw.e12 > d * (1.0 + 1e-6)
        && raw.e44 > 0.5 * d * (1.0 + 1e-6)
        && b.symmetric_eigen().eigenvalues.min() > d * (1.0 + 1e-6);
    if interior {
        for (k, row) in jac.iter_mut().enumerate() {
            row[k] = 1.0;
        }
        return jac;
    }
    let h = 1e-7 * scale;
    for j in 0..5 {
        let mut plus = v;
        let mut minus = v;
        plus[j] += h;
        minus[j] -= h;
        let fp = project_transverse(&TransverseParams::from_slice(&plus), bounds);
        let fm = project_transverse(&TransverseParams::from_slice(&minus), bounds);
        let dp = [
            fp.e11 - fm.e11,
            fp.e12 - fm.e12,
            fp.e13 - fm.e13,
            fp.e33 - fm.e33,
            fp.e44 - fm.e44,
        ];
        for k in 0..5 {
            jac[k][j] = dp[k] / (2.0 * h);
        }
    }
    jac
}

/// Transversely isotropic non-linear base material: (E11, E12, E13, E33, E44) = p(ε) over the
/// 6-D strain (thesis eq. 8.2, 8.5).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TransverseMaterial {
    /// p(ε) → the five parameters \[Pa\].
    pub rbf: StrainRbf,
    /// Valid range enforced on every evaluation.
    pub bounds: TransverseBounds,
}

impl TransverseMaterial {
    /// Linear (strain-independent) material.
    pub fn linear(p: TransverseParams) -> Self {
        Self {
            rbf: StrainRbf::constant(vec![p.e11, p.e12, p.e13, p.e33, p.e44], 6),
            bounds: TransverseBounds::default(),
        }
    }

    /// Projected parameters at strain ε.
    pub fn params_at(&self, eps: &Vector6<f64>) -> TransverseParams {
        let mut p = [0.0; 5];
        self.rbf.evaluate(eps.as_slice(), &mut p);
        project_transverse(&TransverseParams::from_slice(&p), &self.bounds)
    }
}

/// A base material of the design library.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum BaseMaterial {
    /// Isotropic, RBF over strain invariants (thesis eq. 8.1–8.2).
    Isotropic(InvariantMaterial),
    /// Transversely isotropic, RBF over strain (thesis eq. 8.5).
    Transverse(TransverseMaterial),
}

impl BaseMaterial {
    /// Local stress–strain matrix E(p(ε)) at the corotated Voigt strain ε.
    pub fn stiffness(&self, eps: &Vector6<f64>) -> Matrix6<f64> {
        match self {
            BaseMaterial::Isotropic(m) => {
                let (l, mu) = m.lame_at(eps);
                isotropic_matrix(l, mu)
            }
            BaseMaterial::Transverse(m) => m.params_at(eps).matrix(),
        }
    }

    /// The strain-space RBF.
    pub fn rbf(&self) -> &StrainRbf {
        match self {
            BaseMaterial::Isotropic(m) => &m.rbf,
            BaseMaterial::Transverse(m) => &m.rbf,
        }
    }

    /// The strain-space RBF (mutable, for fitting).
    pub fn rbf_mut(&mut self) -> &mut StrainRbf {
        match self {
            BaseMaterial::Isotropic(m) => &mut m.rbf,
            BaseMaterial::Transverse(m) => &mut m.rbf,
        }
    }

    /// Stress σ = E(p(ε)) ε, the secant matrix E(p(ε)) and the material-consistent tangent
    /// C_t = ∂σ/∂ε = E(p(ε)) + Σ_k (∂E/∂p_k ε) ⊗ ∂p_k/∂ε (thesis §8.2 with p(ε) of eq. 8.2),
    /// analytically: E is linear in p (eq. 8.1, 8.5), ∂p/∂ε is the RBF gradient
    /// ([`StrainRbf::evaluate_with_gradient`]) through the invariants
    /// ([`strain_invariant_gradient`], isotropic) or directly (transversely isotropic), and
    /// through the projection onto valid parameters ([`project_lame_jacobian`]; for the
    /// transversely isotropic projection the identity where no eigenvalue is clipped, central
    /// differences of [`project_transverse`] over the five parameters where one is). C_t is not
    /// symmetric in general (Cauchy-elastic material, thesis §7.4.3).
    pub fn stress_tangent(&self, eps: &Vector6<f64>) -> (Vector6<f64>, Matrix6<f64>, Matrix6<f64>) {
        match self {
            BaseMaterial::Isotropic(m) => {
                let inv = strain_invariants(eps);
                let mut p = [0.0; 2];
                let mut g = [0.0; 6];
                m.rbf.evaluate_with_gradient(&inv, &mut p, &mut g);
                let ((l, mu), jac) = project_lame_jacobian(p[0], p[1], &m.bounds);
                let di = strain_invariant_gradient(eps);
                // ∂(λ, μ)/∂ε = J · ∂p/∂I · ∂I/∂ε.
                let mut dl = Vector6::zeros();
                let mut dm = Vector6::zeros();
                for c in 0..6 {
                    let dp0 = (0..3).map(|d| g[d] * di[d][c]).sum::<f64>();
                    let dp1 = (0..3).map(|d| g[3 + d] * di[d][c]).sum::<f64>();
                    dl[c] = jac[0][0] * dp0 + jac[0][1] * dp1;
                    dm[c] = jac[1][0] * dp0 + jac[1][1] * dp1;
                }
                let e = isotropic_matrix(l, mu);
                let sigma = e * eps;
                let tr = eps[0] + eps[1] + eps[2];
                // ∂σ/∂λ = (tr ε, tr ε, tr ε, 0, 0, 0), ∂σ/∂μ = (2ε_xx, 2ε_yy, 2ε_zz, γ_xy, γ_xz, γ_yz).
                let s_l = Vector6::new(tr, tr, tr, 0.0, 0.0, 0.0);
                let s_m = Vector6::new(
                    2.0 * eps[0],
                    2.0 * eps[1],
                    2.0 * eps[2],
                    eps[3],
                    eps[4],
                    eps[5],
                );
                let ct = e + s_l * dl.transpose() + s_m * dm.transpose();
                (sigma, e, ct)
            }
            BaseMaterial::Transverse(m) => {
                let mut p = [0.0; 5];
                let mut g = [0.0; 30];
                m.rbf.evaluate_with_gradient(eps.as_slice(), &mut p, &mut g);
                let raw = TransverseParams::from_slice(&p);
                let q = project_transverse(&raw, &m.bounds);
                let jac = transverse_projection_jacobian(&raw, &q, &m.bounds);
                let e = q.matrix();
                let sigma = e * eps;
                let mut ct = e;
                for (k, unit) in TRANSVERSE_UNITS.iter().enumerate() {
                    let s_k = TransverseParams::from_slice(unit).matrix() * eps;
                    // ∂p′_k/∂ε = Σ_j J_kj ∂p_j/∂ε.
                    let mut dk = Vector6::zeros();
                    for c in 0..6 {
                        dk[c] = (0..5).map(|j| jac[k][j] * g[j * 6 + c]).sum::<f64>();
                    }
                    ct += s_k * dk.transpose();
                }
                (sigma, e, ct)
            }
        }
    }

    /// RBF coordinates of a strain: invariants (isotropic) or the Voigt strain itself.
    pub fn coordinates(&self, eps: &Vector6<f64>) -> Vec<f64> {
        match self {
            BaseMaterial::Isotropic(_) => strain_invariants(eps).to_vec(),
            BaseMaterial::Transverse(_) => eps.as_slice().to_vec(),
        }
    }

    /// Small-strain stiffness E(p(0)).
    pub fn rest_stiffness(&self) -> Matrix6<f64> {
        self.stiffness(&Vector6::zeros())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Rotation3;

    /// Voigt (engineering) → tensor rotation of a 6×6 stiffness: build the Mandel matrix, rotate
    /// with the 6×6 Mandel rotation, convert back.
    fn rotate_stiffness(e: &Matrix6<f64>, r: &Matrix3<f64>) -> Matrix6<f64> {
        // Apply through tensors: σ' = R σ(Rᵀ ε' R) Rᵀ, column by column.
        let mut out = Matrix6::zeros();
        for c in 0..6 {
            let mut ev = Vector6::zeros();
            ev[c] = 1.0;
            let eps_t = strain_tensor(&ev);
            let local = r.transpose() * eps_t * r;
            let lv = softcap_fem::strain_voigt(&local);
            let s = e * lv;
            let st = Matrix3::new(s[0], s[3], s[4], s[3], s[1], s[5], s[4], s[5], s[2]);
            let sg = r * st * r.transpose();
            out.set_column(
                c,
                &Vector6::new(
                    sg[(0, 0)],
                    sg[(1, 1)],
                    sg[(2, 2)],
                    sg[(0, 1)],
                    sg[(0, 2)],
                    sg[(1, 2)],
                ),
            );
        }
        out
    }

    #[test]
    fn invariants_match_principal_values() {
        // ε with principal strains (0.1, −0.2, 0.05) rotated arbitrarily.
        let r = Rotation3::from_euler_angles(0.3, -0.7, 1.1).into_inner();
        let d = Matrix3::from_diagonal(&nalgebra::Vector3::new(0.1, -0.2, 0.05));
        let e = r * d * r.transpose();
        let v = softcap_fem::strain_voigt(&e);
        let [i1, i2, i3] = strain_invariants(&v);
        assert!((i1 - (-0.05)).abs() < 1e-14);
        assert!((i2 - (0.1 * -0.2 + -0.2 * 0.05 + 0.1 * 0.05)).abs() < 1e-14);
        assert!((i3 - (0.1 * -0.2 * 0.05)).abs() < 1e-15);
    }

    #[test]
    fn isotropic_matrix_is_bickel_lambda_g_plus_alpha_h() {
        let p = softcap_fem::LinearParams::from_young_poisson(3.0e5, 0.3).unwrap();
        let (l, m) = p.lame();
        assert!((isotropic_matrix(l, m) - p.stress_strain_matrix()).norm() < 1e-6);
    }

    #[test]
    fn lame_projection_keeps_valid_and_fixes_invalid() {
        let b = IsotropicBounds::default();
        let (l, m) = (1.0e5, 5.0e4);
        let (pl, pm) = project_lame(l, m, &b);
        assert!((pl - l).abs() < 1e-6 && (pm - m).abs() < 1e-6);
        // ν above the bound → clamped at 0.49 keeping E.
        let (pl, pm) = project_lame(1.0e7, 1.0e4, &b);
        let nu = pl / (2.0 * (pl + pm));
        assert!((nu - 0.49).abs() < 1e-12);
        let e_before = 1.0e4 * (3.0e7 + 2.0e4) / (1.0e7 + 1.0e4);
        assert!((pm * (3.0 * pl + 2.0 * pm) / (pl + pm) - e_before).abs() < 1e-6 * e_before);
        // Negative shear → E_min at ν_min.
        let (pl, pm) = project_lame(1.0e4, -5.0, &b);
        assert!(pl.abs() < 1e-12 && pm > 0.0);
    }

    #[test]
    fn transverse_matrix_is_invariant_about_z_and_projection_is_pd() {
        let p = TransverseParams {
            e11: 5.0e5,
            e12: 1.5e5,
            e13: 1.0e5,
            e33: 9.0e5,
            e44: 1.2e5,
        };
        let e = p.matrix();
        let rz = Rotation3::from_axis_angle(&nalgebra::Vector3::z_axis(), 0.37).into_inner();
        assert!((rotate_stiffness(&e, &rz) - e).norm() < 1e-9 * e.norm());
        // Not invariant about x (it is anisotropic).
        let rx = Rotation3::from_axis_angle(&nalgebra::Vector3::x_axis(), 0.37).into_inner();
        assert!((rotate_stiffness(&e, &rx) - e).norm() > 1e-3 * e.norm());
        // A valid material is kept.
        let q = project_transverse(&p, &TransverseBounds::default());
        assert!((q.matrix() - e).norm() < 1e-9 * e.norm());
        // An indefinite one becomes PD and stays TI; the result equals Higham's eigen-clipping of
        // the full Mandel matrix.
        let bad = TransverseParams {
            e11: 2.0e5,
            e12: 3.0e5,
            e13: 6.0e5,
            e33: 1.0e5,
            e44: -1.0e4,
        };
        let bounds = TransverseBounds { eigen_min_pa: 10.0 };
        let q = project_transverse(&bad, &bounds);
        let mandel = |e: &Matrix6<f64>| {
            let mut d = Matrix6::identity();
            for i in 3..6 {
                d[(i, i)] = std::f64::consts::SQRT_2;
            }
            d * e * d
        };
        let m = mandel(&bad.matrix());
        let eig = m.symmetric_eigen();
        let clipped = eig.eigenvectors
            * Matrix6::from_diagonal(&eig.eigenvalues.map(|v| v.max(10.0)))
            * eig.eigenvectors.transpose();
        let mq = mandel(&q.matrix());
        assert!((mq - clipped).norm() < 1e-8 * clipped.norm());
        assert!(mq.symmetric_eigen().eigenvalues.min() >= 10.0 - 1e-6);
        assert!((rotate_stiffness(&q.matrix(), &rz) - q.matrix()).norm() < 1e-9 * mq.norm());
    }

    #[test]
    fn isotropic_as_transverse_matches() {
        let t = TransverseParams::isotropic(1.0e5, 4.0e4);
        assert!((t.matrix() - isotropic_matrix(1.0e5, 4.0e4)).norm() < 1e-9);
    }

    /// The analytic C_t = ∂σ/∂ε of [`BaseMaterial::stress_tangent`] against central differences
    /// of σ(ε) = E(p(ε)) ε, for the nine reference materials, an isotropic material whose
    /// (E, ν) projection is active (ν clamped at 0.49, E at E_min) and a transversely isotropic
    /// one whose eigenvalue clipping is active.
    #[test]
    fn analytic_stress_tangent_matches_finite_differences() {
        let mut lib = crate::experiment::reference_library();
        let stiffening = |w: [f64; 2]| {
            let mut m = InvariantMaterial::from_young_poisson(2.0e5, 0.45);
            m.rbf.scale = vec![0.1, 0.01, 0.001];
            m.rbf.centres = vec![vec![0.0, 0.0, 0.0]];
            let p0 = m.rbf.constant.clone();
            m.rbf.weights = vec![vec![w[0] * p0[0], w[1] * p0[1]]];
            BaseMaterial::Isotropic(m)
        };
        lib.push(stiffening([20.0, 0.0])); // 9: λ grows → ν clamped at 0.49
        lib.push(stiffening([-3.0, -3.0])); // 10: (λ, μ) turn invalid → E_min at ν_min
        // 11: transversely isotropic, E12 grows past E11 and E44 turns negative → clipped.
        let mut ti = TransverseMaterial::linear(TransverseParams {
            e11: 3.0e5,
            e12: 1.0e5,
            e13: 0.8e5,
            e33: 6.0e5,
            e44: 1.0e5,
        });
        ti.rbf.scale = vec![0.1; 6];
        ti.rbf.centres = vec![vec![0.0; 6]];
        ti.rbf.weights = vec![vec![0.0, 6.0e5, 2.0e5, -1.0e5, -3.0e5]];
        lib.push(BaseMaterial::Transverse(ti));
        let strains = [
            Vector6::new(0.03, -0.01, -0.05, 0.02, -0.015, 0.01),
            Vector6::new(-0.004, 0.002, -0.012, 0.001, 0.006, -0.003),
            Vector6::new(0.08, 0.05, -0.1, -0.04, 0.03, 0.05),
        ];
        let mut worst = 0.0f64;
        for (i, mat) in lib.iter().enumerate() {
            for eps in &strains {
                let (sigma, e, ct) = mat.stress_tangent(eps);
                assert!((e - mat.stiffness(eps)).norm() <= 1e-12 * e.norm());
                assert!((sigma - e * eps).norm() <= 1e-12 * sigma.norm().max(1.0));
                let h = 1e-7;
                let mut fd = Matrix6::zeros();
                for k in 0..6 {
                    let mut ep = *eps;
                    let mut em = *eps;
                    ep[k] += h;
                    em[k] -= h;
                    let col = (mat.stiffness(&ep) * ep - mat.stiffness(&em) * em) / (2.0 * h);
                    fd.set_column(k, &col);
                }
                let err = (ct - fd).norm() / ct.norm();
                worst = worst.max(err);
                assert!(
                    err < 1e-5,
                    "material {i}, ε {eps:?}: |C_t − FD|/|C_t| = {err:e}"
                );
            }
        }
        // The added materials really exercise the projections.
        let lame = |i: usize, k: usize| match &lib[i] {
            BaseMaterial::Isotropic(m) => m.lame_at(&strains[k]),
            BaseMaterial::Transverse(_) => unreachable!(),
        };
        let (l, mu) = lame(9, 0);
        assert!((l / (2.0 * (l + mu)) - 0.49).abs() < 1e-9);
        let (l, mu) = lame(10, 2);
        assert!(l.abs() < 1e-9 && (mu - 50.0).abs() < 1e-9, "{l} {mu}");
        let (_, mu) = lame(10, 1);
        assert!(mu > 1.0e4, "{mu}");
        if let BaseMaterial::Transverse(m) = &lib[11] {
            let mut p = [0.0; 5];
            m.rbf.evaluate(strains[0].as_slice(), &mut p);
            let raw = TransverseParams::from_slice(&p);
            assert!(raw.e11 < raw.e12 && raw.e44 < 0.0, "{raw:?}");
        }
        println!("max |C_t − FD| / |C_t| = {worst:.2e}");
    }

    #[test]
    fn rbf_parameters_round_trip() {
        let mut r = StrainRbf {
            constant: vec![1.0, 2.0],
            scale: vec![0.1, 0.01, 0.001],
            centres: vec![vec![0.0, 0.0, 0.0], vec![1.0, 0.0, 0.0]],
            weights: vec![vec![0.5, 0.5], vec![-0.5, 0.25]],
        };
        let theta = r.parameters();
        assert_eq!(theta.len(), r.num_parameters());
        let mut t2 = theta.clone();
        t2[3] = 9.0;
        r.set_parameters(&t2);
        assert_eq!(r.parameters(), t2);
        let mut out = [0.0; 2];
        r.evaluate(&[0.1, 0.0, 0.0], &mut out); // q = (1, 0, 0): distances 1 and 0
        assert!((out[0] - (1.0 + 0.5 * 1.0 - 0.5 * 0.0)).abs() < 1e-12);
        assert!((out[1] - (2.0 + 9.0 * 1.0)).abs() < 1e-12);
    }
}
