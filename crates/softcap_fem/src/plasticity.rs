//! Plasticity: permanent set of soft objects after loading.
//!
//! **(a) Additive small-strain J2 plasticity on the corotational element**
//! ([`ElastoplasticModel`]). The corotated strain ε = sym(RᵀF) − I of [`crate::element`] is split
//! additively, ε = ε_e + ε_p, with the plastic strain ε_p and the equivalent plastic strain ᾱ stored
//! per element in the rest frame. Stress σ = λ_L tr(ε_e) I + 2μ ε_e (the isotropic law of
//! bickel2009 eq. 5 in Lamé form); von Mises yield function with linear isotropic hardening
//!
//! f(σ, ᾱ) = ‖dev σ‖ − √(2/3) (σ_y + H ᾱ) ≤ 0,
//!
//! integrated by the radial return mapping (Simo & Hughes 1998, *Computational Inelasticity*,
//! Box 3.1–3.2): trial s* = dev σ(ε − ε_pⁿ), f* = ‖s*‖ − √(2/3)(σ_y + H ᾱⁿ); if f* > 0,
//! Δγ = f* / (2μ + 2H/3), n = s*/‖s*‖, ε_p = ε_pⁿ + Δγ n, ᾱ = ᾱⁿ + √(2/3) Δγ, σ = σ* − 2μΔγ n.
//! The consistent (algorithmic) tangent is
//! C_ep = κ 1⊗1 + 2μθ (𝕀 − ⅓ 1⊗1) − 2μθ̄ n⊗n, θ = 1 − 2μΔγ/‖s*‖, θ̄ = 1/(1 + H/3μ) − (1 − θ),
//! and it is pushed through the corotational kinematics with the ∂R terms (so Newton converges
//! quadratically). Forces are evaluated from the *committed* state (ε_pⁿ, ᾱⁿ) and the current x,
//! so the model is a pure function inside an equilibrium solve; call
//! [`ElastoplasticModel::commit`] after each converged load step.
//!
//! 1D check (uniaxial stress, strain-controlled to ε_max, then unloaded): the permanent strain is
//! ε_p = (E ε_max − σ_y)/(E + H) (trial stress Eε_max returned to σ_y + H ε_p), and zero when
//! E ε_max ≤ σ_y. H is the uniaxial plastic (hardening) modulus: σ = σ_y + H ε_p on the plastic
//! branch, so the elastoplastic tangent modulus is E H/(E + H).
//! Parameters for a fitter: (σ_y, H) per element ([`ElastoplasticModel::set_plasticity`]), with
//! per-step analytic ∂f/∂(σ_y, H) ([`ElastoplasticModel::plasticity_parameter_forces`]); whole
//! load paths are differentiated by central differences (re-run the path).
//!
//! **(b) Multiplicative plastic deformation gradient on the stable neo-Hookean element**
//! ([`PlasticNeoHookeanModel`], saito-barbic §3.2, eq. 1–2). Each tet carries F_p (det F_p > 0), the
//! elastic deformation gradient is F_e = F F_p⁻¹ (Bargteil et al. 2007) and the element energy is
//!
//! E_e = V_p Ψ(F F_p⁻¹),  V_p = V det F_p  (saito-barbic eq. 1),
//!
//! with Ψ the stable neo-Hookean density ([`crate::neohookean`]). Because dF_e = dF F_p⁻¹, forces
//! and tangent are those of a neo-Hookean tet with gradients g̃_a = F_p⁻ᵀ g_a and volume V_p:
//! f_a = V_p P(F_e) g̃_a. The stress-free state of a tet is x = F_p X (+ rigid motion). F_p may be
//! given as a symmetric 6-vector (saito-barbic eq. 2, [`plastic_from_vector`]); the parameter
//! derivative ∂f/∂s is analytic (saito-barbic Appendix B eq. 31–34,
//! [`PlasticNeoHookeanModel::plastic_force_jacobian`]): with J_p = det F_p and a symmetric
//! direction E = ∂F_p/∂s_k,
//!
//! dJ_p = J_p tr(F_p⁻¹E),  dF_e = −F_e E F_p⁻¹,  d(F_p⁻ᵀ) = −F_p⁻ᵀ E F_p⁻ᵀ,
//! df_a = V [dJ_p P F_p⁻ᵀ + J_p (∂P/∂F : dF_e) F_p⁻ᵀ + J_p P d(F_p⁻ᵀ)] g_a.

