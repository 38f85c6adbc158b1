//! Dynamics: lumped mass, Rayleigh damping and implicit time integration of wang2015 eq. 3,
//!
//! M ẍ + D ẋ + f_int(x) = f_ext (+ probe contact),  D = α M + β K  (wang2015 §3, eq. 3),
//!
//! where M is the lumped (diagonal) mass of [`crate::lumped_masses`], f_int the model's internal
//! force (for the corotational model R K (Rᵀx − X)), and K the model's element matrices at the current
//! iterate ([`StiffnessKind::Warped`] R K Rᵀ by default, as in wang2015; the damping force is
//! β Σ_e K_e v_e evaluated element by element).
//!
//! Two implicit integrators, both solved by Newton iterations on x_{n+1} over the free dofs
//! (constraints eliminated; their prescribed positions at t_{n+1} are applied first):
//!
//! * **implicit (backward) Euler**: v_{n+1} = (x_{n+1} − x_n)/h, a_{n+1} = (v_{n+1} − v_n)/h;
//!   system matrix A = M/h² + D/h + K. First order, numerically damped (for a linear mode the
//!   amplification is z = 1/(1 − h s)).
//! * **Newmark, average acceleration** (β_N = 1/4, γ_N = 1/2): x_{n+1} = x_n + h v_n + h²/4
//!   (a_n + a_{n+1}), v_{n+1} = v_n + h/2 (a_n + a_{n+1}); A = 4M/h² + 2D/h + K. Second order,
//!   unconditionally stable, no numerical damping (for a linear mode it is the trapezoidal rule,
//!   z = (1 + h s/2)/(1 − h s/2)).
//!
//! Each Newton iteration solves A Δx = f_ext + f_c − f_int(x) − D v(x) − M a(x) with the
//! factorization of [`SparseCholesky`] (pattern and symbolic analysis built once per solver).
//! Probe contact enters as the penalty springs of [`crate::contact`] (re-queried each iteration).
//! Models with internal time-dependent state ([`crate::ViscoelasticModel`]) are stepped by the caller:
//! `set_time_step(h)` once, then `commit(x)` after each converged step.

use crate::FemError;
use crate::assembly::{DirichletBc, DofMap, SparseCholesky, SystemPattern, solver_setup};
use crate::contact::{ContactProblem, ContactReport};
use crate::element::StiffnessKind;
use crate::model::{ElasticModel, StepTangent, element_product};
use crate::nodal::NodalTerm;
use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

/// Time integrator.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Integrator {
    /// Backward (implicit) Euler: first order, dissipative.
    ImplicitEuler,
    /// Newmark average acceleration (β = 1/4, γ = 1/2): second order, energy conserving.
    NewmarkAverageAcceleration,
}

/// Rayleigh damping D = α M + β K (wang2015 eq. 3).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RayleighDamping {
    /// mass-proportional coefficient α [1/s]
    pub alpha_per_s: f64,
    /// stiffness-proportional coefficient β \[s\]
    pub beta_s: f64,
}

impl RayleighDamping {
    /// Modal damping ratio of a mode with angular frequency ω [rad/s]: ζ = α/(2ω) + βω/2.
    pub fn damping_ratio(&self, omega_rad_s: f64) -> f64 {
        self.alpha_per_s / (2.0 * omega_rad_s) + 0.5 * self.beta_s * omega_rad_s
    }

    /// (α, β) giving damping ratios ζ₁, ζ₂ at ω₁ ≠ ω₂ (the classical two-frequency fit).
    pub fn from_two_ratios(omega1: f64, zeta1: f64, omega2: f64, zeta2: f64) -> Self {
        // [1/(2ω₁) ω₁/2; 1/(2ω₂) ω₂/2] [α; β] = [ζ₁; ζ₂]
        let det = omega2 / (4.0 * omega1) - omega1 / (4.0 * omega2);
        let alpha = (zeta1 * omega2 / 2.0 - zeta2 * omega1 / 2.0) / det;
        let beta = (zeta2 / (2.0 * omega1) - zeta1 / (2.0 * omega2)) / det;
        Self {
            alpha_per_s: alpha,
            beta_s: beta,
        }
    }
}

/// Settings of the dynamic solver.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DynamicsSettings {
    /// Integrator.
    pub integrator: Integrator,
    /// Time step h \[s\].
    pub time_step_s: f64,
    /// Rayleigh damping.
    pub damping: RayleighDamping,
    /// Element matrix used for K (in A and in the damping force).
    pub stiffness: StiffnessKind,
    /// Newton iterations per step (1 = linearly implicit).
    pub max_iterations: usize,
    /// Converged when ‖r‖₂ ≤ `residual_tol_rel` × max(‖f_ext‖, ‖f_int‖, ‖M a‖, ‖f_c‖), or when
    /// ‖r‖₂ is below what a displacement of this × bounding-box diagonal would cause.
    pub displacement_tol_rel: f64,
    /// Relative residual tolerance (see `displacement_tol_rel`).
    pub residual_tol_rel: f64,
    /// Probe contact springs are re-queried at each Newton iteration up to this many, then frozen
    /// for the rest of the step (as in [`crate::EquilibriumSettings::contact_freeze_after`]: rim
    /// nodes cannot chatter in and out of the patch forever).
    pub contact_freeze_after: usize,
}

impl Default for DynamicsSettings {
    fn default() -> Self {
        Self {
            integrator: Integrator::NewmarkAverageAcceleration,
            time_step_s: 1e-3,
            damping: RayleighDamping::default(),
            stiffness: StiffnessKind::Warped,
            max_iterations: 20,
            displacement_tol_rel: 1e-10,
            residual_tol_rel: 1e-8,
            contact_freeze_after: 8,
        }
    }
}

/// Settings of [`DynamicSolver::step_sensitivities`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SensitivitySettings {
    /// Step ε of the directional differences, in the parameter and along the sensitivity
    /// (x + ε s): the residual is exact to round-off, so a small step loses nothing to the
    /// Newton tolerance.
    pub epsilon: f64,
    /// Converged when an update is at most this × the largest |s| component.
    pub tolerance: f64,
    /// Updates per step at most.
    pub max_iterations: usize,
}

impl Default for SensitivitySettings {
    fn default() -> Self {
        Self {
            epsilon: 1e-6,
            tolerance: 1e-5,
            max_iterations: 8,
        }
    }
}

/// Positions, velocities and accelerations of every node at time t.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DynamicState {
    /// time \[s\]
    pub time_s: f64,
    /// x \[m\]
    pub positions_m: Vec<Vector3<f64>>,
    /// ẋ [m/s]
    pub velocities_m_s: Vec<Vector3<f64>>,
    /// ẍ [m/s²]
    pub accelerations_m_s2: Vec<Vector3<f64>>,
}

