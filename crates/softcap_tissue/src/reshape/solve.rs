//! The saito-barbic optimization (§3.3–3.6): Gauss–Newton over per-tet plastic strains with the
//! equilibrium constraint, in stages, with stopping rules.
//!
//! Objective (eq. 3–6, divided by the attachment stiffness so every term is in m²):
//!
//! E(s, x) = α/2 ‖L s‖² + ½ Σ_c ‖S_c x − p_c‖²,
//!
//! c over the active attachments (the spring energy E_a), landmarks and ICP markers (their
//! closest points on the current surface, recomputed after every iteration, eq. 5), subject to
//! the equilibrium x = x(s) ([`super::equilibrium`]). Stages (§3.4): a constant plastic strain
//! (one 6-vector for every tet) fitted to the attachments and landmarks as the initial guess;
//! then attachments only; + landmarks; attachments + ICP markers (+ landmarks unless
//! `icp_stage_landmarks` is off, as in the paper). A stage stops when (i) it reached
//! `max_iterations`, (ii) the largest error of its image constraints is below `error_tolerance_m`,
//! or (iii) an iteration lowered E by less than `relative_progress`.
//!
//! ICP rows ([`IcpRows`]): by default one point-to-plane row n·(x_q − p) per marker (n from the
//! closest point q to the marker p), whose value at the current iterate is eq. 5's distance but
//! whose linear model lets the surface slide along itself; line-search trials measure the true
//! closest-point distance. With the paper's point-to-point rows (α̂ = 1e-3, landmarks off) the ICP
//! stage of the known-truth box still progressed after 60 iterations (shape error p95 0.41 mm);
//! with point-to-plane rows it converges in 6.
//! Dropping the landmarks in the ICP stage leaves where the material lies on the fitted surface to
//! the smoothness term alone (known truth, α̂ = 1e-3: correspondence error 7.6 mm mean vs 0.69 mm
//! kept).
//!
//! Each iteration: factor K at x, Z = K⁻¹(Dᵀ)Gᵀ, gradient g = α∇E_s − Bᵀ Z W r, the step by
//! preconditioned CG (`step_solver = "pcg"`, the default) or the Woodbury identity
//! ([`super::step`]), then a line search along s + ηΔs (Brent's method on
//! (0, 1), §3.4; the full step is taken without a search when it achieves at least half the
//! decrease the quadratic model predicts — a shortcut that saves equilibrium solves), each trial
//! re-solving the equilibrium from the linear prediction x + ηJΔs. Plastic strains are kept
//! positive definite per tet by clamping eigenvalues below `plastic_eigenvalue_floor` (§3.4).
//! Free-flying objects alternate this step with the rigid block ([`super::gauge`]): the optimal
//! rigid transform at fixed shape (Horn for point-to-point rows, iterated linearized
//! point-to-plane steps otherwise). This block-coordinate descent (§3.6) converges linearly where
//! shape and pose are coupled; once a stage's block steps slow down (an iteration lowers the
//! objective by less than `BLOCK_PROGRESS`, 10 %, or finds no descent) the stage goes on with
//! joint Gauss–Newton steps over the plastic strains and the rigid frame together
//! (`joint_rigid_step`, each still followed by the rigid block) until those stall (rule (iii)).
//! Known-truth box, free-flying, default settings: ICP stage converged in 11 iterations, shape
//! error p95 0.42 mm (handing over only at rule (iii): 20-iteration cap, 0.56 mm).

use faer::Mat;
use nalgebra::{
    Isometry3, Matrix3, Point3, SMatrix, SymmetricEigen, Translation3, UnitQuaternion, Vector3,
    Vector6,
};
use serde::{Deserialize, Serialize};
use softcap_core::{BrentSettings, minimize_bounded};
use softcap_fem::{NeoHookeanParams, PlasticNeoHookeanModel, plastic_from_vector};
use softcap_mesh::{TetMesh, TetQuality, tet_quality};

use super::cv::{CrossValidationReport, CrossValidationSettings, Smoothness};
use super::equilibrium::{Equilibrium, EquilibriumOutcome, EquilibriumSettings};
use super::gauge::{
    Gauge, best_rigid, plane_rigid_step, project_out_modes, rigid_modes, three_two_one_pins,
};
use super::laplacian::PlasticLaplacian;
use super::problem::{ConstraintKind, IcpMarker, MaterialPoint, ReshapeProblem, SurfaceProjector};
use super::step::{
    ImplicitZ, NormalSystem, StepSolver, WoodburySolver, ZOperator, field_norm, forcing_term,
    pcg_step, woodbury_step,
};
use crate::error::{Result, TissueError};

/// The default α̂ (a bulky organ; see docs/reshape.md for a thin layer).
pub const DEFAULT_SMOOTHNESS: f64 = 3e-4;

/// Settings of [`reshape`] (TOML: `softcap tissue reshape --settings`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ReshapeSettings {
    /// α̂: smoothness weight α = α̂ L³ / h (L the template's bounding-box diagonal, h its mean
    /// edge length, so the continuum weight does not change with refinement); a number, or
    /// `"cv"`: chosen by k-fold cross-validation on held-out ICP markers or correspondences
    /// ([`super::cv`]).
    pub smoothness: Smoothness,
    /// The folds and α̂ grid of `smoothness = "cv"`.
    pub cross_validation: CrossValidationSettings,
    /// κ: attachment springs k = κ μ L (μ the elastic shear modulus).
    pub attachment_stiffness: f64,
    /// Poisson ratio of the elastic (stable neo-Hookean) part.
    pub poisson_ratio: f64,
    /// Iteration cap per stage (stopping rule (i)).
    pub max_iterations: usize,
    /// Iteration cap of the constant-plastic-strain initial guess.
    pub constant_iterations: usize,
    /// Stopping rule (ii): largest error of the stage's image constraints \[m\].
    pub error_tolerance_m: f64,
    /// Stopping rule (iii): relative decrease of the objective per iteration.
    pub relative_progress: f64,
    /// Smallest eigenvalue of a tet's plastic strain (§3.4: clamped to 0.01).
    pub plastic_eigenvalue_floor: f64,
    /// How an ICP marker's closest-point residual enters the Gauss–Newton model.
    pub icp_rows: IcpRows,
    /// Keep the landmarks in the ICP stage (the paper turns them off, §3.4). The ICP markers fix
    /// the shape but not where the material lies on it: without landmarks the surface is free to
    /// slide along itself, held only by the smoothness term.
    pub icp_stage_landmarks: bool,
    /// How each Gauss–Newton step is solved: `"pcg"` (inexact, preconditioned CG; the default)
    /// or `"woodbury"` (exact, §3.5).
    pub step_solver: StepSolver,
    /// η_max of the inexact step: CG stops at ‖M Δs + g‖ ≤ η ‖g‖ (also in the P⁻¹-norm) with
    /// η = min(η_max, √(‖g‖/‖g₀‖)), g₀ the stage's first gradient ([`forcing_term`]).
    pub step_forcing: f64,
    /// Cap on the CG iterations of one inexact step.
    pub step_cg_iterations: usize,
    /// Brent line search.
    pub line_search: BrentSettings,
    /// Newton equilibrium solves.
    pub equilibrium: EquilibriumSettings,
}

impl Default for ReshapeSettings {
    fn default() -> Self {
        Self {
            smoothness: Smoothness::Fixed(DEFAULT_SMOOTHNESS),
            cross_validation: CrossValidationSettings::default(),
            attachment_stiffness: 100.0,
            poisson_ratio: 0.4,
            max_iterations: 20,
            constant_iterations: 10,
            error_tolerance_m: 1e-4,
            relative_progress: 0.01,
            plastic_eigenvalue_floor: 0.01,
            icp_rows: IcpRows::PointToPlane,
            icp_stage_landmarks: true,
            step_solver: StepSolver::Pcg,
            step_forcing: 1e-4,
            step_cg_iterations: 500,
            line_search: BrentSettings {
                x_tolerance: 0.02,
                max_evaluations: 8,
            },
            equilibrium: EquilibriumSettings::default(),
        }
    }
}

/// The Gauss–Newton rows of an ICP marker p with closest surface point q (eq. 5).
///
/// Both give the objective the same value at the current iterate (for a closest point,
/// ‖q − p‖ = |n·(q − p)| with n = (p − q)/‖p − q‖, the surface normal where q is inside a face),
/// and both recompute q after every iteration; they differ in what the linear model resists.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum IcpRows {
    /// One row n·(x_q − p) (Chen and Medioni 1992): the surface may slide along itself, so the
    /// ICP stage converges in a few iterations.
    PointToPlane,
    /// Three rows x_q − p, the material point q held to p (the paper's eq. 5 as written): the
    /// model also resists sliding along the surface, so the stage converges linearly.
    PointToPoint,
}

