//! The forward model of the spacetime objective: every free-motion segment simulated from the
//! tracked state and velocity at its start with wang2015 eq. 3,
//!
//! M ẍ + (αM + βK) ẋ + R K (Rᵀx − X) = M g,
//!
//! (corotational tets over the rest shape X, lumped masses, Rayleigh damping, the support
//! prescribed to its tracked positions; `softcap_fem::DynamicSolver`, Newmark average
//! acceleration with `substeps` steps per frame interval), and the residuals x_t(p) − x̂_t of
//! eq. 9 over the segments' later frames and the unsupported nodes.

use nalgebra::Vector3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use softcap_fem::{
    CorotationalModel, DirichletBc, DynamicSolver, DynamicState, DynamicStepReport,
    DynamicStepStatus, DynamicsSettings, Integrator, LinearParams, QuadraticModel, QuadraticSolver,
    RayleighDamping, SensitivitySettings, StepLoads, StiffnessKind, with_serial_element_loops,
};
use softcap_mesh::TetMesh;

use super::sequence::{Segment, TrackedSequence, smoothed_state};
use crate::error::Result;

/// Material, damping (and the rest shape, passed separately) of one forward run.
#[derive(Clone, Debug, PartialEq)]
pub struct DynamicParams {
    /// Young's modulus per tet, Pa.
    pub young_pa: Vec<f64>,
    /// Poisson ratio (shared).
    pub poisson: f64,
    /// Rayleigh damping.
    pub damping: RayleighDamping,
}

/// Settings of the segment simulations.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ForwardSettings {
    /// Time steps per frame interval.
    pub substeps: usize,
    /// Newton iterations per step at most.
    pub newton_iterations: usize,
    /// A step's Newton iterations stop when ‖r‖ ≤ this × the step's force scale
    /// (`softcap_fem::DynamicsSettings::residual_tol_rel`); the displacement test stays at its
    /// default (10⁻¹⁰ of the body's size). The default 10⁻⁶ keeps the trajectories within
    /// 0.1 µm of a tight solve on the small test bar (measured 2.7 nm), far below tracking noise;
    /// the forward sensitivities differentiate the exact step whatever the iterate. A fit whose
    /// Jacobian is taken by forward differences runs at 10⁻⁸ at most (the two trajectories it
    /// differences must lie far closer than its step's effect).
    pub newton_tolerance: f64,
    /// Factorization reuse (`softcap_fem::DynamicSolver::set_refactor_ratio`): a step's later
    /// Newton updates are solved with the factor of its first until an iteration reduces the
    /// residual by less than this factor; then the current matrix is factored. Every step
    /// still converges to the same tolerance. 0: every Newton update factors anew.
    pub refactor_ratio: f64,
    /// With `refactor_ratio` > 0: an iteration whose update reuses the factor evaluates only
    /// the residual (element forces, no element matrices or assembly;
    /// `softcap_fem::DynamicSolver::set_residual_only`). Off: the matrix is assembled at every
    /// iteration (the same trajectories to round-off; for comparison).
    pub residual_only: bool,
    /// Half width (frames) of the polynomial fit that gives a segment's initial state.
    pub velocity_half_window: usize,
    /// Degree of that polynomial.
    pub velocity_degree: usize,
    /// The first time step of a segment is taken as this many implicit-Euler steps (0 = none):
    /// tracking noise in the initial state is strain in the stiffest modes, which the
    /// energy-conserving Newmark rule would carry (and, with the corotational nonlinearity, let
    /// grow); backward Euler removes it (amplification 1/(1 + iωh) per step) while a mode at
    /// ω = 26 rad/s loses 0.2 % of its amplitude over four steps of h/4 at 120 Hz.
    pub startup_euler_steps: usize,
    /// Spatial low-pass of the initial displacement and velocity, u ← (I + λL)⁻¹ u with the
    /// umbrella Laplacian L of the node graph (λ in edges²; 0 = off): tracking noise that is
    /// independent from node to node is strain that would ring in the stiffest modes.
    pub initial_state_smoothing: f64,
    /// Model-based start states ([`Forward::modal_start_states`]; 0 = the tracked state and the
    /// polynomial velocity): each segment's initial displacement and velocity in the first this
    /// many modes of the simulated body, fitted by linear least squares to the tracked motion of
    /// the segment under the body's own linearised damped dynamics (variable projection of the
    /// start state; wang2015 §7 simulates "from estimated initial state").
    pub start_fit_modes: usize,
    /// Frame intervals of a segment the start state is fitted to (at most the segment's; the
    /// default, the whole segment, is the variable projection of eq. 9 for the linearised body).
    pub start_fit_frames: usize,
    /// With `start_fit_modes` > 0: replace only the fitted modes' share of the tracked start
    /// state (x̂ − Σ φ_i φ_iᵀM(x̂ − x_s) + Σ φ_i q_i(0), the same for the velocity), keeping
    /// the tracked state outside them — the bent bar's nonlinear share and the modes above the
    /// fit's frequency cut-off — instead of starting from x_s + Σ φ_i q_i(0) alone.
    pub start_fit_keeps_tracked: bool,
    /// With `start_fit_modes` > 0: per segment, the start state (tracked or model-based) whose
    /// simulation fits the segment better at the warm start ([`Forward::choose_start_states`])
    /// is used throughout the fit.
    pub start_fit_choice: bool,
    /// In a simulation with forward sensitivities near an earlier one ([`Near`]): every step's
    /// Newton iterations start from that run's x_{n+1} moved along its sensitivities,
    /// x_{n+1}(p) + S_{n+1} Δp, and its sensitivity iterations from S_{n+1}, instead of the
    /// predictor x_n + h v_n and the integrator's predictor of s. The same tolerances: the
    /// trajectories stay Newton's to `newton_tolerance`.
    pub start_near: bool,
    /// `refactor_ratio` of the steps started near an earlier run ([`Near`]): such a step
    /// starts within the Newton tolerance's reach, where a Newton update with the warped
    /// stiffness cuts ‖r‖ by less than 3× without the matrix being stale; at 0.3 the 60-frame
    /// bench renewed the factor in 12 % of the steps (1.12 factorizations per step) for the same
    /// Newton updates as at 0.9 (1.00).
    pub near_refactor_ratio: f64,
}

impl Default for ForwardSettings {
    fn default() -> Self {
        Self {
            substeps: 4,
            newton_iterations: 12,
            newton_tolerance: 1e-6,
            refactor_ratio: 0.3,
            residual_only: true,
            velocity_half_window: 2,
            velocity_degree: 4,
            initial_state_smoothing: 0.0,
            startup_euler_steps: 4,
            start_fit_modes: 0,
            start_fit_frames: 30,
            start_fit_keeps_tracked: false,
            start_fit_choice: false,
            start_near: true,
            near_refactor_ratio: 0.9,
        }
    }
}

/// u ← (I + λL)⁻¹ u on the unsupported nodes (supported nodes keep their values and enter as
/// boundary data): one sparse LU, applied per component.
pub(crate) struct Smoother {
    lu: Option<faer::sparse::linalg::solvers::Lu<usize, f64>>,
    free: Vec<usize>,
    coupling: Vec<Vec<usize>>,
    lambda: f64,
}