impl DynamicState {
    /// State at time 0 with positions `x`, zero velocity and acceleration (call
    /// [`DynamicSolver::initialize_acceleration`] before a Newmark run that does not start in
    /// equilibrium).
    pub fn at_rest(x: Vec<Vector3<f64>>) -> Self {
        let n = x.len();
        Self {
            time_s: 0.0,
            positions_m: x,
            velocities_m_s: vec![Vector3::zeros(); n],
            accelerations_m_s2: vec![Vector3::zeros(); n],
        }
    }

    /// The integrator's predictor of x_{n+1} over a step `h`: x_n + h v_n (+ h²/4 a_n for
    /// Newmark average acceleration).
    pub fn predicted_positions(&self, h: f64, integrator: Integrator) -> Vec<Vector3<f64>> {
        let newmark = integrator == Integrator::NewmarkAverageAcceleration;
        self.positions_m
            .iter()
            .zip(&self.velocities_m_s)
            .zip(&self.accelerations_m_s2)
            .map(|((x, v), a)| {
                if newmark {
                    x + v * h + a * (0.25 * h * h)
                } else {
                    x + v * h
                }
            })
            .collect()
    }
}

/// Outcome of one time step (never a panic).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum DynamicStepStatus {
    /// Newton converged.
    Converged,
    /// Iteration limit reached (the state is advanced with the last iterate).
    MaxIterations,
    /// Factorization failed or values became non-finite (the state is not advanced).
    Failed {
        /// reason
        reason: String,
    },
}

/// Report of one time step.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DynamicStepReport {
    /// Status.
    pub status: DynamicStepStatus,
    /// Newton iterations.
    pub iterations: usize,
    /// Final residual norm \[N\].
    pub residual_norm_n: f64,
    /// Contact outcome at the end of the step.
    pub contact: ContactReport,
}

/// Implicit dynamic solver bound to a mesh, masses and a constrained-dof set.
#[derive(Debug)]
pub struct DynamicSolver {
    pattern: SystemPattern,
    cholesky: SparseCholesky,
    masses_kg: Vec<f64>,
    length_scale_m: f64,
    /// Per-chunk element forces, matrices and K_e v_e products of [`Self::linearize`] and
    /// [`Self::force_pass`] (reused across iterations).
    forces: Vec<[Vector3<f64>; 4]>,
    matrices: Vec<crate::element::Matrix12>,
    products: Vec<[Vector3<f64>; 4]>,
    /// The last element pass, for a call with the same inputs (see [`Linearization`]).
    last: Option<Linearization>,
    /// Solve the next steps' Newton updates with the factor of an earlier system matrix (see
    /// [`Self::set_reuse_factorization`]).
    reuse_factorization: bool,
    /// Adaptive reuse ([`Self::set_refactor_ratio`]): the residual ratio above which the factor
    /// is renewed, whether it is due, and the (mass, stiffness) coefficients it was built with.
    refactor_ratio: Option<f64>,
    refactor_due: bool,
    factored_coefficients: Option<[u64; 2]>,
    /// Residual-only element passes for the updates that reuse the factor
    /// ([`Self::set_residual_only`]).
    residual_only: bool,
    /// Largest |entry| of the factored matrix: the displacement test of the iterations that
    /// reuse its factor and assemble no matrix ([`finish_iteration`]).
    factored_entry_max: f64,
    /// Numeric factorizations so far, and the wall time they took \[s\].
    factorizations: usize,
    factor_s: f64,
    /// Evaluate the residual after the last Newton update (see [`DynamicSolver::set_final_residual`]).
    final_residual: bool,
    /// The residual over the free dofs at the state the last step committed, when that step
    /// evaluated it there ([`Self::committed_residual`]).
    committed_residual: Option<Vec<f64>>,
}

/// What one element pass of [`DynamicSolver::linearize`] depends on besides the solver: the
/// model's state id, x, v (as bits), the stiffness kind, the matrix factor and the damping.
#[derive(Debug, PartialEq, Eq)]
struct LinearizationKey {
    state_id: u64,
    x: Vec<[u64; 3]>,
    v: Vec<[u64; 3]>,
    kind: StiffnessKind,
    a_stiff: u64,
    damping: [u64; 2],
}

impl LinearizationKey {
    fn new(
        state_id: u64,
        x: &[Vector3<f64>],
        v: &[Vector3<f64>],
        kind: StiffnessKind,
        a_stiff: f64,
        damping: &RayleighDamping,
    ) -> Self {
        let bits = |p: &[Vector3<f64>]| -> Vec<[u64; 3]> {
            p.iter()
                .map(|a| [a.x, a.y, a.z].map(f64::to_bits))
                .collect()
        };
        Self {
            state_id,
            x: bits(x),
            v: bits(v),
            kind,
            a_stiff: a_stiff.to_bits(),
            damping: [damping.alpha_per_s.to_bits(), damping.beta_s.to_bits()],
        }
    }
}

/// The element pass of the last linearization (matrix without mass blocks, f_int, D v), kept
/// for a call with bitwise the same inputs: a step that ends with a residual check at x_{k+1}
/// and a next step that starts from x_{k+1} (the M-steps of a generalized EM, one Newton update
/// each, as the tracker of wang2015 §5 takes them) need the pass once, not twice.
#[derive(Debug)]
struct Linearization {
    key: LinearizationKey,
    values: Vec<f64>,
    fi: Vec<Vector3<f64>>,
    fd: Vec<Vector3<f64>>,
}

/// What acts on the body during one step of [`DynamicSolver::step_with`].
#[derive(Clone, Copy, Debug)]
pub struct StepLoads<'a> {
    /// External forces at t_{n+1} \[N\], one per node.
    pub external_forces_n: &'a [Vector3<f64>],
    /// Prescribed positions at t_{n+1} of moving constrained dofs.
    pub prescribed: Option<&'a DirichletBc>,
    /// Probe contact.
    pub contact: Option<&'a ContactProblem>,
    /// Initial guess of x_{n+1} (default: the integrator's predictor).
    pub initial_guess: Option<&'a [Vector3<f64>]>,
}

/// The largest |entry| of a system matrix's values.
pub(crate) fn entry_max(values: &[f64]) -> f64 {
    values.iter().fold(0.0f64, |m, v| m.max(v.abs()))
}

/// The residual test that ends a Newton iteration of an implicit dynamic step (shared by
/// [`DynamicSolver`] and the quadratic solver): the residual norm `rn` \[N\] against
/// `residual_tol_rel` × the step's force `scale`, or against the largest system-matrix entry
/// `diag_max` ([`entry_max`]) × the displacement tolerance `tol_x` \[m\], after at least one
/// update (a linear problem converges in one Newton step). When the test passes or the
/// iterations are used up it sets `status` and returns `true`: the caller then commits the
/// trial state and ends the step.
pub(crate) fn finish_iteration(
    settings: &DynamicsSettings,
    it: usize,
    rn: f64,
    scale: f64,
    diag_max: f64,
    tol_x: f64,
    status: &mut DynamicStepStatus,
) -> bool {
    let res_ok = rn <= settings.residual_tol_rel * scale || rn <= diag_max * tol_x;
    let converged = it > 0 && res_ok;
    if !converged && it < settings.max_iterations.max(1) {
        return false;
    }
    *status = if converged {
        DynamicStepStatus::Converged
    } else {
        DynamicStepStatus::MaxIterations
    };
    true
}

