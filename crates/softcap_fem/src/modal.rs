//! Modal analysis: the smallest generalized eigenpairs K φ = λ M φ (λ = ω²) of the linearized model
//! at its rest shape, with lumped (diagonal) M — wang2015 §7 uses the low modes for its warm start.
//!
//! * [`dense_modes`] (small meshes): the symmetric standard problem
//!   (M^{-1/2} K M^{-1/2}) ψ = λ ψ, φ = M^{-1/2} ψ, solved by faer's dense self-adjoint eigensolver.
//! * [`lanczos_modes`] (larger meshes): shift-invert Lanczos. With a shift σ < 0 the matrix
//!   K − σM is symmetric positive definite even when K is singular (a free body's six rigid-body
//!   modes), so it is factored once by the sparse Cholesky of [`crate::assembly`]; Lanczos with full
//!   re-orthogonalization in the M inner product runs on Op = (K − σM)⁻¹ M, whose eigenvalues
//!   θ = 1/(λ − σ) are largest for the λ nearest σ, i.e. the smallest λ. λ = σ + 1/θ; each Ritz pair
//!   is accepted when its true residual ‖Kφ − λMφ‖ ≤ tol · ‖Kφ‖ (+ |λ|‖Mφ‖); the Krylov dimension
//!   grows until the requested modes have converged.
//!
//! Rigid-body modes of a free object come out as λ ≈ 0 (six of them in 3D: three translations,
//! three rotations; |λ| at round-off level relative to the stiff modes). Constrained dofs are
//! eliminated; mode shapes are returned as node fields (zero on constrained dofs), M-orthonormal:
//! φ_iᵀ M φ_j = δ_ij.

use crate::FemError;
use crate::assembly::{DofMap, SparseCholesky, SystemPattern};
use crate::element::StiffnessKind;
use crate::model::ElasticModel;
use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

/// Eigenpairs of K φ = λ M φ, ascending λ.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Modes {
    /// λ_i = ω_i² [rad²/s²].
    pub eigenvalues: Vec<f64>,
    /// Mode shapes as node fields (M-orthonormal), one per eigenvalue.
    pub shapes: Vec<Vec<Vector3<f64>>>,
    /// Relative residuals ‖Kφ − λMφ‖ / ((|λ| + λ_ref)‖Mφ‖) per mode, λ_ref = 10⁻⁶ tr(K)/tr(M).
    pub relative_residuals: Vec<f64>,
}

impl Modes {
    /// Natural frequencies f_i = √max(λ_i, 0) / 2π \[Hz\].
    pub fn frequencies_hz(&self) -> Vec<f64> {
        self.eigenvalues
            .iter()
            .map(|l| l.max(0.0).sqrt() / (2.0 * std::f64::consts::PI))
            .collect()
    }
    /// Angular frequencies ω_i = √max(λ_i, 0) [rad/s].
    pub fn angular_frequencies_rad_s(&self) -> Vec<f64> {
        self.eigenvalues.iter().map(|l| l.max(0.0).sqrt()).collect()
    }
    /// Number of modes with |λ| ≤ `rel` × the largest |λ| returned (rigid-body count).
    pub fn count_near_zero(&self, rel: f64) -> usize {
        let scale = self.eigenvalues.iter().fold(0.0f64, |m, l| m.max(l.abs()));
        self.eigenvalues
            .iter()
            .filter(|l| l.abs() <= rel * scale)
            .count()
    }
}

/// Settings of [`lanczos_modes`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ModalSettings {
    /// Number of smallest modes wanted.
    pub num_modes: usize,
    /// Shift σ [rad²/s²]; `None` = −10⁻⁶ · tr(K)/tr(M) (below every eigenvalue, so K − σM is SPD).
    pub shift: Option<f64>,
    /// Relative residual tolerance per mode.
    pub tolerance: f64,
    /// Krylov dimension per Lanczos run (grown ×1.5 when a run converges nothing); `None` = 2k + 20.
    pub krylov_dimension: Option<usize>,
    /// Seed of the start vector.
    pub seed: u64,
}

impl Default for ModalSettings {
    fn default() -> Self {
        Self {
            num_modes: 20,
            shift: None,
            tolerance: 1e-8,
            krylov_dimension: None,
            seed: 1,
        }
    }
}

