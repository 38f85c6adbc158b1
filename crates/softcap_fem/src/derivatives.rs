//! Parameter derivatives for fitting: ∂K/∂p_i and the Jacobian J = ∂x/∂p of bickel2009 appendix
//! eq. 10–12, with constrained nodes eliminated.
//!
//! Parameters are ordered p = (λ_0, α_0, λ_1, α_1, …) (index 2e for λ_e, 2e + 1 for α_e).
//!
//! At an equilibrium x of f_int(x; p) = F (+ contact), differentiating gives, on the free dofs,
//!
//! A ∂x/∂p_i = −∂f_int/∂p_i,  ∂f_int/∂p_i = R_e (∂K_e/∂p_i)(R_eᵀ x_e − X_e),
//!
//! with ∂K_e/∂λ_e = V_e B_eᵀ G B_e and ∂K_e/∂α_e = V_e B_eᵀ H B_e (eq. 7, 12), and constrained
//! rows of J equal to zero (their positions are prescribed). This is eq. 11 rewritten: with
//! x = K⁻¹(F + K′X), ∂x/∂p_i = −K⁻¹(∂K/∂p_i x − ∂K′/∂p_i X) = −K⁻¹ ∂f_int/∂p_i.
//!
//! * `A = K` (warped, [`StiffnessKind::Warped`]) is the paper's Jacobian: rotations held fixed.
//! * `A = ∂f/∂x` (consistent, [`StiffnessKind::Consistent`]) is the exact derivative of the
//!   corotational equilibrium (rotations follow the parameters); with contact, the active springs'
//!   k n nᵀ is part of A.
//!
//! Both reuse one factorization for every column / row. For thousands of parameters and a few
//! hundred observed coordinates use [`Sensitivity::jacobian_rows`] (one solve per observed dof,
//! adjoint) or [`Sensitivity::jt_times`] (one solve for Jᵀr); [`Sensitivity::jacobian_columns`]
//! costs one solve per parameter.

use crate::FemError;
use crate::contact::ContactProblem;
use crate::element::{Matrix12, StiffnessKind, corotational_parameter_forces, stiffness_basis};
use crate::model::{CorotationalModel, ElasticModel};
use crate::statics::StaticSolver;
use faer::Mat;
use nalgebra::Vector3;

/// Index of λ_e in p.
pub fn lambda_index(element: usize) -> usize {
    2 * element
}

/// Index of α_e in p.
pub fn alpha_index(element: usize) -> usize {
    2 * element + 1
}

/// ∂K_e/∂p_i of the unwarped element stiffness (bickel2009 eq. 7, 12): V BᵀGB for λ, V BᵀHB for α.
/// The global ∂K/∂p_i is R_e (this) R_eᵀ assembled at element e's nodes.
pub fn element_stiffness_derivative(model: &CorotationalModel, param: usize) -> Matrix12 {
    let (kg, kh) = stiffness_basis(&model.elements()[param / 2]);
    if param.is_multiple_of(2) { kg } else { kh }
}

/// Factorized linearization at an equilibrium, ready to produce Jacobian columns, rows and Jᵀr.
pub struct Sensitivity<'s> {
    solver: &'s StaticSolver,
    nodes: Vec<[usize; 4]>,
    /// per element: (∂f/∂λ_e, ∂f/∂α_e) at its 4 nodes
    dforce: Vec<([Vector3<f64>; 4], [Vector3<f64>; 4])>,
}

impl std::fmt::Debug for Sensitivity<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Sensitivity")
            .field("elements", &self.nodes.len())
            .finish()
    }
}

impl<'s> Sensitivity<'s> {
    /// Linearizes `model` at the equilibrium `x` (constrained dofs those of `solver`), factoring
    /// the chosen matrix once. `contact`: the probe active at this equilibrium, if any.
    pub fn new(
        solver: &'s mut StaticSolver,
        model: &CorotationalModel,
        x: &[Vector3<f64>],
        kind: StiffnessKind,
        contact: Option<&ContactProblem>,
    ) -> Result<Self, FemError> {
        if x.len() != model.num_nodes() {
            return Err(FemError::LengthMismatch {
                what: "positions",
                expected: model.num_nodes(),
                got: x.len(),
            });
        }
        solver.assemble_and_factor(model, x, kind, contact)?;
        let dforce = model
            .elements()
            .iter()
            .map(|g| corotational_parameter_forces(g, x))
            .collect();
        let nodes = model.elements().iter().map(|g| g.nodes).collect();
        let solver: &'s StaticSolver = solver;
        Ok(Self {
            solver,
            nodes,
            dforce,
        })
    }

