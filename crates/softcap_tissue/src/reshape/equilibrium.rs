//! The elastic equilibrium under plastic strains and attachment springs (saito-barbic eq. 4 / 7):
//!
//! f_int(x; s) = Σ_a k (a − x_a),
//!
//! solved by Newton's method on the potential Π(x) = Σ_e V det F_p Ψ(F F_p⁻¹) + k/2 Σ_a ‖x_a − a‖²
//! with an Armijo backtracking line search (the paper uses Knitro or Newton–Raphson; §3.4). When
//! the tangent is indefinite far from equilibrium, a growing multiple of the identity is added
//! until the Newton direction descends. The tangent K = ∂f_int/∂x + k Σ_a (node blocks) at the
//! solution is factored on request ([`Equilibrium::factor_at`]) for the Jacobian solves of the
//! Gauss–Newton step (eq. 10).
//!
//! A free-flying object has no attachments; its equilibrium is unique only up to a rigid motion
//! (§3.6, Nullspace Lemma). The caller then pins six degrees of freedom (a 3-2-1 set: one node
//! fully, a second node across the line to it, a third node out of the plane), which removes the
//! rigid motions without changing the equilibrium shape: the internal forces are self-equilibrated,
//! so the reactions at the pins vanish at equilibrium. Pinned rows of a solve are zero; the caller
//! projects out the rigid null space (singular lemma (ii), see [`super::gauge`]).

use faer::Mat;
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use softcap_fem::assembly::{AssemblyScratch, solver_setup};
use softcap_fem::{
    DofMap, ElasticModel, FemError, PlasticNeoHookeanModel, SparseCholesky, StiffnessKind,
    SystemPattern,
};

/// Tolerances of the Newton iterations.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EquilibriumSettings {
    /// Iteration cap.
    pub max_iterations: usize,
    /// Converged when the last update's largest component ≤ this × the template's bounding-box
    /// diagonal …
    pub displacement_tol_rel: f64,
    /// … and ‖∇Π‖ ≤ this × μ × diagonal² (a force scale of the mesh).
    pub residual_tol_rel: f64,
}

impl Default for EquilibriumSettings {
    fn default() -> Self {
        Self {
            max_iterations: 60,
            displacement_tol_rel: 1e-9,
            residual_tol_rel: 1e-9,
        }
    }
}

/// How an equilibrium solve ended (never a panic).
#[derive(Clone, Debug, PartialEq)]
pub enum EquilibriumStatus {
    /// Both tolerances met.
    Converged,
    /// Iteration cap reached.
    MaxIterations,
    /// A factorization failed or a value became non-finite.
    Failed(String),
}

/// Report of one equilibrium solve.
#[derive(Clone, Debug, PartialEq)]
pub struct EquilibriumOutcome {
    /// Status.
    pub status: EquilibriumStatus,
    /// Newton iterations.
    pub iterations: usize,
    /// Final ‖∇Π‖ over the free dofs \[N\].
    pub residual_norm_n: f64,
}

impl EquilibriumOutcome {
    /// True if converged.
    pub fn converged(&self) -> bool {
        self.status == EquilibriumStatus::Converged
    }
}

/// Newton solver for one template mesh with its attachment springs and pinned dofs.
#[derive(Debug)]
pub struct Equilibrium {
    pattern: SystemPattern,
    cholesky: SparseCholesky,
    scratch: AssemblyScratch,
    values: Vec<f64>,
    gradient: Vec<Vector3<f64>>,
    attachments: Vec<(usize, Vector3<f64>)>,
    stiffness_n_per_m: f64,
    length_scale_m: f64,
    force_scale_n: f64,
    factored: bool,
}

impl Equilibrium {
    /// Solver over `model`'s mesh with springs of stiffness `stiffness_n_per_m` tying each
    /// `(node, target)` of `attachments`, and the dofs `pinned` eliminated.
    pub fn new(
        model: &PlasticNeoHookeanModel,
        attachments: Vec<(usize, Vector3<f64>)>,
        stiffness_n_per_m: f64,
        pinned: &[usize],
    ) -> Result<Self, FemError> {
        let (pattern, cholesky, length_scale_m) = solver_setup(model, pinned)?;
        let mu = model.params().first().map_or(1.0, |p| p.mu);
        Ok(Self {
            pattern,
            cholesky,
            scratch: AssemblyScratch::default(),
            values: Vec::new(),
            gradient: Vec::new(),
            attachments,
            stiffness_n_per_m,
            length_scale_m,
            force_scale_n: mu * length_scale_m * length_scale_m,
            factored: false,
        })
    }