/// Why a stage stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum StopReason {
    /// (ii) every image constraint within the tolerance.
    ErrorTolerance,
    /// (iii) an iteration lowered the objective by less than the relative threshold.
    SmallProgress,
    /// No step along the Gauss–Newton direction lowered the objective.
    NoDescent,
    /// (i) iteration cap.
    MaxIterations,
}

impl StopReason {
    /// Name in reports.
    pub fn name(self) -> &'static str {
        match self {
            Self::ErrorTolerance => "error-tolerance",
            Self::SmallProgress => "small-progress",
            Self::NoDescent => "no-descent",
            Self::MaxIterations => "max-iterations",
        }
    }

    /// Rules (ii)/(iii) (and a stationary point) count as converged; the iteration cap does not.
    pub fn converged(self) -> bool {
        self != Self::MaxIterations
    }
}

/// One stage of the schedule.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct Stage {
    name: &'static str,
    constant: bool,
    landmarks: bool,
    /// The stage uses the ICP markers (the last one).
    pub(super) icp: bool,
}

/// Summary of one stage.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StageReport {
    /// "constant", "attachments", "landmarks", "icp".
    pub name: String,
    /// Gauss–Newton iterations.
    pub iterations: usize,
    /// Why it stopped.
    pub stop: StopReason,
    /// Objective at the start \[m²\].
    pub objective_start: f64,
    /// Objective at the end \[m²\].
    pub objective_end: f64,
    /// Largest error of the stage's image constraints at the end \[m\].
    pub max_error_m: f64,
}

/// One Gauss–Newton iteration (the convergence history, saito-barbic Fig. 9).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct IterationRecord {
    /// Stage name.
    pub stage: String,
    /// Objective after the iteration \[m²\].
    pub objective: f64,
    /// Largest error of the stage's image constraints after the iteration \[m\].
    pub max_error_m: f64,
    /// Accepted step length η.
    pub step_length: f64,
    /// Equilibrium solves of the line search.
    pub equilibrium_solves: usize,
    /// CG iterations of the inexact step (0: exact step).
    #[serde(default)]
    pub step_iterations: usize,
}

/// Error of one constraint on the result.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ConstraintError {
    /// Kind.
    pub kind: ConstraintKind,
    /// Id from the input.
    pub id: String,
    /// Target \[m\].
    pub target_m: [f64; 3],
    /// The reshaped point (for ICP: the closest surface point) \[m\].
    pub achieved_m: [f64; 3],
    /// Distance \[m\].
    pub error_m: f64,
}

/// Overall status.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ReshapeStatus {
    /// The last stage stopped by a convergence rule.
    Converged,
    /// The last stage hit its iteration cap.
    MaxIterations,
}

/// The result of [`reshape`].
#[derive(Clone, Debug)]
pub struct ReshapeOutcome {
    /// Reshaped node positions \[m\] (world frame).
    pub positions_m: Vec<Vector3<f64>>,
    /// Plastic strain per tet (saito-barbic eq. 2 order: xx, yy, zz, xy, xz, yz).
    pub plastic: Vec<Vector6<f64>>,
    /// Stages in order.
    pub stages: Vec<StageReport>,
    /// Every iteration.
    pub history: Vec<IterationRecord>,
    /// Per-constraint errors on the result (attachments, landmarks, ICP markers).
    pub errors: Vec<ConstraintError>,
    /// Quality of the template.
    pub template_quality: TetQuality,
    /// Quality of the reshaped mesh.
    pub reshaped_quality: TetQuality,
    /// Status.
    pub status: ReshapeStatus,
    /// α̂ used (the setting, or the one cross-validation chose).
    pub smoothness: f64,
    /// α used \[m²\].
    pub alpha_m2: f64,
    /// The cross-validation that chose α̂ (`smoothness = "cv"`).
    pub cross_validation: Option<CrossValidationReport>,
}

impl ReshapeOutcome {
    /// The errors of the constraints of one kind \[m\], in input order.
    pub fn errors_of(&self, kind: ConstraintKind) -> Vec<f64> {
        self.errors
            .iter()
            .filter(|e| e.kind == kind)
            .map(|e| e.error_m)
            .collect()
    }
}

/// Point-to-plane rigid steps per rigid block (each recomputes the closest points).
const RIGID_STEPS: usize = 5;

/// Free-flying: the block-coordinate steps of §3.6 go on while each lowers the objective by at
/// least this fraction; below it (their linear regime) the stage goes on with joint steps
/// ([`joint_rigid_step`]). Known-truth box, default settings: from its fifth iteration on the ICP
/// stage's block steps lower the objective by 2–11 % per iteration (once 37 %) and had reached
/// 7.6e-6 m² at the 20-iteration cap (4.76e-6 after 100 with `relative_progress = 1e-5`); handing
/// over at 10 % the stage converges in 11 iterations to 4.65e-6. Joint steps from the first iteration stall at 1.12e-5
/// (a stationary point with a marker 1.7 mm off: far from the shape, the joint steps' large
/// pose corrections let markers snap to the wrong faces).
const BLOCK_PROGRESS: f64 = 0.1;

/// A constraint: material point, target (solver frame), weight, and for a point-to-plane ICP
/// row the unit direction along which its residual is measured (one scalar row instead of three).
#[derive(Clone, Copy, Debug)]
struct Row {
    point: MaterialPoint,
    target: Vector3<f64>,
    weight: f64,
    normal: Option<Vector3<f64>>,
}

impl Row {
    /// The directions of its scalar rows: x, y, z, or the normal alone.
    fn directions(&self) -> Vec<Vector3<f64>> {
        match self.normal {
            Some(n) => vec![n],
            None => vec![Vector3::x(), Vector3::y(), Vector3::z()],
        }
    }

    /// Squared residual at positions `x`.
    fn squared(&self, x: &[Vector3<f64>]) -> f64 {
        let d = self.point.at(x) - self.target;
        self.normal.map_or(d.norm_squared(), |n| n.dot(&d).powi(2))
    }
}

/// Scalar rows of `rows`: (row index, direction).
fn scalar_rows(rows: &[Row]) -> Vec<(usize, Vector3<f64>)> {
    rows.iter()
        .enumerate()
        .flat_map(|(c, r)| r.directions().into_iter().map(move |d| (c, d)))
        .collect()
}

/// The solver state: plastic strains, shape (canonical frame when free-flying) and frame.
#[derive(Clone, Debug)]
pub(super) struct State {
    s: Vec<Vector6<f64>>,
    x: Vec<Vector3<f64>>,
    frame: Isometry3<f64>,
}

/// Progress callback: (stage, iteration, objective, max error).
pub type ProgressFn<'a> = dyn FnMut(&str, usize, f64, f64) + 'a;

/// The solver of one problem; α̂ and the active ICP markers can change between runs of its
/// stages (cross-validation, [`super::cv`]).
pub(super) struct Solver<'p> {
    pub(super) problem: &'p ReshapeProblem,
    pub(super) settings: &'p ReshapeSettings,
    model: PlasticNeoHookeanModel,
    laplacian: PlasticLaplacian,
    equilibrium: Equilibrium,
    gauge: Option<Gauge>,
    /// The boundary triangles ICP markers project onto ([`ReshapeProblem::icp_surface`]).
    icp_surface: Vec<[usize; 3]>,
    /// The ICP markers the stages use (all of the problem's but during cross-validation).
    icp_markers: Vec<IcpMarker>,
    /// L³ / h: α = α̂ × this.
    alpha_scale: f64,
    smoothness: f64,
    alpha: f64,
    equilibrium_solves: usize,
    /// Free-flying: the current stage has handed over from block-coordinate steps (§3.6) to
    /// joint shape-and-pose steps ([`joint_rigid_step`]; module docs).
    joint_rigid: bool,
    /// ‖g₀‖, the first gradient of the current stage (the inexact step's forcing term); NaN
    /// before its first step.
    stage_gradient_norm: f64,
    /// CG iterations of the last inexact step.
    step_iterations: usize,
}

