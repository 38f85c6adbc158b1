//! Equilibrium with node-level boundary terms: frictional probe contact ([`crate::friction`]) and
//! support planes ([`crate::support`]).
//!
//! A [`NodalTerm`] adds forces f_b(x) on individual nodes and their stiffness blocks −∂f_b/∂x to
//! the system. [`NodalSolver::solve`] runs the iterations of [`crate::StaticSolver::solve`] on
//!
//! A Δx = f_ext + Σ_b f_b(x) − f_int(x),  A = K(x) + Σ_b (−∂f_b/∂x),
//!
//! with residual-norm backtracking. Each term is refreshed at every iteration (active sets and
//! closest points re-queried up to `contact_freeze_after`, lagged quantities such as the normal
//! force of regularized friction always), and [`NodalTerm::commit`] updates its history (stick
//! anchors) once a load step has converged.
//!
//! A is assembled and factored at every iteration, or — [`Refactorization::WhenStale`], modified
//! Newton — kept across iterations and solves while it contracts: refactored only when there is
//! no factor, a term's blocks differ from the factored ones (a term with a constant matrix, such
//! as the linear tangential springs of a [`crate::SupportPlane`], never triggers it), or an
//! iteration left the residual norm above a quarter of the previous one. The convergence test is
//! the same, so the equilibrium is the same to the solver tolerance.

use crate::FemError;
use crate::assembly::{
    AssemblyScratch, DofMap, SparseCholesky, SystemPattern, free_residual, solver_setup,
};
use crate::model::ElasticModel;
use crate::statics::{
    EquilibriumReport, EquilibriumSettings, Refactorization, STALE_CONTRACTION, SolveStatus,
};
use nalgebra::{Matrix3, Vector3};

/// A node-level boundary term.
pub trait NodalTerm {
    /// Refreshes the term at positions `x`. `requery` is false once the active set is frozen
    /// (then only lagged quantities may change). `node_stiffness(n)` is the mean diagonal entry of
    /// node n's free dofs in the assembled elastic matrix (for scale-free penalties).
    fn refresh(&mut self, x: &[Vector3<f64>], node_stiffness: &dyn Fn(usize) -> f64, requery: bool);
    /// Adds the forces the term exerts on the body \[N\] into `out`.
    fn add_forces(&self, x: &[Vector3<f64>], out: &mut [Vector3<f64>]);
    /// The blocks (node, −∂f/∂x) added to the system matrix (symmetric PSD).
    fn blocks(&self, x: &[Vector3<f64>]) -> Vec<(usize, Matrix3<f64>)>;
    /// Off-diagonal blocks (a, b, −∂f_a/∂x_b) of a term that couples two distinct nodes a ≠ b
    /// (the quadrature-point contact of [`crate::ContactDiscretisation::Quadrature`], whose
    /// point force N_a f_q depends on every node of its triangle); −∂f_b/∂x_a is the transpose,
    /// implied. Together with [`Self::blocks`] the term's matrix is symmetric PSD; a and b must
    /// share an element (the system pattern). Default: none (node-local terms).
    fn pair_blocks(&self, _x: &[Vector3<f64>]) -> Vec<(usize, usize, Matrix3<f64>)> {
        Vec::new()
    }
    /// History update after a converged load step (default: nothing).
    fn commit(&mut self, _x: &[Vector3<f64>]) {}
}

/// Static solver with node-level terms; owns the pattern and symbolic factorization.
#[derive(Debug)]
pub struct NodalSolver {
    pattern: SystemPattern,
    cholesky: SparseCholesky,
    length_scale_m: f64,
    scratch: AssemblyScratch,
    /// The matrix in the factor when [`Refactorization::WhenStale`] made it (`None`: no factor,
    /// or another policy made it).
    factored: Option<Factored>,
}