fn check_masses(masses_kg: &[f64], dofs: &DofMap) -> Result<(), FemError> {
    for f in 0..dofs.num_free() {
        let m = masses_kg[dofs.dof(f) / 3];
        if !(m.is_finite() && m > 0.0) {
            return Err(FemError::InvalidSetting {
                what: "nodal mass kg of a free node",
                value: m,
            });
        }
    }
    Ok(())
}

fn setup<M: ElasticModel + ?Sized>(
    model: &M,
    masses_kg: &[f64],
    constrained_dofs: &[usize],
) -> Result<(SystemPattern, Vec<f64>, Vec<f64>), FemError> {
    let n = model.num_nodes();
    if masses_kg.len() != n {
        return Err(FemError::LengthMismatch {
            what: "nodal masses",
            expected: n,
            got: masses_kg.len(),
        });
    }
    let dofs = DofMap::new(n, constrained_dofs)?;
    check_masses(masses_kg, &dofs)?;
    let tets: Vec<[usize; 4]> = model.elements().iter().map(|g| g.nodes).collect();
    let pattern = SystemPattern::new(n, &tets, dofs)?;
    let k = pattern.assemble(model, model.rest_positions(), StiffnessKind::Consistent);
    let m: Vec<f64> = (0..pattern.dofs().num_free())
        .map(|f| masses_kg[pattern.dofs().dof(f) / 3])
        .collect();
    Ok((pattern, k, m))
}

fn to_field(dofs: &DofMap, n: usize, phi: &[f64]) -> Vec<Vector3<f64>> {
    let mut out = vec![Vector3::zeros(); n];
    dofs.scatter_add(phi, 1.0, &mut out);
    out
}

/// ‖Kφ − λMφ‖ / ((|λ| + λ_ref) ‖Mφ‖).
fn relative_residual(
    pattern: &SystemPattern,
    k: &[f64],
    m: &[f64],
    lambda: f64,
    lambda_ref: f64,
    phi: &[f64],
) -> f64 {
    let kphi = pattern.mul_vec(k, phi);
    let mut r2 = 0.0;
    let mut m2 = 0.0;
    for i in 0..phi.len() {
        let mp = m[i] * phi[i];
        r2 += (kphi[i] - lambda * mp).powi(2);
        m2 += mp * mp;
    }
    r2.sqrt() / ((lambda.abs() + lambda_ref) * m2.sqrt()).max(f64::MIN_POSITIVE)
}

/// The `num_modes` smallest eigenpairs by a dense eigensolve of M^{-1/2} K M^{-1/2} (use for up to a
/// few thousand free dofs). K is the model's consistent tangent at its rest shape.
pub fn dense_modes<M: ElasticModel + ?Sized>(
    model: &M,
    masses_kg: &[f64],
    constrained_dofs: &[usize],
    num_modes: usize,
) -> Result<Modes, FemError> {
    let (pattern, k, m) = setup(model, masses_kg, constrained_dofs)?;
    let nf = m.len();
    let inv_sqrt: Vec<f64> = m.iter().map(|v| 1.0 / v.sqrt()).collect();
    let lambda_ref = reference_eigenvalue(model, &pattern, &k, &m);
    // Dense symmetric matrix from the lower-triangle CSC pattern.
    let a_ref = pattern.matrix(&k);
    let sym = a_ref.symbolic();
    let (cp, ri) = (sym.col_ptr(), sym.row_idx());
    let vals = a_ref.val();
    let mut a = faer::Mat::<f64>::zeros(nf, nf);
    for j in 0..nf {
        for p in cp[j]..cp[j + 1] {
            let i = ri[p];
            let v = vals[p] * inv_sqrt[i] * inv_sqrt[j];
            a[(i, j)] = v;
            a[(j, i)] = v;
        }
    }
    let evd = a
        .self_adjoint_eigen(faer::Side::Lower)
        .map_err(|e| FemError::Factorization {
            reason: format!("dense eigen: {e:?}"),
        })?;
    let s = evd.S().column_vector();
    let u = evd.U();
    let count = num_modes.min(nf);
    let mut modes = Modes {
        eigenvalues: Vec::with_capacity(count),
        shapes: Vec::with_capacity(count),
        relative_residuals: Vec::with_capacity(count),
    };
    for c in 0..count {
        let lambda = s[c];
        let phi: Vec<f64> = (0..nf).map(|i| u[(i, c)] * inv_sqrt[i]).collect();
        modes.relative_residuals.push(relative_residual(
            &pattern, &k, &m, lambda, lambda_ref, &phi,
        ));
        modes.eigenvalues.push(lambda);
        modes
            .shapes
            .push(to_field(pattern.dofs(), model.num_nodes(), &phi));
    }
    Ok(modes)
}