use crate::corotated::{forces_from_stress, kinematics, tangent_from_stress};
use crate::element::{Matrix12, StiffnessKind, TetGeometry, tet_geometries};
use crate::model::{ElasticModel, NeoHookeanModel, fresh_state_id};
use crate::neohookean::{pk1, pk1_derivative};
use crate::{FemError, LinearParams, NeoHookeanParams};
use nalgebra::{Matrix3, SMatrix, SVector, Vector3, Vector6};
use serde::{Deserialize, Serialize};
use softcap_mesh::TetMesh;

/// Von Mises yield with linear isotropic hardening (Simo & Hughes 1998 §3.3).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct J2PlasticityParams {
    /// Initial uniaxial yield stress σ_y \[Pa\] (> 0).
    pub yield_stress_pa: f64,
    /// Uniaxial hardening modulus H \[Pa\] (≥ 0): σ = σ_y + H ᾱ on the plastic branch.
    pub hardening_modulus_pa: f64,
}

impl J2PlasticityParams {
    /// Checks σ_y > 0, H ≥ 0, both finite.
    pub fn validate(&self, element: usize) -> Result<(), FemError> {
        let ok = self.yield_stress_pa.is_finite()
            && self.hardening_modulus_pa.is_finite()
            && self.yield_stress_pa > 0.0
            && self.hardening_modulus_pa >= 0.0;
        if ok {
            Ok(())
        } else {
            Err(FemError::InvalidPlasticity {
                element,
                yield_stress_pa: self.yield_stress_pa,
                hardening_modulus_pa: self.hardening_modulus_pa,
            })
        }
    }
}

/// Committed plastic state of one element (rest frame).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PlasticState {
    /// Plastic strain ε_p (symmetric, traceless under J2 flow) [-].
    pub plastic_strain: Matrix3<f64>,
    /// Equivalent plastic strain ᾱ = Σ √(2/3) Δγ [-].
    pub equivalent_plastic_strain: f64,
}

impl Default for PlasticState {
    fn default() -> Self {
        Self {
            plastic_strain: Matrix3::zeros(),
            equivalent_plastic_strain: 0.0,
        }
    }
}

/// Result of the radial return at one material point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReturnMapping {
    /// Stress σ \[Pa\].
    pub stress_pa: Matrix3<f64>,
    /// Updated state (equals the committed one when elastic).
    pub state: PlasticState,
    /// Plastic multiplier Δγ (0 when elastic).
    pub delta_gamma: f64,
    /// Flow direction n = s*/‖s*‖ (zero when elastic).
    pub normal: Matrix3<f64>,
    /// θ of the algorithmic tangent (1 when elastic).
    pub theta: f64,
    /// θ̄ of the algorithmic tangent (0 when elastic).
    pub theta_bar: f64,
}

impl ReturnMapping {
    /// dσ = C_ep : dε (Simo & Hughes Box 3.2) for Lamé parameters of `elastic`.
    pub fn tangent_apply(&self, elastic: &LinearParams, de: &Matrix3<f64>) -> Matrix3<f64> {
        let (lame, mu) = elastic.lame();
        let kappa = lame + 2.0 * mu / 3.0;
        let tr = de.trace();
        let dev = de - Matrix3::identity() * (tr / 3.0);
        Matrix3::identity() * (kappa * tr) + dev * (2.0 * mu * self.theta)
            - self.normal * (2.0 * mu * self.theta_bar * self.normal.component_mul(de).sum())
    }
}

