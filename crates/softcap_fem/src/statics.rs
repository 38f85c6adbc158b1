//! Static equilibrium: the equilibrium iterations and incremental loading of bickel2009 §3.4, and a
//! Newton solver with line search (used with the stable neo-Hookean model).
//!
//! Every iteration solves, over the free DOFs (constraints eliminated),
//!
//! A Δx = f_ext + f_c(x) − f_int(x),  x ← x + s Δx,
//!
//! where A is the assembled element matrix plus contact springs k n nᵀ. With
//! [`StiffnessKind::Warped`] (default) A = K(x) = Σ R_e K_e R_eᵀ and one full step is exactly the
//! paper's update x ← K⁻¹(F + K′X) (bickel2009 eq. 10, since f_int = K x − K′X): the quasi-static
//! fixed-point iteration of §3.4, where the parameters p_e(ε_e) are refreshed from the current
//! strain at the start of each iteration ([`ElasticModel::update_state`]). With
//! [`StiffnessKind::Consistent`] it is Newton's method. The step length s comes from backtracking:
//! on the energy (Armijo) when the model has one, otherwise on the residual norm;
//! if no step decreases the merit the full step is taken (fixed-point behaviour). With a probe the
//! energy includes the contact penalty ½ Σ k_c depth² (see [`StaticSolver::solve`]).

use crate::FemError;
use crate::assembly::{
    AssemblyScratch, DirichletBc, DofMap, SparseCholesky, SystemPattern, contact_residual,
    solver_setup,
};
use crate::contact::{ContactProblem, ContactReport, ContactSpring};
use crate::element::StiffnessKind;
use crate::model::ElasticModel;
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

/// Settings of the equilibrium iterations.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EquilibriumSettings {
    /// Maximum iterations per solve.
    pub max_iterations: usize,
    /// Converged when ‖Δx‖_∞ ≤ this × (bounding-box diagonal of the rest mesh) …
    pub displacement_tol_rel: f64,
    /// … and ‖r‖₂ ≤ this × max(‖f_ext‖₂, ‖f_int‖₂, ‖f_c‖₂) (or the residual is exactly tiny).
    pub residual_tol_rel: f64,
    /// Matrix used in the iterations.
    pub stiffness: StiffnessKind,
    /// Backtracking line search on/off.
    pub line_search: bool,
    /// Maximum number of step halvings.
    pub max_halvings: usize,
    /// Contact active set (and each spring's closest point / normal) is re-queried at every
    /// iteration up to this many, then frozen, so that nodes at the rim of the contact patch cannot
    /// chatter in and out forever; the remaining iterations converge the frozen linear force field.
    pub contact_freeze_after: usize,
    /// When the system matrix is refactored (default: at every iterate).
    #[serde(default)]
    pub refactorization: Refactorization,
}

/// [`Refactorization::WhenStale`]: a reused factor is stale when its iteration reduced the
/// residual norm to more than this fraction of the previous one (the modified Newton of
/// [`StaticSolver::solve`] and [`crate::NodalSolver::solve`]).
pub(crate) const STALE_CONTRACTION: f64 = 0.25;

/// When the equilibrium iterations assemble and factor the system matrix A.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum Refactorization {
    /// Assemble and factor A at every iterate; after a solve, [`StaticSolver::cholesky`] holds A at
    /// the solution (what a tangent response ∂x/∂f needs).
    #[default]
    EveryIteration,
    /// Modified Newton for interactive loops (many small load steps, e.g. a probe advancing a
    /// fraction of a millimetre per frame): the numeric factor is kept across iterations *and
    /// across solves* and reused while it still contracts. A is re-assembled and refactored only
    /// when there is no factor, the contact active set (the set of spring nodes) differs from the
    /// factored one, or an iteration left the residual norm above a quarter of the previous one
    /// ([`crate::NodalSolver`]: when a node-level term's blocks differ from the factored ones,
    /// or on that contraction test). The
    /// convergence test is the same, so the equilibrium is the same to the solver tolerance; each
    /// reused iteration costs one force pass and one back-substitution instead of an assembly and
    /// a factorization, and the accepted line-search point's forces (and energy) are carried into
    /// the next iteration. The factor left in [`StaticSolver::cholesky`] may belong to an earlier
    /// iterate or solve. Requires, like the energy line search, that a model with an energy keeps
    /// its forces fixed in [`ElasticModel::update_state`]. With a probe, the per-node penalty
    /// scale of a solve is the one of the matrix in the current factor (made by an earlier
    /// WhenStale solve), so a frame that reuses the factor assembles nothing; for the corotational
    /// model this is the scale a fresh assembly gives (the trace of R K Rᵀ does not depend on R),
    /// for other models it is the scale at the factored iterate.
    WhenStale,
    /// Full Newton, but the matrix is assembled and factored only at iterates that take a step:
    /// an iterate whose previous update was already within the displacement tolerance is first
    /// tested with its forces alone (those of the accepted line-search point when the search
    /// computed them), and when it has converged the solve returns without the assembly and the
    /// factorization nothing would use. The iterates are those of
    /// [`Refactorization::EveryIteration`]; the forces-only test's alternative residual bound
    /// (‖r‖ ≤ max|A_ij| · tol_x) takes max|A_ij| from the previous iterate's matrix (with a
    /// probe dominated by the penalty springs, whose stiffness is fixed for the whole solve), so
    /// a solve can stop one iterate earlier at most. The factor and
    /// [`StaticSolver::last_matrix_values`] left after a
    /// solve belong to the last step's iterate, not to the solution: for loops that read only
    /// the equilibrium (rigid-tip replays), never for a tangent response ∂x/∂f.
    EveryStep,
}