impl DynamicState {
    /// Commits a finished step of length `h` \[s\]: time, positions, velocities, accelerations.
    pub(crate) fn advance(
        &mut self,
        h: f64,
        x: Vec<Vector3<f64>>,
        v: Vec<Vector3<f64>>,
        a: Vec<Vector3<f64>>,
    ) {
        self.time_s += h;
        self.positions_m = x;
        self.velocities_m_s = v;
        self.accelerations_m_s2 = a;
    }
}

pub(crate) struct Kinematics {
    pub(crate) cx: f64,
    pub(crate) cv: f64,
}

impl DynamicSolver {
    /// Pattern + symbolic factorization; `masses_kg` one per node (positive where free).
    pub fn new<M: ElasticModel + ?Sized>(
        model: &M,
        masses_kg: Vec<f64>,
        constrained_dofs: &[usize],
    ) -> Result<Self, FemError> {
        let n = model.num_nodes();
        if masses_kg.len() != n {
            return Err(FemError::LengthMismatch {
                what: "nodal masses",
                expected: n,
                got: masses_kg.len(),
            });
        }
        if let Some(&m) = masses_kg.iter().find(|m| !(m.is_finite() && **m >= 0.0)) {
            return Err(FemError::InvalidSetting {
                what: "nodal mass kg",
                value: m,
            });
        }
        let (pattern, cholesky, length_scale_m) = solver_setup(model, constrained_dofs)?;
        Ok(Self {
            pattern,
            cholesky,
            masses_kg,
            length_scale_m,
            forces: Vec::new(),
            matrices: Vec::new(),
            products: Vec::new(),
            last: None,
            reuse_factorization: false,
            refactor_ratio: None,
            refactor_due: false,
            factored_coefficients: None,
            residual_only: true,
            factored_entry_max: 0.0,
            factorizations: 0,
            factor_s: 0.0,
            final_residual: true,
            committed_residual: None,
        })
    }

    /// While `reuse` is set, a step's Newton updates are solved with the numeric factor of the
    /// last factored system matrix instead of the current one (a chord step; factored anew when
    /// none exists). The step still converges to the same solution — the residual is the current
    /// one — but linearly, at a rate set by how far the matrix has moved since. For callers
    /// whose consecutive steps have nearly the same matrix, e.g. the EM iterations of a tracker at
    /// a fixed σ (wang2015 §5), where one factorization then serves several M-steps.
    pub fn set_reuse_factorization(&mut self, reuse: bool) {
        self.reuse_factorization = reuse;
    }

    /// Adaptive factorization reuse within a step (a modified Newton method with renewal):
    /// with `Some(ρ)`, a step's first update factors the system matrix at the initial guess
    /// (as Newton does) and its later updates are solved with that factor until an iteration
    /// reduces the residual norm by less than the factor ρ (‖r_{k+1}‖ > ρ ‖r_k‖: the matrix
    /// has moved too far from the factored one); then the current matrix is factored for the
    /// next update. Each step still converges to its tolerance on the current residual, so the
    /// solution is Newton's to that tolerance, with about one factorization per step instead
    /// of one per update. (A factor carried over from the previous step was tried: from noisy
    /// initial states its first chord updates diverged.) `None` (default): every update
    /// factors anew (unless [`Self::set_reuse_factorization`]).
    ///
    /// An iteration whose update will reuse the factor (no contact, no nodal terms) evaluates
    /// only the residual — element forces and K_e v_e for the damping force
    /// ([`ElasticModel::element_forces_products`]), no element matrices and no assembly; its
    /// displacement test takes the largest entry of the factored matrix. When that residual
    /// calls for a renewal, the matrix at the iterate is assembled then
    /// ([`Self::set_residual_only`]).
    pub fn set_refactor_ratio(&mut self, ratio: Option<f64>) {
        self.refactor_ratio = ratio.filter(|r| r.is_finite() && *r > 0.0);
    }

    /// Whether, under [`Self::set_refactor_ratio`], an iteration whose update reuses the factor
    /// evaluates only the residual (on by default). Off: every iteration assembles the system
    /// matrix as well, which such an update does not use — the same iterates to round-off
    /// (up to the displacement test, which then takes the current matrix's largest entry),
    /// for measuring what the residual-only passes save.
    pub fn set_residual_only(&mut self, on: bool) {
        self.residual_only = on;
    }

    /// With `evaluate` off, a step that has used up its Newton iterations ends at its last update
    /// without the element pass that would measure the residual there: the report then holds
    /// the residual before that update and the status [`DynamicStepStatus::MaxIterations`]. For
    /// callers that take a fixed number of updates and do not read the residual, e.g. the
    /// one-update M-steps of a tracker (wang2015 §5), whose next M-step starts elsewhere. On by
    /// default.
    pub fn set_final_residual(&mut self, evaluate: bool) {
        self.final_residual = evaluate;
    }

    /// Solver for the constraint set of `bc`.
    pub fn with_bc<M: ElasticModel + ?Sized>(
        model: &M,
        masses_kg: Vec<f64>,
        bc: &DirichletBc,
    ) -> Result<Self, FemError> {
        Self::new(model, masses_kg, &bc.dofs())
    }

    /// The dof map.
    pub fn dofs(&self) -> &DofMap {
        self.pattern.dofs()
    }

    /// Nodal masses \[kg\].
    pub fn masses_kg(&self) -> &[f64] {
        &self.masses_kg
    }

    /// Damping force D v = α M v + β Σ_e K_e v_e at positions `x`.
    pub fn damping_forces<M: ElasticModel + ?Sized>(
        &self,
        model: &M,
        x: &[Vector3<f64>],
        v: &[Vector3<f64>],
        damping: &RayleighDamping,
        kind: StiffnessKind,
    ) -> Vec<Vector3<f64>> {
        let mut out = self.mass_damping_forces(v, damping);
        if damping.beta_s != 0.0 {
            for (e, g) in model.elements().iter().enumerate() {
                let kv = element_product(&model.element_matrix(e, x, kind), &g.nodes, v);
                for a in 0..4 {
                    out[g.nodes[a]] += kv[a] * damping.beta_s;
                }
            }
        }
        out
    }

    /// The mass-proportional part α M v of the damping force (lumped M).
    fn mass_damping_forces(
        &self,
        v: &[Vector3<f64>],
        damping: &RayleighDamping,
    ) -> Vec<Vector3<f64>> {
        v.iter()
            .zip(&self.masses_kg)
            .map(|(vi, m)| vi * (damping.alpha_per_s * m))
            .collect()
    }