impl ReturnMapping {
    /// ∂σ/∂σ_y and ∂σ/∂H of this return at fixed total strain and committed state (zero when
    /// elastic): σ = σ* − 2μΔγ n with Δγ = (‖s*‖ − √(2/3)(σ_y + Hᾱⁿ))/(2μ + 2H/3), so
    /// ∂Δγ/∂σ_y = −√(2/3)/(2μ + 2H/3) and ∂Δγ/∂H = −(√(2/3)ᾱⁿ + ⅔Δγ)/(2μ + 2H/3).
    pub fn parameter_derivatives(
        &self,
        elastic: &LinearParams,
        plastic: &J2PlasticityParams,
        committed: &PlasticState,
    ) -> (Matrix3<f64>, Matrix3<f64>) {
        if self.delta_gamma <= 0.0 {
            return (Matrix3::zeros(), Matrix3::zeros());
        }
        let (_, mu) = elastic.lame();
        let den = 2.0 * mu + 2.0 * plastic.hardening_modulus_pa / 3.0;
        let c = (2.0f64 / 3.0).sqrt();
        let dg_dsy = -c / den;
        let dg_dh = -(c * committed.equivalent_plastic_strain + 2.0 / 3.0 * self.delta_gamma) / den;
        (
            self.normal * (-2.0 * mu * dg_dsy),
            self.normal * (-2.0 * mu * dg_dh),
        )
    }
}

/// Radial return mapping (Simo & Hughes 1998, Box 3.1) from the committed `state` at total strain
/// `strain` (rest-frame corotated strain).
pub fn radial_return(
    elastic: &LinearParams,
    plastic: &J2PlasticityParams,
    strain: &Matrix3<f64>,
    state: &PlasticState,
) -> ReturnMapping {
    let (lame, mu) = elastic.lame();
    let ee = strain - state.plastic_strain;
    let sigma_trial = ee * (2.0 * mu) + Matrix3::identity() * (lame * ee.trace());
    let p = sigma_trial.trace() / 3.0;
    let s_trial = sigma_trial - Matrix3::identity() * p;
    let xi = s_trial.norm();
    let radius = (2.0f64 / 3.0).sqrt()
        * (plastic.yield_stress_pa
            + plastic.hardening_modulus_pa * state.equivalent_plastic_strain);
    let f_trial = xi - radius;
    if f_trial <= 0.0 || xi == 0.0 {
        return ReturnMapping {
            stress_pa: sigma_trial,
            state: *state,
            delta_gamma: 0.0,
            normal: Matrix3::zeros(),
            theta: 1.0,
            theta_bar: 0.0,
        };
    }
    let h = plastic.hardening_modulus_pa;
    let dg = f_trial / (2.0 * mu + 2.0 * h / 3.0);
    let n = s_trial / xi;
    let theta = 1.0 - 2.0 * mu * dg / xi;
    let theta_bar = 1.0 / (1.0 + h / (3.0 * mu)) - (1.0 - theta);
    ReturnMapping {
        stress_pa: sigma_trial - n * (2.0 * mu * dg),
        state: PlasticState {
            plastic_strain: state.plastic_strain + n * dg,
            equivalent_plastic_strain: state.equivalent_plastic_strain + (2.0f64 / 3.0).sqrt() * dg,
        },
        delta_gamma: dg,
        normal: n,
        theta,
        theta_bar,
    }
}

/// Corotational tet model with per-element additive J2 plasticity (module docs, part (a)).
#[derive(Clone, Debug)]
pub struct ElastoplasticModel {
    rest: Vec<Vector3<f64>>,
    geometry: Vec<TetGeometry>,
    params: Vec<LinearParams>,
    plasticity: Vec<J2PlasticityParams>,
    committed: Vec<PlasticState>,
    /// [`ElasticModel::state_id`]: renewed by every change of the parameters or the committed
    /// state.
    state_id: u64,
}

impl ElastoplasticModel {
    /// Model over `mesh` with per-element elastic and plastic parameters (validated), virgin state.
    pub fn new(
        mesh: &TetMesh,
        params: Vec<LinearParams>,
        plasticity: Vec<J2PlasticityParams>,
    ) -> Result<Self, FemError> {
        let geometry = tet_geometries(&mesh.vertices, &mesh.tets)?;
        for (what, len) in [
            ("per-element parameters", params.len()),
            ("per-element plasticity", plasticity.len()),
        ] {
            if len != geometry.len() {
                return Err(FemError::LengthMismatch {
                    what,
                    expected: geometry.len(),
                    got: len,
                });
            }
        }
        for (e, (p, q)) in params.iter().zip(&plasticity).enumerate() {
            p.validate(e)?;
            q.validate(e)?;
        }
        Ok(Self {
            rest: mesh.vertices.clone(),
            committed: vec![PlasticState::default(); geometry.len()],
            state_id: fresh_state_id(),
            geometry,
            params,
            plasticity,
        })
    }