impl Default for EquilibriumSettings {
    fn default() -> Self {
        Self {
            max_iterations: 100,
            displacement_tol_rel: 1e-10,
            residual_tol_rel: 1e-8,
            stiffness: StiffnessKind::Warped,
            line_search: true,
            max_halvings: 12,
            contact_freeze_after: 12,
            refactorization: Refactorization::EveryIteration,
        }
    }
}

impl EquilibriumSettings {
    /// Newton's method (consistent tangent) with line search: the neo-Hookean solver.
    pub fn newton() -> Self {
        Self {
            stiffness: StiffnessKind::Consistent,
            ..Self::default()
        }
    }
}

/// Outcome of an equilibrium solve; never a panic.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum SolveStatus {
    /// Both tolerances met.
    Converged,
    /// Iteration limit reached.
    MaxIterations,
    /// The system matrix could not be factored.
    FactorizationFailed {
        /// reason reported by the factorization
        reason: String,
    },
    /// Positions or forces became non-finite.
    NonFinite,
}

/// Report of one equilibrium solve.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EquilibriumReport {
    /// Status.
    pub status: SolveStatus,
    /// Iterations performed.
    pub iterations: usize,
    /// Final ‖r‖₂ over free dofs \[N\].
    pub residual_norm_n: f64,
    /// Last ‖Δx‖_∞ \[m\].
    pub last_update_m: f64,
    /// Contact outcome (default/empty without a probe).
    pub contact: ContactReport,
}

impl EquilibriumReport {
    /// True if converged.
    pub fn converged(&self) -> bool {
        self.status == SolveStatus::Converged
    }

    /// The report an equilibrium solve starts from (no iterations yet, status `MaxIterations`), or
    /// the length-mismatch failure when `x` or `f_ext` does not have one entry per model node.
    pub fn begin(num_nodes: usize, x_len: usize, f_ext_len: usize) -> Self {
        let mut report = Self {
            status: SolveStatus::MaxIterations,
            iterations: 0,
            residual_norm_n: f64::NAN,
            last_update_m: f64::NAN,
            contact: ContactReport::default(),
        };
        if x_len != num_nodes || f_ext_len != num_nodes {
            report.status = SolveStatus::FactorizationFailed {
                reason: "length mismatch of x / f_ext".into(),
            };
        }
        report
    }
}

/// Static solver bound to a mesh and a set of constrained dofs; owns the sparsity pattern and the
/// symbolic factorization (reused across iterations, load steps and right-hand sides).
#[derive(Debug)]
pub struct StaticSolver {
    pattern: SystemPattern,
    cholesky: SparseCholesky,
    length_scale_m: f64,
    values: Vec<f64>,
    /// Strictly upper triangle of the last assembled matrix in the lower-triangle layout
    /// ([`SystemPattern::add_element_transposed`]) when the model's tangent is not symmetric
    /// ([`ElasticModel::tangent_is_symmetric`]); empty otherwise.
    upper: Vec<f64>,
    /// f_int at the last assembled iterate (same pass as the matrix).
    f_int: Vec<Vector3<f64>>,
    /// Model energy at the last assembled iterate, when the pass produced it.
    energy: Option<f64>,
    scratch: AssemblyScratch,
    /// Contact springs of the matrix in the current factor when [`Refactorization::WhenStale`]
    /// made it (`None`: unknown — any other path factored it, or nothing was factored).
    factored_springs: Option<Vec<ContactSpring>>,
    /// Per-node penalty scale (mean |diagonal| of the element-only matrix) of the current factor
    /// when [`Refactorization::WhenStale`] made it (empty otherwise): the next WhenStale solve
    /// takes its penalty table from here instead of assembling at its first iterate.
    factored_node_stiffness: Vec<f64>,
    /// (model state id, positions) at which the last [`Refactorization::WhenStale`] solve
    /// converged; `f_int` and `energy` still hold the model's forces and energy there, so the next
    /// WhenStale solve starting from the same positions of the same model state reuses them.
    converged_at: Option<(u64, Vec<Vector3<f64>>)>,
}