    /// Sets a₀ = M⁻¹ (f_ext − f_int(x₀) − D v₀) on the free dofs (zero on constrained dofs and on
    /// massless nodes): the consistent start of a Newmark run.
    pub fn initialize_acceleration<M: ElasticModel + ?Sized>(
        &self,
        model: &M,
        state: &mut DynamicState,
        external_forces_n: &[Vector3<f64>],
        settings: &DynamicsSettings,
    ) {
        let fi = model.internal_forces(&state.positions_m);
        let fd = self.damping_forces(
            model,
            &state.positions_m,
            &state.velocities_m_s,
            &settings.damping,
            settings.stiffness,
        );
        for (i, a) in state.accelerations_m_s2.iter_mut().enumerate() {
            let m = self.masses_kg[i];
            *a = Vector3::zeros();
            if m > 0.0 {
                for c in 0..3 {
                    if self.dofs().free_index(3 * i + c).is_some() {
                        a[c] = (external_forces_n[i][c] - fi[i][c] - fd[i][c]) / m;
                    }
                }
            }
        }
    }

    /// The step residual R = f_ext − f_int(x) − D v − M a over the free dofs for a trial
    /// x_{n+1} = `x` of a step from `before` with `settings` (v, a from the integrator; one
    /// residual-only element pass): the base that [`Self::step_sensitivities`] differences against.
    pub fn step_residual<M: ElasticModel + ?Sized>(
        &mut self,
        model: &M,
        before: &DynamicState,
        x: &[Vector3<f64>],
        external_forces_n: &[Vector3<f64>],
        settings: &DynamicsSettings,
    ) -> Vec<f64> {
        let (v, a) = Self::velocity_acceleration(settings, before, x);
        let (fi, fd) = self.force_pass(model, x, &v, settings);
        let r: Vec<Vector3<f64>> = (0..x.len())
            .map(|i| external_forces_n[i] - fi[i] - fd[i] - a[i] * self.masses_kg[i])
            .collect();
        self.dofs().gather(&r)
    }

    /// The step residual R = f_ext − f_int(x) − D v − M a over the free dofs at the state the
    /// last step committed, bitwise [`Self::step_residual`] there, when that step evaluated it
    /// there with the same residual-only pass: its Newton iterations ended on the residual test
    /// (converged, or at their limit with [`Self::set_final_residual`] on) after an update that
    /// reused the factor ([`Self::set_refactor_ratio`]), without contact or nodal terms. `None`
    /// otherwise (a pass that also assembled the matrix differs from it by round-off, which the
    /// directional differences of [`Self::step_sensitivities`] divide by ε). The base of
    /// [`Self::step_sensitivities`] without another element pass.
    pub fn committed_residual(&self) -> Option<&[f64]> {
        self.committed_residual.as_deref()
    }