    /// The dof map (free and pinned dofs).
    pub fn dofs(&self) -> &DofMap {
        self.pattern.dofs()
    }

    /// Π(x) without forces or matrix (the line search's merit).
    fn potential(&self, model: &PlasticNeoHookeanModel, x: &[Vector3<f64>]) -> f64 {
        let mut pi = model.energy(x).unwrap_or(f64::NAN);
        for (node, target) in &self.attachments {
            pi += 0.5 * self.stiffness_n_per_m * (x[*node] - target).norm_squared();
        }
        pi
    }

    /// Assembles K (elastic tangent + springs) and ∇Π at `x`; returns Π.
    fn assemble(&mut self, model: &PlasticNeoHookeanModel, x: &[Vector3<f64>]) -> f64 {
        let mut values = std::mem::take(&mut self.values);
        let mut gradient = std::mem::take(&mut self.gradient);
        let energy = self.pattern.assemble_linearized(
            model,
            x,
            StiffnessKind::Consistent,
            &mut self.scratch,
            &mut values,
            None,
            &mut gradient,
        );
        let mut pi = energy.or_else(|| model.energy(x)).unwrap_or(f64::NAN);
        let spring = Matrix3::identity() * self.stiffness_n_per_m;
        for (node, target) in &self.attachments {
            let d = x[*node] - target;
            gradient[*node] += d * self.stiffness_n_per_m;
            pi += 0.5 * self.stiffness_n_per_m * d.norm_squared();
            self.pattern.add_node_block(*node, &spring, &mut values);
        }
        self.values = values;
        self.gradient = gradient;
        pi
    }

    /// Factors the assembled matrix plus `shift` on the diagonal.
    fn factor(&mut self, shift: f64) -> Result<(), FemError> {
        self.factored = false;
        let mut values = self.values.clone();
        if shift > 0.0 {
            let block = Matrix3::identity() * shift;
            for node in 0..self.gradient.len() {
                self.pattern.add_node_block(node, &block, &mut values);
            }
        }
        self.cholesky.factor(&self.pattern, &values)?;
        self.factored = true;
        Ok(())
    }

    /// Assembles and factors K at `x` (the matrix of the Jacobian solves).
    pub fn factor_at(
        &mut self,
        model: &PlasticNeoHookeanModel,
        x: &[Vector3<f64>],
    ) -> Result<(), FemError> {
        self.assemble(model, x);
        self.factor(0.0)
    }

    /// Solves the equilibrium from `x` (pinned components keep their values). The factor is not
    /// kept: [`Self::factor_at`] the returned `x` before [`Self::solve_columns`] (one
    /// factorization less per solve: of a Gauss–Newton iteration's line-search trials only the
    /// accepted one needs the tangent).
    pub fn solve(
        &mut self,
        model: &PlasticNeoHookeanModel,
        x: &mut [Vector3<f64>],
        settings: &EquilibriumSettings,
    ) -> EquilibriumOutcome {
        let tol_x = settings.displacement_tol_rel * self.length_scale_m;
        let tol_r = settings.residual_tol_rel * self.force_scale_n;
        let mut outcome = EquilibriumOutcome {
            status: EquilibriumStatus::MaxIterations,
            iterations: 0,
            residual_norm_n: f64::NAN,
        };
        let mut last_update = f64::INFINITY;
        for it in 0..=settings.max_iterations {
            let pi = self.assemble(model, x);
            let g = self.dofs().gather(&self.gradient);
            let gnorm = g.iter().map(|v| v * v).sum::<f64>().sqrt();
            outcome.residual_norm_n = gnorm;
            outcome.iterations = it;
            if !pi.is_finite() || !gnorm.is_finite() {
                outcome.status = EquilibriumStatus::Failed("non-finite energy or forces".into());
                return outcome;
            }
            if gnorm <= tol_r && (last_update <= tol_x || gnorm == 0.0) {
                // The factor is of the previous iterate's tangent: a line-search trial that is
                // not kept needs none, the kept one gets its own from `factor_at`.
                self.factored = false;
                outcome.status = EquilibriumStatus::Converged;
                return outcome;
            }
            if it == settings.max_iterations {
                break;
            }
            let Some((dx, slope)) = self.descent_direction(&g) else {
                outcome.status = EquilibriumStatus::Failed("no factorizable tangent".into());
                return outcome;
            };
            // Armijo backtracking on Π.
            let mut step = 1.0;
            let mut accepted = false;
            for _ in 0..30 {
                let mut trial = x.to_vec();
                self.dofs().scatter_add(&dx, step, &mut trial);
                let pt = self.potential(model, &trial);
                if pt.is_finite() && pt <= pi + 1e-4 * step * slope + 1e-14 * pi.abs() {
                    x.copy_from_slice(&trial);
                    accepted = true;
                    break;
                }
                step *= 0.5;
            }
            let dx_inf = dx.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            if !accepted {
                // Round-off floor: the step changes Π by less than its last bits.
                if dx_inf <= tol_x {
                    self.dofs().scatter_add(&dx, 1.0, x);
                    last_update = dx_inf;
                    continue;
                }
                outcome.status = EquilibriumStatus::Failed("line search found no decrease".into());
                return outcome;
            }
            last_update = dx_inf * step;
        }
        outcome
    }