    /// Homogeneous model.
    pub fn homogeneous(
        mesh: &TetMesh,
        p: LinearParams,
        q: J2PlasticityParams,
    ) -> Result<Self, FemError> {
        Self::new(mesh, vec![p; mesh.tets.len()], vec![q; mesh.tets.len()])
    }

    /// Elastic parameters per element.
    pub fn params(&self) -> &[LinearParams] {
        &self.params
    }

    /// Plastic parameters per element.
    pub fn plasticity(&self) -> &[J2PlasticityParams] {
        &self.plasticity
    }

    /// Replaces the plastic parameters (a fitter's entry point; not validated).
    pub fn set_plasticity(&mut self, q: &[J2PlasticityParams]) -> Result<(), FemError> {
        if q.len() != self.plasticity.len() {
            return Err(FemError::LengthMismatch {
                what: "per-element plasticity",
                expected: self.plasticity.len(),
                got: q.len(),
            });
        }
        self.plasticity.copy_from_slice(q);
        self.state_id = fresh_state_id();
        Ok(())
    }

    /// Replaces the elastic parameters (not validated).
    pub fn set_params(&mut self, p: &[LinearParams]) -> Result<(), FemError> {
        if p.len() != self.params.len() {
            return Err(FemError::LengthMismatch {
                what: "per-element parameters",
                expected: self.params.len(),
                got: p.len(),
            });
        }
        self.params.copy_from_slice(p);
        self.state_id = fresh_state_id();
        Ok(())
    }

    /// Committed plastic states.
    pub fn plastic_states(&self) -> &[PlasticState] {
        &self.committed
    }

    /// Back to the virgin (unyielded) state.
    pub fn reset(&mut self) {
        self.committed.fill(PlasticState::default());
        self.state_id = fresh_state_id();
    }

    /// Return mapping of element `e` at positions `x` (from the committed state) together with the
    /// element rotation and stretch.
    pub fn element_return(
        &self,
        e: usize,
        x: &[Vector3<f64>],
    ) -> (ReturnMapping, Matrix3<f64>, Matrix3<f64>) {
        let (r, s, eps) = kinematics(&self.geometry[e], x);
        (
            radial_return(
                &self.params[e],
                &self.plasticity[e],
                &eps,
                &self.committed[e],
            ),
            r,
            s,
        )
    }

    /// ∂f_e/∂σ_y and ∂f_e/∂H of element `e` at `x` for the current load step (committed state
    /// held fixed): V R (∂σ/∂q) g_a. Over a multi-step path the committed state also depends on
    /// (σ_y, H); a fitter differentiates the whole path by central differences through
    /// [`Self::set_plasticity`] (re-run the path) — these per-step derivatives are exact for a
    /// single step from the virgin state.
    pub fn plasticity_parameter_forces(
        &self,
        e: usize,
        x: &[Vector3<f64>],
    ) -> ([Vector3<f64>; 4], [Vector3<f64>; 4]) {
        let (rm, r, _) = self.element_return(e, x);
        let (dsy, dh) =
            rm.parameter_derivatives(&self.params[e], &self.plasticity[e], &self.committed[e]);
        (
            forces_from_stress(&self.geometry[e], &r, &dsy),
            forces_from_stress(&self.geometry[e], &r, &dh),
        )
    }

    /// Commits the return-mapped state at the converged positions `x` (end of a load step);
    /// returns the number of elements that yielded in this step.
    pub fn commit(&mut self, x: &[Vector3<f64>]) -> usize {
        let mut yielded = 0;
        let states: Vec<PlasticState> = (0..self.geometry.len())
            .map(|e| {
                let (rm, _, _) = self.element_return(e, x);
                if rm.delta_gamma > 0.0 {
                    yielded += 1;
                }
                rm.state
            })
            .collect();
        self.committed = states;
        self.state_id = fresh_state_id();
        yielded
    }
}

