//! Viscoelasticity: a generalized Maxwell body (Prony series) on top of any elastic tet model, as
//! quasi-linear viscoelasticity (QLV, Fung 1981; Puso & Weiss 1998) in each element's unrotated
//! frame. It is the "viscoelastic rate dependence and creep" hypothesis of the diagnose catalog.
//!
//! **Relaxation function.** The base model gives the *long-term* (fully relaxed) response; each of
//! the 0–3 Maxwell branches adds a fraction g_i ≥ 0 of it that relaxes with time constant τ_i:
//!
//! G(t) / G_∞ = 1 + Σ_i g_i e^{−t/τ_i}  (instantaneous stiffness (1 + Σ g_i) G_∞).
//!
//! With one branch this is the standard linear solid (a spring E_∞ in parallel with a Maxwell arm
//! E₁ = g E_∞, η = E₁ τ). With g = 0 the model *is* the base model, so the elastic fit is nested in
//! the viscoelastic one.
//!
//! **Element stress.** For element e with deformation gradient F = R S (polar decomposition) the base
//! model's first Piola–Kirchhoff stress P_∞ is recovered from its nodal forces
//! ([f₁ f₂ f₃] = V P_∞ D_m⁻ᵀ) and pulled back to the unrotated frame, T = Rᵀ P_∞ (for the corotational
//! element T = σ(ε) = (λG + αH) ε, bickel2009 eq. 5; for the stable neo-Hookean element the Biot
//! stress). Each branch carries a history stress h_i (3×3) obeying ḣ_i + h_i/τ_i = g_i Ṫ, and the
//! element's stress is
//!
//! P = R (T + Σ_i h_i),  f_a = V P g_a.
//!
//! **Time stepping** (exact exponential recurrence, Simo & Hughes 1998 §10.3, exact when T is linear
//! in time over the step): with a_i = e^{−Δt/τ_i} and b_i = g_i (1 − a_i) τ_i / Δt,
//!
//! h_i^{n+1} = a_i h_i^n + b_i (T^{n+1} − T^n),
//!
//! so at step n+1 the element force is f_a = (1 + Σ b_i) f_∞,a(x) + V R (Σ_i (a_i h_i^n − b_i T^n)) g_a:
//! the base force scaled by the algorithmic stiffness 1 + Σ b_i plus a history stress carried in the
//! rotating element frame (objective). Δt → 0 gives b_i → g_i (instantaneous response), Δt → ∞ gives
//! b_i → 0 (relaxed). [`ViscoelasticModel`] implements [`ElasticModel`], so the static solver
//! (quasi-static creep / relaxation, [`viscoelastic_quasi_static_step`]) and the dynamic integrators
//! use it like any other model: set the step with [`ViscoelasticModel::set_time_step`], solve, then
//! [`ViscoelasticModel::commit`] the converged positions.
//!
//! **Derivatives for fitting.** The relaxation function's derivatives in (g_i, τ_i) are analytic
//! ([`PronySeries::relaxation_gradient`]); derivatives of a simulated trajectory with respect to
//! (g_i, τ_i) are taken by central finite differences of the time-stepped simulation (step
//! h = 1e-6 · max(1, |p|) in g and in ln τ; the recurrence is smooth in both), as documented for
//! the diagnose refits.

use crate::FemError;
use crate::assembly::DirichletBc;
use crate::contact::ContactProblem;
use crate::element::{Matrix12, StiffnessKind, TetGeometry};
use crate::model::ElasticModel;
use crate::statics::{EquilibriumReport, EquilibriumSettings, StaticSolver};
use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

/// One Maxwell branch: relative stiffness g (fraction of the long-term stiffness) and relaxation
/// time τ \[s\].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PronyBranch {
    /// g_i ≥ 0 (dimensionless, relative to the long-term stiffness)
    pub g: f64,
    /// τ_i > 0 \[s\]
    pub tau_s: f64,
}