/// Reshapes `problem.template` (saito-barbic §3): see the module docs. Errors only for unusable
/// input or an equilibrium that cannot be solved even once; non-convergence is a status.
pub fn reshape(
    problem: &ReshapeProblem,
    settings: &ReshapeSettings,
    progress: &mut ProgressFn<'_>,
) -> Result<ReshapeOutcome> {
    let mut solver = Solver::new(problem, settings)?;
    let mut state = solver.initial_state()?;
    match settings.smoothness {
        Smoothness::Fixed(smoothness) => {
            solver.set_smoothness(smoothness)?;
            let mut history = Vec::new();
            let schedule = solver.schedule();
            let stages = solver.run_stages(&schedule, &mut state, &mut history, progress)?;
            Ok(solver.finish(state, stages, history, None))
        }
        Smoothness::CrossValidated => super::cv::cross_validated(solver, state, progress),
    }
}

impl<'p> Solver<'p> {
    fn new(problem: &'p ReshapeProblem, settings: &'p ReshapeSettings) -> Result<Self> {
        let mesh = &problem.template;
        let params = NeoHookeanParams::from_young_poisson(
            2.0 * (1.0 + settings.poisson_ratio),
            settings.poisson_ratio,
        )
        .map_err(|e| TissueError::BadSettings {
            field: "poisson_ratio".into(),
            problem: e.to_string(),
        })?;
        let model = PlasticNeoHookeanModel::homogeneous(mesh, params)?;
        let laplacian = PlasticLaplacian::new(&mesh.tets)?;
        let (diag, edge) = size_scales(mesh);
        let stiffness = settings.attachment_stiffness * params.mu * diag;
        let (pins, gauge) = if problem.free_flying {
            let boundary_nodes = mesh.surface_map().surface_to_volume;
            (
                three_two_one_pins(&mesh.vertices),
                Some(Gauge::new(boundary_nodes, &mesh.vertices)),
            )
        } else {
            (Vec::new(), None)
        };
        let attachments = problem
            .attachments
            .iter()
            .map(|a| (a.node, a.target_m))
            .collect();
        let equilibrium = Equilibrium::new(&model, attachments, stiffness, &pins)?;
        let icp_surface = match &problem.icp_surface {
            Some(faces) => {
                let n = mesh.vertices.len();
                if faces.is_empty() || faces.iter().flatten().any(|&v| v >= n) {
                    return Err(TissueError::BadSettings {
                        field: "icp_surface".into(),
                        problem: format!(
                            "{} triangles, some with a node outside the template's {n} nodes (or none)",
                            faces.len()
                        ),
                    });
                }
                faces.clone()
            }
            None => mesh.boundary_faces(),
        };
        Ok(Self {
            problem,
            settings,
            model,
            laplacian,
            equilibrium,
            gauge,
            icp_surface,
            icp_markers: problem.icp_markers.clone(),
            alpha_scale: diag.powi(3) / edge,
            smoothness: f64::NAN,
            alpha: f64::NAN,
            equilibrium_solves: 0,
            joint_rigid: true,
            stage_gradient_norm: f64::NAN,
            step_iterations: 0,
        })
    }

    /// Sets α̂ (α = α̂ L³ / h); it must be positive and finite.
    pub(super) fn set_smoothness(&mut self, smoothness: f64) -> Result<()> {
        if !(smoothness.is_finite() && smoothness > 0.0) {
            return Err(TissueError::BadSettings {
                field: "smoothness".into(),
                problem: format!("{smoothness}: α̂ must be a positive number (or \"cv\")"),
            });
        }
        self.smoothness = smoothness;
        self.alpha = smoothness * self.alpha_scale;
        Ok(())
    }

    /// The ICP markers the following stages use.
    pub(super) fn set_icp_markers(&mut self, markers: Vec<IcpMarker>) {
        self.icp_markers = markers;
    }

    /// Runs `stages` from `state` in order, appending to `history`.
    pub(super) fn run_stages(
        &mut self,
        stages: &[Stage],
        state: &mut State,
        history: &mut Vec<IterationRecord>,
        progress: &mut ProgressFn<'_>,
    ) -> Result<Vec<StageReport>> {
        stages
            .iter()
            .map(|&stage| self.run_stage(stage, state, history, progress))
            .collect()
    }

    /// Distance of each of `markers` to the ICP surface of `state` (world frame) \[m\].
    pub(super) fn marker_distances(&self, state: &State, markers: &[IcpMarker]) -> Vec<f64> {
        let world: Vec<Vector3<f64>> = state
            .x
            .iter()
            .map(|p| state.frame.transform_point(&Point3::from(*p)).coords)
            .collect();
        let projector = SurfaceProjector::new(&self.icp_surface, &world);
        markers
            .iter()
            .map(|m| {
                projector
                    .project(&m.position_m)
                    .map_or(f64::INFINITY, |(_, d)| d)
            })
            .collect()
    }

    /// The stages of §3.4 that have constraints.
    pub(super) fn schedule(&self) -> Vec<Stage> {
        let p = self.problem;
        let has_a = !p.attachments.is_empty();
        let has_l = !p.landmarks.is_empty();
        let mut out = Vec::new();
        if has_a || has_l {
            out.push(Stage {
                name: "constant",
                constant: true,
                landmarks: has_l,
                icp: false,
            });
        }
        if has_a {
            out.push(Stage {
                name: "attachments",
                constant: false,
                landmarks: false,
                icp: false,
            });
        }
        if has_l {
            out.push(Stage {
                name: "landmarks",
                constant: false,
                landmarks: true,
                icp: false,
            });
        }
        if !p.icp_markers.is_empty() {
            out.push(Stage {
                name: "icp",
                constant: false,
                landmarks: has_l && self.settings.icp_stage_landmarks,
                icp: true,
            });
        }
        out
    }

    /// s = I everywhere, the template (rigidly aligned to the landmarks when free-flying) in
    /// equilibrium.
    pub(super) fn initial_state(&mut self) -> Result<State> {
        let t = self.problem.template.tets.len();
        let mut state = State {
            s: vec![Vector6::new(1.0, 1.0, 1.0, 0.0, 0.0, 0.0); t],
            x: self.problem.template.vertices.clone(),
            frame: Isometry3::identity(),
        };
        if self.gauge.is_some() {
            let q: Vec<Vector3<f64>> = self
                .problem
                .landmarks
                .iter()
                .map(|l| l.point.at(&state.x))
                .collect();
            let p: Vec<Vector3<f64>> = self.problem.landmarks.iter().map(|l| l.target_m).collect();
            state.frame = best_rigid(&q, &p, &vec![1.0; q.len()]).ok_or_else(|| {
                TissueError::BadSettings {
                    field: "landmarks".into(),
                    problem:
                        "a free-flying reshape needs at least three landmarks for its initial \
                              rigid alignment"
                            .into(),
                }
            })?;
        }
        self.set_plastic(&state.s)?;
        let outcome = self.solve_equilibrium(&mut state.x);
        if !outcome.converged() {
            return Err(TissueError::NotConverged {
                what: "the template's equilibrium under its attachments".into(),
                status: format!("{outcome:?}"),
            });
        }
        Ok(state)
    }

    fn set_plastic(&mut self, s: &[Vector6<f64>]) -> Result<()> {
        let fp: Vec<Matrix3<f64>> = s.iter().map(plastic_from_vector).collect();
        self.model.set_plastic_gradients(&fp)?;
        Ok(())
    }

    /// Newton from `x`; canonicalizes a free-flying shape.
    fn solve_equilibrium(&mut self, x: &mut [Vector3<f64>]) -> EquilibriumOutcome {
        self.equilibrium_solves += 1;
        let outcome = self
            .equilibrium
            .solve(&self.model, x, &self.settings.equilibrium);
        if let Some(g) = &self.gauge {
            g.canonicalize(x);
        }
        outcome
    }

    /// The active constraint rows of `stage` at `state` (ICP closest points on the current
    /// surface), targets in the solver frame.
    fn rows(&self, stage: Stage, state: &State) -> Vec<Row> {
        self.rows_at(stage, &state.x, &state.frame)
    }

    /// [`Self::rows`] at shape `x` and frame `frame`.
    fn rows_at(&self, stage: Stage, x: &[Vector3<f64>], frame: &Isometry3<f64>) -> Vec<Row> {
        let to_frame = |p: &Vector3<f64>| frame.inverse_transform_point(&Point3::from(*p)).coords;
        let mut rows: Vec<Row> = self
            .problem
            .attachments
            .iter()
            .map(|a| Row {
                point: MaterialPoint::node(a.node),
                target: a.target_m,
                weight: 1.0,
                normal: None,
            })
            .collect();
        if stage.landmarks {
            rows.extend(self.problem.landmarks.iter().map(|l| Row {
                point: l.point,
                target: to_frame(&l.target_m),
                weight: 1.0,
                normal: None,
            }));
        }
        if stage.icp {
            let projector = SurfaceProjector::new(&self.icp_surface, x);
            for m in &self.icp_markers {
                let target = to_frame(&m.position_m);
                if let Some((point, _)) = projector.project(&target) {
                    let normal = match self.settings.icp_rows {
                        IcpRows::PointToPoint => None,
                        IcpRows::PointToPlane => Some(closest_point_normal(&point, &target, x)),
                    };
                    rows.push(Row {
                        point,
                        target,
                        weight: 1.0,
                        normal,
                    });
                }
            }
        }
        rows
    }