    /// A Newton direction −K⁻¹∇Π that descends (slope ∇Π·dx < 0), with a diagonal shift added
    /// to K as long as it does not; `None` when no shift helps.
    fn descent_direction(&mut self, g: &[f64]) -> Option<(Vec<f64>, f64)> {
        let diag_mean = {
            let n = self.gradient.len().max(1);
            (0..self.gradient.len())
                .map(|node| {
                    let d = self.pattern.node_diagonal(node, &self.values);
                    d.iter()
                        .filter(|v| v.is_finite())
                        .map(|v| v.abs())
                        .sum::<f64>()
                })
                .sum::<f64>()
                / (3 * n) as f64
        };
        let mut shift = 0.0;
        for _ in 0..12 {
            if self.factor(shift).is_ok() {
                let mut dx: Vec<f64> = g.iter().map(|v| -v).collect();
                if self.cholesky.solve_in_place(&mut dx).is_ok() {
                    let slope: f64 = dx.iter().zip(g).map(|(a, b)| a * b).sum();
                    if slope < 0.0 && slope.is_finite() {
                        return Some((dx, slope));
                    }
                }
            }
            shift = if shift == 0.0 {
                1e-6 * diag_mean.max(f64::MIN_POSITIVE)
            } else {
                shift * 10.0
            };
        }
        None
    }

    /// K⁻¹ applied to every column of `rhs` (3·nodes rows, dof order 3·node + axis), in place:
    /// pinned rows are ignored on input and zero on output. Columns are solved in parallel blocks.
    pub fn solve_columns(&self, rhs: &mut Mat<f64>) -> Result<(), FemError> {
        if !self.factored {
            return Err(FemError::Factorization {
                reason: "equilibrium tangent not factored".into(),
            });
        }
        let dofs = self.dofs();
        let nfree = dofs.num_free();
        let free: Vec<usize> = (0..nfree).map(|f| dofs.dof(f)).collect();
        let ncols = rhs.ncols();
        let threads = rayon::current_num_threads().max(1);
        let block = ncols.div_ceil(threads).max(1);
        let starts: Vec<usize> = (0..ncols).step_by(block).collect();
        let solved: Vec<Result<Vec<f64>, FemError>> = starts
            .par_iter()
            .map(|&c0| {
                let c1 = (c0 + block).min(ncols);
                let mut buf = vec![0.0; nfree * (c1 - c0)];
                for c in c0..c1 {
                    let col = rhs.col(c);
                    for (f, &d) in free.iter().enumerate() {
                        buf[(c - c0) * nfree + f] = col[d];
                    }
                }
                self.cholesky.solve_in_place(&mut buf)?;
                Ok(buf)
            })
            .collect();
        for (&c0, buf) in starts.iter().zip(solved) {
            let buf = buf?;
            let c1 = (c0 + block).min(ncols);
            for c in c0..c1 {
                let mut col = rhs.col_mut(c);
                col.fill(0.0);
                for (f, &d) in free.iter().enumerate() {
                    col[d] = buf[(c - c0) * nfree + f];
                }
            }
        }
        Ok(())
    }
}