impl Smoother {
    pub(crate) fn new(mesh: &TetMesh, support: &[usize], lambda: f64) -> Result<Self> {
        let n = mesh.vertices.len();
        let adjacency = softcap_mesh::adjacency::vertex_vertices(n, &mesh.tets);
        let mut index = vec![usize::MAX; n];
        let mut held = vec![false; n];
        for &i in support {
            held[i] = true;
        }
        let free: Vec<usize> = (0..n).filter(|&i| !held[i]).collect();
        for (k, &i) in free.iter().enumerate() {
            index[i] = k;
        }
        if lambda <= 0.0 {
            return Ok(Self {
                lu: None,
                free,
                coupling: Vec::new(),
                lambda,
            });
        }
        let mut triplets = Vec::new();
        let mut coupling = vec![Vec::new(); free.len()];
        for (k, &i) in free.iter().enumerate() {
            triplets.push(faer::sparse::Triplet::new(
                k,
                k,
                1.0 + lambda * adjacency[i].len() as f64,
            ));
            for &j in &adjacency[i] {
                if held[j] {
                    coupling[k].push(j);
                } else {
                    triplets.push(faer::sparse::Triplet::new(k, index[j], -lambda));
                }
            }
        }
        let lu = faer::sparse::SparseColMat::<usize, f64>::try_new_from_triplets(
            free.len(),
            free.len(),
            &triplets,
        )
        .map_err(|e| format!("{e:?}"))
        .and_then(|a| a.sp_lu().map_err(|e| format!("{e:?}")))
        .map_err(|status| crate::TissueError::NotConverged {
            what: "initial-state smoothing".into(),
            status,
        })?;
        Ok(Self {
            lu: Some(lu),
            free,
            coupling,
            lambda,
        })
    }

    pub(crate) fn apply(&self, u: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        use faer::linalg::solvers::Solve;
        let Some(lu) = &self.lu else {
            return u.to_vec();
        };
        let mut rhs = faer::Mat::<f64>::zeros(self.free.len(), 3);
        for (k, &i) in self.free.iter().enumerate() {
            for c in 0..3 {
                rhs[(k, c)] =
                    u[i][c] + self.lambda * self.coupling[k].iter().map(|&j| u[j][c]).sum::<f64>();
            }
        }
        lu.solve_in_place(rhs.as_mut());
        let mut out = u.to_vec();
        for (k, &i) in self.free.iter().enumerate() {
            out[i] = Vector3::new(rhs[(k, 0)], rhs[(k, 1)], rhs[(k, 2)]);
        }
        out
    }
}

/// Low-mode corrections of the segments' initial states, fitted with the parameters (wang2015
/// eq. 6/9 simulates each segment "from the same initial state"; its §7 simulates the learned
/// models "from estimated initial state"). A segment's state is the tracked one plus
/// Σ_i a_i φ̂_i in position and Σ_i b_i ω_i φ̂_i in velocity, φ̂_i the i-th mode scaled to
/// [`START_MODE_SCALE_M`] at its largest node displacement: the tracked state's noise in the
/// lowest modes (and the polynomial velocity's lag) would otherwise ring through the whole
/// segment, and the fit would take damping to remove it.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct StartModes {
    shapes: Vec<Vec<Vector3<f64>>>,
    omegas_rad_s: Vec<f64>,
}

/// Length unit of the start-state coefficients (1 mm).
pub const START_MODE_SCALE_M: f64 = 1.0e-3;

impl StartModes {
    /// The first `count` of `modes` (shapes zeroed on `support` nodes).
    pub fn new(modes: &softcap_fem::Modes, count: usize, support: &[usize]) -> Self {
        let omegas = modes.angular_frequencies_rad_s();
        let mut out = Self::default();
        for (shape, &omega) in modes.shapes.iter().zip(&omegas).take(count) {
            let mut phi = shape.clone();
            for &i in support {
                phi[i] = Vector3::zeros();
            }
            let peak = phi.iter().map(|v| v.norm()).fold(0.0f64, f64::max);
            if peak > 0.0 && omega > 0.0 {
                phi.iter_mut().for_each(|v| *v *= START_MODE_SCALE_M / peak);
                out.shapes.push(phi);
                out.omegas_rad_s.push(omega);
            }
        }
        out
    }

    /// Coefficients per segment (a_i and b_i of every mode).
    pub fn per_segment(&self) -> usize {
        2 * self.shapes.len()
    }

    /// Segment `k`'s coefficients in the segment-major vector `c`.
    pub fn of_segment<'a>(&self, c: &'a [f64], k: usize) -> &'a [f64] {
        let n = self.per_segment();
        &c[k * n..(k + 1) * n]
    }

    /// The corrected state (x + Σ a_i φ̂_i, v + Σ b_i ω_i φ̂_i); `c` = (a…, b…).
    fn apply(&self, x: &mut [Vector3<f64>], v: &mut [Vector3<f64>], c: &[f64]) {
        let m = self.shapes.len();
        for (i, phi) in self.shapes.iter().enumerate() {
            let (a, b) = (c[i], c[m + i] * self.omegas_rad_s[i]);
            for ((xn, vn), p) in x.iter_mut().zip(v.iter_mut()).zip(phi) {
                *xn += p * a;
                *vn += p * b;
            }
        }
    }
}

/// The simulated positions of one segment's frames `start + 1 ..= end`.
#[derive(Clone, Debug, PartialEq)]
pub struct SegmentRun {
    /// The segment.
    pub segment: Segment,
    /// Positions per frame after the start, m.
    pub positions_m: Vec<Vec<Vector3<f64>>>,
    /// Steps whose Newton iterations hit their limit.
    pub max_iteration_steps: usize,
    /// Set when a step failed (the run stopped there).
    pub failure: Option<String>,
    /// Forward sensitivities ∂x/∂p_k per parameter k, per frame after the start, per node, m
    /// per unit of p_k ([`Forward::simulate_with_sensitivities`]; empty otherwise).
    pub sensitivities_m: Vec<Vec<Vec<Vector3<f64>>>>,
    /// Every time step's x_{n+1} and sensitivities, all nodes (a run with sensitivities; the
    /// start of a later run near it, [`Near`]).
    pub steps: Option<std::sync::Arc<StepTrack>>,
}

/// Every time step's positions and forward sensitivities of one segment's run, all nodes.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct StepTrack {
    /// x_{n+1} per step (the startup Euler steps included), m.
    pub positions_m: Vec<Vec<Vector3<f64>>>,
    /// s_{n+1} = ∂x_{n+1}/∂p_k per step, per parameter k, m per unit of p_k.
    pub sensitivities_m: Vec<Vec<Vec<Vector3<f64>>>>,
}

/// An earlier simulation with sensitivities to start from ([`ForwardSettings::start_near`]):
/// its step tracks per segment ([`SegmentRun::steps`]) and Δp = p − p_earlier in the
/// parameters of its sensitivities.
#[derive(Clone, Copy, Debug)]
pub struct Near<'a> {
    /// Per segment, its run's steps (`None`: start as usual).
    pub tracks: &'a [Option<std::sync::Arc<StepTrack>>],
    /// Δp per parameter.
    pub dp: &'a [f64],
}

/// The body at p + ε e_k for the forward sensitivity of parameter k
/// ([`Forward::simulate_with_sensitivities`]): its parameters and rest shape (X + ε dX/dp_k,
/// the rest shape of eq. 7 moving with the moduli).
#[derive(Clone, Debug)]
pub struct Perturbed {
    /// Parameters at p + ε e_k.
    pub params: DynamicParams,
    /// Rest shape at p + ε e_k, m.
    pub rest_m: Vec<Vector3<f64>>,
}

/// The perturbed bodies of one simulation with sensitivities, and their settings.
struct SensitivityModels {
    bodies: Vec<(FitModel, RayleighDamping)>,
    options: SensitivitySettings,
}