/// Generalized Maxwell relaxation function G(t)/G_∞ = 1 + Σ g_i e^{−t/τ_i}.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PronySeries {
    /// The branches (typically 1–3; none = purely elastic).
    pub branches: Vec<PronyBranch>,
}

impl PronySeries {
    /// One-branch series (standard linear solid).
    pub fn standard_linear_solid(g: f64, tau_s: f64) -> Result<Self, FemError> {
        let s = Self {
            branches: vec![PronyBranch { g, tau_s }],
        };
        s.validate()?;
        Ok(s)
    }

    /// Checks g_i ≥ 0 and 0 < τ_i < ∞, all finite.
    pub fn validate(&self) -> Result<(), FemError> {
        for b in &self.branches {
            if !(b.g.is_finite() && b.g >= 0.0) {
                return Err(FemError::InvalidSetting {
                    what: "Prony branch g",
                    value: b.g,
                });
            }
            if !(b.tau_s.is_finite() && b.tau_s > 0.0) {
                return Err(FemError::InvalidSetting {
                    what: "Prony branch tau_s",
                    value: b.tau_s,
                });
            }
        }
        Ok(())
    }

    /// G(t)/G_∞ = 1 + Σ g_i e^{−t/τ_i}.
    pub fn relaxation(&self, t_s: f64) -> f64 {
        1.0 + self
            .branches
            .iter()
            .map(|b| b.g * (-t_s / b.tau_s).exp())
            .sum::<f64>()
    }

    /// Instantaneous-to-relaxed stiffness ratio 1 + Σ g_i.
    pub fn instantaneous_ratio(&self) -> f64 {
        1.0 + self.branches.iter().map(|b| b.g).sum::<f64>()
    }

    /// Flat parameter vector (g₁, τ₁, g₂, τ₂, …) for a fitter.
    pub fn parameters(&self) -> Vec<f64> {
        self.branches.iter().flat_map(|b| [b.g, b.tau_s]).collect()
    }

    /// Series from a flat (g₁, τ₁, …) vector (validated).
    pub fn from_parameters(p: &[f64]) -> Result<Self, FemError> {
        if !p.len().is_multiple_of(2) {
            return Err(FemError::LengthMismatch {
                what: "Prony parameters (g, tau) pairs",
                expected: p.len() + 1,
                got: p.len(),
            });
        }
        let s = Self {
            branches: p
                .chunks_exact(2)
                .map(|c| PronyBranch {
                    g: c[0],
                    tau_s: c[1],
                })
                .collect(),
        };
        s.validate()?;
        Ok(s)
    }

    /// Analytic gradient of G(t)/G_∞ in the order of [`Self::parameters`]:
    /// ∂/∂g_i = e^{−t/τ_i}, ∂/∂τ_i = g_i t/τ_i² e^{−t/τ_i}.
    pub fn relaxation_gradient(&self, t_s: f64) -> Vec<f64> {
        self.branches
            .iter()
            .flat_map(|b| {
                let e = (-t_s / b.tau_s).exp();
                [e, b.g * t_s / (b.tau_s * b.tau_s) * e]
            })
            .collect()
    }

    /// Recurrence coefficients (a_i, b_i) = (e^{−Δt/τ_i}, g_i (1 − a_i) τ_i/Δt) of one step Δt ≥ 0.
    pub fn step_coefficients(&self, dt_s: f64) -> Vec<(f64, f64)> {
        self.branches
            .iter()
            .map(|b| {
                let x = dt_s / b.tau_s;
                let a = (-x).exp();
                let frac = if x > 1e-12 { -(-x).exp_m1() / x } else { 1.0 };
                (a, b.g * frac)
            })
            .collect()
    }
}