impl ElasticModel for ElastoplasticModel {
    fn rest_positions(&self) -> &[Vector3<f64>] {
        &self.rest
    }
    fn elements(&self) -> &[TetGeometry] {
        &self.geometry
    }
    fn element_forces(&self, e: usize, x: &[Vector3<f64>]) -> [Vector3<f64>; 4] {
        let (rm, r, _) = self.element_return(e, x);
        forces_from_stress(&self.geometry[e], &r, &rm.stress_pa)
    }
    fn element_matrix(&self, e: usize, x: &[Vector3<f64>], kind: StiffnessKind) -> Matrix12 {
        let (rm, r, s) = self.element_return(e, x);
        let p = self.params[e];
        tangent_from_stress(
            &self.geometry[e],
            &r,
            &s,
            &rm.stress_pa,
            |de| rm.tangent_apply(&p, de),
            kind == StiffnessKind::Consistent,
        )
    }
    fn energy(&self, _x: &[Vector3<f64>]) -> Option<f64> {
        None // path dependent: no potential in x alone
    }
    fn state_id(&self) -> Option<u64> {
        Some(self.state_id)
    }
    fn internal_forces(&self, x: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        crate::model::ordered_parallel_forces(&self.geometry, self.rest.len(), |e| {
            self.element_forces(e, x)
        })
    }
    /// One return mapping (polar decomposition and radial return) per element for its forces
    /// and its matrix, elements in parallel: the bits of `element_forces` / `element_matrix`
    /// (the default evaluated the return mapping twice, serially; a rigid-tip J2 replay spends
    /// most of its time here).
    fn linearize_elements(
        &self,
        first: usize,
        x: &[Vector3<f64>],
        kind: StiffnessKind,
        forces: &mut [[Vector3<f64>; 4]],
        matrices: &mut [Matrix12],
    ) -> Option<f64> {
        crate::model::fill_linearization(forces, matrices, |k, f, m| {
            let e = first + k;
            let (rm, r, s) = self.element_return(e, x);
            let (g, p) = (&self.geometry[e], self.params[e]);
            *f = forces_from_stress(g, &r, &rm.stress_pa);
            *m = tangent_from_stress(
                g,
                &r,
                &s,
                &rm.stress_pa,
                |de| rm.tangent_apply(&p, de),
                kind == StiffnessKind::Consistent,
            );
        });
        None
    }
}

/// F_p from the symmetric 6-vector s = (s_xx, s_yy, s_zz, s_xy, s_xz, s_yz) (saito-barbic eq. 2).
pub fn plastic_from_vector(s: &Vector6<f64>) -> Matrix3<f64> {
    Matrix3::new(s[0], s[3], s[4], s[3], s[1], s[5], s[4], s[5], s[2])
}

/// The inverse of [`plastic_from_vector`] (reads the upper triangle).
pub fn plastic_to_vector(fp: &Matrix3<f64>) -> Vector6<f64> {
    Vector6::new(
        fp[(0, 0)],
        fp[(1, 1)],
        fp[(2, 2)],
        fp[(0, 1)],
        fp[(0, 2)],
        fp[(1, 2)],
    )
}

/// Stable neo-Hookean tet model with a per-tet plastic deformation gradient F_p (module docs,
/// part (b); saito-barbic §3.2): a [`NeoHookeanModel`] whose element kernels run on the plastic
/// configuration (gradients F_p⁻ᵀ g_a, volume V det F_p), so F = F_e = F F_p⁻¹ and
/// E_e = V det F_p Ψ(F_e).
#[derive(Clone, Debug)]
pub struct PlasticNeoHookeanModel {
    elastic: NeoHookeanModel,
    plastic: Vec<Matrix3<f64>>,
}