    /// Number of parameters (2 × elements).
    pub fn num_params(&self) -> usize {
        2 * self.nodes.len()
    }

    fn param_force(&self, param: usize) -> &[Vector3<f64>; 4] {
        let d = &self.dforce[param / 2];
        if param.is_multiple_of(2) { &d.0 } else { &d.1 }
    }

    /// Columns J[:, i] = ∂x/∂p_i (3·nodes rows, dof order; constrained rows 0) for `params`.
    pub fn jacobian_columns(&self, params: &[usize]) -> Result<Mat<f64>, FemError> {
        let dofs = self.solver.dofs();
        let nf = dofs.num_free();
        let mut rhs = vec![0.0; nf * params.len()];
        for (c, &p) in params.iter().enumerate() {
            if p >= self.num_params() {
                return Err(FemError::LengthMismatch {
                    what: "parameter index",
                    expected: self.num_params(),
                    got: p,
                });
            }
            let nodes = self.nodes[p / 2];
            let f = self.param_force(p);
            for a in 0..4 {
                for k in 0..3 {
                    if let Some(fi) = dofs.free_index(3 * nodes[a] + k) {
                        rhs[c * nf + fi] -= f[a][k];
                    }
                }
            }
        }
        self.solver.cholesky().solve_in_place(&mut rhs)?;
        let mut j = Mat::<f64>::zeros(dofs.num_dofs(), params.len());
        for c in 0..params.len() {
            for fi in 0..nf {
                j[(dofs.dof(fi), c)] = rhs[c * nf + fi];
            }
        }
        Ok(j)
    }

    /// Rows J[d, :] for the observed dofs `dofs_observed` (adjoint: one solve per row, A symmetric):
    /// J[d, i] = −yᵀ ∂f/∂p_i with A y = e_d. Rows of constrained dofs are zero.
    pub fn jacobian_rows(&self, dofs_observed: &[usize]) -> Result<Mat<f64>, FemError> {
        let dofs = self.solver.dofs();
        let nf = dofs.num_free();
        let mut rhs = vec![0.0; nf * dofs_observed.len()];
        for (r, &d) in dofs_observed.iter().enumerate() {
            if d >= dofs.num_dofs() {
                return Err(FemError::DofOutOfRange {
                    dof: d,
                    num_dofs: dofs.num_dofs(),
                });
            }
            if let Some(fi) = dofs.free_index(d) {
                rhs[r * nf + fi] = 1.0;
            }
        }
        self.solver.cholesky().solve_in_place(&mut rhs)?;
        let mut j = Mat::<f64>::zeros(dofs_observed.len(), self.num_params());
        for r in 0..dofs_observed.len() {
            let y = &rhs[r * nf..(r + 1) * nf];
            for p in 0..self.num_params() {
                j[(r, p)] = -self.dot_free(y, p);
            }
        }
        Ok(j)
    }

    fn dot_free(&self, y: &[f64], p: usize) -> f64 {
        let dofs = self.solver.dofs();
        let nodes = self.nodes[p / 2];
        let f = self.param_force(p);
        let mut s = 0.0;
        for a in 0..4 {
            for k in 0..3 {
                if let Some(fi) = dofs.free_index(3 * nodes[a] + k) {
                    s += y[fi] * f[a][k];
                }
            }
        }
        s
    }