/// Quasi-linear viscoelastic wrapper of an elastic model (see the module docs).
#[derive(Clone, Debug)]
pub struct ViscoelasticModel<M> {
    base: M,
    prony: PronySeries,
    /// per element, rest edge matrix D_mᵀ / V (P = [f₁ f₂ f₃] · this)
    dm_t_over_v: Vec<Matrix3<f64>>,
    /// per element × branch: h_i (unrotated frame) [Pa]
    history: Vec<Matrix3<f64>>,
    /// per element: T^n at the last committed state [Pa]
    t_prev: Vec<Matrix3<f64>>,
    dt_s: f64,
    coeffs: Vec<(f64, f64)>,
    /// 1 + Σ b_i of the current step
    scale: f64,
    /// per element: Σ (a_i h_i − b_i T^n) of the current step [Pa]
    step_stress: Vec<Matrix3<f64>>,
}

impl<M: ElasticModel> ViscoelasticModel<M> {
    /// Wraps `base` (whose parameters are the long-term response) with the branches of `prony`,
    /// starting undeformed and unloaded (all history zero) with Δt = 0 (instantaneous response).
    pub fn new(base: M, prony: PronySeries) -> Result<Self, FemError> {
        prony.validate()?;
        let rest = base.rest_positions();
        let dm_t_over_v = base
            .elements()
            .iter()
            .map(|g| {
                let x0 = rest[g.nodes[0]];
                Matrix3::from_columns(&[
                    rest[g.nodes[1]] - x0,
                    rest[g.nodes[2]] - x0,
                    rest[g.nodes[3]] - x0,
                ])
                .transpose()
                    / g.volume_m3
            })
            .collect();
        let ne = base.elements().len();
        let nb = prony.branches.len();
        let mut m = Self {
            base,
            prony,
            dm_t_over_v,
            history: vec![Matrix3::zeros(); ne * nb],
            t_prev: vec![Matrix3::zeros(); ne],
            dt_s: 0.0,
            coeffs: Vec::new(),
            scale: 1.0,
            step_stress: vec![Matrix3::zeros(); ne],
        };
        m.set_time_step(0.0)?;
        Ok(m)
    }

    /// The base (long-term) model.
    pub fn base(&self) -> &M {
        &self.base
    }

    /// Mutable base model (e.g. to change its parameters; the history is kept).
    pub fn base_mut(&mut self) -> &mut M {
        &mut self.base
    }

    /// The Prony series.
    pub fn prony(&self) -> &PronySeries {
        &self.prony
    }

    /// Current step Δt \[s\].
    pub fn time_step_s(&self) -> f64 {
        self.dt_s
    }

    /// Algorithmic stiffness factor 1 + Σ b_i of the current step.
    pub fn stiffness_scale(&self) -> f64 {
        self.scale
    }

    /// Sets the step Δt ≥ 0 \[s\] of the next solve (recomputes a_i, b_i and the history stress).
    pub fn set_time_step(&mut self, dt_s: f64) -> Result<(), FemError> {
        if !(dt_s.is_finite() && dt_s >= 0.0) {
            return Err(FemError::InvalidSetting {
                what: "time step dt_s",
                value: dt_s,
            });
        }
        self.dt_s = dt_s;
        self.coeffs = self.prony.step_coefficients(dt_s);
        self.scale = 1.0 + self.coeffs.iter().map(|c| c.1).sum::<f64>();
        self.refresh_step_stress();
        Ok(())
    }

    fn refresh_step_stress(&mut self) {
        let nb = self.coeffs.len();
        for (e, s) in self.step_stress.iter_mut().enumerate() {
            let mut acc = Matrix3::zeros();
            for (i, &(a, b)) in self.coeffs.iter().enumerate() {
                acc += self.history[e * nb + i] * a - self.t_prev[e] * b;
            }
            *s = acc;
        }
    }

    /// Unrotated long-term stress T = Rᵀ P_∞ of element `e` at `x`, and R.
    pub fn unrotated_stress(&self, e: usize, x: &[Vector3<f64>]) -> (Matrix3<f64>, Matrix3<f64>) {
        let g = &self.base.elements()[e];
        let f = self.base.element_forces(e, x);
        let p = Matrix3::from_columns(&[f[1], f[2], f[3]]) * self.dm_t_over_v[e];
        let r = softcap_core::polar_decomposition(&g.deformation_gradient(x)).rotation;
        (r.transpose() * p, r)
    }