    /// Largest distance of the stage's image constraints (attachments only in the attachments
    /// stage; ICP closest points re-projected) at `state`.
    fn max_error(&self, stage: Stage, state: &State) -> f64 {
        let image = stage.landmarks || stage.icp;
        self.rows(stage, state)
            .iter()
            .skip(if image {
                self.problem.attachments.len()
            } else {
                0
            })
            .map(|r| (r.point.at(&state.x) - r.target).norm())
            .fold(0.0, f64::max)
    }

    fn objective(&self, s: &[Vector6<f64>], x: &[Vector3<f64>], rows: &[Row]) -> f64 {
        let data: f64 = rows.iter().map(|r| r.weight * r.squared(x)).sum();
        0.5 * self.alpha * self.laplacian.energy(s) + 0.5 * data
    }

    /// Gᵀ (3N × scalar rows) with the free-flying gauge, solved: Z = K⁻¹ (Dᵀ) Gᵀ at `x`.
    fn z_matrix(&self, x: &[Vector3<f64>], rows: &[Row]) -> Result<Mat<f64>> {
        let g = g_rows(rows);
        let all: Vec<usize> = (0..g.len()).collect();
        let mut z = g_transposed_columns(&g, x.len(), &all);
        if let Some(g) = &self.gauge {
            g.project_transposed_columns(x, &mut z);
        }
        self.equilibrium.solve_columns(&mut z)?;
        if self.gauge.is_some() {
            project_out_modes(&rigid_modes(x), &mut z);
        }
        Ok(z)
    }

    /// J v = −D K⁻¹ B v for a 3N right-hand side `bv` (B v).
    fn jacobian_times(&self, x: &[Vector3<f64>], bv: &[f64]) -> Result<Vec<Vector3<f64>>> {
        let mut m = Mat::from_fn(bv.len(), 1, |i, _| -bv[i]);
        self.equilibrium.solve_columns(&mut m)?;
        let mut v: Vec<Vector3<f64>> = (0..x.len())
            .map(|j| Vector3::new(m[(3 * j, 0)], m[(3 * j + 1, 0)], m[(3 * j + 2, 0)]))
            .collect();
        if let Some(g) = &self.gauge {
            g.project(x, &mut v);
        }
        Ok(v)
    }

    fn run_stage(
        &mut self,
        stage: Stage,
        state: &mut State,
        history: &mut Vec<IterationRecord>,
        progress: &mut ProgressFn<'_>,
    ) -> Result<StageReport> {
        let cap = if stage.constant {
            self.settings.constant_iterations
        } else {
            self.settings.max_iterations
        };
        let start = self.objective(&state.s, &state.x, &self.rows(stage, state));
        let mut report = StageReport {
            name: stage.name.into(),
            iterations: 0,
            stop: StopReason::MaxIterations,
            objective_start: start,
            objective_end: start,
            max_error_m: self.max_error(stage, state),
        };
        if !stage.constant && report.max_error_m <= self.settings.error_tolerance_m {
            report.stop = StopReason::ErrorTolerance;
            return Ok(report);
        }
        self.joint_rigid = false;
        self.stage_gradient_norm = f64::NAN;
        // Free-flying block-coordinate steps that slow down (less than `BLOCK_PROGRESS`) or find
        // no descent hand over to joint steps (module docs); `true` if the stage goes on.
        let hand_over = |solver: &mut Self| {
            let block = solver.gauge.is_some() && !stage.constant && !solver.joint_rigid;
            solver.joint_rigid = true;
            block
        };
        for it in 0..cap {
            let step = self.iteration(stage, state)?;
            report.iterations = it + 1;
            let Some(step) = step else {
                if hand_over(self) {
                    continue;
                }
                report.stop = StopReason::NoDescent;
                break;
            };
            let max_error = self.max_error(stage, state);
            report.objective_end = step.objective_after;
            report.max_error_m = max_error;
            history.push(IterationRecord {
                stage: stage.name.into(),
                objective: step.objective_after,
                max_error_m: max_error,
                step_length: step.eta,
                equilibrium_solves: step.solves,
                step_iterations: self.step_iterations,
            });
            progress(stage.name, it + 1, step.objective_after, max_error);
            if !stage.constant && max_error <= self.settings.error_tolerance_m {
                report.stop = StopReason::ErrorTolerance;
                break;
            }
            let decrease = (step.objective_before - step.objective_after)
                / step.objective_before.max(f64::MIN_POSITIVE);
            if decrease < BLOCK_PROGRESS.max(self.settings.relative_progress) && hand_over(self) {
                continue;
            }
            if decrease < self.settings.relative_progress {
                report.stop = StopReason::SmallProgress;
                break;
            }
        }
        Ok(report)
    }

    /// One Gauss–Newton iteration (+ rigid block when free-flying); `None` if no step length
    /// lowers the objective (the state is then unchanged).
    fn iteration(&mut self, stage: Stage, state: &mut State) -> Result<Option<AcceptedStep>> {
        let rows = self.rows(stage, state);
        let e0 = self.objective(&state.s, &state.x, &rows);
        let StepParts {
            jacobians,
            z,
            kept,
            weights,
            gradient,
        } = self.step_parts(stage, state, &rows)?;
        let tets = &self.problem.template.tets;
        let n = state.x.len();
        let mut rigid = None;
        let op = FactorZ {
            equilibrium: &self.equilibrium,
            g: g_rows(&rows),
            num_nodes: n,
        };
        let sys = NormalSystem {
            jacobians: &jacobians,
            tets,
            num_nodes: n,
            z: &z,
            implicit: kept.as_deref().map(|kept| ImplicitZ { kept, op: &op }),
            weights: &weights,
            gradient: &gradient,
            laplacian: &self.laplacian,
            alpha: self.alpha,
        };
        // The direction and the CG iterations it took (0 for the exact steps).
        let (direction, iterations) = if stage.constant {
            (constant_step(&sys), 0)
        } else if self.gauge.is_some() && self.joint_rigid {
            let ds = joint_rigid_step(&sys, &rows, &state.x, &state.frame).map(|(ds, motion)| {
                rigid = Some(motion);
                ds
            });
            (ds, 0)
        } else {
            gauss_newton_step(self.settings, &mut self.stage_gradient_norm, &sys)
        };
        self.step_iterations = iterations;
        let Some(ds) = direction else {
            return Ok(None);
        };
        let predicted = -0.5 * gradient.iter().zip(&ds).map(|(g, d)| g.dot(d)).sum::<f64>()
            - 0.5
                * rigid
                    .as_ref()
                    .map_or(0.0, |m: &RigidMotion| m.gradient.dot(&m.xi));
        let bds = element_b_times(&jacobians, tets, n, &ds);
        let jds = self.jacobian_times(&state.x, &bds)?;
        let accepted = self.line_search(stage, state, &rows, e0, predicted, &ds, &jds, rigid)?;
        let Some(mut step) = accepted else {
            self.set_plastic(&state.s)?;
            return Ok(None);
        };
        if self.gauge.is_some() {
            self.rigid_block(stage, state);
            // The objective of the accepted point after the rigid block.
            step.objective_after = self.objective(&state.s, &state.x, &self.rows(stage, state));
        }
        Ok(Some(step))
    }