    /// J v = (∂x/∂p) v for a parameter direction `v` (2 × elements, (λ_e, α_e) interleaved):
    /// the forward sensitivity of bickel2009 appendix eq. 11 along v, one solve
    /// A (J v) = −Σᵢ vᵢ ∂f/∂pᵢ. Result over all dofs (3·nodes, constrained entries 0).
    pub fn jacobian_times(&self, v: &[f64]) -> Result<Vec<f64>, FemError> {
        if v.len() != self.num_params() {
            return Err(FemError::LengthMismatch {
                what: "parameter direction",
                expected: self.num_params(),
                got: v.len(),
            });
        }
        let dofs = self.solver.dofs();
        let mut rhs = vec![0.0; dofs.num_free()];
        for (p, &vp) in v.iter().enumerate() {
            if vp == 0.0 {
                continue;
            }
            let nodes = self.nodes[p / 2];
            let f = self.param_force(p);
            for a in 0..4 {
                for k in 0..3 {
                    if let Some(fi) = dofs.free_index(3 * nodes[a] + k) {
                        rhs[fi] -= vp * f[a][k];
                    }
                }
            }
        }
        self.solver.cholesky().solve_in_place(&mut rhs)?;
        let mut out = vec![0.0; dofs.num_dofs()];
        for (fi, val) in rhs.iter().enumerate() {
            out[dofs.dof(fi)] = *val;
        }
        Ok(out)
    }

    /// Jᵀ wₖ for several sparse dof weightings wₖ = Σ (dof, weight) at once (the adjoint rows of
    /// bickel2009 appendix eq. 12 for embedded markers): one multi-column solve A Y = W, then
    /// (Jᵀ wₖ)_p = −yₖᵀ ∂f/∂p_p. Same values as [`Self::jt_times`] per row, with the triangular
    /// solves blocked over the columns.
    pub fn jt_times_sparse(&self, rows: &[Vec<(usize, f64)>]) -> Result<Vec<Vec<f64>>, FemError> {
        let dofs = self.solver.dofs();
        let nf = dofs.num_free();
        let k = rows.len();
        let mut rhs = vec![0.0; nf * k];
        for (r, row) in rows.iter().enumerate() {
            for &(d, w) in row {
                if d >= dofs.num_dofs() {
                    return Err(FemError::DofOutOfRange {
                        dof: d,
                        num_dofs: dofs.num_dofs(),
                    });
                }
                if let Some(fi) = dofs.free_index(d) {
                    rhs[r * nf + fi] += w;
                }
            }
        }
        if k > 0 {
            self.solver.cholesky().solve_in_place(&mut rhs)?;
        }
        // Free index of each element dof once (usize::MAX = constrained).
        let free: Vec<[usize; 12]> = self
            .nodes
            .iter()
            .map(|nodes| {
                let mut f = [usize::MAX; 12];
                for a in 0..4 {
                    for c in 0..3 {
                        if let Some(fi) = dofs.free_index(3 * nodes[a] + c) {
                            f[3 * a + c] = fi;
                        }
                    }
                }
                f
            })
            .collect();
        let np = self.num_params();
        Ok((0..k)
            .map(|r| {
                let y = &rhs[r * nf..(r + 1) * nf];
                let mut out = vec![0.0; np];
                for (e, fe) in free.iter().enumerate() {
                    let (dl, da) = &self.dforce[e];
                    let (mut sl, mut sa) = (0.0, 0.0);
                    for a in 0..4 {
                        for c in 0..3 {
                            let fi = fe[3 * a + c];
                            if fi != usize::MAX {
                                sl += y[fi] * dl[a][c];
                                sa += y[fi] * da[a][c];
                            }
                        }
                    }
                    out[2 * e] = -sl;
                    out[2 * e + 1] = -sa;
                }
                out
            })
            .collect())
    }

    /// Jᵀ r for a residual over all dofs (3·nodes; constrained entries ignored): one solve.
    pub fn jt_times(&self, r: &[f64]) -> Result<Vec<f64>, FemError> {
        let dofs = self.solver.dofs();
        if r.len() != dofs.num_dofs() {
            return Err(FemError::LengthMismatch {
                what: "residual",
                expected: dofs.num_dofs(),
                got: r.len(),
            });
        }
        let mut y: Vec<f64> = (0..dofs.num_free()).map(|f| r[dofs.dof(f)]).collect();
        self.solver.cholesky().solve_in_place(&mut y)?;
        Ok((0..self.num_params())
            .map(|p| -self.dot_free(&y, p))
            .collect())
    }
}