fn plastic_geometry(e: usize, g: &TetGeometry, fp: &Matrix3<f64>) -> Result<TetGeometry, FemError> {
    let det = fp.determinant();
    let inv = fp.try_inverse();
    match inv {
        Some(inv) if det > 0.0 && det.is_finite() => {
            let it = inv.transpose();
            Ok(TetGeometry {
                nodes: g.nodes,
                grads: g.grads.map(|ga| it * ga),
                volume_m3: g.volume_m3 * det,
            })
        }
        _ => Err(FemError::InvalidPlasticGradient { tet: e, det }),
    }
}

impl PlasticNeoHookeanModel {
    /// Model over `mesh` with per-element parameters; F_p = I everywhere.
    pub fn new(mesh: &TetMesh, params: Vec<NeoHookeanParams>) -> Result<Self, FemError> {
        let elastic = NeoHookeanModel::new(mesh, params)?;
        Ok(Self {
            plastic: vec![Matrix3::identity(); elastic.elements().len()],
            elastic,
        })
    }

    /// Homogeneous model.
    pub fn homogeneous(mesh: &TetMesh, p: NeoHookeanParams) -> Result<Self, FemError> {
        Self::new(mesh, vec![p; mesh.tets.len()])
    }

    /// Per-element F_p.
    pub fn plastic_gradients(&self) -> &[Matrix3<f64>] {
        &self.plastic
    }

    /// Sets every F_p (det F_p > 0 required; the first offending tet is named).
    pub fn set_plastic_gradients(&mut self, fp: &[Matrix3<f64>]) -> Result<(), FemError> {
        let geometry = self.elastic.elements();
        if fp.len() != geometry.len() {
            return Err(FemError::LengthMismatch {
                what: "plastic deformation gradients",
                expected: geometry.len(),
                got: fp.len(),
            });
        }
        let geo = geometry
            .iter()
            .zip(fp)
            .enumerate()
            .map(|(e, (g, f))| plastic_geometry(e, g, f))
            .collect::<Result<Vec<_>, _>>()?;
        self.elastic.material_geometry_mut().clone_from_slice(&geo);
        self.plastic.copy_from_slice(fp);
        Ok(())
    }

    /// Sets F_p of one element.
    pub fn set_plastic_gradient(&mut self, e: usize, fp: Matrix3<f64>) -> Result<(), FemError> {
        let Some(g) = self.elastic.elements().get(e) else {
            return Err(FemError::LengthMismatch {
                what: "element index",
                expected: self.elastic.elements().len(),
                got: e,
            });
        };
        let pg = plastic_geometry(e, g, &fp)?;
        self.elastic.material_geometry_mut()[e] = pg;
        self.plastic[e] = fp;
        Ok(())
    }

    /// Per-element parameters.
    pub fn params(&self) -> &[NeoHookeanParams] {
        self.elastic.params()
    }

    /// Elastic deformation gradient F_e = F F_p⁻¹ of element `e`.
    pub fn elastic_gradient(&self, e: usize, x: &[Vector3<f64>]) -> Matrix3<f64> {
        self.elastic.material_geometry()[e].deformation_gradient(x)
    }

    /// ∂f_e/∂s (12×6) of element `e` at `x` with respect to the symmetric 6-vector s of its F_p
    /// (saito-barbic eq. 2), analytic (Appendix B eq. 31–34; module docs, part (b)). Column k is
    /// the force change per unit s_k; F_p's antisymmetric part is held fixed.
    pub fn plastic_force_jacobian(&self, e: usize, x: &[Vector3<f64>]) -> SMatrix<f64, 12, 6> {
        plastic_force_jacobian(
            &self.elastic.elements()[e],
            &self.elastic.params()[e],
            &self.plastic[e],
            x,
        )
    }

    /// [`Self::plastic_force_jacobian`] of every element (in parallel for large meshes; each
    /// element's value is independent of the split).
    pub fn plastic_force_jacobians(&self, x: &[Vector3<f64>]) -> Vec<SMatrix<f64, 12, 6>> {
        let mut out = vec![SMatrix::<f64, 12, 6>::zeros(); self.plastic.len()];
        crate::model::fill_elements(&mut out, |e, j| *j = self.plastic_force_jacobian(e, x));
        out
    }
}

