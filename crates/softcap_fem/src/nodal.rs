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

use crate::FemError;
use crate::assembly::{
    AssemblyScratch, DofMap, SparseCholesky, SystemPattern, free_residual, solver_setup,
};
use crate::model::ElasticModel;
use crate::statics::{EquilibriumReport, EquilibriumSettings, SolveStatus};
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

    /// Solves f_int(x) = f_ext + Σ f_b(x) for the free dofs from `x` (constrained components hold
    /// their prescribed values). Does not commit the terms' history: call
    /// [`NodalTerm::commit`] on each term after a converged step. Never panics.
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
        let tol_x = settings.displacement_tol_rel * self.length_scale_m;
        let (mut values, mut upper, mut f_int) = (Vec::new(), Vec::new(), Vec::new());
        let unsymmetric = !model.tangent_is_symmetric(settings.stiffness);
        for it in 0..settings.max_iterations {
            model.update_state(x);
            self.pattern.assemble_linearized(
                &*model,
                x,
                settings.stiffness,
                &mut self.scratch,
                &mut values,
                unsymmetric.then_some(&mut upper),
                &mut f_int,
            );
            {
                let pat = &self.pattern;
                let vals = &values;
                let node_k = |n: usize| {
                    let d = pat.node_diagonal(n, vals);
                    let (s, k) = d
                        .iter()
                        .filter(|v| v.is_finite())
                        .fold((0.0, 0), |(s, k), v| (s + v.abs(), k + 1));
                    if k > 0 { s / k as f64 } else { 0.0 }
                };
                let requery = it < settings.contact_freeze_after || it == 0;
                for t in terms.iter_mut() {
                    t.refresh(x, &node_k, requery);
                }
            }
            for t in terms.iter() {
                for (n, m) in t.blocks(x) {
                    self.pattern.add_node_block(n, &m, &mut values);
                    if unsymmetric {
                        self.pattern.add_node_block(n, &m.transpose(), &mut upper);
                    }
                }
                for (a, b, m) in t.pair_blocks(x) {
                    self.pattern.add_pair_block(a, b, &m, &mut values);
                    if unsymmetric {
                        self.pattern.add_pair_block(a, b, &m, &mut upper);
                    }
                }
            }
            let upper_ref = unsymmetric.then_some(upper.as_slice());
            if let Err(e) = self
                .cholesky
                .factor_general(&self.pattern, &values, upper_ref)
            {
                report.status = match e {
                    FemError::NonFinite { .. } => SolveStatus::NonFinite,
                    e => SolveStatus::FactorizationFailed {
                        reason: e.to_string(),
                    },
                };
                return report;
            }
            let (r, scale) = self.residual_with(&f_int, x, f_ext, terms);
            let rnorm = r.iter().map(|v| v * v).sum::<f64>().sqrt();
            report.residual_norm_n = rnorm;
            if !rnorm.is_finite() {
                report.status = SolveStatus::NonFinite;
                return report;
            }
            let diag_max = values.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let res_ok = rnorm <= settings.residual_tol_rel * scale || rnorm <= diag_max * tol_x;
            if it > 0 && res_ok && report.last_update_m <= tol_x {
                report.status = SolveStatus::Converged;
                return report;
            }
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
                    let (rt, _) =
                        self.residual_with(&model.internal_forces(&xt), &xt, f_ext, terms);
                    let rn = rt.iter().map(|v| v * v).sum::<f64>();
                    if rn.is_finite() && rn < r0 {
                        step = s;
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