    /// Accepts `x` as the converged state at the end of the current step: h_i ← a_i h_i +
    /// b_i (T(x) − T^n), T^n ← T(x); the history stress is refreshed for the same Δt.
    pub fn commit(&mut self, x: &[Vector3<f64>]) {
        let nb = self.coeffs.len();
        for e in 0..self.t_prev.len() {
            let (t_new, _) = self.unrotated_stress(e, x);
            for (i, &(a, b)) in self.coeffs.iter().enumerate() {
                let h = &mut self.history[e * nb + i];
                *h = *h * a + (t_new - self.t_prev[e]) * b;
            }
            self.t_prev[e] = t_new;
        }
        self.refresh_step_stress();
    }

    /// Internal forces of the *committed* state at `x`: f_a = V R (T(x) + Σ_i h_i) g_a, the forces
    /// at the end of the last committed step when `x` is the committed position (what a reaction
    /// force or a probe force reading is compared with). [`ElasticModel::internal_forces`] instead
    /// evaluates the next step's algorithmic force (Δt of [`Self::set_time_step`]).
    pub fn committed_forces(&self, x: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        let nb = self.coeffs.len();
        let mut out = vec![Vector3::zeros(); self.base.num_nodes()];
        for (e, g) in self.base.elements().iter().enumerate() {
            let (t, r) = self.unrotated_stress(e, x);
            let mut s = t;
            for i in 0..nb {
                s += self.history[e * nb + i];
            }
            let pm = r * s * g.volume_m3;
            for a in 0..4 {
                out[g.nodes[a]] += pm * g.grads[a];
            }
        }
        out
    }

    /// Clears the history (back to the unloaded virgin state).
    pub fn reset(&mut self) {
        self.history.iter_mut().for_each(|h| *h = Matrix3::zeros());
        self.t_prev.iter_mut().for_each(|h| *h = Matrix3::zeros());
        self.refresh_step_stress();
    }

    /// Branch history stresses h_i of element `e` (unrotated frame) \[Pa\].
    pub fn branch_stresses(&self, e: usize) -> &[Matrix3<f64>] {
        let nb = self.coeffs.len();
        &self.history[e * nb..(e + 1) * nb]
    }

    fn history_forces(&self, e: usize, x: &[Vector3<f64>]) -> (Matrix3<f64>, [Vector3<f64>; 4]) {
        let g = &self.base.elements()[e];
        let polar = softcap_core::polar_decomposition(&g.deformation_gradient(x));
        let pm = polar.rotation * self.step_stress[e] * g.volume_m3;
        (
            polar.rotation,
            [
                pm * g.grads[0],
                pm * g.grads[1],
                pm * g.grads[2],
                pm * g.grads[3],
            ],
        )
    }
}

/// ∂(V R H g_a)/∂x for a fixed H: the rotation-derivative term (dR = R [w]×, w from
/// (tr S I − S) w = axial(RᵀdF − dFᵀR), as in [`crate::corotational_tangent`]).
fn rotated_stress_tangent(geom: &TetGeometry, x: &[Vector3<f64>], h: &Matrix3<f64>) -> Matrix12 {
    let f = geom.deformation_gradient(x);
    let polar = softcap_core::polar_decomposition(&f);
    let r = polar.rotation;
    let rtf = r.transpose() * f;
    let s = 0.5 * (rtf + rtf.transpose());
    let sys = Matrix3::identity() * s.trace() - s;
    let mut out = Matrix12::zeros();
    let Some(sys_inv) = (if sys.determinant().abs() > 1e-10 * (1.0 + s.norm().powi(3)) {
        sys.try_inverse()
    } else {
        None
    }) else {
        return out;
    };
    for b in 0..4 {
        for j in 0..3 {
            let mut df = Matrix3::zeros();
            for k in 0..3 {
                df[(j, k)] = geom.grads[b][k];
            }
            let m = r.transpose() * df;
            let am = m - m.transpose();
            let w = sys_inv * Vector3::new(am[(2, 1)], am[(0, 2)], am[(1, 0)]);
            let dp = r * w.cross_matrix() * h * geom.volume_m3;
            for a in 0..4 {
                let col = dp * geom.grads[a];
                for i in 0..3 {
                    out[(3 * a + i, 3 * b + j)] = col[i];
                }
            }
        }
    }
    out
}