impl StaticSolver {
    /// Pattern + symbolic factorization for `model`'s mesh with `constrained_dofs` eliminated.
    pub fn new<M: ElasticModel + ?Sized>(
        model: &M,
        constrained_dofs: &[usize],
    ) -> Result<Self, FemError> {
        let (pattern, cholesky, length_scale_m) = solver_setup(model, constrained_dofs)?;
        Ok(Self {
            pattern,
            cholesky,
            length_scale_m,
            values: Vec::new(),
            upper: Vec::new(),
            f_int: Vec::new(),
            energy: None,
            scratch: AssemblyScratch::default(),
            factored_springs: None,
            factored_node_stiffness: Vec::new(),
            converged_at: None,
        })
    }

    /// Solver for the constraint set of `bc`.
    pub fn with_bc<M: ElasticModel + ?Sized>(
        model: &M,
        bc: &DirichletBc,
    ) -> Result<Self, FemError> {
        Self::new(model, &bc.dofs())
    }

    /// The pattern (dof map, scatter maps).
    pub fn pattern(&self) -> &SystemPattern {
        &self.pattern
    }

    /// The dof map.
    pub fn dofs(&self) -> &DofMap {
        self.pattern.dofs()
    }

    /// The factorization of the last system matrix (valid after a solve).
    pub fn cholesky(&self) -> &SparseCholesky {
        &self.cholesky
    }

    /// Values of the last assembled system matrix (lower triangle, pattern order; for a model with
    /// a non-symmetric tangent the upper triangle is not in here, the factor has both).
    pub fn last_matrix_values(&self) -> &[f64] {
        &self.values
    }

    /// Assembles A (+ contact springs) at `x` and factors it.
    pub fn assemble_and_factor<M: ElasticModel + ?Sized>(
        &mut self,
        model: &M,
        x: &[Vector3<f64>],
        kind: StiffnessKind,
        contact: Option<&ContactProblem>,
    ) -> Result<Vec<ContactSpring>, FemError> {
        self.assemble_and_factor_with(model, x, kind, contact, None)
    }

    /// As [`Self::assemble_and_factor`], but with a given (frozen) set of contact springs instead of
    /// querying the probe when `frozen` is `Some`.
    pub fn assemble_and_factor_with<M: ElasticModel + ?Sized>(
        &mut self,
        model: &M,
        x: &[Vector3<f64>],
        kind: StiffnessKind,
        contact: Option<&ContactProblem>,
        frozen: Option<&[ContactSpring]>,
    ) -> Result<Vec<ContactSpring>, FemError> {
        self.assemble_and_factor_impl(model, x, kind, contact, frozen, None)
    }

    /// Assembly + factorization. `node_stiffness`: the per-node penalty scale, fixed for a whole
    /// solve (an empty table is filled from this assembly, before the springs are added), and the
    /// previous iteration's springs for the active-set hysteresis; `None` takes the scale from this
    /// assembly without keeping it and queries the tip afresh.
    fn assemble_and_factor_impl<M: ElasticModel + ?Sized>(
        &mut self,
        model: &M,
        x: &[Vector3<f64>],
        kind: StiffnessKind,
        contact: Option<&ContactProblem>,
        frozen: Option<&[ContactSpring]>,
        node_stiffness: Option<(&mut Vec<f64>, &[ContactSpring])>,
    ) -> Result<Vec<ContactSpring>, FemError> {
        self.assemble_values(model, x, kind);
        let springs = self.contact_springs(x, contact, frozen, node_stiffness);
        self.factor_with_springs(&springs)?;
        Ok(springs)
    }

    /// One fused pass at `x`: `values` (elements only), `f_int`, `energy`.
    fn assemble_values<M: ElasticModel + ?Sized>(
        &mut self,
        model: &M,
        x: &[Vector3<f64>],
        kind: StiffnessKind,
    ) {
        self.converged_at = None;
        let mut values = std::mem::take(&mut self.values);
        let mut upper = std::mem::take(&mut self.upper);
        let mut f_int = std::mem::take(&mut self.f_int);
        let unsymmetric = !model.tangent_is_symmetric(kind);
        self.energy = self.pattern.assemble_linearized(
            model,
            x,
            kind,
            &mut self.scratch,
            &mut values,
            unsymmetric.then_some(&mut upper),
            &mut f_int,
        );
        if !unsymmetric {
            upper.clear();
        }
        self.f_int = f_int;
        self.values = values;
        self.upper = upper;
    }