/// What [`NodalSolver`] keeps of the matrix in its factor under [`Refactorization::WhenStale`].
#[derive(Debug)]
struct Factored {
    /// Per-node penalty scale of its elastic part (`SystemPattern::node_stiffness`): the terms
    /// are refreshed with it while the factor is reused.
    node_stiffness: Vec<f64>,
    /// The terms' blocks in it.
    blocks: TermBlocks,
    /// max |A_ij| (the residual test's alternative bound).
    abs_max: f64,
}

/// The node and pair blocks of the terms, in term order.
type TermBlocks = (
    Vec<(usize, Matrix3<f64>)>,
    Vec<(usize, usize, Matrix3<f64>)>,
);

/// A linearization at an iterate: f_int and the terms' blocks, the assembled matrix (elastic part
/// plus the blocks) when it was assembled.
struct Linearized {
    f_int: Vec<Vector3<f64>>,
    blocks: TermBlocks,
    assembled: Option<Assembled>,
}

struct Assembled {
    values: Vec<f64>,
    upper: Option<Vec<f64>>,
    node_stiffness: Vec<f64>,
}

fn term_blocks(terms: &[&mut dyn NodalTerm], x: &[Vector3<f64>]) -> TermBlocks {
    let mut blocks = (Vec::new(), Vec::new());
    for t in terms {
        blocks.0.extend(t.blocks(x));
        blocks.1.extend(t.pair_blocks(x));
    }
    blocks
}

impl NodalSolver {
    /// Pattern + symbolic factorization with `constrained_dofs` eliminated (may be empty when the
    /// terms remove every rigid mode).
    pub fn new<M: ElasticModel + ?Sized>(
        model: &M,
        constrained_dofs: &[usize],
    ) -> Result<Self, FemError> {
        let (pattern, cholesky, length_scale_m) = solver_setup(model, constrained_dofs)?;
        Ok(Self {
            pattern,
            cholesky,
            length_scale_m,
            scratch: AssemblyScratch::default(),
            factored: None,
        })
    }

    /// The dof map.
    pub fn dofs(&self) -> &DofMap {
        self.pattern.dofs()
    }

    /// Free-dof residual f_ext + Σ f_b − f_int for the given f_int, and its tolerance scale.
    fn residual_with(
        &self,
        f_int: &[Vector3<f64>],
        x: &[Vector3<f64>],
        f_ext: &[Vector3<f64>],
        terms: &[&mut dyn NodalTerm],
    ) -> (Vec<f64>, f64) {
        let mut fb = vec![Vector3::zeros(); x.len()];
        for t in terms {
            t.add_forces(x, &mut fb);
        }
        free_residual(self.dofs(), f_ext, f_int, &fb)
    }

    /// Assembles A = K(x) + Σ_b (−∂f_b/∂x) and f_int at `x`, the terms refreshed with the
    /// assembled elastic matrix's node stiffnesses.
    fn assemble<M: ElasticModel + ?Sized>(
        &mut self,
        model: &M,
        x: &[Vector3<f64>],
        terms: &mut [&mut dyn NodalTerm],
        settings: &EquilibriumSettings,
        requery: bool,
    ) -> Linearized {
        let unsymmetric = !model.tangent_is_symmetric(settings.stiffness);
        let (mut values, mut upper, mut f_int) = (Vec::new(), Vec::new(), Vec::new());
        self.pattern.assemble_linearized(
            model,
            x,
            settings.stiffness,
            &mut self.scratch,
            &mut values,
            unsymmetric.then_some(&mut upper),
            &mut f_int,
        );
        let node_stiffness: Vec<f64> = (0..x.len())
            .map(|n| self.pattern.node_stiffness(n, &values))
            .collect();
        for t in terms.iter_mut() {
            t.refresh(x, &|n| node_stiffness[n], requery);
        }
        let blocks = term_blocks(terms, x);
        for (n, m) in &blocks.0 {
            self.pattern.add_node_block(*n, m, &mut values);
            if unsymmetric {
                self.pattern.add_node_block(*n, &m.transpose(), &mut upper);
            }
        }
        for (a, b, m) in &blocks.1 {
            self.pattern.add_pair_block(*a, *b, m, &mut values);
            if unsymmetric {
                self.pattern.add_pair_block(*a, *b, m, &mut upper);
            }
        }
        Linearized {
            f_int,
            blocks,
            assembled: Some(Assembled {
                values,
                upper: unsymmetric.then_some(upper),
                node_stiffness,
            }),
        }
    }