impl<M: ElasticModel> ElasticModel for ViscoelasticModel<M> {
    fn rest_positions(&self) -> &[Vector3<f64>] {
        self.base.rest_positions()
    }
    fn tangent_is_symmetric(&self, kind: StiffnessKind) -> bool {
        self.base.tangent_is_symmetric(kind)
    }
    fn elements(&self) -> &[TetGeometry] {
        self.base.elements()
    }
    fn element_forces(&self, e: usize, x: &[Vector3<f64>]) -> [Vector3<f64>; 4] {
        let f = self.base.element_forces(e, x);
        if self.coeffs.is_empty() {
            return f;
        }
        let (_, fh) = self.history_forces(e, x);
        [
            f[0] * self.scale + fh[0],
            f[1] * self.scale + fh[1],
            f[2] * self.scale + fh[2],
            f[3] * self.scale + fh[3],
        ]
    }
    fn element_matrix(&self, e: usize, x: &[Vector3<f64>], kind: StiffnessKind) -> Matrix12 {
        let k = self.base.element_matrix(e, x, kind) * self.scale;
        match kind {
            StiffnessKind::Consistent if !self.coeffs.is_empty() => {
                k + rotated_stress_tangent(&self.base.elements()[e], x, &self.step_stress[e])
            }
            _ => k,
        }
    }
    fn energy(&self, _x: &[Vector3<f64>]) -> Option<f64> {
        None // dissipative: no potential
    }
    fn update_state(&mut self, x: &[Vector3<f64>]) {
        self.base.update_state(x);
    }
}