    /// The contact springs at `x` (see [`Self::assemble_and_factor_impl`]); the penalty table is
    /// filled from the element-only `values` of the last [`Self::assemble_values`].
    fn contact_springs(
        &self,
        x: &[Vector3<f64>],
        contact: Option<&ContactProblem>,
        frozen: Option<&[ContactSpring]>,
        node_stiffness: Option<(&mut Vec<f64>, &[ContactSpring])>,
    ) -> Vec<ContactSpring> {
        let values = &self.values;
        match (contact, frozen) {
            (Some(_), Some(f)) => f.to_vec(),
            (Some(c), None) => {
                let pat = &self.pattern;
                let vals = &values;
                match node_stiffness {
                    Some((table, previous)) => {
                        if table.len() != x.len() {
                            *table = vec![0.0; x.len()];
                            for &n in &c.candidate_nodes {
                                if n < x.len() {
                                    table[n] = pat.node_stiffness(n, vals);
                                }
                            }
                        }
                        c.springs_with_hysteresis(x, |n| table[n], previous, false)
                    }
                    None => c.springs(x, |n| pat.node_stiffness(n, vals)),
                }
            }
            (None, _) => Vec::new(),
        }
    }

    /// Adds the springs to the element-only `values` (and `upper`, for a non-symmetric tangent) and
    /// factors the result (sparse LU when `upper` is in use, [`SparseCholesky::factor_general`]).
    fn factor_with_springs(&mut self, springs: &[ContactSpring]) -> Result<(), FemError> {
        let unsymmetric = !self.upper.is_empty();
        for s in springs {
            let m = s.matrix();
            self.pattern.add_node_block(s.node, &m, &mut self.values);
            if unsymmetric {
                self.pattern
                    .add_node_block(s.node, &m.transpose(), &mut self.upper);
            }
        }
        self.factored_springs = None;
        self.factored_node_stiffness.clear();
        self.cholesky
            .factor_general(
                &self.pattern,
                &self.values,
                unsymmetric.then_some(self.upper.as_slice()),
            )
            .map(|_| ())
    }

    /// Free-dof residual f_ext + f_c − f_int(x) for the given f_int and its tolerance scale: the
    /// largest of the external, internal (incl. reactions at constrained dofs) and contact force
    /// norms.
    fn residual_with(
        &self,
        f_int: &[Vector3<f64>],
        x: &[Vector3<f64>],
        f_ext: &[Vector3<f64>],
        springs: &[ContactSpring],
    ) -> (Vec<f64>, f64) {
        contact_residual(self.dofs(), f_ext, f_int, x, springs)
    }