    /// The rows whose columns of Z the step of `stage` forms (`None`: every row's), the whole of
    /// Z applied through the factor ([`ZOperator`]: two single-column sparse solves per product
    /// with M). The constant step needs Zᵀ B E alone (six solves instead of one per row; Table 1
    /// size: 1,044). The inexact step of an attached object keeps the image rows (landmarks,
    /// ICP markers): its preconditioner needs only the soft rows' columns ([`super::step::soft_rows`]), and
    /// the attachment rows, whose points the stiff springs hold, are never soft (known-truth
    /// box: w‖z_j‖² ≤ 1e-7 of the largest, the threshold 1e-4). First ICP step at Table 1 size
    /// (1,194 rows, 186 image rows, 155 soft; one thread, same load): forming every column
    /// 3.5 CPU-s vs the image rows' 0.45, each CG iteration 0.22 vs 0.14 CPU-s, step with Z to
    /// η = 1e-6 9.3 vs 6.5 CPU-s (benches/reshape.rs `SOFTCAP_RESHAPE_BENCH_DENSE_Z`). The
    /// exact step and free-flying objects (the gauge's projections) keep every column, and so
    /// does a stage with attachment rows only.
    fn kept_rows(&self, stage: Stage, rows: &[Row]) -> Option<Vec<usize>> {
        if self.gauge.is_some() {
            return None;
        }
        if stage.constant {
            return Some(Vec::new());
        }
        if self.settings.step_solver != StepSolver::Pcg {
            return None;
        }
        let image = image_rows(rows, self.problem.attachments.len());
        (!image.is_empty()).then_some(image)
    }

    /// The pieces of the Gauss–Newton normal equations of `stage` at `state` for `rows` (module
    /// docs).
    fn step_parts(&mut self, stage: Stage, state: &State, rows: &[Row]) -> Result<StepParts> {
        self.set_plastic(&state.s)?;
        self.equilibrium.factor_at(&self.model, &state.x)?;
        let jacobians = self.model.plastic_force_jacobians(&state.x);
        let kept = self.kept_rows(stage, rows);
        let op = FactorZ {
            equilibrium: &self.equilibrium,
            g: g_rows(rows),
            num_nodes: state.x.len(),
        };
        let z = match &kept {
            Some(kept) => op.columns(kept),
            None => self.z_matrix(&state.x, rows)?,
        };
        let scalars = scalar_rows(rows);
        let weights: Vec<f64> = scalars.iter().map(|(c, _)| rows[*c].weight).collect();
        let residual = Mat::<f64>::from_fn(scalars.len(), 1, |i, _| {
            let (c, d) = scalars[i];
            let r = &rows[c];
            d.dot(&(r.point.at(&state.x) - r.target)) * r.weight
        });
        let zr_mat = match kept {
            Some(_) => op.apply(residual.as_ref()),
            None => &z * &residual,
        };
        let zr: Vec<f64> = (0..zr_mat.nrows()).map(|i| zr_mat[(i, 0)]).collect();
        let tets = &self.problem.template.tets;
        let bt_zr: Vec<Vector6<f64>> = jacobians
            .iter()
            .zip(tets)
            .map(|(b, tet)| element_bt(b, tet, &zr))
            .collect();
        let smooth_gradient = self.laplacian.normal_apply(&state.s);
        let gradient: Vec<Vector6<f64>> = smooth_gradient
            .iter()
            .zip(&bt_zr)
            .map(|(l, b)| l * self.alpha - b)
            .collect();
        Ok(StepParts {
            jacobians,
            z,
            kept,
            weights,
            gradient,
        })
    }

    /// Brent line search along s + ηΔs (module docs); updates `state` on success.
    #[allow(clippy::too_many_arguments)]
    fn line_search(
        &mut self,
        stage: Stage,
        state: &mut State,
        rows: &[Row],
        e0: f64,
        predicted: f64,
        ds: &[Vector6<f64>],
        jds: &[Vector3<f64>],
        rigid: Option<RigidMotion>,
    ) -> Result<Option<AcceptedStep>> {
        let solves_before = self.equilibrium_solves;
        let mut best: Option<Trial> = None;
        let full = self.trial(stage, state, rows, ds, jds, rigid.as_ref(), 1.0)?;
        let full_value = full.as_ref().map_or(f64::INFINITY, |t| t.value);
        keep_best(&mut best, full);
        let good_full = predicted > 0.0 && e0 - full_value >= 0.5 * predicted;
        if !good_full {
            let mut trials: Vec<Trial> = Vec::new();
            let mut error = None;
            let brent = self.settings.line_search;
            minimize_bounded(
                |eta| match self.trial(stage, state, rows, ds, jds, rigid.as_ref(), eta) {
                    Ok(Some(t)) => {
                        let v = t.value;
                        trials.push(t);
                        v
                    }
                    Ok(None) => f64::INFINITY,
                    Err(e) => {
                        error = Some(e);
                        f64::INFINITY
                    }
                },
                0.0,
                1.0,
                &brent,
            );
            if let Some(e) = error {
                return Err(e);
            }
            for t in trials {
                keep_best(&mut best, Some(t));
            }
        }
        let solves = self.equilibrium_solves - solves_before;
        match best {
            Some(t) if t.value < e0 => {
                state.s = t.s;
                state.x = t.x;
                state.frame = t.frame;
                self.set_plastic(&state.s)?;
                Ok(Some(AcceptedStep {
                    eta: t.eta,
                    objective_before: e0,
                    objective_after: t.value,
                    solves,
                }))
            }
            _ => Ok(None),
        }
    }

    /// The objective at step length `eta` (`None` if the equilibrium does not converge).
    fn trial(
        &mut self,
        stage: Stage,
        state: &State,
        rows: &[Row],
        ds: &[Vector6<f64>],
        jds: &[Vector3<f64>],
        rigid: Option<&RigidMotion>,
        eta: f64,
    ) -> Result<Option<Trial>> {
        let floor = self.settings.plastic_eigenvalue_floor;
        let s: Vec<Vector6<f64>> = state
            .s
            .iter()
            .zip(ds)
            .map(|(s, d)| clamp_plastic(&(s + d * eta), floor))
            .collect();
        self.set_plastic(&s)?;
        let mut x: Vec<Vector3<f64>> = state.x.iter().zip(jds).map(|(x, d)| x + d * eta).collect();
        if !self.solve_equilibrium(&mut x).converged() {
            return Ok(None);
        }
        let frame = rigid.map_or(state.frame, |m| m.frame_at(&state.frame, eta));
        let value = match self.settings.icp_rows {
            // The linear model's planes are only a model: the value is the closest-point
            // distance (eq. 5) at the trial shape.
            IcpRows::PointToPlane if stage.icp => {
                self.objective(&s, &x, &self.rows_at(stage, &x, &frame))
            }
            // A moved frame moves the targets (solver frame) and the closest points.
            _ if rigid.is_some() => self.objective(&s, &x, &self.rows_at(stage, &x, &frame)),
            _ => self.objective(&s, &x, rows),
        };
        Ok(Some(Trial {
            eta,
            value,
            s,
            x,
            frame,
        }))
    }

    /// The rigid block of §3.6: the rigid transform for the current shape. Point-to-point rows:
    /// the optimal transform for the closest points of `stage` at the current shape (Horn).
    /// Point-to-plane rows: linearized point-to-plane steps ([`plane_rigid_step`]), each with the
    /// closest points recomputed, while they lower the objective (at most `RIGID_STEPS`).
    fn rigid_block(&self, stage: Stage, state: &mut State) {
        let skip = self.problem.attachments.len();
        if self.settings.icp_rows == IcpRows::PointToPoint {
            let rows = self.rows(stage, state);
            let image = &rows[skip..];
            let q: Vec<Vector3<f64>> = image.iter().map(|r| r.point.at(&state.x)).collect();
            let p: Vec<Vector3<f64>> = image
                .iter()
                .map(|r| state.frame.transform_point(&Point3::from(r.target)).coords)
                .collect();
            let w: Vec<f64> = image.iter().map(|r| r.weight).collect();
            if let Some(t) = best_rigid(&q, &p, &w) {
                state.frame = t;
            }
            return;
        }
        for _ in 0..RIGID_STEPS {
            let rows = self.rows(stage, state);
            let before = self.objective(&state.s, &state.x, &rows);
            let world: Vec<_> = scalar_rows(&rows[skip..])
                .into_iter()
                .map(|(c, d)| {
                    let r = &rows[skip + c];
                    let f = &state.frame;
                    (
                        f.transform_point(&Point3::from(r.point.at(&state.x)))
                            .coords,
                        f.rotation * d,
                        f.transform_point(&Point3::from(r.target)).coords,
                        r.weight,
                    )
                })
                .collect();
            let Some(frame) = plane_rigid_step(&world, &state.frame) else {
                return;
            };
            let previous = std::mem::replace(&mut state.frame, frame);
            let after = self.objective(&state.s, &state.x, &self.rows(stage, state));
            if after >= before {
                state.frame = previous;
                return;
            }
        }
    }