/// One quasi-static step of length `dt_s` (inertia neglected: creep and relaxation tests, slow
/// probing): sets the step, applies `prescribed` to `x`, solves equilibrium with the viscoelastic
/// forces and commits the state if the solve converged (otherwise the history is left unchanged).
pub fn viscoelastic_quasi_static_step<M: ElasticModel>(
    solver: &mut StaticSolver,
    model: &mut ViscoelasticModel<M>,
    x: &mut [Vector3<f64>],
    external_forces_n: &[Vector3<f64>],
    prescribed: Option<&DirichletBc>,
    contact: Option<&ContactProblem>,
    dt_s: f64,
    settings: &EquilibriumSettings,
) -> Result<EquilibriumReport, FemError> {
    model.set_time_step(dt_s)?;
    if let Some(bc) = prescribed {
        bc.apply(x);
    }
    let rep = solver.solve(model, x, external_forces_n, contact, settings);
    if rep.converged() {
        model.commit(x);
    }
    Ok(rep)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{CorotationalModel, LinearParams, NeoHookeanModel, NeoHookeanParams};

    fn tet() -> softcap_mesh::TetMesh {
        softcap_mesh::TetMesh {
            vertices: vec![
                Vector3::new(0.1, 0.0, 0.0),
                Vector3::new(1.0, 0.2, 0.1),
                Vector3::new(0.2, 1.1, 0.0),
                Vector3::new(0.0, 0.3, 0.9),
            ],
            tets: vec![[0, 1, 2, 3]],
        }
    }

    fn deformed(mesh: &softcap_mesh::TetMesh, s: f64) -> Vec<Vector3<f64>> {
        let rot = nalgebra::Rotation3::from_euler_angles(0.3 * s, -0.2, 0.5);
        mesh.vertices
            .iter()
            .enumerate()
            .map(|(i, v)| rot * (v * (1.0 + 0.04 * s * i as f64)))
            .collect()
    }

    fn fd_tangent_error<M: ElasticModel>(m: &ViscoelasticModel<M>, x: &[Vector3<f64>]) -> f64 {
        let k = m.element_matrix(0, x, StiffnessKind::Consistent);
        let h = 1e-7;
        let mut err: f64 = 0.0;
        for c in 0..12 {
            let mut xp = x.to_vec();
            let mut xm = x.to_vec();
            xp[c / 3][c % 3] += h;
            xm[c / 3][c % 3] -= h;
            let fp = m.element_forces(0, &xp);
            let fm = m.element_forces(0, &xm);
            for r in 0..12 {
                let fd = (fp[r / 3][r % 3] - fm[r / 3][r % 3]) / (2.0 * h);
                err = err.max((fd - k[(r, c)]).abs());
            }
        }
        err / k.norm()
    }

    #[test]
    fn consistent_tangent_with_history_matches_finite_differences() {
        let mesh = tet();
        let prony = PronySeries::from_parameters(&[0.7, 0.5, 0.3, 5.0]).unwrap();
        let co = CorotationalModel::homogeneous(
            &mesh,
            LinearParams::from_young_poisson(1e4, 0.3).unwrap(),
        )
        .unwrap();
        let nh = NeoHookeanModel::homogeneous(
            &mesh,
            NeoHookeanParams::from_young_poisson(1e4, 0.3).unwrap(),
        )
        .unwrap();
        let mut vc = ViscoelasticModel::new(co, prony.clone()).unwrap();
        let mut vn = ViscoelasticModel::new(nh, prony).unwrap();
        // Build some history, then evaluate at a different state.
        vc.set_time_step(0.1).unwrap();
        vn.set_time_step(0.1).unwrap();
        vc.commit(&deformed(&mesh, 1.0));
        vn.commit(&deformed(&mesh, 1.0));
        let x = deformed(&mesh, 1.7);
        let (ec, en) = (fd_tangent_error(&vc, &x), fd_tangent_error(&vn, &x));
        assert!(ec < 1e-6 && en < 1e-6, "tangent rel err {ec:e} {en:e}");
    }

    #[test]
    fn unrotated_stress_of_corotational_is_sigma_of_eps() {
        let mesh = tet();
        let p = LinearParams::from_young_poisson(1e4, 0.3).unwrap();
        let co = CorotationalModel::homogeneous(&mesh, p).unwrap();
        let x = deformed(&mesh, 1.0);
        let v = ViscoelasticModel::new(co.clone(), PronySeries::default()).unwrap();
        let (t, _) = v.unrotated_stress(0, &x);
        let f = co.elements()[0].deformation_gradient(&x);
        let (_, eps) = crate::element::corotated_strain(&f);
        let sigma = crate::element::linear_stress(&p, &eps);
        assert!((t - sigma).norm() < 1e-9 * sigma.norm());
    }

    #[test]
    fn prony_gradient_matches_finite_differences() {
        let s = PronySeries::from_parameters(&[0.7, 0.5, 0.3, 5.0]).unwrap();
        let t = 0.8;
        let g = s.relaxation_gradient(t);
        let p = s.parameters();
        for k in 0..p.len() {
            let h = 1e-6;
            let mut pp = p.clone();
            let mut pm = p.clone();
            pp[k] += h;
            pm[k] -= h;
            let fd = (PronySeries::from_parameters(&pp).unwrap().relaxation(t)
                - PronySeries::from_parameters(&pm).unwrap().relaxation(t))
                / (2.0 * h);
            assert!((fd - g[k]).abs() < 1e-8, "param {k}: {fd} vs {}", g[k]);
        }
        assert!(PronySeries::from_parameters(&[-0.1, 1.0]).is_err());
        assert!(PronySeries::from_parameters(&[0.1, 0.0]).is_err());
    }
}