    /// Solves f_int(x) = f_ext (+ contact) for the free dofs, starting from `x` (whose constrained
    /// components must already hold the prescribed values). Never panics: failures are reported in
    /// the status, and `x` keeps the last finite iterate.
    ///
    /// With a probe, the penalty stiffness of every candidate node is fixed at the first iteration
    /// and the active set has hysteresis (a spring stays while its node is compressed against its
    /// plane, re-linearized at the node's closest tip point; see
    /// `ContactProblem::springs_with_hysteresis`). The line search then minimises, per iteration,
    /// Π(x) = Ψ(x) − f_extᵀx + ½ Σ_springs k_c (n·(c − x))² + ½ Σ_others k_c depth(x)², whose
    /// gradient is −(residual): a step that would throw a rim node out of the tip, or push a free
    /// node deep into it, is cut back, so the active set settles instead of cycling. A
    /// Cauchy-elastic model (strain-dependent hook, no Ψ) backtracks on the norm of the residual of
    /// the same contact forces.
    pub fn solve<M: ElasticModel + ?Sized>(
        &mut self,
        model: &mut M,
        x: &mut [Vector3<f64>],
        f_ext: &[Vector3<f64>],
        contact: Option<&ContactProblem>,
        settings: &EquilibriumSettings,
    ) -> EquilibriumReport {
        let mut report = EquilibriumReport::begin(model.num_nodes(), x.len(), f_ext.len());
        if report.status != SolveStatus::MaxIterations {
            return report;
        }
        let tol_x = settings.displacement_tol_rel * self.length_scale_m;
        let mut last_springs: Option<Vec<ContactSpring>> = None;
        let reuse = settings.refactorization == Refactorization::WhenStale;
        // WhenStale: the penalty scale of the matrix in the reused factor (the springs of this
        // solve then match that factor; for the corotational model with free candidate nodes it
        // is exactly the scale a fresh assembly would give, tr(R K Rᵀ) = tr K).
        let mut node_stiffness: Vec<f64> = if reuse
            && self.factored_springs.is_some()
            && self.factored_node_stiffness.len() == x.len()
        {
            self.factored_node_stiffness.clone()
        } else {
            Vec::new()
        };
        // max |A_ij| of the current `values` (recomputed only when they change).
        let mut values_abs_max: Option<f64> = None;
        // (f_int, energy) at the current x, carried over from the accepted line-search point.
        let mut carried: Option<(Vec<Vector3<f64>>, Option<f64>)> = None;
        let mut previous_rnorm = f64::INFINITY;
        let failed = |e: FemError| match e {
            FemError::NonFinite { .. } => SolveStatus::NonFinite,
            e => SolveStatus::FactorizationFailed {
                reason: e.to_string(),
            },
        };
        let converged_before = self.converged_at.take();
        let lazy = settings.refactorization == Refactorization::EveryStep;
        // EveryStep: f_int at the current x from the accepted line-search point, if it made it,
        // with the model state it was computed in.
        let mut searched: Option<(Vec<Vector3<f64>>, Option<u64>)> = None;
        for it in 0..settings.max_iterations {
            model.update_state(x);
            if lazy && it > 0 && report.last_update_m <= tol_x {
                // the searched forces only when the model state did not change since
                let f_int = match searched.take() {
                    Some((f, Some(id))) if model.state_id() == Some(id) => f,
                    _ => model.internal_forces(x),
                };
                let frozen_ref = (it >= settings.contact_freeze_after)
                    .then_some(last_springs.as_deref())
                    .flatten();
                let previous = last_springs.as_deref().unwrap_or(&[]);
                let springs = self.contact_springs(
                    x,
                    contact,
                    frozen_ref,
                    Some((&mut node_stiffness, previous)),
                );
                let (r, scale) = self.residual_with(&f_int, x, f_ext, &springs);
                let rnorm = r.iter().map(|v| v * v).sum::<f64>().sqrt();
                // the diagonal test against the last assembled matrix (that of the previous
                // iterate: its penalty springs keep the stiffness fixed for the whole solve)
                let diag_max = *values_abs_max
                    .get_or_insert_with(|| self.values.iter().fold(0.0f64, |m, v| m.max(v.abs())));
                if rnorm.is_finite()
                    && (rnorm <= settings.residual_tol_rel * scale || rnorm <= diag_max * tol_x)
                {
                    report.residual_norm_n = rnorm;
                    if let Some(c) = contact {
                        report.contact = c.report(&springs, x);
                    }
                    report.status = SolveStatus::Converged;
                    return report;
                }
            }
            searched = None;
            if it == 0
                && reuse
                && let Some((id, at)) = &converged_before
                && model.state_id() == Some(*id)
                && bitwise_equal(at, x)
                && self.f_int.len() == x.len()
            {
                // Same model state, same positions: the forces of the last converged iterate.
                carried = Some((std::mem::take(&mut self.f_int), self.energy));
            }
            let freeze = it >= settings.contact_freeze_after && it > 0;
            let frozen_ref = if freeze {
                last_springs.as_deref()
            } else {
                None
            };
            let previous = last_springs.as_deref().unwrap_or(&[]);
            let mut assembled = !reuse;
            if !reuse {
                values_abs_max = None;
            }
            let springs = if !reuse {
                match self.assemble_and_factor_impl(
                    &*model,
                    x,
                    settings.stiffness,
                    contact,
                    frozen_ref,
                    Some((&mut node_stiffness, previous)),
                ) {
                    Ok(s) => s,
                    Err(e) => {
                        report.status = failed(e);
                        return report;
                    }
                }
            } else {
                // Modified Newton: linearize only as far as this iterate needs.
                let need_table = contact.is_some() && node_stiffness.len() != x.len();
                let carried_in = carried.take();
                if need_table || self.values.is_empty() {
                    self.assemble_values(&*model, x, settings.stiffness);
                    values_abs_max = None;
                    assembled = true;
                } else if let Some((f, e)) = carried_in {
                    (self.f_int, self.energy) = (f, e);
                } else {
                    (self.f_int, self.energy) = model.forces_and_energy(x);
                }
                self.contact_springs(
                    x,
                    contact,
                    frozen_ref,
                    Some((&mut node_stiffness, previous)),
                )
            };
            let (r, scale) = self.residual_with(&self.f_int, x, f_ext, &springs);
            let rnorm = r.iter().map(|v| v * v).sum::<f64>().sqrt();
            report.residual_norm_n = rnorm;
            if let Some(c) = contact {
                report.contact = c.report(&springs, x);
            }
            if !rnorm.is_finite() {
                report.status = SolveStatus::NonFinite;
                return report;
            }
            // A residual below what a displacement of tol_x would cause is also accepted.
            let diag_max = *values_abs_max
                .get_or_insert_with(|| self.values.iter().fold(0.0f64, |m, v| m.max(v.abs())));
            let res_ok = rnorm <= settings.residual_tol_rel * scale || rnorm <= diag_max * tol_x;
            if it > 0 && res_ok && report.last_update_m <= tol_x {
                if reuse && let Some(id) = model.state_id() {
                    self.converged_at = Some((id, x.to_vec()));
                }
                report.status = SolveStatus::Converged;
                return report;
            }
            if reuse {
                let penalty = contact.map_or(1.0, |c| c.settings.penalty_factor);
                let stale = self.cholesky.kind().is_none()
                    || self
                        .factored_springs
                        .as_deref()
                        .is_none_or(|f| !springs_match(f, &springs, penalty))
                    || rnorm > STALE_CONTRACTION * previous_rnorm;
                if stale {
                    if !assembled {
                        self.assemble_values(&*model, x, settings.stiffness);
                    }
                    values_abs_max = None;
                    let table: Vec<f64> = (0..x.len())
                        .map(|n| self.pattern.node_stiffness(n, &self.values))
                        .collect();
                    if let Err(e) = self.factor_with_springs(&springs) {
                        report.status = failed(e);
                        return report;
                    }
                    self.factored_springs = Some(springs.clone());
                    self.factored_node_stiffness = table;
                } else if assembled {
                    values_abs_max = None;
                    // Keep `last_matrix_values` = A at the last assembled iterate.
                    for s in &springs {
                        self.pattern
                            .add_node_block(s.node, &s.matrix(), &mut self.values);
                    }
                }
            }
            previous_rnorm = rnorm;
            let mut dx = r.clone();
            if let Err(e) = self.cholesky.solve_in_place(&mut dx) {
                report.status = SolveStatus::FactorizationFailed {
                    reason: e.to_string(),
                };
                return report;
            }
            let dx_inf = dx.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            if !dx_inf.is_finite() {
                report.status = SolveStatus::NonFinite;
                return report;
            }
            let step = if settings.line_search {
                let merit = contact.map(|problem| ContactMerit {
                    problem,
                    node_stiffness: &node_stiffness,
                    springs: &springs,
                    frozen: freeze,
                });
                let energy = self.energy;
                let carry = if reuse || lazy {
                    Some(&mut carried)
                } else {
                    None
                };
                let (s, residual_forces) =
                    self.line_search(&*model, x, energy, f_ext, merit, &dx, &r, settings, carry);
                if lazy {
                    // the accepted point's forces serve the next iterate's forces-only test
                    searched = residual_forces
                        .or_else(|| carried.take().map(|(f, _)| f))
                        .map(|f| (f, model.state_id()));
                }
                s
            } else {
                searched = None;
                1.0
            };
            last_springs = Some(springs);
            self.dofs().scatter_add(&dx, step, x);
            report.iterations = it + 1;
            report.last_update_m = dx_inf * step;
        }
        report
    }