    pub(super) fn finish(
        mut self,
        state: State,
        stages: Vec<StageReport>,
        history: Vec<IterationRecord>,
        cross_validation: Option<CrossValidationReport>,
    ) -> ReshapeOutcome {
        let positions_m: Vec<Vector3<f64>> = state
            .x
            .iter()
            .map(|p| state.frame.transform_point(&Point3::from(*p)).coords)
            .collect();
        let errors = self.constraint_errors(&positions_m);
        let status = match stages.last() {
            Some(s) if !s.stop.converged() => ReshapeStatus::MaxIterations,
            _ => ReshapeStatus::Converged,
        };
        let _ = self.set_plastic(&state.s);
        ReshapeOutcome {
            template_quality: tet_quality(&self.problem.template, &self.problem.template.vertices),
            reshaped_quality: tet_quality(&self.problem.template, &positions_m),
            positions_m,
            plastic: state.s,
            stages,
            history,
            errors,
            status,
            smoothness: self.smoothness,
            alpha_m2: self.alpha,
            cross_validation,
        }
    }

    fn constraint_errors(&self, x: &[Vector3<f64>]) -> Vec<ConstraintError> {
        let p = self.problem;
        let entry =
            |kind, id: &str, target: Vector3<f64>, achieved: Vector3<f64>| ConstraintError {
                kind,
                id: id.to_string(),
                target_m: target.into(),
                achieved_m: achieved.into(),
                error_m: (achieved - target).norm(),
            };
        let mut out: Vec<ConstraintError> = p
            .attachments
            .iter()
            .map(|a| entry(ConstraintKind::Attachment, &a.id, a.target_m, x[a.node]))
            .collect();
        out.extend(
            p.landmarks
                .iter()
                .map(|l| entry(ConstraintKind::Landmark, &l.id, l.target_m, l.point.at(x))),
        );
        let projector = SurfaceProjector::new(&self.icp_surface, x);
        out.extend(p.icp_markers.iter().filter_map(|m| {
            let (point, _) = projector.project(&m.position_m)?;
            Some(entry(ConstraintKind::Icp, &m.id, m.position_m, point.at(x)))
        }));
        out
    }
}

/// The pieces of one Gauss–Newton step's normal equations ([`NormalSystem`]).
struct StepParts {
    jacobians: Vec<SMatrix<f64, 12, 6>>,
    /// Z's columns: every row's, or those of `kept`.
    z: Mat<f64>,
    /// The rows whose columns `z` holds when not every row's (`Solver::kept_rows`).
    kept: Option<Vec<usize>>,
    weights: Vec<f64>,
    gradient: Vec<Vector6<f64>>,
}

/// The normal equations of the first Gauss–Newton step of the ICP stage of `problem` (from the
/// template with s = I; every constraint active), owned: the same system for the Woodbury solve
/// and for CG in the benches (saito-barbic Table 1).
pub struct FirstStep {
    parts: StepParts,
    /// Z through the factor at the step's state (`parts` keeps the image rows' columns).
    op: FactorZ<Equilibrium>,
    tets: Vec<[usize; 4]>,
    num_nodes: usize,
    laplacian: PlasticLaplacian,
    alpha: f64,
}

impl FirstStep {
    /// Builds the system as the reshape does (one equilibrium solve, one factorization, the
    /// columns of Z for the image rows with the inexact step, for every row otherwise; the rest
    /// of Z through the factor).
    pub fn new(problem: &ReshapeProblem, settings: &ReshapeSettings) -> Result<Self> {
        let mut solver = Solver::new(problem, settings)?;
        // Cross-validation would run whole reshapes: the step is built at the default α̂.
        solver.set_smoothness(settings.smoothness.fixed().unwrap_or(DEFAULT_SMOOTHNESS))?;
        let state = solver.initial_state()?;
        let stage = Stage {
            name: "icp",
            constant: false,
            landmarks: !problem.landmarks.is_empty(),
            icp: true,
        };
        let rows = solver.rows(stage, &state);
        let parts = solver.step_parts(stage, &state, &rows)?;
        Ok(Self {
            parts,
            op: FactorZ {
                g: g_rows(&rows),
                num_nodes: state.x.len(),
                equilibrium: solver.equilibrium,
            },
            tets: problem.template.tets.clone(),
            num_nodes: state.x.len(),
            laplacian: solver.laplacian,
            alpha: solver.alpha,
        })
    }

    /// The system for [`woodbury_step`] and [`super::step::cg_step`].
    pub fn system(&self) -> NormalSystem<'_> {
        NormalSystem {
            jacobians: &self.parts.jacobians,
            tets: &self.tets,
            num_nodes: self.num_nodes,
            z: &self.parts.z,
            implicit: self
                .parts
                .kept
                .as_deref()
                .map(|kept| ImplicitZ { kept, op: &self.op }),
            weights: &self.parts.weights,
            gradient: &self.parts.gradient,
            laplacian: &self.laplacian,
            alpha: self.alpha,
        }
    }

    /// Number of scalar constraint rows.
    pub fn rows(&self) -> usize {
        self.parts.weights.len()
    }
}

/// A line-search point.
struct Trial {
    eta: f64,
    value: f64,
    s: Vec<Vector6<f64>>,
    x: Vec<Vector3<f64>>,
    frame: Isometry3<f64>,
}

/// The rigid part of a free-flying Gauss–Newton step ([`joint_rigid_step`]): the motion
/// y ↦ exp(η\[ω\]×)(y − c) + c + η t of the world frame (ξ = (ω, t)) and the objective's
/// gradient with respect to ξ.
#[derive(Clone, Copy, Debug)]
struct RigidMotion {
    center: Vector3<f64>,
    xi: Vector6<f64>,
    gradient: Vector6<f64>,
}

impl RigidMotion {
    /// The frame after the motion at step length `eta`, applied after `frame`.
    fn frame_at(&self, frame: &Isometry3<f64>, eta: f64) -> Isometry3<f64> {
        let rotation = UnitQuaternion::from_scaled_axis(self.xi.fixed_rows::<3>(0) * eta);
        let translation = self.center - rotation * self.center + self.xi.fixed_rows::<3>(3) * eta;
        Isometry3::from_parts(Translation3::from(translation), rotation) * frame
    }
}

/// The Gauss–Newton step of a free-flying object over the plastic strains *and* the rigid
/// frame together (§3.6 solves the two blocks alternately; the block-coordinate descent
/// converges linearly where shape and pose are coupled). With the rigid motion ξ = (ω, t) of the
/// world frame about the rows' centroid c, a scalar row (direction d, world point y, weight w)
/// changes by R_i ξ, R_i = ((y − c) × d_w, d_w), d_w the direction in the world. The normal
/// equations
///
/// \[M, H; Hᵀ, RᵀWR\] (Δs, ξ) = −(g, RᵀWr),  H = VᵀWR = −BᵀZWR,
///
/// are solved by the Schur complement on ξ: Δs = −M⁻¹g − M⁻¹H ξ with
/// (RᵀWR − HᵀM⁻¹H) ξ = −(RᵀWr − HᵀM⁻¹g). M⁻¹ is the Woodbury solve of eq. 14 with its small
/// matrix factored once for the seven right-hand sides ([`WoodburySolver`]).
fn joint_rigid_step(
    sys: &NormalSystem<'_>,
    rows: &[Row],
    x: &[Vector3<f64>],
    frame: &Isometry3<f64>,
) -> Option<(Vec<Vector6<f64>>, RigidMotion)> {
    let scalars = scalar_rows(rows);
    let world: Vec<(Vector3<f64>, Vector3<f64>)> = scalars
        .iter()
        .map(|&(c, d)| {
            let y = frame
                .transform_point(&Point3::from(rows[c].point.at(x)))
                .coords;
            (y, frame.rotation * d)
        })
        .collect();
    let total: f64 = sys.weights.iter().sum();
    if scalars.len() < 6 || total <= 0.0 {
        return None;
    }
    let center = world
        .iter()
        .zip(sys.weights)
        .map(|((y, _), w)| y * *w)
        .sum::<Vector3<f64>>()
        / total;
    let r_rows: Vec<Vector6<f64>> = world
        .iter()
        .map(|(y, d)| Vector6::from_iterator((y - center).cross(d).iter().chain(d.iter()).copied()))
        .collect();
    // RᵀWR and RᵀWr.
    let mut rwr = nalgebra::Matrix6::<f64>::zeros();
    let mut rwres = Vector6::<f64>::zeros();
    for (i, &(c, d)) in scalars.iter().enumerate() {
        let w = sys.weights[i];
        let r = d.dot(&(rows[c].point.at(x) - rows[c].target));
        rwr += r_rows[i] * r_rows[i].transpose() * w;
        rwres += r_rows[i] * (r * w);
    }
    // H = −Bᵀ Z (W R): six 6-vector fields.
    let wr = Mat::<f64>::from_fn(scalars.len(), 6, |i, j| sys.weights[i] * r_rows[i][j]);
    let zwr = sys.z_times(wr.as_ref());
    let bt = sys.bt_times(zwr.as_ref());
    let h: Vec<Vec<Vector6<f64>>> = (0..6)
        .map(|j| {
            (0..sys.jacobians.len())
                .map(|e| Vector6::from_fn(|k, _| -bt[(e, 6 * j + k)]))
                .collect()
        })
        .collect();
    let solver = WoodburySolver::new(sys)?;
    let minus_g: Vec<Vector6<f64>> = sys.gradient.iter().map(|g| -g).collect();
    let a = solver.solve(&minus_g)?;
    let b: Vec<Vec<Vector6<f64>>> = h.iter().map(|hj| solver.solve(hj)).collect::<Option<_>>()?;
    let dot = |u: &[Vector6<f64>], v: &[Vector6<f64>]| {
        u.iter().zip(v).map(|(p, q)| p.dot(q)).sum::<f64>()
    };
    let schur = nalgebra::Matrix6::<f64>::from_fn(|i, j| rwr[(i, j)] - dot(&h[i], &b[j]));
    let rhs = Vector6::<f64>::from_fn(|i, _| -(rwres[i] + dot(&h[i], &a)));
    let xi = schur.cholesky()?.solve(&rhs);
    if !xi.iter().all(|v| v.is_finite()) {
        return None;
    }
    let ds: Vec<Vector6<f64>> = a
        .iter()
        .enumerate()
        .map(|(e, ae)| ae - (0..6).map(|j| b[j][e] * xi[j]).sum::<Vector6<f64>>())
        .collect();
    Some((
        ds,
        RigidMotion {
            center,
            xi,
            gradient: rwres,
        },
    ))
}