/// Where the time of a fit went (summed over the fit; [`Forward::timing`]). CPU-s are the
/// process's CPU time over each phase (the phases run one after another; the segments of one
/// simulation run in parallel); thread-s are wall time summed over the threads that did the
/// work.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FitTiming {
    /// Forward simulations (every segment of one evaluation, [`Forward::simulate_from`]): CPU-s.
    pub simulate_cpu_s: f64,
    /// Their wall time, s.
    pub simulate_wall_s: f64,
    /// Rest-shape solves (eq. 7): CPU-s.
    pub rest_shape_cpu_s: f64,
    /// Their wall time, s.
    pub rest_shape_wall_s: f64,
    /// Modal warm start (§6.3: eigen-solves and modal measurements, rest shapes excluded): CPU-s.
    pub modal_cpu_s: f64,
    /// Its wall time, s.
    pub modal_wall_s: f64,
    /// Segment simulations, time steps, Newton iterations (element passes) and numeric
    /// factorizations in them.
    pub segment_runs: usize,
    /// Time steps.
    pub steps: usize,
    /// Newton iterations.
    pub newton_iterations: usize,
    /// Numeric factorizations of the system matrix.
    pub factorizations: usize,
    /// Thread-s in segment simulations, and in their factorizations (the numeric Cholesky
    /// runs sequentially on its thread).
    pub segment_thread_s: f64,
    /// Thread-s in factorizations.
    pub factor_thread_s: f64,
    /// Iterations of the forward-sensitivity steps (one back-substitution each after a
    /// directional difference of the residual, the first, or a product with the step tangent,
    /// [`softcap_fem::DynamicSolver::step_sensitivities`]), over all parameters.
    pub sensitivity_iterations: usize,
    /// Rest-shape solves (eq. 7; a rest shape kept for its modulus is not counted).
    pub rest_shape_solves: usize,
    /// Their Newton iterations (one Jacobian assembly and sparse LU each).
    pub rest_shape_iterations: usize,
}

impl FitTiming {
    /// CPU-s of the factorizations, estimated as their share of the segments' thread time.
    pub fn factor_cpu_s(&self) -> f64 {
        if self.segment_thread_s > 0.0 {
            self.simulate_cpu_s * self.factor_thread_s / self.segment_thread_s
        } else {
            0.0
        }
    }

    /// The sum of `self` and `other`.
    pub fn plus(&self, o: &Self) -> Self {
        Self {
            simulate_cpu_s: self.simulate_cpu_s + o.simulate_cpu_s,
            simulate_wall_s: self.simulate_wall_s + o.simulate_wall_s,
            rest_shape_cpu_s: self.rest_shape_cpu_s + o.rest_shape_cpu_s,
            rest_shape_wall_s: self.rest_shape_wall_s + o.rest_shape_wall_s,
            modal_cpu_s: self.modal_cpu_s + o.modal_cpu_s,
            modal_wall_s: self.modal_wall_s + o.modal_wall_s,
            segment_runs: self.segment_runs + o.segment_runs,
            steps: self.steps + o.steps,
            newton_iterations: self.newton_iterations + o.newton_iterations,
            factorizations: self.factorizations + o.factorizations,
            segment_thread_s: self.segment_thread_s + o.segment_thread_s,
            factor_thread_s: self.factor_thread_s + o.factor_thread_s,
            sensitivity_iterations: self.sensitivity_iterations + o.sensitivity_iterations,
            rest_shape_solves: self.rest_shape_solves + o.rest_shape_solves,
            rest_shape_iterations: self.rest_shape_iterations + o.rest_shape_iterations,
        }
    }
}

/// The phases of [`FitTiming`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Phase {
    Simulate,
    RestShape,
    Modal,
}

/// A [`FitTiming`] shared by the threads of a fit.
#[derive(Debug, Default)]
struct TimingCell(std::sync::Mutex<FitTiming>);

impl Clone for TimingCell {
    fn clone(&self) -> Self {
        Self(std::sync::Mutex::new(self.get()))
    }
}

impl TimingCell {
    fn get(&self) -> FitTiming {
        *self.0.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn update(&self, f: impl FnOnce(&mut FitTiming)) {
        f(&mut self.0.lock().unwrap_or_else(|e| e.into_inner()));
    }
}

/// Segments, initial states, masses and loads of a sequence on a mesh: evaluates the forward
/// model for any (p, X).
#[derive(Clone, Debug)]
pub struct Forward {
    mesh: TetMesh,
    seq: TrackedSequence,
    segments: Vec<Segment>,
    starts: Vec<(Vec<Vector3<f64>>, Vec<Vector3<f64>>)>,
    masses_kg: Vec<f64>,
    gravity_n: Vec<Vector3<f64>>,
    free_nodes: Vec<usize>,
    observed: Vec<bool>,
    settings: ForwardSettings,
    /// Quadratic elements over the mesh's nodes (then `mesh` is the once-refined linear mesh of
    /// their parent mesh and gives the masses, supports and smoothing only).
    quadratic: Option<Vec<[usize; 10]>>,
    /// Per segment, whether the model-based start state is used ([`Self::choose_start_states`]).
    start_choice: std::sync::OnceLock<Vec<bool>>,
    /// Where the time went.
    timing: TimingCell,
}

/// The elastic model of a forward run: corotational linear tets of the fit mesh, or quadratic
/// tets over the same nodes (`softcap_fem::quadratic`).
#[derive(Clone, Debug)]
pub enum FitModel {
    /// Linear tets.
    Linear(CorotationalModel),
    /// Quadratic tets.
    Quadratic(QuadraticModel),
}

/// The time stepper of a [`FitModel`].
pub(crate) enum Stepper {
    Linear(Box<DynamicSolver>),
    Quadratic(Box<QuadraticSolver>),
}

impl Stepper {
    /// The stepper with factorization reuse at `ratio` ([`ForwardSettings::refactor_ratio`])
    /// and residual-only passes if `residual_only` ([`ForwardSettings::residual_only`]; linear
    /// tets only).
    pub(crate) fn with_refactor_ratio(
        model: &FitModel,
        masses_kg: Vec<f64>,
        dofs: &[usize],
        ratio: f64,
        residual_only: bool,
    ) -> Result<Self> {
        let mut stepper = Self::new(model, masses_kg, dofs)?;
        if let Self::Linear(s) = &mut stepper {
            s.set_refactor_ratio((ratio > 0.0).then_some(ratio));
            s.set_residual_only(residual_only);
        }
        Ok(stepper)
    }

    pub(crate) fn new(model: &FitModel, masses_kg: Vec<f64>, dofs: &[usize]) -> Result<Self> {
        Ok(match model {
            FitModel::Linear(m) => Self::Linear(Box::new(DynamicSolver::new(m, masses_kg, dofs)?)),
            FitModel::Quadratic(m) => {
                Self::Quadratic(Box::new(QuadraticSolver::new(m, masses_kg, dofs)?))
            }
        })
    }

    pub(crate) fn step(
        &mut self,
        model: &mut FitModel,
        state: &mut DynamicState,
        loads: &StepLoads<'_>,
        settings: &DynamicsSettings,
    ) -> DynamicStepReport {
        match (self, model) {
            (Self::Linear(s), FitModel::Linear(m)) => {
                s.step_with(m, state, loads, &mut [], settings)
            }
            (Self::Quadratic(s), FitModel::Quadratic(m)) => s.step(
                m,
                state,
                loads.external_forces_n,
                loads.prescribed,
                loads.initial_guess,
                settings,
            ),
            _ => unreachable!("a stepper is built for its model"),
        }
    }

    /// [`Self::step`], then the sensitivities of the `perturbed` bodies (if any) through it
    /// ([`Self::sensitivity_step`]; not after a failed step). Returns the report and the
    /// sensitivity iterations.
    fn step_and_sensitivities(
        &mut self,
        model: &mut FitModel,
        state: &mut DynamicState,
        loads: &StepLoads<'_>,
        settings: &DynamicsSettings,
        perturbed: Option<&SensitivityModels>,
        sensitivities: &mut [DynamicState],
        initial: Option<&[Vec<Vector3<f64>>]>,
    ) -> Result<(DynamicStepReport, usize)> {
        let before = perturbed.map(|_| state.clone());
        let report = self.step(model, state, loads, settings);
        let failed = matches!(report.status, DynamicStepStatus::Failed { .. });
        let iterations = match (perturbed, before) {
            (Some(p), Some(before)) if !failed => self.sensitivity_step(
                model,
                &before,
                state,
                loads.external_forces_n,
                settings,
                p,
                sensitivities,
                initial,
            )?,
            _ => 0,
        };
        Ok((report, iterations))
    }