    #[allow(clippy::too_many_arguments)]
    fn line_search<M: ElasticModel + ?Sized>(
        &self,
        model: &M,
        x: &[Vector3<f64>],
        energy_at_x: Option<f64>,
        f_ext: &[Vector3<f64>],
        contact: Option<ContactMerit<'_>>,
        dx: &[f64],
        r: &[f64],
        settings: &EquilibriumSettings,
        mut carry: Option<&mut Option<(Vec<Vector3<f64>>, Option<f64>)>>,
    ) -> (f64, Option<Vec<Vector3<f64>>>) {
        let dofs = self.dofs();
        let trial = |s: f64| {
            let mut xt = x.to_vec();
            dofs.scatter_add(dx, s, &mut xt);
            xt
        };
        // Frozen springs are a fixed linear force field: no potential of the probe to add.
        let energy0 = if contact.as_ref().is_none_or(|c| !c.frozen) {
            energy_at_x.or_else(|| model.energy(x))
        } else {
            None
        };
        if let Some(energy0) = energy0 {
            let merit_with = |xs: &[Vector3<f64>], energy: f64| {
                let ext = xs.iter().zip(f_ext).map(|(a, f)| a.dot(f)).sum::<f64>();
                let penalty = contact.as_ref().map_or(0.0, |c| c.energy(xs));
                energy - ext + penalty
            };
            let e0 = merit_with(x, energy0);
            let slope = -dx.iter().zip(r).map(|(a, b)| a * b).sum::<f64>();
            if slope < 0.0 && e0.is_finite() {
                let mut s = 1.0;
                for _ in 0..=settings.max_halvings {
                    let xt = trial(s);
                    // With a carry slot, the forces of the trial come with its energy (one pass)
                    // and, if accepted, serve the next iteration.
                    let (forces, energy) = match carry {
                        Some(_) => {
                            let (f, e) = model.forces_and_energy(&xt);
                            (Some(f), e)
                        }
                        None => (None, model.energy(&xt)),
                    };
                    let e = merit_with(&xt, energy.unwrap_or(f64::NAN));
                    if e.is_finite() && e <= e0 + 1e-4 * s * slope + 1e-14 * e0.abs() {
                        if let (Some(slot), Some(f)) = (carry.as_deref_mut(), forces) {
                            *slot = Some((f, energy));
                        }
                        return (s, None);
                    }
                    s *= 0.5;
                }
                return (1.0, None);
            }
        }
        let r0 = r.iter().map(|v| v * v).sum::<f64>();
        let mut s = 1.0;
        for _ in 0..=settings.max_halvings {
            let xt = trial(s);
            let springs = contact.as_ref().map_or(Vec::new(), |c| c.springs(&xt));
            let f_int = model.internal_forces(&xt);
            let (rt, _) = self.residual_with(&f_int, &xt, f_ext, &springs);
            let rn = rt.iter().map(|v| v * v).sum::<f64>();
            if rn.is_finite() && rn < r0 {
                return (s, Some(f_int));
            }
            s *= 0.5;
        }
        (1.0, None)
    }