/// Δs of an ordinary Gauss–Newton step by `settings.step_solver` and its CG iterations:
/// exact (Woodbury; 0 iterations) or inexact (CG preconditioned by the Woodbury base to the
/// forcing term of [`forcing_term`] relative to ‖g₀‖, `stage_gradient_norm`, set from `sys` at
/// the stage's first step).
fn gauss_newton_step(
    settings: &ReshapeSettings,
    stage_gradient_norm: &mut f64,
    sys: &NormalSystem<'_>,
) -> (Option<Vec<Vector6<f64>>>, usize) {
    match settings.step_solver {
        StepSolver::Woodbury => (woodbury_step(sys), 0),
        StepSolver::Pcg => {
            let norm = field_norm(sys.gradient);
            if stage_gradient_norm.is_nan() {
                *stage_gradient_norm = norm;
            }
            let eta = forcing_term(settings.step_forcing, norm, *stage_gradient_norm);
            let cg = pcg_step(sys, eta, settings.step_cg_iterations);
            let finite = cg.step.iter().all(|s| s.iter().all(|v| v.is_finite()));
            let ds = (cg.iterations > 0 && finite).then_some(cg.step);
            (ds, cg.iterations)
        }
    }
}

/// The scalar rows of the image constraints (landmarks, ICP markers): those after the first
/// `attachments` rows of `rows`.
fn image_rows(rows: &[Row], attachments: usize) -> Vec<usize> {
    scalar_rows(rows)
        .iter()
        .enumerate()
        .filter(|(_, (c, _))| *c >= attachments)
        .map(|(j, _)| j)
        .collect()
}

/// A row of G: the material point and the direction of a scalar constraint row.
type GRow = (MaterialPoint, Vector3<f64>);

/// The rows of G for `rows` (one per scalar row, [`scalar_rows`] order).
fn g_rows(rows: &[Row]) -> Vec<GRow> {
    scalar_rows(rows)
        .into_iter()
        .map(|(c, d)| (rows[c].point, d))
        .collect()
}

/// Gᵀ restricted to the columns of `which` (3N × which.len()).
fn g_transposed_columns(g: &[GRow], num_nodes: usize, which: &[usize]) -> Mat<f64> {
    let mut out = Mat::<f64>::zeros(3 * num_nodes, which.len());
    for (col, &j) in which.iter().enumerate() {
        let (point, d) = &g[j];
        for k in 0..4 {
            for i in 0..3 {
                out[(3 * point.nodes[k] + i, col)] += point.weights[k] * d[i];
            }
        }
    }
    out
}

/// Z = K⁻¹ Gᵀ of an attached object (no gauge: no pinned dofs, no projections) through the
/// equilibrium factor ([`Equilibrium::solve_columns`], multi-column sparse solves).
struct FactorZ<E> {
    equilibrium: E,
    g: Vec<GRow>,
    num_nodes: usize,
}

impl<E: std::borrow::Borrow<Equilibrium> + Sync> FactorZ<E> {
    /// K⁻¹ applied to the columns of `m` in place; NaN where the solve fails (a factor is
    /// always there when Z is: a failure is reported by CG's non-finite curvature).
    fn solve(&self, m: &mut Mat<f64>) {
        if self.equilibrium.borrow().solve_columns(m).is_err() {
            m.fill(f64::NAN);
        }
    }
}

impl<E: std::borrow::Borrow<Equilibrium> + Sync> ZOperator for FactorZ<E> {
    fn transpose_apply(&self, u: faer::MatRef<'_, f64>) -> Mat<f64> {
        let mut y = u.to_owned();
        self.solve(&mut y);
        Mat::from_fn(self.g.len(), u.ncols(), |j, c| {
            let (point, d) = &self.g[j];
            let col = y.col(c);
            (0..4)
                .map(|k| {
                    let n = point.nodes[k];
                    point.weights[k]
                        * (d[0] * col[3 * n] + d[1] * col[3 * n + 1] + d[2] * col[3 * n + 2])
                })
                .sum()
        })
    }

    fn apply(&self, c: faer::MatRef<'_, f64>) -> Mat<f64> {
        let mut out = Mat::<f64>::zeros(3 * self.num_nodes, c.ncols());
        for m in 0..c.ncols() {
            for (j, (point, d)) in self.g.iter().enumerate() {
                let v = c[(j, m)];
                for k in 0..4 {
                    for i in 0..3 {
                        out[(3 * point.nodes[k] + i, m)] += point.weights[k] * d[i] * v;
                    }
                }
            }
        }
        self.solve(&mut out);
        out
    }

    fn columns(&self, rows: &[usize]) -> Mat<f64> {
        let mut z = g_transposed_columns(&self.g, self.num_nodes, rows);
        self.solve(&mut z);
        z
    }
}

/// Keeps the lower of `best` and `candidate`.
fn keep_best(best: &mut Option<Trial>, candidate: Option<Trial>) {
    if let Some(c) = candidate
        && c.value.is_finite()
        && best.as_ref().is_none_or(|b| c.value < b.value)
    {
        *best = Some(c);
    }
}

/// An accepted line-search point.
#[derive(Clone, Copy, Debug)]
struct AcceptedStep {
    eta: f64,
    objective_before: f64,
    objective_after: f64,
    solves: usize,
}

/// B_eᵀ v restricted to the tet's 12 dofs.
fn element_bt(b: &SMatrix<f64, 12, 6>, tet: &[usize; 4], v: &[f64]) -> Vector6<f64> {
    let mut local = SMatrix::<f64, 12, 1>::zeros();
    for (a, &node) in tet.iter().enumerate() {
        for i in 0..3 {
            local[3 * a + i] = v[3 * node + i];
        }
    }
    b.transpose() * local
}

/// B v (3N) for a 6-vector field v.
fn element_b_times(
    jacobians: &[SMatrix<f64, 12, 6>],
    tets: &[[usize; 4]],
    n: usize,
    v: &[Vector6<f64>],
) -> Vec<f64> {
    let mut out = vec![0.0; 3 * n];
    for ((b, tet), s) in jacobians.iter().zip(tets).zip(v) {
        let f = b * s;
        for (a, &node) in tet.iter().enumerate() {
            for i in 0..3 {
                out[3 * node + i] += f[3 * a + i];
            }
        }
    }
    out
}