/// ∂f/∂s of one tet with rest geometry `g`, parameters `p` and plastic gradient `fp` at `x`
/// (saito-barbic Appendix B eq. 31–34; see the module docs, part (b)).
fn plastic_force_jacobian(
    g: &TetGeometry,
    p: &NeoHookeanParams,
    fp: &Matrix3<f64>,
    x: &[Vector3<f64>],
) -> SMatrix<f64, 12, 6> {
    let mut out = SMatrix::<f64, 12, 6>::zeros();
    let (Some(fp_inv), jp) = (fp.try_inverse(), fp.determinant()) else {
        return out;
    };
    let fp_inv_t = fp_inv.transpose();
    let fe = g.deformation_gradient(x) * fp_inv;
    let pk = pk1(p, &fe);
    let dpdf = pk1_derivative(p, &fe);
    for k in 0..6 {
        let mut unit = Vector6::zeros();
        unit[k] = 1.0;
        let dir = plastic_from_vector(&unit);
        let djp = jp * (fp_inv * dir).trace();
        let dfe = -fe * dir * fp_inv;
        let dp_vec = dpdf * SVector::<f64, 9>::from_column_slice(dfe.as_slice());
        let dp = Matrix3::from_column_slice(dp_vec.as_slice());
        let dfp_inv_t = -fp_inv_t * dir * fp_inv_t;
        let q = (pk * fp_inv_t * djp + dp * fp_inv_t * jp + pk * dfp_inv_t * jp) * g.volume_m3;
        for a in 0..4 {
            let df = q * g.grads[a];
            for i in 0..3 {
                out[(3 * a + i, k)] = df[i];
            }
        }
    }
    out
}