    /// Forward sensitivities of parameters p_k through the step just taken by `model` from
    /// `before` to x_{n+1} = `x` (wang2015 eq. 3 differentiated along the implicit step): with
    /// R(x_{n+1}; x_n, v_n, a_n, p) = 0 at every step, s_{n+1} = dx_{n+1}/dp_k solves
    ///
    /// −∂R/∂x_{n+1} s_{n+1} = ∂R/∂p_k + ∂R/∂(x_n, v_n, a_n) · (s_n, ṡ_n, s̈_n),
    ///
    /// and (ṡ, s̈)_{n+1} follow from the integrator's kinematics, which are linear. Each s is
    /// iterated as s ← s + A⁻¹ Φ_k(s) with the factor of the step's system matrix A (the Newton
    /// updates' last factor), from `initial[k]` when given (e.g. the sensitivity of the same step at nearby parameters) or else the
    /// integrator's predictor of its `sensitivities` entry, until an update
    /// is at most `options.tolerance` × max |s|, where the linearized residual is
    /// Φ_k(s) = ∂R/∂p_k + ∂R/∂(state_n) · sens_n + ∂R/∂x_{n+1} s. Its first value is a
    /// directional difference of the residual,
    /// Φ_k(s) = (R(x + ε s; state_n + ε sens_n, p + ε e_k) − R(x; state_n, p)) / ε, with the
    /// `perturbed` model and settings of p + ε e_k against the `base_residual`
    /// ([`Self::step_residual`] of `model` and `settings`, or [`Self::committed_residual`]).
    /// After an update Δs it moves by the exact tangent's product ∂R/∂x_{n+1} Δs
    /// ([`ElasticModel::step_tangent`], the element state at x_{n+1} kept from one pass: no
    /// polar decomposition per round; a model without it differences the residual again at
    /// every round). The parameters iterate in lockstep: each round is one tangent product (or
    /// element pass) per parameter still iterating and one back-substitution of all their
    /// updates as a block of right-hand sides (one sweep through the factor); no factorization.
    /// The result is the derivative of the exact step, not of its Newton iterate, so it does not
    /// need a tight Newton tolerance. Each `sensitivities` entry (s, ṡ, s̈ at t_n, zero on the
    /// constrained dofs, whose prescribed motion does not depend on p) is advanced to t_{n+1}.
    /// Returns the iterations summed over the parameters; errors when no factor exists or a
    /// result is not finite. Models with internal state ([`ElasticModel::update_state`]) are not
    /// supported.
    #[allow(clippy::too_many_arguments)]
    pub fn step_sensitivities<M: ElasticModel + ?Sized>(
        &mut self,
        model: &M,
        before: &DynamicState,
        x: &[Vector3<f64>],
        base_residual: &[f64],
        external_forces_n: &[Vector3<f64>],
        settings: &DynamicsSettings,
        perturbed: &[(&M, &DynamicsSettings)],
        sensitivities: &mut [DynamicState],
        initial: Option<&[Vec<Vector3<f64>>]>,
        options: &SensitivitySettings,
    ) -> Result<usize, FemError> {
        if self.cholesky.kind().is_none() {
            return Err(FemError::Factorization {
                reason: "no factored system matrix for the sensitivity step".into(),
            });
        }
        if perturbed.len() != sensitivities.len() {
            return Err(FemError::LengthMismatch {
                what: "sensitivities",
                expected: perturbed.len(),
                got: sensitivities.len(),
            });
        }
        let eps = options.epsilon;
        let h = settings.time_step_s;
        let shifted = |a: &[Vector3<f64>], d: &[Vector3<f64>]| -> Vec<Vector3<f64>> {
            a.iter().zip(d).map(|(a, d)| a + d * eps).collect()
        };
        let mut s: Vec<Vec<Vector3<f64>>> = sensitivities
            .iter()
            .enumerate()
            .map(|(k, sens)| {
                let mut s = match initial.and_then(|i| i.get(k)) {
                    Some(s0) if s0.len() == sens.positions_m.len() => s0.clone(),
                    _ => sens.predicted_positions(h, settings.integrator),
                };
                for d in 0..3 * s.len() {
                    if self.dofs().free_index(d).is_none() {
                        s[d / 3][d % 3] = 0.0;
                    }
                }
                s
            })
            .collect();
        let nf = base_residual.len();
        let mut iterations = 0;
        let mut active: Vec<usize> = (0..perturbed.len()).collect();
        // Φ_k at the current s_k, and the last update of s_k.
        let mut phis: Vec<Vec<f64>> = vec![Vec::new(); perturbed.len()];
        let mut updates: Vec<Vec<f64>> = vec![Vec::new(); perturbed.len()];
        // Bodies with `model`'s elastic state differ in α, β only: R is linear in them, so their
        // first right side is the tangent's too (no element pass).
        let damping_only: Vec<bool> = perturbed
            .iter()
            .map(|(body, _)| body.state_id().is_some() && body.state_id() == model.state_id())
            .collect();
        let v_next = Self::velocity_acceleration(settings, before, x).0;
        // The tangent at x_{n+1}, built when it is first needed.
        let mut tangent: Option<Option<StepTangent>> = None;
        let mut block = Vec::new();
        for round in 0..options.max_iterations.max(1) {
            if active.is_empty() {
                break;
            }
            if tangent.is_none() && (round > 0 || damping_only.contains(&true)) {
                tangent = Some(model.step_tangent(
                    x,
                    &v_next,
                    settings.stiffness,
                    settings.damping.beta_s,
                    Self::kinematics(settings).cv,
                ));
            }
            let t = tangent.as_ref().and_then(Option::as_ref);
            if let (Some(t), true) = (t, round > 0) {
                let du: Vec<&[f64]> = active.iter().map(|&k| &updates[k][..]).collect();
                let products = self.residual_differentials(model, t, settings, &du);
                for (&k, p) in active.iter().zip(products) {
                    for (f, d) in phis[k].iter_mut().zip(p) {
                        *f += d;
                    }
                }
            } else {
                let (linear, differenced): (Vec<usize>, Vec<usize>) = active
                    .iter()
                    .partition(|&&k| t.is_some() && damping_only[k]);
                if let Some(t) = t.filter(|_| !linear.is_empty()) {
                    let items: Vec<_> = linear
                        .iter()
                        .map(|&k| (&s[k][..], &sensitivities[k], perturbed[k].1))
                        .collect();
                    let sides = self.damping_right_sides(model, t, settings, &v_next, &items, eps);
                    for (&k, side) in linear.iter().zip(sides) {
                        phis[k] = side;
                    }
                }
                for &k in &differenced {
                    let (body, p_settings) = perturbed[k];
                    let sens = &sensitivities[k];
                    let moved = DynamicState {
                        time_s: before.time_s,
                        positions_m: shifted(&before.positions_m, &sens.positions_m),
                        velocities_m_s: shifted(&before.velocities_m_s, &sens.velocities_m_s),
                        accelerations_m_s2: shifted(
                            &before.accelerations_m_s2,
                            &sens.accelerations_m_s2,
                        ),
                    };
                    let xp = shifted(x, &s[k]);
                    let phi = self.step_residual(body, &moved, &xp, external_forces_n, p_settings);
                    phis[k] = phi
                        .iter()
                        .zip(base_residual)
                        .map(|(f, b)| (f - b) / eps)
                        .collect();
                }
            }
            block.clear();
            for &k in &active {
                block.extend_from_slice(&phis[k]);
            }
            self.cholesky.solve_in_place(&mut block)?;
            let mut still = Vec::with_capacity(active.len());
            for (j, &k) in active.iter().enumerate() {
                let du = &block[j * nf..(j + 1) * nf];
                self.dofs().scatter_add(du, 1.0, &mut s[k]);
                iterations += 1;
                let update = du.iter().fold(0.0f64, |m, v| m.max(v.abs()));
                let size = s[k].iter().fold(0.0f64, |m, v| m.max(v.amax()));
                if !(update.is_finite() && size.is_finite()) {
                    return Err(FemError::Factorization {
                        reason: "non-finite sensitivity".into(),
                    });
                }
                if update > options.tolerance * size {
                    updates[k].clear();
                    updates[k].extend_from_slice(du);
                    still.push(k);
                }
            }
            active = still;
        }
        for (sens, s) in sensitivities.iter_mut().zip(s) {
            let (v, a) = Self::velocity_acceleration(settings, sens, &s);
            sens.advance(h, s, v, a);
        }
        Ok(iterations)
    }

    /// The first right sides Φ_k(s⁰) of parameters that change only the damping (α + Δα,
    /// β + Δβ in each item's settings; `items`: s⁰ as a nodal field, the sensitivity state at
    /// t_n and the settings), from `tangent` at x_{n+1} with velocities `v` instead of an
    /// element pass. R is linear in α and β and in the kinematics, so with (ṽ, ã) the
    /// integrator's velocity and acceleration of the sensitivity state at s⁰:
    /// Φ = −(∂(f_int + β K v)/∂x s⁰ [v moving by c_v s⁰] + K (β (ṽ − c_v s⁰) + Δβ/ε v)
    /// + M (ã + α ṽ + Δα/ε v)), over the free dofs.
    fn damping_right_sides<M: ElasticModel + ?Sized>(
        &self,
        model: &M,
        tangent: &StepTangent,
        settings: &DynamicsSettings,
        v: &[Vector3<f64>],
        items: &[(&[Vector3<f64>], &DynamicState, &DynamicsSettings)],
        eps: f64,
    ) -> Vec<Vec<f64>> {
        let cv = Self::kinematics(settings).cv;
        let (alpha, beta) = (settings.damping.alpha_per_s, settings.damping.beta_s);
        let mut warped = Vec::with_capacity(items.len());
        let mut inertial = Vec::with_capacity(items.len());
        for (s0, sens, p_settings) in items {
            let (vt, at) = Self::velocity_acceleration(settings, sens, s0);
            let d_alpha = (p_settings.damping.alpha_per_s - alpha) / eps;
            let d_beta = (p_settings.damping.beta_s - beta) / eps;
            let w: Vec<Vector3<f64>> = (0..v.len())
                .map(|i| (vt[i] - s0[i] * cv) * beta + v[i] * d_beta)
                .collect();
            let m: Vec<Vector3<f64>> = (0..v.len())
                .map(|i| (at[i] + vt[i] * alpha + v[i] * d_alpha) * self.masses_kg[i])
                .collect();
            warped.push(w);
            inertial.push(m);
        }
        let s0: Vec<&[Vector3<f64>]> = items.iter().map(|item| item.0).collect();
        let w: Vec<&[Vector3<f64>]> = warped.iter().map(|w| &w[..]).collect();
        let mut products = vec![Vec::new(); items.len()];
        let mut kw = vec![Vec::new(); items.len()];
        tangent.apply(model.elements(), &s0, &mut products);
        tangent.warped_products(model.elements(), &w, &mut kw);
        products
            .iter()
            .zip(&kw)
            .zip(&inertial)
            .map(|((p, k), m)| {
                let total: Vec<Vector3<f64>> = (0..p.len()).map(|i| p[i] + k[i] + m[i]).collect();
                self.dofs().gather(&total).into_iter().map(|r| -r).collect()
            })
            .collect()
    }