/// The Gauss–Newton step restricted to a constant plastic strain (one 6-vector σ for every tet,
/// the initial guess of §3.4): (V_σᵀ W V_σ) Δσ = −Σ_e g_e with V_σ = −Zᵀ B E.
fn constant_step(sys: &NormalSystem<'_>) -> Option<Vec<Vector6<f64>>> {
    let (jacobians, weights, gradient) = (sys.jacobians, sys.weights, sys.gradient);
    let mut be = Mat::<f64>::zeros(3 * sys.num_nodes, 6);
    for (b, tet) in jacobians.iter().zip(sys.tets) {
        for (a, &node) in tet.iter().enumerate() {
            for i in 0..3 {
                for k in 0..6 {
                    be[(3 * node + i, k)] += b[(3 * a + i, k)];
                }
            }
        }
    }
    let v = sys.zt_times(be.as_ref());
    let mut normal = nalgebra::Matrix6::<f64>::zeros();
    for i in 0..v.nrows() {
        for a in 0..6 {
            for b in 0..6 {
                normal[(a, b)] += weights[i] * v[(i, a)] * v[(i, b)];
            }
        }
    }
    let g: Vector6<f64> = gradient.iter().sum();
    let step = normal.cholesky()?.solve(&(-g));
    step.iter()
        .all(|v| v.is_finite())
        .then(|| vec![step; jacobians.len()])
}

/// s with its symmetric matrix's eigenvalues clamped to ≥ `floor` (F_p positive definite, §3.4).
pub fn clamp_plastic(s: &Vector6<f64>, floor: f64) -> Vector6<f64> {
    let m = plastic_from_vector(s);
    let eig = SymmetricEigen::new(m);
    if eig.eigenvalues.iter().all(|&l| l >= floor) {
        return *s;
    }
    let clamped = eig.eigenvalues.map(|l| l.max(floor));
    let m = eig.eigenvectors * Matrix3::from_diagonal(&clamped) * eig.eigenvectors.transpose();
    softcap_fem::plastic_to_vector(&m)
}

/// (bounding-box diagonal, mean edge length) of the template.
fn size_scales(mesh: &TetMesh) -> (f64, f64) {
    let (mut lo, mut hi) = (
        Vector3::repeat(f64::INFINITY),
        Vector3::repeat(f64::NEG_INFINITY),
    );
    for p in &mesh.vertices {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    let mut total = 0.0;
    let mut count = 0usize;
    for t in &mesh.tets {
        for a in 0..4 {
            for b in a + 1..4 {
                total += (mesh.vertices[t[a]] - mesh.vertices[t[b]]).norm();
                count += 1;
            }
        }
    }
    ((hi - lo).norm(), total / count.max(1) as f64)
}

/// Unit direction from the closest point `q` (on the surface at `x`) to the marker `p`; the face
/// normal when p lies on the surface.
fn closest_point_normal(q: &MaterialPoint, p: &Vector3<f64>, x: &[Vector3<f64>]) -> Vector3<f64> {
    let d = p - q.at(x);
    let [a, b, c] = [0, 1, 2].map(|k| x[q.nodes[k]]);
    let face = (b - a).cross(&(c - a));
    let scale = (b - a).norm().max((c - a).norm());
    if d.norm() > 1e-9 * scale {
        d.normalize()
    } else {
        face.try_normalize(0.0).unwrap_or_else(Vector3::z)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A deterministic pseudo-random number in (−1, 1).
    fn noise(i: usize) -> f64 {
        ((i as f64 * 12.9898).sin() * 43758.5453).fract()
    }

    /// The joint step solves the augmented normal equations
    /// \[M, VᵀWR; RᵀWV, RᵀWR\] (Δs, ξ) = −(g, RᵀWr), checked against the dense system built
    /// column by column (M from the Laplacian and V = −ZᵀB), and its ξ is the rigid motion's.
    #[test]
    fn joint_rigid_step_solves_the_augmented_normal_equations() {
        let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [1.0, 0.7, 0.5], [2, 2, 1]);
        let laplacian = PlasticLaplacian::new(&mesh.tets).unwrap();
        let (t, n) = (mesh.tets.len(), mesh.vertices.len());
        let x: Vec<Vector3<f64>> = mesh
            .vertices
            .iter()
            .enumerate()
            .map(|(i, v)| v + Vector3::new(noise(3 * i), noise(3 * i + 1), noise(3 * i + 2)) * 0.05)
            .collect();
        // Four point rows (three scalar rows each) and three plane rows.
        let rows: Vec<Row> = (0..7)
            .map(|c| Row {
                point: MaterialPoint::node((5 * c + 1) % n),
                target: Vector3::new(noise(50 + c), noise(60 + c), noise(70 + c)),
                weight: 0.5 + 0.2 * c as f64,
                normal: (c >= 4)
                    .then(|| Vector3::new(noise(80 + c), noise(90 + c), 1.0).normalize()),
            })
            .collect();
        let scalars = scalar_rows(&rows);
        let m = scalars.len();
        let weights: Vec<f64> = scalars.iter().map(|(c, _)| rows[*c].weight).collect();
        let jacobians: Vec<SMatrix<f64, 12, 6>> = (0..t)
            .map(|e| SMatrix::from_fn(|i, j| noise(1000 * e + 12 * j + i)))
            .collect();
        let z = Mat::from_fn(3 * n, m, |i, j| noise(7 + 31 * i + 1013 * j));
        let gradient: Vec<Vector6<f64>> = (0..t)
            .map(|e| Vector6::from_fn(|k, _| noise(99_991 + 6 * e + k)))
            .collect();
        let alpha = 0.3;
        let sys = NormalSystem {
            jacobians: &jacobians,
            tets: &mesh.tets,
            num_nodes: n,
            z: &z,
            implicit: None,
            weights: &weights,
            gradient: &gradient,
            laplacian: &laplacian,
            alpha,
        };
        let frame = Isometry3::new(Vector3::new(0.1, -0.2, 0.3), Vector3::new(0.2, 0.1, -0.3));
        let (ds, motion) = joint_rigid_step(&sys, &rows, &x, &frame).unwrap();
        // Dense V (m × 6T), R (m × 6), M = α A₀ + VᵀWV.
        let u = 6 * t;
        let mut v = Mat::<f64>::zeros(m, u);
        let mut a0 = Mat::<f64>::zeros(u, u);
        for j in 0..u {
            let mut unit = vec![Vector6::zeros(); t];
            unit[j / 6][j % 6] = 1.0;
            let b = element_b_times(&jacobians, &mesh.tets, n, &unit);
            for i in 0..m {
                v[(i, j)] = -(0..3 * n).map(|k| z[(k, i)] * b[k]).sum::<f64>();
            }
            for (e, l) in laplacian.normal_apply(&unit).iter().enumerate() {
                for k in 0..6 {
                    a0[(6 * e + k, j)] = alpha * l[k];
                }
            }
        }
        let c = motion.center;
        let mut r = Mat::<f64>::zeros(m, 6);
        let mut res = vec![0.0; m];
        for (i, &(row, d)) in scalars.iter().enumerate() {
            let q = rows[row].point.at(&x);
            let y = frame.transform_point(&Point3::from(q)).coords;
            let dw = frame.rotation * d;
            let ri = (y - c).cross(&dw);
            for k in 0..3 {
                r[(i, k)] = ri[k];
                r[(i, 3 + k)] = dw[k];
            }
            res[i] = d.dot(&(q - rows[row].target));
        }
        let w = Mat::from_fn(m, m, |i, j| if i == j { weights[i] } else { 0.0 });
        let big = Mat::from_fn(u + 6, u + 6, |i, j| {
            let col = |k: usize| {
                if k < u {
                    v.col(k).to_owned()
                } else {
                    r.col(k - u).to_owned()
                }
            };
            let base = if i < u && j < u { a0[(i, j)] } else { 0.0 };
            let ci = col(i);
            let cj = col(j);
            base + (0..m).map(|k| ci[k] * w[(k, k)] * cj[k]).sum::<f64>()
        });
        let mut rhs = vec![0.0; u + 6];
        for e in 0..t {
            for k in 0..6 {
                rhs[6 * e + k] = -gradient[e][k];
            }
        }
        for k in 0..6 {
            rhs[u + k] = -(0..m).map(|i| r[(i, k)] * weights[i] * res[i]).sum::<f64>();
        }
        let sol = Mat::from_fn(u + 6, 1, |i, _| {
            if i < u {
                ds[i / 6][i % 6]
            } else {
                motion.xi[i - u]
            }
        });
        let lhs = &big * &sol;
        let scale = rhs.iter().fold(0.0f64, |a, b| a.max(b.abs()));
        for i in 0..u + 6 {
            let e = (lhs[(i, 0)] - rhs[i]).abs();
            assert!(e < 1e-8 * scale, "row {i}: residual {e} (scale {scale})");
        }
        for k in 0..6 {
            assert!((motion.gradient[k] + rhs[u + k]).abs() < 1e-12 * scale.max(1.0));
        }
    }
}