/// The elastic part evaluated on the plastic configuration (see the type docs).
impl ElasticModel for PlasticNeoHookeanModel {
    fn rest_positions(&self) -> &[Vector3<f64>] {
        self.elastic.rest_positions()
    }
    fn elements(&self) -> &[TetGeometry] {
        self.elastic.elements()
    }
    fn element_forces(&self, e: usize, x: &[Vector3<f64>]) -> [Vector3<f64>; 4] {
        self.elastic.element_forces(e, x)
    }
    fn element_matrix(&self, e: usize, x: &[Vector3<f64>], kind: StiffnessKind) -> Matrix12 {
        self.elastic.element_matrix(e, x, kind)
    }
    fn energy(&self, x: &[Vector3<f64>]) -> Option<f64> {
        self.elastic.energy(x)
    }
    fn internal_forces(&self, x: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        self.elastic.internal_forces(x)
    }
    fn forces_and_energy(&self, x: &[Vector3<f64>]) -> (Vec<Vector3<f64>>, Option<f64>) {
        self.elastic.forces_and_energy(x)
    }
    fn linearize_elements(
        &self,
        first: usize,
        x: &[Vector3<f64>],
        kind: StiffnessKind,
        forces: &mut [[Vector3<f64>; 4]],
        matrices: &mut [Matrix12],
    ) -> Option<f64> {
        self.elastic
            .linearize_elements(first, x, kind, forces, matrices)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn radial_return_is_on_the_yield_surface_and_tangent_matches_fd() {
        let el = LinearParams::from_young_poisson(1.0e4, 0.3).unwrap();
        let pl = J2PlasticityParams {
            yield_stress_pa: 50.0,
            hardening_modulus_pa: 2.0e3,
        };
        let state = PlasticState {
            plastic_strain: Matrix3::new(
                0.001, 0.0005, 0.0, 0.0005, -0.0004, 0.0002, 0.0, 0.0002, -0.0006,
            ),
            equivalent_plastic_strain: 0.002,
        };
        let eps = Matrix3::new(
            0.02, 0.004, -0.003, 0.004, -0.006, 0.001, -0.003, 0.001, -0.002,
        );
        let rm = radial_return(&el, &pl, &eps, &state);
        assert!(rm.delta_gamma > 0.0);
        let s = rm.stress_pa - Matrix3::identity() * (rm.stress_pa.trace() / 3.0);
        let radius = (2.0f64 / 3.0).sqrt()
            * (pl.yield_stress_pa + pl.hardening_modulus_pa * rm.state.equivalent_plastic_strain);
        assert!(
            (s.norm() - radius).abs() < 1e-9 * radius,
            "{} vs {radius}",
            s.norm()
        );
        // Algorithmic tangent vs central differences of the return map (rel 1e-6).
        let de = Matrix3::new(0.3, 0.1, -0.2, 0.1, -0.5, 0.4, -0.2, 0.4, 0.2);
        let h = 1e-7;
        let fd = (radial_return(&el, &pl, &(eps + de * h), &state).stress_pa
            - radial_return(&el, &pl, &(eps - de * h), &state).stress_pa)
            / (2.0 * h);
        let an = rm.tangent_apply(&el, &de);
        assert!((fd - an).norm() < 1e-6 * an.norm(), "{fd} vs {an}");
        // Parameter derivatives vs central differences in σ_y and H.
        let (dsy, dh) = rm.parameter_derivatives(&el, &pl, &state);
        let at = |sy: f64, hh: f64| {
            let q = J2PlasticityParams {
                yield_stress_pa: sy,
                hardening_modulus_pa: hh,
            };
            radial_return(&el, &q, &eps, &state).stress_pa
        };
        let (sy, hh) = (pl.yield_stress_pa, pl.hardening_modulus_pa);
        let fd_sy = (at(sy + 1e-4, hh) - at(sy - 1e-4, hh)) / 2e-4;
        let fd_h = (at(sy, hh + 1e-2) - at(sy, hh - 1e-2)) / 2e-2;
        assert!((fd_sy - dsy).norm() < 1e-6 * dsy.norm(), "{fd_sy} vs {dsy}");
        assert!((fd_h - dh).norm() < 1e-6 * dh.norm(), "{fd_h} vs {dh}");
    }

    /// The one-pass linearization and the parallel forces are the per-element methods' bits,
    /// for yielded and elastic elements, both stiffness kinds, serial and parallel lengths.
    #[test]
    fn linearization_is_the_per_element_bits() {
        let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [0.04, 0.04, 0.02], [8, 8, 2]);
        let el = LinearParams::from_young_poisson(2.0e4, 0.45).unwrap();
        let pl = J2PlasticityParams {
            yield_stress_pa: 300.0,
            hardening_modulus_pa: 1.0e3,
        };
        let mut model = ElastoplasticModel::homogeneous(&mesh, el, pl).unwrap();
        let press = |v: &Vector3<f64>| {
            let r = ((v.x - 0.02).powi(2) + (v.y - 0.02).powi(2)).sqrt();
            let dz = -0.003 * (v.z / 0.02) * (-(r / 0.008).powi(2)).exp();
            v + Vector3::new(0.1 * dz, 0.05 * dz, dz)
        };
        let x: Vec<Vector3<f64>> = mesh.vertices.iter().map(press).collect();
        assert!(model.commit(&x) > 0, "the press must yield some elements");
        let x2: Vec<Vector3<f64>> = x.iter().map(|v| v * 1.001).collect();
        let n = model.elements().len();
        assert!(n >= crate::model::PARALLEL_MIN_ELEMENTS);
        let serial: Vec<Vector3<f64>> = {
            let mut out = vec![Vector3::zeros(); model.num_nodes()];
            for (e, g) in model.elements().iter().enumerate() {
                let f = model.element_forces(e, &x2);
                for a in 0..4 {
                    out[g.nodes[a]] += f[a];
                }
            }
            out
        };
        assert_eq!(model.internal_forces(&x2), serial);
        for kind in [StiffnessKind::Consistent, StiffnessKind::Warped] {
            for (first, len) in [(0, n), (3, 10)] {
                let mut f = vec![[Vector3::zeros(); 4]; len];
                let mut m = vec![Matrix12::zeros(); len];
                model.linearize_elements(first, &x2, kind, &mut f, &mut m);
                for k in 0..len {
                    assert_eq!(f[k], model.element_forces(first + k, &x2));
                    assert_eq!(m[k], model.element_matrix(first + k, &x2, kind));
                }
            }
        }
    }
}