    /// The products ∂R/∂x_{n+1} du of the step residual R = f_ext − f_int(x) − D v − M a with
    /// each free-dof direction of `directions`, over the free dofs: the element part from
    /// `tangent` ([`StepTangent::apply`]: f_int and β K v with v = v(x)), the lumped-mass part
    /// (c_x + α c_v) M du of the integrator's ∂a/∂x = c_x and ∂v/∂x = c_v.
    fn residual_differentials<M: ElasticModel + ?Sized>(
        &self,
        model: &M,
        tangent: &StepTangent,
        settings: &DynamicsSettings,
        directions: &[&[f64]],
    ) -> Vec<Vec<f64>> {
        let n = model.num_nodes();
        let fields: Vec<Vec<Vector3<f64>>> = directions
            .iter()
            .map(|du| {
                let mut field = vec![Vector3::zeros(); n];
                self.dofs().scatter_add(du, 1.0, &mut field);
                field
            })
            .collect();
        let views: Vec<&[Vector3<f64>]> = fields.iter().map(|f| &f[..]).collect();
        let mut out = vec![Vec::new(); fields.len()];
        tangent.apply(model.elements(), &views, &mut out);
        let kin = Self::kinematics(settings);
        let c_mass = kin.cx + settings.damping.alpha_per_s * kin.cv;
        out.iter_mut()
            .zip(&fields)
            .map(|(o, field)| {
                for ((oi, fi), m) in o.iter_mut().zip(field).zip(&self.masses_kg) {
                    *oi += fi * (c_mass * m);
                }
                self.dofs().gather(o).into_iter().map(|v| -v).collect()
            })
            .collect()
    }

    pub(crate) fn kinematics(settings: &DynamicsSettings) -> Kinematics {
        let h = settings.time_step_s;
        match settings.integrator {
            Integrator::ImplicitEuler => Kinematics {
                cx: 1.0 / (h * h),
                cv: 1.0 / h,
            },
            Integrator::NewmarkAverageAcceleration => Kinematics {
                cx: 4.0 / (h * h),
                cv: 2.0 / h,
            },
        }
    }

    /// (v_{n+1}, a_{n+1}) of the integrator for a trial x_{n+1}.
    pub(crate) fn velocity_acceleration(
        settings: &DynamicsSettings,
        state: &DynamicState,
        x: &[Vector3<f64>],
    ) -> (Vec<Vector3<f64>>, Vec<Vector3<f64>>) {
        let h = settings.time_step_s;
        let n = x.len();
        let mut v = Vec::with_capacity(n);
        let mut a = Vec::with_capacity(n);
        for i in 0..n {
            let dx = x[i] - state.positions_m[i];
            match settings.integrator {
                Integrator::ImplicitEuler => {
                    let vi = dx / h;
                    a.push((vi - state.velocities_m_s[i]) / h);
                    v.push(vi);
                }
                Integrator::NewmarkAverageAcceleration => {
                    let ai = (dx - state.velocities_m_s[i] * h) * (4.0 / (h * h))
                        - state.accelerations_m_s2[i];
                    v.push(
                        state.velocities_m_s[i] + (state.accelerations_m_s2[i] + ai) * (0.5 * h),
                    );
                    a.push(ai);
                }
            }
        }
        (v, a)
    }

    /// Advances `state` by one step h under `external_forces_n` (at t_{n+1}), optional prescribed
    /// positions at t_{n+1} (must cover the solver's constrained dofs if they move; otherwise the
    /// constrained components keep their current values) and optional probe contact.
    pub fn step<M: ElasticModel + ?Sized>(
        &mut self,
        model: &mut M,
        state: &mut DynamicState,
        external_forces_n: &[Vector3<f64>],
        prescribed: Option<&DirichletBc>,
        contact: Option<&ContactProblem>,
        settings: &DynamicsSettings,
    ) -> DynamicStepReport {
        self.step_with(
            model,
            state,
            &StepLoads {
                external_forces_n,
                prescribed,
                contact,
                initial_guess: None,
            },
            &mut [],
            settings,
        )
    }