    /// bickel2009 eq. 10 with the rotations *frozen*: x = K(R)⁻¹(F + K′(R) X) for given element
    /// rotations (the linear problem whose parameter derivative is appendix eq. 11). Constrained
    /// components of `x` hold the prescribed values; the free ones are overwritten.
    pub fn solve_frozen_rotations(
        &mut self,
        model: &crate::CorotationalModel,
        rotations: &[nalgebra::Matrix3<f64>],
        x: &mut [Vector3<f64>],
        f_ext: &[Vector3<f64>],
    ) -> Result<(), FemError> {
        let geoms = model.elements();
        if rotations.len() != geoms.len() {
            return Err(FemError::LengthMismatch {
                what: "rotations",
                expected: geoms.len(),
                got: rotations.len(),
            });
        }
        let mut values = self.pattern.zeros();
        let mut f_int = vec![Vector3::zeros(); x.len()];
        for (e, g) in geoms.iter().enumerate() {
            let k = crate::element::warped_stiffness(g, &model.params()[e], &rotations[e]);
            self.pattern.add_element(e, &k, &mut values);
            // f_int = R K (Rᵀx − X) with the given R.
            let ke = crate::element::element_stiffness(g, &model.params()[e]);
            let r = rotations[e];
            let mut u = nalgebra::SVector::<f64, 12>::zeros();
            for a in 0..4 {
                let ua = r.transpose() * x[g.nodes[a]] - model.rest_positions()[g.nodes[a]];
                u.fixed_rows_mut::<3>(3 * a).copy_from(&ua);
            }
            let fu = ke * u;
            for a in 0..4 {
                f_int[g.nodes[a]] += r * fu.fixed_rows::<3>(3 * a);
            }
        }
        self.factored_springs = None;
        self.factored_node_stiffness.clear();
        self.cholesky.factor(&self.pattern, &values)?;
        self.values = values;
        self.upper.clear();
        let r: Vec<Vector3<f64>> = f_ext.iter().zip(&f_int).map(|(a, b)| a - b).collect();
        let mut dx = self.dofs().gather(&r);
        self.cholesky.solve_in_place(&mut dx)?;
        self.dofs().scatter_add(&dx, 1.0, x);
        Ok(())
    }
}

/// Whether two position arrays hold the same bits.
fn bitwise_equal(a: &[Vector3<f64>], b: &[Vector3<f64>]) -> bool {
    a.len() == b.len()
        && a.iter().zip(b).all(|(p, q)| {
            p.iter()
                .zip(q.iter())
                .all(|(u, v)| u.to_bits() == v.to_bits())
        })
}