    /// Factors the assembled matrix of `lin`; under `reuse` remembers what is in the factor.
    fn factor(&mut self, lin: &Linearized, reuse: bool) -> Result<(), SolveStatus> {
        let Some(a) = &lin.assembled else {
            return Ok(());
        };
        self.factored = None;
        self.cholesky
            .factor_general(&self.pattern, &a.values, a.upper.as_deref())
            .map_err(|e| match e {
                FemError::NonFinite { .. } => SolveStatus::NonFinite,
                e => SolveStatus::FactorizationFailed {
                    reason: e.to_string(),
                },
            })?;
        if reuse {
            self.factored = Some(Factored {
                node_stiffness: a.node_stiffness.clone(),
                blocks: lin.blocks.clone(),
                abs_max: a.values.iter().fold(0.0f64, |m, v| m.max(v.abs())),
            });
        }
        Ok(())
    }

    /// Solves f_int(x) = f_ext + Σ f_b(x) for the free dofs from `x` (constrained components hold
    /// their prescribed values). Does not commit the terms' history: call
    /// [`NodalTerm::commit`] on each term after a converged step. Never panics.
    ///
    /// `settings.refactorization`: [`Refactorization::WhenStale`] keeps the factor across
    /// iterations and solves (module docs; the terms are then refreshed with the node stiffnesses
    /// of the factored matrix, and the accepted line-search point's forces are carried into the
    /// next iteration, which requires a model whose forces do not change in
    /// [`ElasticModel::update_state`] unless its state id does). [`Refactorization::EveryStep`]
    /// assembles and factors at every iterate that takes a step: an iterate whose previous update
    /// was within the displacement tolerance is first tested with its forces alone (the terms
    /// refreshed with the last assembled matrix's node stiffnesses, the alternative residual bound
    /// with its max |A_ij|), as [`crate::StaticSolver`] does; `EveryIteration` assembles and
    /// factors at every iteration.
    pub fn solve<M: ElasticModel + ?Sized>(
        &mut self,
        model: &mut M,
        x: &mut [Vector3<f64>],
        f_ext: &[Vector3<f64>],
        terms: &mut [&mut dyn NodalTerm],
        settings: &EquilibriumSettings,
    ) -> EquilibriumReport {
        let mut report = EquilibriumReport::begin(model.num_nodes(), x.len(), f_ext.len());
        if report.status != SolveStatus::MaxIterations {
            return report;
        }
        let reuse = settings.refactorization == Refactorization::WhenStale;
        if !reuse {
            self.factored = None;
        }
        let tol_x = settings.displacement_tol_rel * self.length_scale_m;
        // f_int at the current x from the accepted line-search point, with its model state id
        let mut carried: Option<(Vec<Vector3<f64>>, Option<u64>)> = None;
        let mut previous_rnorm = f64::INFINITY;
        // EveryStep: the forces-only convergence test of an iterate whose previous update was
        // within tol_x (`Refactorization::EveryStep`), with the searched forces, and the node
        // stiffnesses and max |A_ij| of the last assembled matrix.
        let lazy = settings.refactorization == Refactorization::EveryStep;
        let mut searched: Option<(Vec<Vector3<f64>>, Option<u64>)> = None;
        let mut last_assembled: Option<(Vec<f64>, f64)> = None;
        for it in 0..settings.max_iterations {
            model.update_state(x);
            let requery = it < settings.contact_freeze_after || it == 0;
            if lazy
                && it > 0
                && report.last_update_m <= tol_x
                && let Some((node_stiffness, abs_max)) = &last_assembled
            {
                let f_int = match searched.take() {
                    Some((f, Some(id))) if model.state_id() == Some(id) => f,
                    _ => model.internal_forces(x),
                };
                for t in terms.iter_mut() {
                    t.refresh(x, &|n| node_stiffness[n], requery);
                }
                let (r, scale) = self.residual_with(&f_int, x, f_ext, terms);
                let rnorm = r.iter().map(|v| v * v).sum::<f64>().sqrt();
                if rnorm.is_finite()
                    && (rnorm <= settings.residual_tol_rel * scale || rnorm <= abs_max * tol_x)
                {
                    report.residual_norm_n = rnorm;
                    report.status = SolveStatus::Converged;
                    return report;
                }
            }
            searched = None;
            let mut lin = match &self.factored {
                Some(fac) if reuse => {
                    let f_int = match carried.take() {
                        Some((f, Some(id))) if model.state_id() == Some(id) => f,
                        _ => model.internal_forces(x),
                    };
                    for t in terms.iter_mut() {
                        t.refresh(x, &|n| fac.node_stiffness[n], requery);
                    }
                    Linearized {
                        f_int,
                        blocks: term_blocks(terms, x),
                        assembled: None,
                    }
                }
                _ => self.assemble(&*model, x, terms, settings, requery),
            };
            if let Err(status) = self.factor(&lin, reuse) {
                report.status = status;
                return report;
            }
            let (mut r, scale) = self.residual_with(&lin.f_int, x, f_ext, terms);
            let mut rnorm = r.iter().map(|v| v * v).sum::<f64>().sqrt();
            report.residual_norm_n = rnorm;
            if !rnorm.is_finite() {
                report.status = SolveStatus::NonFinite;
                return report;
            }
            let abs_max = match (&lin.assembled, &self.factored) {
                (Some(a), _) => a.values.iter().fold(0.0f64, |m, v| m.max(v.abs())),
                (None, Some(fac)) => fac.abs_max,
                (None, None) => 0.0,
            };
            if lazy && let Some(a) = &lin.assembled {
                last_assembled = Some((a.node_stiffness.clone(), abs_max));
            }
            let res_ok = rnorm <= settings.residual_tol_rel * scale || rnorm <= abs_max * tol_x;
            if it > 0 && res_ok && report.last_update_m <= tol_x {
                report.status = SolveStatus::Converged;
                return report;
            }
            let stale = lin.assembled.is_none()
                && (self
                    .factored
                    .as_ref()
                    .is_none_or(|fac| fac.blocks != lin.blocks)
                    || rnorm > STALE_CONTRACTION * previous_rnorm);
            if stale {
                // this iterate linearized afresh (the terms with the new node stiffnesses)
                lin = self.assemble(&*model, x, terms, settings, requery);
                if let Err(status) = self.factor(&lin, reuse) {
                    report.status = status;
                    return report;
                }
                (r, _) = self.residual_with(&lin.f_int, x, f_ext, terms);
                rnorm = r.iter().map(|v| v * v).sum::<f64>().sqrt();
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
            let mut step = 1.0;
            if settings.line_search {
                let r0 = rnorm * rnorm;
                let mut s = 1.0;
                for _ in 0..=settings.max_halvings {
                    let mut xt = x.to_vec();
                    self.dofs().scatter_add(&dx, s, &mut xt);
                    let f_t = model.internal_forces(&xt);
                    let (rt, _) = self.residual_with(&f_t, &xt, f_ext, terms);
                    let rn = rt.iter().map(|v| v * v).sum::<f64>();
                    if rn.is_finite() && rn < r0 {
                        step = s;
                        if reuse {
                            carried = Some((f_t, model.state_id()));
                        } else if lazy {
                            searched = Some((f_t, model.state_id()));
                        }
                        break;
                    }
                    s *= 0.5;
                }
            }
            self.dofs().scatter_add(&dx, step, x);
            report.iterations = it + 1;
            report.last_update_m = dx_inf * step;
        }
        report
    }
}