    /// [`Self::step`] with node-level terms (forces f_b(x) on nodes and their stiffness blocks
    /// −∂f_b/∂x in A, e.g. the virtual forces of a tracker, wang2015 eq. 5) and an optional
    /// initial guess for x_{n+1} (default: the integrator's predictor). The terms are refreshed
    /// at every Newton iteration (`requery` while below `contact_freeze_after`); their history is
    /// the caller's to commit.
    pub fn step_with<M: ElasticModel + ?Sized>(
        &mut self,
        model: &mut M,
        state: &mut DynamicState,
        loads: &StepLoads<'_>,
        terms: &mut [&mut dyn NodalTerm],
        settings: &DynamicsSettings,
    ) -> DynamicStepReport {
        let StepLoads {
            external_forces_n,
            prescribed,
            contact,
            initial_guess,
        } = *loads;
        let mut report = DynamicStepReport {
            status: DynamicStepStatus::MaxIterations,
            iterations: 0,
            residual_norm_n: f64::NAN,
            contact: ContactReport::default(),
        };
        self.committed_residual = None;
        let n = model.num_nodes();
        let h = settings.time_step_s;
        if state.positions_m.len() != n
            || external_forces_n.len() != n
            || initial_guess.is_some_and(|x| x.len() != n)
            || !(h > 0.0 && h.is_finite())
        {
            report.status = DynamicStepStatus::Failed {
                reason:
                    "length mismatch of state / forces / initial guess, or time step not positive"
                        .into(),
            };
            return report;
        }
        let (a_mass, a_stiff) = Self::system_coefficients(settings);
        // Predictor, or the caller's guess.
        let mut x: Vec<Vector3<f64>> = match initial_guess {
            Some(g) => g.to_vec(),
            None => state.predicted_positions(h, settings.integrator),
        };
        // Constrained dofs: keep the current value unless prescribed.
        for d in 0..3 * n {
            if self.dofs().free_index(d).is_none() {
                x[d / 3][d % 3] = state.positions_m[d / 3][d % 3];
            }
        }
        if let Some(bc) = prescribed {
            bc.apply(&mut x);
        }
        let tol_x = settings.displacement_tol_rel * self.length_scale_m;
        let norm = |v: &[Vector3<f64>]| v.iter().map(|a| a.norm_squared()).sum::<f64>().sqrt();
        let mut frozen: Option<Vec<crate::contact::ContactSpring>> = None;
        let coefficients = [a_mass.to_bits(), a_stiff.to_bits()];
        let mut previous_rn: Option<f64> = None;
        // Factorization reuse: the step's first update factors (Newton's first iteration).
        self.refactor_due = true;
        for it in 0..settings.max_iterations.max(1) + 1 {
            if it == settings.max_iterations.max(1) && !self.final_residual {
                // the iterations are used up and the caller does not want the residual there
                let (v, a) = Self::velocity_acceleration(settings, state, &x);
                state.advance(h, x, v, a);
                return report;
            }
            model.update_state(&x);
            let (v, a) = Self::velocity_acceleration(settings, state, &x);
            // An update that will reuse the factor needs the residual only.
            let residual_only = self.residual_only
                && self.refactor_ratio.is_some()
                && contact.is_none()
                && terms.is_empty()
                && self.reuses_factor(coefficients);
            let (mut values, fi, fd) = if residual_only {
                let (fi, fd) = self.force_pass(&*model, &x, &v, settings);
                (None, fi, fd)
            } else {
                let (values, fi, fd) = self.system(&*model, &x, &v, settings);
                (Some(values), fi, fd)
            };
            let mut r: Vec<Vector3<f64>> = (0..n)
                .map(|i| external_forces_n[i] - fi[i] - fd[i] - a[i] * self.masses_kg[i])
                .collect();
            let mut fc_norm = 0.0;
            if let (Some(c), Some(values)) = (contact, values.as_mut()) {
                let springs = match &frozen {
                    Some(f) => f.clone(),
                    None => {
                        let pat = &self.pattern;
                        c.springs(&x, |node| pat.node_stiffness(node, values))
                    }
                };
                if it + 1 >= settings.contact_freeze_after {
                    frozen = Some(springs.clone());
                }
                let mut fcs = Vec::with_capacity(springs.len());
                for s in &springs {
                    self.pattern.add_node_block(s.node, &s.matrix(), values);
                    let f = s.force(&x[s.node]);
                    r[s.node] += f;
                    fcs.push(f);
                }
                fc_norm = norm(&fcs);
                report.contact = c.report(&springs, &x);
            }
            if let Some(values) = values.as_mut().filter(|_| !terms.is_empty()) {
                let requery = it < settings.contact_freeze_after;
                {
                    let pat = &self.pattern;
                    let node_k = |node: usize| pat.node_stiffness(node, values);
                    for t in terms.iter_mut() {
                        t.refresh(&x, &node_k, requery);
                    }
                }
                let mut fb = vec![Vector3::zeros(); n];
                for t in terms.iter() {
                    t.add_forces(&x, &mut fb);
                    for (node, m) in t.blocks(&x) {
                        self.pattern.add_node_block(node, &m, values);
                    }
                    for (p, q, m) in t.pair_blocks(&x) {
                        self.pattern.add_pair_block(p, q, &m, values);
                    }
                }
                for (ri, fi) in r.iter_mut().zip(&fb) {
                    *ri += fi;
                }
                fc_norm = fc_norm.max(norm(&fb));
            }
            let rf = self.dofs().gather(&r);
            let rn = rf.iter().map(|v| v * v).sum::<f64>().sqrt();
            report.residual_norm_n = rn;
            let slow = matches!((self.refactor_ratio, previous_rn),
                (Some(ratio), Some(prev)) if rn > ratio * prev);
            previous_rn = Some(rn);
            if !rn.is_finite() {
                report.status = DynamicStepStatus::Failed {
                    reason: "non-finite residual".into(),
                };
                return report;
            }
            let inertia: Vec<Vector3<f64>> = a
                .iter()
                .zip(&self.masses_kg)
                .map(|(ai, m)| ai * *m)
                .collect();
            let scale = norm(external_forces_n)
                .max(norm(&fi))
                .max(norm(&inertia))
                .max(fc_norm);
            let diag_max = values.as_deref().map_or(self.factored_entry_max, entry_max);
            if finish_iteration(settings, it, rn, scale, diag_max, tol_x, &mut report.status) {
                // Kept when it came from a residual-only pass: bitwise Self::step_residual's.
                let plain = values.is_none() && contact.is_none() && terms.is_empty();
                self.committed_residual = plain.then_some(rf);
                state.advance(h, x, v, a);
                return report;
            }
            // A slow reduction by the reused factor (not the last, converged iteration's, which
            // may sit at the rounding floor) renews it for this update: with the matrix at x.
            self.refactor_due |= slow;
            if values.is_none() && !self.reuses_factor(coefficients) {
                values = Some(self.system(&*model, &x, &v, settings).0);
            }
            let dx = match self.solve_update(values.as_deref(), rf, coefficients) {
                Ok(dx) => dx,
                Err(e) => {
                    report.status = DynamicStepStatus::Failed {
                        reason: e.to_string(),
                    };
                    return report;
                }
            };
            let last_dx = dx.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            if !last_dx.is_finite() {
                report.status = DynamicStepStatus::Failed {
                    reason: "non-finite update".into(),
                };
                return report;
            }
            self.dofs().scatter_add(&dx, 1.0, &mut x);
            report.iterations = it + 1;
        }
        report
    }

    /// Whether the next Newton update is solved with the existing factor: while
    /// [`Self::set_reuse_factorization`] is on, or under [`Self::set_refactor_ratio`] until a
    /// renewal is due or the system's (mass, stiffness) coefficients changed.
    fn reuses_factor(&self, coefficients: [u64; 2]) -> bool {
        self.cholesky.kind().is_some()
            && if self.refactor_ratio.is_some() {
                !self.refactor_due && self.factored_coefficients == Some(coefficients)
            } else {
                self.reuse_factorization
            }
    }

    /// The Newton update A⁻¹ r: with the existing factor when [`Self::reuses_factor`] (a chord
    /// step), else with a fresh factorization of A (`values`, which must then be given).
    fn solve_update(
        &mut self,
        values: Option<&[f64]>,
        rf: Vec<f64>,
        coefficients: [u64; 2],
    ) -> Result<Vec<f64>, FemError> {
        if !self.reuses_factor(coefficients) {
            let Some(values) = values else {
                return Err(FemError::Factorization {
                    reason: "no system matrix assembled for a renewed factorization".into(),
                });
            };
            let t0 = std::time::Instant::now();
            let factored = self.cholesky.factor(&self.pattern, values);
            self.factor_s += t0.elapsed().as_secs_f64();
            self.factored_coefficients = factored.is_ok().then_some(coefficients);
            self.factored_entry_max = entry_max(values);
            self.refactor_due = false;
            factored?;
            self.factorizations += 1;
        }
        let mut dx = rf;
        self.cholesky.solve_in_place(&mut dx)?;
        Ok(dx)
    }

    /// Numeric factorizations of the system matrix so far (one per Newton update, except those
    /// of [`Self::set_reuse_factorization`]).
    pub fn factorizations(&self) -> usize {
        self.factorizations
    }