    /// [`Self::initialize_acceleration`], and the sensitivities of a₀ for the `perturbed`
    /// bodies if any ([`Self::acceleration_sensitivities`]).
    fn start_acceleration(
        &self,
        model: &FitModel,
        state: &mut DynamicState,
        forces: &[Vector3<f64>],
        settings: &DynamicsSettings,
        perturbed: Option<&SensitivityModels>,
        sensitivities: &mut [DynamicState],
    ) {
        self.initialize_acceleration(model, state, forces, settings);
        if let Some(p) = perturbed {
            self.acceleration_sensitivities(state, forces, settings, p, sensitivities);
        }
    }

    /// The forward sensitivities of every perturbed body through the step just taken from
    /// `before` to `after` ([`DynamicSolver::step_sensitivities`]; the base residual is the
    /// Newton iterations' last, at `after`); returns the iterations. Linear tets only.
    #[allow(clippy::too_many_arguments)]
    fn sensitivity_step(
        &mut self,
        model: &FitModel,
        before: &DynamicState,
        after: &DynamicState,
        forces: &[Vector3<f64>],
        settings: &DynamicsSettings,
        perturbed: &SensitivityModels,
        sensitivities: &mut [DynamicState],
        initial: Option<&[Vec<Vector3<f64>>]>,
    ) -> Result<usize> {
        let (Self::Linear(s), FitModel::Linear(m)) = (self, model) else {
            return Err(not_linear());
        };
        let x = &after.positions_m;
        // The Newton iterations' last residual pass was at x (to round-off the same).
        let base = match s.committed_residual() {
            Some(r) => r.to_vec(),
            None => s.step_residual(m, before, x, forces, settings),
        };
        let settings_p: Vec<DynamicsSettings> = perturbed
            .bodies
            .iter()
            .map(|(_, damping)| DynamicsSettings {
                damping: *damping,
                ..settings.clone()
            })
            .collect();
        let bodies = perturbed
            .bodies
            .iter()
            .zip(&settings_p)
            .map(|((body, _), ps)| match body {
                FitModel::Linear(pm) => Ok((pm, ps)),
                FitModel::Quadratic(_) => Err(not_linear()),
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(s.step_sensitivities(
            m,
            before,
            x,
            &base,
            forces,
            settings,
            &bodies,
            sensitivities,
            initial,
            &perturbed.options,
        )?)
    }

    /// The sensitivities of the consistent start acceleration a₀ = M⁻¹ (f_ext − f_int − D v)
    /// (after [`Self::initialize_acceleration`] of `state`): the same with each perturbed body
    /// at the state moved by ε × its sensitivity, differenced against `state`'s.
    fn acceleration_sensitivities(
        &self,
        state: &DynamicState,
        forces: &[Vector3<f64>],
        settings: &DynamicsSettings,
        perturbed: &SensitivityModels,
        sensitivities: &mut [DynamicState],
    ) {
        let eps = perturbed.options.epsilon;
        for ((body, damping), sens) in perturbed.bodies.iter().zip(sensitivities) {
            let shifted = |a: &[Vector3<f64>], d: &[Vector3<f64>]| -> Vec<Vector3<f64>> {
                a.iter().zip(d).map(|(a, d)| a + d * eps).collect()
            };
            let mut moved = DynamicState::at_rest(shifted(&state.positions_m, &sens.positions_m));
            moved.velocities_m_s = shifted(&state.velocities_m_s, &sens.velocities_m_s);
            let ps = DynamicsSettings {
                damping: *damping,
                ..settings.clone()
            };
            self.initialize_acceleration(body, &mut moved, forces, &ps);
            sens.accelerations_m_s2 = moved
                .accelerations_m_s2
                .iter()
                .zip(&state.accelerations_m_s2)
                .map(|(a, b)| (a - b) / eps)
                .collect();
        }
    }

    fn initialize_acceleration(
        &self,
        model: &FitModel,
        state: &mut DynamicState,
        forces: &[Vector3<f64>],
        settings: &DynamicsSettings,
    ) {
        match (self, model) {
            (Self::Linear(s), FitModel::Linear(m)) => {
                s.initialize_acceleration(m, state, forces, settings)
            }
            (Self::Quadratic(s), FitModel::Quadratic(m)) => {
                s.initialize_acceleration(m, state, forces, settings)
            }
            _ => unreachable!("a stepper is built for its model"),
        }
    }
}

/// Whether `tasks` segment simulations in one parallel pass run their element loops serially
/// (`softcap_fem::with_serial_element_loops`): with at least two per thread the segments keep
/// every thread busy by themselves; fewer (the first segments of a fit coarse to fine in time)
/// share their element loops between the threads.
fn serial_segments(tasks: usize) -> bool {
    tasks >= 2 * rayon::current_num_threads()
}

/// The error of a sensitivity run on quadratic tets.
fn not_linear() -> crate::TissueError {
    crate::TissueError::BadSettings {
        field: "jacobian".into(),
        problem: "forward sensitivities are implemented for linear tets (use forward differences)"
            .into(),
    }
}

impl Forward {
    /// `mesh` (frame-0 shape; topology and masses), the sequence on its nodes, the segments,
    /// and which nodes are observations (residuals are taken on those that are unsupported).
    pub fn new(
        mesh: &TetMesh,
        seq: &TrackedSequence,
        segments: Vec<Segment>,
        observed: Vec<bool>,
        settings: &ForwardSettings,
    ) -> Result<Self> {
        let frame0 =
            CorotationalModel::homogeneous(mesh, LinearParams::from_young_poisson(1e5, 0.3)?)?;
        let masses_kg = softcap_fem::lumped_masses(&frame0, seq.density_kg_m3);
        let gravity_n = softcap_fem::gravity_forces(&masses_kg, seq.gravity_m_s2);
        let smoother = Smoother::new(mesh, &seq.support_nodes, settings.initial_state_smoothing)?;
        let starts = segments
            .iter()
            .map(|s| {
                let (x, mut v) = smoothed_state(
                    seq,
                    s.start,
                    settings.velocity_half_window,
                    settings.velocity_degree,
                );
                if let Some(known) = seq.velocities_m_s.as_ref().and_then(|vs| vs.get(s.start)) {
                    v.clone_from(known);
                }
                let u: Vec<Vector3<f64>> =
                    x.iter().zip(&mesh.vertices).map(|(a, b)| a - b).collect();
                let u = smoother.apply(&u);
                let x = mesh.vertices.iter().zip(&u).map(|(b, d)| b + d).collect();
                (x, smoother.apply(&v))
            })
            .collect();
        let mut supported = vec![false; mesh.vertices.len()];
        for &i in &seq.support_nodes {
            supported[i] = true;
        }
        let free_nodes = (0..mesh.vertices.len())
            .filter(|&i| !supported[i] && observed[i])
            .collect();
        Ok(Self {
            mesh: mesh.clone(),
            seq: seq.clone(),
            segments,
            starts,
            masses_kg,
            gravity_n,
            free_nodes,
            observed,
            settings: settings.clone(),
            quadratic: None,
            start_choice: std::sync::OnceLock::new(),
            timing: TimingCell::default(),
        })
    }

    /// The same forward model on quadratic `elements` over the mesh's nodes (the mesh being the
    /// once-refined linear mesh of their parent mesh: `softcap_fem::quadratic_tets`).
    pub fn with_quadratic(mut self, elements: Vec<[usize; 10]>) -> Self {
        self.quadratic = Some(elements);
        self
    }

    /// Where the time of the evaluations so far went.
    pub fn timing(&self) -> FitTiming {
        self.timing.get()
    }

    /// Runs `f` as a `phase` of [`Self::timing`] (process CPU-s and wall).
    pub(crate) fn timed<T>(&self, phase: Phase, f: impl FnOnce() -> T) -> T {
        let (c0, t0) = (
            softcap_app::process::cpu_seconds(),
            std::time::Instant::now(),
        );
        let out = f();
        let wall = t0.elapsed().as_secs_f64();
        let cpu = match (c0, softcap_app::process::cpu_seconds()) {
            (Some(a), Some(b)) => b - a,
            _ => wall,
        };
        self.timing.update(|t| {
            let (c, w) = match phase {
                Phase::Simulate => (&mut t.simulate_cpu_s, &mut t.simulate_wall_s),
                Phase::RestShape => (&mut t.rest_shape_cpu_s, &mut t.rest_shape_wall_s),
                Phase::Modal => (&mut t.modal_cpu_s, &mut t.modal_wall_s),
            };
            *c += cpu;
            *w += wall;
        });
        out
    }

    /// Elements of the model (one E per element in [`DynamicParams`]).
    pub fn num_elements(&self) -> usize {
        self.quadratic
            .as_ref()
            .map_or(self.mesh.tets.len(), |q| q.len())
    }

    /// The segments.
    pub fn segments(&self) -> &[Segment] {
        &self.segments
    }

    /// The sequence.
    pub fn sequence(&self) -> &TrackedSequence {
        &self.seq
    }

    /// The mesh (frame-0 shape).
    pub fn mesh(&self) -> &TetMesh {
        &self.mesh
    }

    /// Lumped masses, kg.
    pub fn masses_kg(&self) -> &[f64] {
        &self.masses_kg
    }

    /// Gravity loads M g, N.
    pub fn gravity_n(&self) -> &[Vector3<f64>] {
        &self.gravity_n
    }

    /// Which nodes are observations.
    pub fn observed(&self) -> &[bool] {
        &self.observed
    }

    /// Number of residuals (3 per unsupported observed node per simulated frame).
    pub fn num_residuals(&self) -> usize {
        let frames: usize = self.segments.iter().map(|s| s.end - s.start).sum();
        3 * self.free_nodes.len() * frames
    }

    /// The support dofs.
    pub fn support_dofs(&self) -> Vec<usize> {
        self.seq
            .support_nodes
            .iter()
            .flat_map(|&i| [3 * i, 3 * i + 1, 3 * i + 2])
            .collect()
    }

    /// The corotational model of `params` over the rest shape `rest_m`.
    pub fn model(&self, params: &DynamicParams, rest_m: &[Vector3<f64>]) -> Result<FitModel> {
        let lp = params
            .young_pa
            .iter()
            .map(|&e| LinearParams::from_young_poisson(e, params.poisson))
            .collect::<std::result::Result<Vec<_>, _>>()?;
        Ok(match &self.quadratic {
            Some(elements) => FitModel::Quadratic(QuadraticModel::new(rest_m, elements, &lp)?),
            None => FitModel::Linear(CorotationalModel::new(
                &TetMesh {
                    vertices: rest_m.to_vec(),
                    tets: self.mesh.tets.clone(),
                },
                lp,
            )?),
        })
    }

    /// Runs every segment from its tracked initial state (in parallel; results in segment order).
    pub fn simulate(
        &self,
        params: &DynamicParams,
        rest_m: &[Vector3<f64>],
    ) -> Result<Vec<SegmentRun>> {
        self.simulate_from(params, rest_m, None)
    }

    /// Runs every segment from its initial state corrected by `start` (the modes and the
    /// segment-major coefficients, [`StartModes`]; `None`: the tracked states).
    pub fn simulate_from(
        &self,
        params: &DynamicParams,
        rest_m: &[Vector3<f64>],
        start: Option<(&StartModes, &[f64])>,
    ) -> Result<Vec<SegmentRun>> {
        self.timed(Phase::Simulate, || {
            let model = self.model(params, rest_m)?;
            let starts = self.start_states(&model, params.damping)?;
            let serial = serial_segments(self.segments.len());
            let runs = (0..self.segments.len())
                .into_par_iter()
                .map(|k| {
                    let correction = start.map(|(m, c)| (m, m.of_segment(c, k)));
                    with_serial_element_loops(serial, || {
                        self.simulate_segment(k, &model, params.damping, &starts[k], correction)
                    })
                })
                .collect::<Vec<_>>();
            runs.into_iter().collect()
        })
    }

    /// [`Self::simulate_from`] with the forward sensitivities ∂x_t/∂p_k of every segment's
    /// frames for each `perturbed` body k (the parameters and rest shape at p + ε e_k,
    /// [`Perturbed`]; ε = `options.epsilon`): along every implicit step the sensitivity of each
    /// parameter is one linear solve with the step's factored system matrix
    /// ([`softcap_fem::DynamicSolver::step_sensitivities`]), instead of a simulation per parameter
    /// as forward differences take. Linear tets and the tracked start states (which do not
    /// depend on p) only. With `near` (and [`ForwardSettings::start_near`]) every step starts
    /// from that earlier run's, moved along its sensitivities. Every run keeps its steps
    /// ([`SegmentRun::steps`]).
    pub fn simulate_with_sensitivities(
        &self,
        params: &DynamicParams,
        rest_m: &[Vector3<f64>],
        start: Option<(&StartModes, &[f64])>,
        perturbed: &[Perturbed],
        options: &SensitivitySettings,
        near: Option<Near<'_>>,
    ) -> Result<Vec<SegmentRun>> {
        if self.quadratic.is_some() {
            return Err(not_linear());
        }
        if self.settings.start_fit_modes > 0 {
            return Err(crate::TissueError::BadSettings {
                field: "forward.start_fit_modes".into(),
                problem: "forward sensitivities need start states that do not depend on the \
                          parameters (use forward differences)"
                    .into(),
            });
        }
        self.timed(Phase::Simulate, || {
            let model = self.model(params, rest_m)?;
            // A perturbation of the damping only keeps the body (a clone: the same elastic
            // state, which `step_sensitivities` differentiates without an element pass).
            let bodies = perturbed
                .iter()
                .map(|p| {
                    let same = p.params.young_pa == params.young_pa
                        && p.params.poisson == params.poisson
                        && p.rest_m == rest_m;
                    let body = if same {
                        model.clone()
                    } else {
                        self.model(&p.params, &p.rest_m)?
                    };
                    Ok((body, p.params.damping))
                })
                .collect::<Result<Vec<_>>>()?;
            let sens = SensitivityModels {
                bodies,
                options: *options,
            };
            let serial = serial_segments(self.segments.len());
            let runs = (0..self.segments.len())
                .into_par_iter()
                .map(|k| {
                    let correction = start.map(|(m, c)| (m, m.of_segment(c, k)));
                    let start = &self.starts[k];
                    let near = near
                        .filter(|n| self.settings.start_near && n.dp.len() == sens.bodies.len())
                        .and_then(|n| Some((n.tracks.get(k)?.as_deref()?, n.dp)));
                    with_serial_element_loops(serial, || {
                        let d = params.damping;
                        self.run_segment(k, &model, d, start, correction, Some(&sens), near)
                    })
                })
                .collect::<Vec<_>>();
            runs.into_iter().collect()
        })
    }

    /// Several evaluations at once (e.g. the columns of a finite-difference Jacobian): every
    /// segment of every job is one task of one parallel pass (the segments are independent,
    /// each starts from its own state, wang2015 eq. 6/9), so a pass of n jobs keeps the threads
    /// busy where one job's few, unequal segments would not. The results are in job order, each
    /// equal bit for bit to [`Self::simulate_from`] of that job alone, on any number of threads.
    pub fn simulate_batch(
        &self,
        jobs: &[(
            &DynamicParams,
            &[Vector3<f64>],
            Option<(&StartModes, &[f64])>,
        )],
    ) -> Vec<Result<Vec<SegmentRun>>> {
        self.timed(Phase::Simulate, || {
            let prepared: Vec<Result<(FitModel, Vec<_>)>> = jobs
                .iter()
                .map(|(params, rest, _)| {
                    let model = self.model(params, rest)?;
                    let starts = self.start_states(&model, params.damping)?;
                    Ok((model, starts))
                })
                .collect();
            let ns = self.segments.len();
            let tasks: Vec<(usize, usize)> = (0..jobs.len())
                .filter(|&j| prepared[j].is_ok())
                .flat_map(|j| (0..ns).map(move |k| (j, k)))
                .collect();
            let serial = serial_segments(tasks.len());
            let mut runs = tasks
                .into_par_iter()
                .map(|(j, k)| {
                    let Ok((model, starts)) = &prepared[j] else {
                        unreachable!("only prepared jobs are tasks")
                    };
                    let (params, _, start) = &jobs[j];
                    let correction = start.map(|(m, c)| (m, m.of_segment(c, k)));
                    with_serial_element_loops(serial, || {
                        self.simulate_segment(k, model, params.damping, &starts[k], correction)
                    })
                })
                .collect::<Vec<_>>()
                .into_iter();
            prepared
                .into_iter()
                .map(|p| {
                    p?;
                    // Take all of the job's segments before looking for a failure in them.
                    let job: Vec<Result<SegmentRun>> = runs.by_ref().take(ns).collect();
                    job.into_iter().collect()
                })
                .collect()
        })
    }

    /// Where segment `k`'s residuals sit in [`Self::residuals`].
    pub fn residual_range(&self, k: usize) -> std::ops::Range<usize> {
        let per_frame = 3 * self.free_nodes.len();
        let before: usize = self.segments[..k].iter().map(|s| s.end - s.start).sum();
        let seg = &self.segments[k];
        before * per_frame..(before + seg.end - seg.start) * per_frame
    }

    fn dynamics_settings(&self, h: f64, damping: RayleighDamping) -> DynamicsSettings {
        DynamicsSettings {
            integrator: Integrator::NewmarkAverageAcceleration,
            time_step_s: h,
            damping,
            stiffness: StiffnessKind::Warped,
            max_iterations: self.settings.newton_iterations.max(1),
            residual_tol_rel: self.settings.newton_tolerance,
            ..DynamicsSettings::default()
        }
    }

    /// The initial state (positions, velocities) of every segment for the body `model` with
    /// `damping`: the tracked state and polynomial velocity, or, with
    /// `ForwardSettings::start_fit_modes` = M > 0, the model-based estimate
    /// ([`Self::modal_start_states`]).
    pub fn start_states(
        &self,
        model: &FitModel,
        damping: RayleighDamping,
    ) -> Result<Vec<(Vec<Vector3<f64>>, Vec<Vector3<f64>>)>> {
        if self.settings.start_fit_modes == 0 {
            return Ok(self.starts.clone());
        }
        let modal = self.modal_start_states(model, damping)?;
        Ok(match self.start_choice.get() {
            Some(choice) => modal
                .into_iter()
                .zip(&self.starts)
                .zip(choice)
                .map(|((m, t), &use_model)| if use_model { m } else { t.clone() })
                .collect(),
            None => modal,
        })
    }

    /// Per segment, the start state — tracked or model-based ([`Self::modal_start_states`]) —
    /// whose simulation with `params` over `rest_m` has the smaller residual over the segment;
    /// with `ForwardSettings::start_fit_choice` the choice is kept for every later evaluation
    /// (set once). Returns the choice (true: model-based) and each segment's residual sums of
    /// squares (tracked, model-based), m².
    pub fn choose_start_states(
        &self,
        params: &DynamicParams,
        rest_m: &[Vector3<f64>],
    ) -> Result<(Vec<bool>, Vec<(f64, f64)>)> {
        let model = self.model(params, rest_m)?;
        let modal = self.modal_start_states(&model, params.damping)?;
        let sums = (0..self.segments.len())
            .into_par_iter()
            .map(|k| {
                let ss = |start| -> Result<f64> {
                    let run = self.simulate_segment(k, &model, params.damping, start, None)?;
                    let mut r = Vec::new();
                    self.extend_residuals(&run, &mut r);
                    let ss: f64 = r.iter().map(|v| v * v).sum();
                    Ok(if ss.is_finite() { ss } else { f64::INFINITY })
                };
                Ok((ss(&self.starts[k])?, ss(&modal[k])?))
            })
            .collect::<Result<Vec<_>>>()?;
        let choice: Vec<bool> = sums.iter().map(|(t, m)| m < t).collect();
        if self.settings.start_fit_modes > 0 && self.settings.start_fit_choice {
            let _ = self.start_choice.set(choice.clone());
        }
        Ok((choice, sums))
    }

    /// Model-based initial states (variable projection of the start state, wang2015 §7's
    /// "estimated initial state"): linearised about the static shape x_s, the body's free
    /// motion is u(t) = Σ_i φ_i q_i(t) with every modal coordinate obeying
    /// q̈ + 2σ_i q̇ + ω_i² q = 0, σ_i = α/2 + βω_i²/2 (Rayleigh damping, eq. 3), so
    /// q_i(t) = q_i(0) f₁(t) + q̇_i(0) f₂(t) is linear in the start state. For each of the first
    /// M modes (M-orthonormal, K φ = ω² M φ of the body simulated, at the current parameters)
    /// and each segment, (q_i(0), q̇_i(0)) is the least-squares fit of the tracked coordinate
    /// φ_iᵀ M (x̂_t − x_s) over the segment's first `start_fit_frames` frame intervals; the start
    /// state is x_s + Σ φ_i q_i(0), velocity Σ φ_i q̇_i(0), the support at its tracked position.
    /// Modes above 0.8 of the segment's Nyquist frequency are left out (the frames cannot tell
    /// their motion from noise), and a mode within 2 % of the M-th's frequency is taken with it
    /// (the two bending directions of a square bar). The tracked state instead carries the
    /// tracking noise of every mode and the polynomial velocity's error in the fast ones, which
    /// ring through the segment where the data does not, and the fit pays for them with damping
    /// (β up, α down); this estimate costs no simulation, one eigen-solve per evaluation.
    pub fn modal_start_states(
        &self,
        model: &FitModel,
        damping: RayleighDamping,
    ) -> Result<Vec<(Vec<Vector3<f64>>, Vec<Vector3<f64>>)>> {
        let count = self.settings.start_fit_modes;
        let modes = super::warm::modes_to(self, model, count + 1, 1e-9)?;
        let omegas = modes.angular_frequencies_rad_s();
        let mut used = count.min(omegas.len());
        if used > 0 && used < omegas.len() && omegas[used] < 1.02 * omegas[used - 1] {
            used += 1;
        }
        let xs = &self.mesh.vertices;
        let window = self.settings.start_fit_frames.max(1);
        let keep = self.settings.start_fit_keeps_tracked;
        let out = self
            .segments
            .iter()
            .zip(&self.starts)
            .map(|(seg, (tracked_x, tracked_v))| {
                let frames = seg.start..=(seg.start + window).min(seg.end);
                let t: Vec<f64> = frames
                    .clone()
                    .map(|j| self.seq.times_s[j] - self.seq.times_s[seg.start])
                    .collect();
                let dt = self.seq.times_s[seg.start..=seg.end]
                    .windows(2)
                    .map(|w| w[1] - w[0])
                    .fold(f64::INFINITY, f64::min);
                let nyquist = std::f64::consts::PI / dt.max(1e-12);
                let (mut x, mut v) = if keep {
                    (tracked_x.clone(), tracked_v.clone())
                } else {
                    (xs.clone(), vec![Vector3::zeros(); xs.len()])
                };
                for (phi, &omega) in modes.shapes.iter().zip(&omegas).take(used) {
                    if !(omega > 0.0 && omega <= 0.8 * nyquist) {
                        continue;
                    }
                    // Least squares in (q(0), q̇(0)/ω) with a small ridge (a mode sampled near a
                    // multiple of the frame rate has almost no f₂).
                    let sigma = 0.5 * (damping.alpha_per_s + damping.beta_s * omega * omega);
                    let (mut a, mut b) = (nalgebra::Matrix2::zeros(), nalgebra::Vector2::zeros());
                    for (&tj, j) in t.iter().zip(frames.clone()) {
                        let q: f64 = self.seq.positions_m[j]
                            .iter()
                            .zip(xs)
                            .zip(phi)
                            .zip(&self.masses_kg)
                            .map(|(((p, s), f), m)| m * f.dot(&(p - s)))
                            .sum();
                        let f = free_response(omega, sigma, tj)
                            .component_mul(&nalgebra::Vector2::new(1.0, omega));
                        a += f * f.transpose();
                        b += f * q;
                    }
                    let ridge = 1e-4 * a.trace();
                    a[(0, 0)] += ridge;
                    a[(1, 1)] += ridge;
                    let Some(c) = a.try_inverse().map(|i| i * b) else {
                        continue;
                    };
                    let (mut q0, mut qd0) = (c[0], c[1] * omega);
                    if keep {
                        // The tracked state's own share of this mode is replaced.
                        let (qx, qv) = phi
                            .iter()
                            .zip(xs)
                            .zip(self.masses_kg.iter())
                            .zip(tracked_x.iter().zip(tracked_v))
                            .fold((0.0, 0.0), |(a, b), (((f, s), m), (p, u))| {
                                (a + m * f.dot(&(p - s)), b + m * f.dot(u))
                            });
                        q0 -= qx;
                        qd0 -= qv;
                    }
                    for ((xn, vn), f) in x.iter_mut().zip(v.iter_mut()).zip(phi) {
                        *xn += f * q0;
                        *vn += f * qd0;
                    }
                }
                for &i in &self.seq.support_nodes {
                    x[i] = self.seq.positions_m[seg.start][i];
                    v[i] = Vector3::zeros();
                }
                (x, v)
            })
            .collect();
        Ok(out)
    }

    /// Runs segment `k` alone from the initial state `start` ([`Self::start_states`]),
    /// corrected by the modes and its own coefficients if given.
    pub fn simulate_segment(
        &self,
        k: usize,
        model: &FitModel,
        damping: RayleighDamping,
        start: &(Vec<Vector3<f64>>, Vec<Vector3<f64>>),
        correction: Option<(&StartModes, &[f64])>,
    ) -> Result<SegmentRun> {
        self.run_segment(k, model, damping, start, correction, None, None)
    }

    /// [`Self::simulate_segment`], with the forward sensitivities of the `perturbed` bodies if
    /// given (every step followed by their sensitivity steps; the start state's sensitivity is
    /// zero; the steps kept in [`SegmentRun::steps`]), every step started from the `near` run's
    /// if given ([`Near`]).
    #[allow(clippy::too_many_arguments)]
    fn run_segment(
        &self,
        k: usize,
        model: &FitModel,
        damping: RayleighDamping,
        start: &(Vec<Vector3<f64>>, Vec<Vector3<f64>>),
        correction: Option<(&StartModes, &[f64])>,
        perturbed: Option<&SensitivityModels>,
        near: Option<(&StepTrack, &[f64])>,
    ) -> Result<SegmentRun> {
        let t0 = std::time::Instant::now();
        let seg = self.segments[k].clone();
        let mut model = model.clone();
        let mut solver = Stepper::with_refactor_ratio(
            &model,
            self.masses_kg.clone(),
            &self.support_dofs(),
            self.settings.refactor_ratio,
            self.settings.residual_only,
        )?;
        if let (Stepper::Linear(s), Some(_)) = (&mut solver, near) {
            let ratio = self.settings.near_refactor_ratio;
            s.set_refactor_ratio((ratio > 0.0).then_some(ratio));
        }
        let (mut x0, mut v0) = start.clone();
        if let Some((modes, c)) = correction {
            modes.apply(&mut x0, &mut v0, c);
        }
        let mut state = DynamicState::at_rest(x0);
        state.time_s = self.seq.times_s[seg.start];
        state.velocities_m_s = v0;
        for &i in &self.seq.support_nodes {
            state.velocities_m_s[i] = Vector3::zeros();
        }
        let substeps = self.settings.substeps.max(1);
        let first_h =
            (self.seq.times_s[seg.start + 1] - self.seq.times_s[seg.start]) / substeps as f64;
        let startup = self.settings.startup_euler_steps;
        let (mut steps, mut iterations) = (0, 0);
        let n_sens = perturbed.map_or(0, |p| p.bodies.len());
        let mut sens: Vec<DynamicState> = (0..n_sens)
            .map(|_| DynamicState::at_rest(vec![Vector3::zeros(); state.positions_m.len()]))
            .collect();
        let mut sens_iterations = 0;
        // Solver steps taken (the index into a near run's steps).
        let mut n = 0;
        let mut run = SegmentRun {
            segment: seg.clone(),
            positions_m: Vec::with_capacity(seg.end - seg.start),
            max_iteration_steps: 0,
            failure: None,
            sensitivities_m: vec![Vec::with_capacity(seg.end - seg.start); n_sens],
            steps: None,
        };
        let mut track = StepTrack::default();
        // Step n's start (x guess, sensitivity guesses): from the near run's step moved by
        // S Δp, else x_n + h v_n — rather than Newmark's predictor with h²/4 a_n: the
        // acceleration of noisy tracked positions is large in the stiffest modes and its
        // predictor can invert tets before Newton starts.
        let start_of = |n: usize, state: &DynamicState, h: f64| {
            let earlier = near
                .and_then(|(t, dp)| Some((t.positions_m.get(n)?, t.sensitivities_m.get(n)?, dp)));
            match earlier {
                Some((x, s, dp)) => {
                    let mut guess = x.clone();
                    for (sk, d) in s.iter().zip(dp) {
                        for (g, v) in guess.iter_mut().zip(sk) {
                            *g += v * *d;
                        }
                    }
                    (guess, Some(s))
                }
                None => (
                    state
                        .positions_m
                        .iter()
                        .zip(&state.velocities_m_s)
                        .map(|(x, v)| x + v * h)
                        .collect::<Vec<_>>(),
                    None,
                ),
            }
        };
        let mut keep = |state: &DynamicState, sens: &[DynamicState]| {
            if perturbed.is_some() {
                track.positions_m.push(state.positions_m.clone());
                track
                    .sensitivities_m
                    .push(sens.iter().map(|s| s.positions_m.clone()).collect());
            }
        };
        for j in seg.start..seg.end {
            let (ta, tb) = (self.seq.times_s[j], self.seq.times_s[j + 1]);
            let h = (tb - ta) / substeps as f64;
            let settings = self.dynamics_settings(h, damping);
            for s in 1..=substeps {
                let w = s as f64 / substeps as f64;
                let mut bc = DirichletBc::new();
                for &i in &self.seq.support_nodes {
                    let p =
                        self.seq.positions_m[j][i] * (1.0 - w) + self.seq.positions_m[j + 1][i] * w;
                    bc.fix_node(i, p);
                }
                let (guess, initial) = start_of(n, &state, h);
                let loads = StepLoads {
                    external_forces_n: &self.gravity_n,
                    prescribed: Some(&bc),
                    contact: None,
                    initial_guess: Some(&guess),
                };
                // A segment's first step: the startup Euler steps (standing for it) if any,
                // then the consistent acceleration for the Newmark steps.
                let mut startup_report = None;
                if j == seg.start && s == 1 {
                    if startup > 0 {
                        let euler = DynamicsSettings {
                            integrator: Integrator::ImplicitEuler,
                            time_step_s: first_h / startup as f64,
                            ..settings.clone()
                        };
                        for e in 0..startup {
                            // Without a near run every startup step starts from x₀ + h v₀.
                            let (near_guess, near_initial) = match near {
                                Some(_) if e > 0 => start_of(n, &state, h),
                                _ => (Vec::new(), initial),
                            };
                            let step_loads = StepLoads {
                                initial_guess: Some(if near_guess.is_empty() {
                                    &guess
                                } else {
                                    &near_guess
                                }),
                                ..loads
                            };
                            let (r, si) = solver.step_and_sensitivities(
                                &mut model,
                                &mut state,
                                &step_loads,
                                &euler,
                                perturbed,
                                &mut sens,
                                near_initial.map(|v| v.as_slice()),
                            )?;
                            n += 1;
                            keep(&state, &sens);
                            iterations += r.iterations;
                            sens_iterations += si;
                            let failed = matches!(r.status, DynamicStepStatus::Failed { .. });
                            startup_report = Some(r);
                            if failed {
                                break;
                            }
                        }
                        steps += startup - 1;
                    }
                    solver.start_acceleration(
                        &model,
                        &mut state,
                        &self.gravity_n,
                        &settings,
                        perturbed,
                        &mut sens,
                    );
                }
                let report = match startup_report {
                    Some(last) => {
                        iterations -= last.iterations; // counted below with the step
                        last
                    }
                    None => {
                        let (report, si) = solver.step_and_sensitivities(
                            &mut model,
                            &mut state,
                            &loads,
                            &settings,
                            perturbed,
                            &mut sens,
                            initial.map(|v| v.as_slice()),
                        )?;
                        n += 1;
                        keep(&state, &sens);
                        sens_iterations += si;
                        report
                    }
                };
                steps += 1;
                iterations += report.iterations;
                match report.status {
                    DynamicStepStatus::Converged => {}
                    DynamicStepStatus::MaxIterations => run.max_iteration_steps += 1,
                    DynamicStepStatus::Failed { reason } => {
                        run.failure = Some(format!("frame {}: {reason}", j + 1));
                        self.record_segment(&solver, t0, steps, [iterations, sens_iterations]);
                        return Ok(run);
                    }
                }
            }
            run.positions_m.push(state.positions_m.clone());
            for (out, s) in run.sensitivities_m.iter_mut().zip(&sens) {
                out.push(s.positions_m.clone());
            }
        }
        self.record_segment(&solver, t0, steps, [iterations, sens_iterations]);
        if perturbed.is_some() {
            run.steps = Some(std::sync::Arc::new(track));
        }
        Ok(run)
    }

    /// Counts a rest-shape solve of `iterations` Newton iterations in [`Self::timing`].
    pub(crate) fn record_rest_shape(&self, iterations: usize) {
        self.timing.update(|t| {
            t.rest_shape_solves += 1;
            t.rest_shape_iterations += iterations;
        });
    }

    fn record_segment(
        &self,
        solver: &Stepper,
        t0: std::time::Instant,
        steps: usize,
        [iterations, sensitivity_iterations]: [usize; 2],
    ) {
        let wall = t0.elapsed().as_secs_f64();
        let (factorizations, factor_s) = match solver {
            Stepper::Linear(s) => (s.factorizations(), s.factor_seconds()),
            Stepper::Quadratic(_) => (0, 0.0),
        };
        self.timing.update(|t| {
            t.segment_runs += 1;
            t.steps += steps;
            t.newton_iterations += iterations;
            t.sensitivity_iterations += sensitivity_iterations;
            t.factorizations += factorizations;
            t.segment_thread_s += wall;
            t.factor_thread_s += factor_s;
        });
    }

    /// Residuals x_t(p) − x̂_t (eq. 9) of `runs`, in segment, frame, node, axis order; a failed
    /// segment's missing frames count as non-finite.
    pub fn residuals(&self, runs: &[SegmentRun]) -> Vec<f64> {
        let mut r = Vec::with_capacity(self.num_residuals());
        for run in runs {
            self.extend_residuals(run, &mut r);
        }
        r
    }

    /// Appends the residuals of one segment's run.
    pub fn extend_residuals(&self, run: &SegmentRun, r: &mut Vec<f64>) {
        let seg = &run.segment;
        for (o, j) in (seg.start + 1..=seg.end).enumerate() {
            let sim = run.positions_m.get(o);
            for &i in &self.free_nodes {
                let d = match sim {
                    Some(x) => x[i] - self.seq.positions_m[j][i],
                    None => Vector3::repeat(f64::NAN),
                };
                r.extend([d.x, d.y, d.z]);
            }
        }
    }

    /// Column k of the Jacobian ∂r/∂p_k of [`Self::residuals`] (same order) from the forward
    /// sensitivities of `runs` ([`Self::simulate_with_sensitivities`]; non-finite where a
    /// segment failed or has none).
    pub fn sensitivity_column(&self, runs: &[SegmentRun], k: usize) -> Vec<f64> {
        let mut out = Vec::with_capacity(self.num_residuals());
        for run in runs {
            let seg = &run.segment;
            let sens = run.sensitivities_m.get(k);
            for o in 0..seg.end - seg.start {
                let frame = sens.and_then(|s| s.get(o));
                for &i in &self.free_nodes {
                    let d = frame.map_or(Vector3::repeat(f64::NAN), |x| x[i]);
                    out.extend([d.x, d.y, d.z]);
                }
            }
        }
        out
    }

    /// Root-mean-square node distance of `runs` to the tracked positions, m (over the residuals).
    pub fn rms_m(&self, runs: &[SegmentRun]) -> f64 {
        let r = self.residuals(runs);
        let ss: f64 = r.iter().map(|v| v * v).sum();
        (3.0 * ss / r.len().max(1) as f64).sqrt()
    }
}

/// The free responses (f₁(t), f₂(t)) of q̈ + 2σ q̇ + ω² q = 0 with f₁(0) = 1, f₁'(0) = 0 and
/// f₂(0) = 0, f₂'(0) = 1 (under-, over- or critically damped).
fn free_response(omega: f64, sigma: f64, t: f64) -> nalgebra::Vector2<f64> {
    let d = omega * omega - sigma * sigma;
    let e = (-sigma * t).exp();
    let (c, s) = if d.abs() <= 1e-12 * omega * omega {
        (1.0, t)
    } else if d > 0.0 {
        let w = d.sqrt();
        ((w * t).cos(), (w * t).sin() / w)
    } else {
        let w = (-d).sqrt();
        ((w * t).cosh(), (w * t).sinh() / w)
    };
    nalgebra::Vector2::new(e * (c + sigma * s), e * s)
}

#[cfg(test)]
mod tests {
    use super::free_response;

    /// f₁, f₂ solve q̈ + 2σq̇ + ω²q = 0 (central differences) with f(0) = (1, 0), ḟ(0) = (0, 1),
    /// under-, over- and critically damped.
    #[test]
    fn free_responses_solve_the_damped_oscillator() {
        for (omega, sigma) in [(20.0, 0.7), (20.0, 35.0), (20.0, 20.0)] {
            let h = 1e-4;
            let f0 = free_response(omega, sigma, 0.0);
            let d0 = (free_response(omega, sigma, h) - free_response(omega, sigma, -h)) / (2.0 * h);
            assert!(
                (f0 - nalgebra::Vector2::new(1.0, 0.0)).norm() < 1e-12,
                "{f0}"
            );
            assert!(
                (d0 - nalgebra::Vector2::new(0.0, 1.0)).norm() < 1e-3, // central difference: h²/6 × f‴ ≈ 5e-5 at σ = 35 1/s
                "{d0}"
            );
            for t in [0.01, 0.05, 0.2] {
                let [a, b, c] = [t - h, t, t + h].map(|s| free_response(omega, sigma, s));
                let (d1, d2) = ((c - a) / (2.0 * h), (c - 2.0 * b + a) / (h * h));
                let r = d2 + 2.0 * sigma * d1 + omega * omega * b;
                assert!(
                    r.norm() < 1e-3 * omega * omega,
                    "ω {omega} σ {sigma} t {t}: {r}"
                );
            }
        }
    }
}