/// Deterministic start vector (SplitMix64 in [−1, 1]).
fn start_vector(n: usize, seed: u64) -> Vec<f64> {
    let mut s = seed;
    (0..n)
        .map(|_| {
            s = s.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = s;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^= z >> 31;
            (z >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        })
        .collect()
}

fn m_dot(m: &[f64], a: &[f64], b: &[f64]) -> f64 {
    m.iter().zip(a).zip(b).map(|((w, x), y)| w * x * y).sum()
}

/// Report of a Lanczos run (inside [`LanczosModes`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LanczosReport {
    /// Shift σ used.
    pub shift: f64,
    /// Final Krylov dimension.
    pub krylov_dimension: usize,
    /// Number of operator applications (sparse triangular solve pairs).
    pub solves: usize,
    /// True if every requested mode met the tolerance.
    pub converged: bool,
}

/// Modes and the run report of [`lanczos_modes`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LanczosModes {
    /// The eigenpairs (ascending).
    pub modes: Modes,
    /// Run report.
    pub report: LanczosReport,
}

/// The smallest `settings.num_modes` eigenpairs by shift-invert Lanczos with full
/// re-orthogonalization in the M inner product (see the module docs). A single Krylov space holds
/// one vector per repeated eigenvalue (the six rigid-body modes, the two bending modes of a square
/// beam), so converged Ritz pairs are *locked* and Lanczos is restarted from a new start vector
/// M-orthogonal to them (explicit deflation) until a restart finds no new eigenvalue at or below the
/// k-th locked one. Non-convergence is reported in `report.converged`, with the best pairs returned.
pub fn lanczos_modes<M: ElasticModel + ?Sized>(
    model: &M,
    masses_kg: &[f64],
    constrained_dofs: &[usize],
    settings: &ModalSettings,
) -> Result<LanczosModes, FemError> {
    let (pattern, k, m) = setup(model, masses_kg, constrained_dofs)?;
    let nf = m.len();
    let want = settings.num_modes.min(nf);
    let lambda_ref = reference_eigenvalue(model, &pattern, &k, &m);
    let sigma = settings.shift.unwrap_or(-lambda_ref);
    // Factor K − σM.
    let mut shifted = k.clone();
    for node in 0..model.num_nodes() {
        pattern.add_node_block(
            node,
            &(Matrix3::identity() * (-sigma * masses_kg[node])),
            &mut shifted,
        );
    }
    let mut chol = SparseCholesky::new(&pattern)?;
    chol.factor(&pattern, &shifted)?;
    let mut dim = settings
        .krylov_dimension
        .unwrap_or(2 * want + 20)
        .clamp(want.min(nf).max(1), nf);
    let mut solves = 0usize;
    let mut locked: Vec<(f64, Vec<f64>, f64)> = Vec::new();
    let mut converged = false;
    let mut last_dim = 0;
    for run in 0..32u64 {
        let avail = nf - locked.len();
        if avail == 0 {
            converged = locked.len() >= want;
            break;
        }
        let run_dim = dim.min(avail);
        last_dim = run_dim;
        let orth = |w: &mut Vec<f64>, q: &[Vec<f64>]| {
            for _ in 0..2 {
                for qi in q.iter().chain(locked.iter().map(|l| &l.1)) {
                    let c = m_dot(&m, qi, w);
                    w.iter_mut().zip(qi).for_each(|(x, y)| *x -= c * y);
                }
            }
        };
        // Lanczos on Op = (K − σM)⁻¹ M, M-orthonormal basis Q ⟂_M locked.
        let mut q: Vec<Vec<f64>> = Vec::with_capacity(run_dim);
        let mut alpha = Vec::with_capacity(run_dim);
        let mut beta: Vec<f64> = Vec::with_capacity(run_dim);
        let mut v = start_vector(nf, settings.seed.wrapping_add(run));
        orth(&mut v, &q);
        let nv = m_dot(&m, &v, &v).sqrt();
        v.iter_mut().for_each(|x| *x /= nv);
        for j in 0..run_dim {
            let mut w: Vec<f64> = v.iter().zip(&m).map(|(a, b)| a * b).collect();
            chol.solve_in_place(&mut w)?;
            solves += 1;
            q.push(v);
            let a = m_dot(&m, &q[j], &w);
            alpha.push(a);
            orth(&mut w, &q);
            let b = m_dot(&m, &w, &w).sqrt();
            if j + 1 == run_dim || b <= 1e-13 * a.abs().max(f64::MIN_POSITIVE) {
                break;
            }
            beta.push(b);
            v = w.into_iter().map(|x| x / b).collect();
        }
        let msize = alpha.len();
        let mut t = nalgebra::DMatrix::<f64>::zeros(msize, msize);
        for i in 0..msize {
            t[(i, i)] = alpha[i];
            if i + 1 < msize {
                t[(i, i + 1)] = beta[i];
                t[(i + 1, i)] = beta[i];
            }
        }
        let eig = nalgebra::SymmetricEigen::new(t);
        let mut order: Vec<usize> = (0..msize).collect();
        // Largest θ = 1/(λ − σ) first: the smallest λ.
        order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
        let mut new: Vec<(f64, Vec<f64>, f64)> = Vec::new();
        for &c in order.iter().take(want.min(msize)) {
            let theta = eig.eigenvalues[c];
            let lambda = sigma + 1.0 / theta;
            let mut phi = vec![0.0; nf];
            for (i, qi) in q.iter().enumerate() {
                let s = eig.eigenvectors[(i, c)];
                phi.iter_mut().zip(qi).for_each(|(x, y)| *x += s * y);
            }
            let nphi = m_dot(&m, &phi, &phi).sqrt();
            phi.iter_mut().for_each(|x| *x /= nphi);
            let res = relative_residual(&pattern, &k, &m, lambda, lambda_ref, &phi);
            if res <= settings.tolerance {
                new.push((lambda, phi, res));
            }
        }
        let threshold = if locked.len() >= want {
            locked[want - 1].0
        } else {
            f64::INFINITY
        };
        let slack = 1e-9 * threshold.abs().max(lambda_ref);
        let below = new.iter().filter(|p| p.0 <= threshold + slack).count();
        if locked.len() >= want && below == 0 {
            converged = true;
            break;
        }
        if new.is_empty() {
            if run_dim >= avail {
                break;
            }
            dim = (dim + dim / 2).min(nf);
            continue;
        }
        locked.extend(new);
        locked.sort_by(|a, b| a.0.total_cmp(&b.0));
    }
    locked.truncate(want);
    let modes = Modes {
        eigenvalues: locked.iter().map(|p| p.0).collect(),
        relative_residuals: locked.iter().map(|p| p.2).collect(),
        shapes: locked
            .iter()
            .map(|p| to_field(pattern.dofs(), model.num_nodes(), &p.1))
            .collect(),
    };
    Ok(LanczosModes {
        modes,
        report: LanczosReport {
            shift: sigma,
            krylov_dimension: last_dim,
            solves,
            converged: converged && locked.len() == want,
        },
    })
}

/// λ_ref = 10⁻⁶ · tr(K)/tr(M): the eigenvalue scale below which a mode counts as rigid, the default
/// |shift|, and the floor of the residual normalization.
fn reference_eigenvalue<M: ElasticModel + ?Sized>(
    model: &M,
    pattern: &SystemPattern,
    k: &[f64],
    m: &[f64],
) -> f64 {
    let mut trk = 0.0;
    for node in 0..model.num_nodes() {
        let d = pattern.node_diagonal(node, k);
        trk += d.iter().filter(|v| v.is_finite()).sum::<f64>();
    }
    let trm: f64 = m.iter().sum();
    1e-6 * trk / trm
}