    /// Wall time of those factorizations so far \[s\] (on the calling thread: the numeric
    /// factorization runs sequentially), for splitting a simulation's cost.
    pub fn factor_seconds(&self) -> f64 {
        self.factor_s
    }

    /// One pass over the elements at `x` (chunks evaluated by
    /// [`ElasticModel::linearize_elements`], possibly in parallel, scattered serially in element
    /// order): the system matrix Σ_e `a_stiff` K_e (mass blocks not yet added), f_int(x), and the
    /// damping force D v = α M v + β Σ_e K_e v_e. The same bits as the element-by-element loop
    /// over [`ElasticModel::element_matrix`] and [`ElasticModel::internal_forces`]. A call with
    /// the same inputs as the previous one (and a model with a state id) reuses its pass.
    fn linearize<M: ElasticModel + ?Sized>(
        &mut self,
        model: &M,
        x: &[Vector3<f64>],
        v: &[Vector3<f64>],
        kind: StiffnessKind,
        a_stiff: f64,
        damping: &RayleighDamping,
    ) -> (Vec<f64>, Vec<Vector3<f64>>, Vec<Vector3<f64>>) {
        let key = model
            .state_id()
            .map(|id| LinearizationKey::new(id, x, v, kind, a_stiff, damping));
        if let (Some(key), Some(last)) = (&key, &self.last)
            && *key == last.key
        {
            return (last.values.clone(), last.fi.clone(), last.fd.clone());
        }
        let (values, fi, fd) = self.element_pass(model, x, v, kind, a_stiff, damping);
        self.last = key.map(|key| Linearization {
            key,
            values: values.clone(),
            fi: fi.clone(),
            fd: fd.clone(),
        });
        (values, fi, fd)
    }

    /// The coefficients (a_mass, a_stiff) of a step's system matrix A = a_mass M + a_stiff K:
    /// c_x + α c_v and 1 + β c_v of the integrator's [`Self::kinematics`] and the Rayleigh
    /// damping.
    fn system_coefficients(settings: &DynamicsSettings) -> (f64, f64) {
        let kin = Self::kinematics(settings);
        let damping = &settings.damping;
        let a_mass = kin.cx + damping.alpha_per_s * kin.cv;
        let a_stiff = 1.0 + damping.beta_s * kin.cv;
        (a_mass, a_stiff)
    }

    /// The system matrix A = a_mass M + a_stiff Σ_e K_e of a step with `settings` at `x`
    /// ([`Self::system_coefficients`]; [`Self::linearize`] plus the mass blocks), f_int(x) and
    /// D v.
    fn system<M: ElasticModel + ?Sized>(
        &mut self,
        model: &M,
        x: &[Vector3<f64>],
        v: &[Vector3<f64>],
        settings: &DynamicsSettings,
    ) -> (Vec<f64>, Vec<Vector3<f64>>, Vec<Vector3<f64>>) {
        let (a_mass, a_stiff) = Self::system_coefficients(settings);
        let (mut values, fi, fd) =
            self.linearize(model, x, v, settings.stiffness, a_stiff, &settings.damping);
        for (i, &m) in self.masses_kg.iter().enumerate() {
            self.pattern
                .add_node_block(i, &(Matrix3::identity() * (a_mass * m)), &mut values);
        }
        (values, fi, fd)
    }

    /// The residual's element pass of a step with `settings` without the system matrix: f_int(x)
    /// and the damping force D v = α M v + β Σ_e K_e v_e
    /// ([`ElasticModel::element_forces_products`]; chunks possibly in parallel, accumulated
    /// serially in element order). The forces of [`Self::linearize`] to round-off, for an update
    /// that reuses the factor of an earlier matrix.
    fn force_pass<M: ElasticModel + ?Sized>(
        &mut self,
        model: &M,
        x: &[Vector3<f64>],
        v: &[Vector3<f64>],
        settings: &DynamicsSettings,
    ) -> (Vec<Vector3<f64>>, Vec<Vector3<f64>>) {
        let kind = settings.stiffness;
        let n_el = model.elements().len();
        let mut fi = vec![Vector3::zeros(); model.num_nodes()];
        let mut fd = self.mass_damping_forces(v, &settings.damping);
        let beta = settings.damping.beta_s;
        let chunk = crate::model::ELEMENT_CHUNK.min(n_el.max(1));
        self.forces.resize(chunk, [Vector3::zeros(); 4]);
        self.products.resize(chunk, [Vector3::zeros(); 4]);
        for start in (0..n_el).step_by(chunk) {
            let len = chunk.min(n_el - start);
            let forces = &mut self.forces[..len];
            let products = &mut self.products[..len];
            let velocities = (beta != 0.0).then_some(v);
            model.element_forces_products(start, x, velocities, kind, forces, products);
            for (k, g) in model.elements()[start..start + len].iter().enumerate() {
                for q in 0..4 {
                    fi[g.nodes[q]] += forces[k][q];
                }
                if beta != 0.0 {
                    for q in 0..4 {
                        fd[g.nodes[q]] += products[k][q] * beta;
                    }
                }
            }
        }
        (fi, fd)
    }

    /// The element pass of [`Self::linearize`].
    fn element_pass<M: ElasticModel + ?Sized>(
        &mut self,
        model: &M,
        x: &[Vector3<f64>],
        v: &[Vector3<f64>],
        kind: StiffnessKind,
        a_stiff: f64,
        damping: &RayleighDamping,
    ) -> (Vec<f64>, Vec<Vector3<f64>>, Vec<Vector3<f64>>) {
        let n_el = model.elements().len();
        let mut values = self.pattern.zeros();
        let mut fi = vec![Vector3::zeros(); model.num_nodes()];
        let mut fd = self.mass_damping_forces(v, damping);
        let chunk = crate::model::ELEMENT_CHUNK.min(n_el.max(1));
        self.forces.resize(chunk, [Vector3::zeros(); 4]);
        self.matrices
            .resize(chunk, crate::element::Matrix12::zeros());
        for start in (0..n_el).step_by(chunk) {
            let len = chunk.min(n_el - start);
            let forces = &mut self.forces[..len];
            let matrices = &mut self.matrices[..len];
            model.linearize_elements(start, x, kind, forces, matrices);
            for (k, g) in model.elements()[start..start + len].iter().enumerate() {
                let ke = &matrices[k];
                self.pattern
                    .add_element_scaled(start + k, ke, a_stiff, &mut values);
                for q in 0..4 {
                    fi[g.nodes[q]] += forces[k][q];
                }
                if damping.beta_s != 0.0 {
                    let kv = element_product(ke, &g.nodes, v);
                    for q in 0..4 {
                        fd[g.nodes[q]] += kv[q] * damping.beta_s;
                    }
                }
            }
        }
        (values, fi, fd)
    }
}