/// Whether a factor made with springs `old` still serves springs `new` (modified Newton): the same
/// nodes, penalty stiffness within 5 %, and normals within 0.05 / penalty_factor — a spring is
/// `penalty_factor` times stiffer than the elements around its node, so a normal rotated by δ
/// changes the matrix by ≈ penalty_factor · δ relative to the element stiffness in the tangential
/// directions, and the stale factor contracts only while that stays small.
fn springs_match(old: &[ContactSpring], new: &[ContactSpring], penalty_factor: f64) -> bool {
    old.len() == new.len()
        && old.iter().zip(new).all(|(a, b)| {
            a.node == b.node
                && (b.stiffness_n_per_m - a.stiffness_n_per_m).abs()
                    <= 0.05 * a.stiffness_n_per_m.abs()
                && (b.normal - a.normal).norm() <= 0.05 / penalty_factor.max(1.0)
        })
}

/// The probe as the line search sees it: this iteration's springs (compressive part) plus the true
/// penetration of every other candidate, per-node stiffness fixed for the solve; or a frozen set.
struct ContactMerit<'a> {
    problem: &'a ContactProblem,
    node_stiffness: &'a [f64],
    /// The springs of this iteration (fixed during the line search).
    springs: &'a [ContactSpring],
    /// Springs frozen (linear force field, no potential of the tip).
    frozen: bool,
}

impl ContactMerit<'_> {
    fn energy(&self, x: &[Vector3<f64>]) -> f64 {
        self.problem
            .penalty_energy_with(x, |n| self.node_stiffness[n], self.springs)
    }
    fn springs(&self, x: &[Vector3<f64>]) -> Vec<ContactSpring> {
        if self.frozen {
            self.springs.to_vec()
        } else {
            self.problem
                .springs_with(x, |n| self.node_stiffness[n], self.springs)
        }
    }
}

/// The load applied at pseudo-time t ∈ (0, 1] of an incremental loading run.
#[derive(Clone, Debug, Default)]
pub struct LoadState {
    /// External nodal forces \[N\] (one per node).
    pub external_forces_n: Vec<Vector3<f64>>,
    /// Prescribed positions of the constrained dofs (must cover the solver's constrained set).
    pub prescribed: DirichletBc,
    /// The probe and its candidate nodes, if any.
    pub contact: Option<ContactProblem>,
}

/// Settings of incremental loading (bickel2009 §3.4).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct IncrementalSettings {
    /// Number of load increments.
    pub steps: usize,
    /// Equilibrium iterations per increment.
    pub equilibrium: EquilibriumSettings,
}

impl Default for IncrementalSettings {
    fn default() -> Self {
        Self {
            steps: 10,
            equilibrium: EquilibriumSettings::default(),
        }
    }
}

/// Per-increment record.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StepReport {
    /// Load factor t of this increment.
    pub t: f64,
    /// Equilibrium outcome.
    pub equilibrium: EquilibriumReport,
}

/// Report of an incremental loading run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct IncrementalReport {
    /// One record per increment performed.
    pub steps: Vec<StepReport>,
    /// Converged if every increment converged; otherwise the first failing status.
    pub status: SolveStatus,
}

/// Incremental loading (bickel2009 §3.4): the load `load(t)` is applied in `settings.steps` equal
/// increments of t; at each increment the constraints and probe pose are updated and equilibrium is
/// iterated (parameters refreshed from the current strain at every iteration). Stops at the first
/// increment that fails (reported, `x` keeps the last iterate).
pub fn incremental_loading<M: ElasticModel + ?Sized>(
    solver: &mut StaticSolver,
    model: &mut M,
    x: &mut [Vector3<f64>],
    mut load: impl FnMut(f64) -> LoadState,
    settings: &IncrementalSettings,
) -> IncrementalReport {
    let n = settings.steps.max(1);
    let mut steps = Vec::with_capacity(n);
    for s in 1..=n {
        let t = s as f64 / n as f64;
        let state = load(t);
        state.prescribed.apply(x);
        let forces = if state.external_forces_n.len() == x.len() {
            state.external_forces_n
        } else {
            vec![Vector3::zeros(); x.len()]
        };
        let rep = solver.solve(
            model,
            x,
            &forces,
            state.contact.as_ref(),
            &settings.equilibrium,
        );
        let ok = rep.converged();
        let status = rep.status.clone();
        steps.push(StepReport {
            t,
            equilibrium: rep,
        });
        if !ok {
            return IncrementalReport { steps, status };
        }
    }
    IncrementalReport {
        steps,
        status: SolveStatus::Converged,
    }
}
