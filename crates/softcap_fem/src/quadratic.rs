//! Quadratic (10-node) corotational tetrahedra: the converged-in-bending companion of the linear
//! tets, for fits whose modulus must be the material's, not the mesh's (wang2015 §7 notes the
//! artificial stiffness of coarse linear meshes; a linear-tet bar in bending is 1.1–2.6× too
//! stiff at the sizes softcap fits on, see docs/dynamic-fit.md).
//!
//! Element: the isoparametric 10-node tet (corners, then the midpoints of the edges
//! [`EDGES`]), shape functions N_i = L_i (2L_i − 1) at corner i and N_ij = 4 L_i L_j at edge
//! (i, j) in barycentric coordinates L, stiffness K_e = ∫ Bᵀ C B by the 4-point rule of degree 2
//! (exact for a straight-sided element), per 3×3 node block
//!
//! K_ab = Σ_q w_q det J_q (λ_L g_a g_bᵀ + μ (g_b g_aᵀ + (g_a·g_b) I)),  g = ∇_X N(ξ_q).
//!
//! Corotation per element (Müller & Gross 2004, as the linear model; Mezger et al. 2008 for
//! quadratic tets), with the rotation R of the polar decomposition of the deformation gradient
//! at the element centroid: f_e = R K_e (Rᵀ x_e − X_e), warped stiffness R K_e Rᵀ, energy
//! ½ ũᵀ K_e ũ with ũ = Rᵀ x_e − X_e.
//!
//! [`QuadraticSolver`] integrates M ẍ + (αM + βK) ẋ + f_int(x) = f_ext with the same implicit
//! Euler / Newmark kinematics, settings and reports as [`crate::DynamicSolver`] (Newton per
//! step on the free dofs, Dirichlet constraints eliminated), solves statics, and computes the
//! smallest modes of K φ = λ M φ by subspace iteration. Masses are lumped, one per node, from
//! the caller (e.g. [`crate::lumped_masses`] of the once-refined linear mesh on the same nodes:
//! the eight sub-tets' quarter masses, all positive, unlike the row sums of the consistent
//! quadratic mass matrix).

use crate::assembly::{DirichletBc, DofMap, SparseCholesky, SystemPattern, quadratic_solver_setup};
use crate::dynamics::{
    DynamicSolver, DynamicState, DynamicStepReport, DynamicStepStatus, DynamicsSettings, entry_max,
    finish_iteration,
};
use crate::modal::Modes;
use crate::{FemError, LinearParams};
use nalgebra::{DMatrix, Matrix3, Vector3};
use softcap_mesh::TetMesh;

/// Local corner pairs of the six edge nodes 4..10 of a quadratic element.
pub const EDGES: [[usize; 2]; 6] = [[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]];

/// A mesh of quadratic tets: nodes and 10-node elements (corners, then edge midpoints).
#[derive(Clone, Debug, PartialEq)]
pub struct QuadraticTetMesh {
    /// Node positions \[m\]: the linear mesh's vertices (same indices), then the edge midpoints.
    pub nodes: Vec<Vector3<f64>>,
    /// 10 node indices per element.
    pub elements: Vec<[usize; 10]>,
}

/// The quadratic tets of a linear tet mesh. Its nodes are those of
/// [`softcap_mesh::refine_tets`] (the input vertices, then the edge midpoints in the same order),
/// so a field on the once-refined mesh is a field on the quadratic mesh.
pub fn quadratic_tets(mesh: &TetMesh) -> QuadraticTetMesh {
    let refined = softcap_mesh::refine_tets(mesh);
    let n = mesh.vertices.len();
    let index: std::collections::HashMap<[usize; 2], usize> = refined
        .midpoint_of
        .iter()
        .enumerate()
        .map(|(k, &e)| (e, n + k))
        .collect();
    let elements = mesh
        .tets
        .iter()
        .map(|t| {
            let mut el = [0usize; 10];
            el[..4].copy_from_slice(t);
            for (k, [i, j]) in EDGES.iter().enumerate() {
                let key = [t[*i].min(t[*j]), t[*i].max(t[*j])];
                el[4 + k] = index[&key];
            }
            el
        })
        .collect();
    QuadraticTetMesh {
        nodes: refined.mesh.vertices,
        elements,
    }
}

/// The ten shape functions N_a at barycentric coordinates `l` (corners L_i (2L_i − 1), edges
/// 4 L_i L_j in the order of [`EDGES`]): a field on the quadratic nodes evaluated inside an element.
pub fn shape_functions(l: [f64; 4]) -> [f64; 10] {
    let mut n = [0.0; 10];
    for i in 0..4 {
        n[i] = l[i] * (2.0 * l[i] - 1.0);
    }
    for (k, [i, j]) in EDGES.iter().enumerate() {
        n[4 + k] = 4.0 * l[*i] * l[*j];
    }
    n
}

/// ∂N_a/∂L_k of the ten shape functions at barycentric coordinates `l`.
pub(crate) fn shape_derivatives(l: [f64; 4]) -> [[f64; 4]; 10] {
    let mut d = [[0.0; 4]; 10];
    for i in 0..4 {
        d[i][i] = 4.0 * l[i] - 1.0;
    }
    for (k, [i, j]) in EDGES.iter().enumerate() {
        d[4 + k][*i] = 4.0 * l[*j];
        d[4 + k][*j] = 4.0 * l[*i];
    }
    d
}

/// Gradients ∇_X N_a at barycentric `l` of the element with nodes `x`, and det J (6 × the
/// volume of a straight-sided element).
pub(crate) fn gradients(x: &[Vector3<f64>; 10], l: [f64; 4]) -> Option<([Vector3<f64>; 10], f64)> {
    // ξ = (L1, L2, L3), L0 = 1 − ξ₁ − ξ₂ − ξ₃: ∂N/∂ξ_j = ∂N/∂L_j − ∂N/∂L_0.
    let d = shape_derivatives(l);
    let dxi: [Vector3<f64>; 10] = std::array::from_fn(|a| {
        Vector3::new(d[a][1] - d[a][0], d[a][2] - d[a][0], d[a][3] - d[a][0])
    });
    let mut j = Matrix3::zeros();
    for a in 0..10 {
        j += x[a] * dxi[a].transpose();
    }
    let det = j.determinant();
    let jinv_t = j.try_inverse()?.transpose();
    (det > 0.0).then(|| (std::array::from_fn(|a| jinv_t * dxi[a]), det))
}

/// The 4-point rule of degree 2 on the tet: barycentric points, weight 1/24 each (of the
/// reference volume 1/6).
pub(crate) fn quadrature() -> [[f64; 4]; 4] {
    let (a, b) = (0.585_410_196_624_968_5, 0.138_196_601_125_010_5);
    [[a, b, b, b], [b, a, b, b], [b, b, a, b], [b, b, b, a]]
}

/// 3×3 block of a 30×30 element matrix.
type Blocks = [[Matrix3<f64>; 10]; 10];

/// Corotational quadratic-tet model with per-element linear parameters.
#[derive(Clone, Debug)]
pub struct QuadraticModel {
    rest: Vec<Vector3<f64>>,
    elements: Vec<[usize; 10]>,
    /// K_e per element as node blocks.
    stiffness: Vec<Box<Blocks>>,
    /// ∇_X N_a at the centroid (the rotation's deformation gradient).
    centroid_grads: Vec<[Vector3<f64>; 10]>,
}

impl QuadraticModel {
    /// Model over rest positions `rest` with `elements` and one parameter set per element.
    pub fn new(
        rest: &[Vector3<f64>],
        elements: &[[usize; 10]],
        params: &[LinearParams],
    ) -> Result<Self, FemError> {
        if params.len() != elements.len() {
            return Err(FemError::LengthMismatch {
                what: "per-element parameters",
                expected: elements.len(),
                got: params.len(),
            });
        }
        let mut stiffness = Vec::with_capacity(elements.len());
        let mut centroid_grads = Vec::with_capacity(elements.len());
        for (e, (el, p)) in elements.iter().zip(params).enumerate() {
            p.validate(e)?;
            if let Some(&v) = el.iter().find(|&&v| v >= rest.len()) {
                return Err(FemError::VertexOutOfRange {
                    tet: e,
                    vertex: v,
                    num_vertices: rest.len(),
                });
            }
            let xe: [Vector3<f64>; 10] = std::array::from_fn(|a| rest[el[a]]);
            let (lame, mu) = p.lame();
            let degenerate = || {
                let volume_m3 = (xe[1] - xe[0]).dot(&(xe[2] - xe[0]).cross(&(xe[3] - xe[0]))) / 6.0;
                FemError::DegenerateElement { tet: e, volume_m3 }
            };
            let mut k: Box<Blocks> = Box::new([[Matrix3::zeros(); 10]; 10]);
            for l in quadrature() {
                let (g, det) = gradients(&xe, l).ok_or_else(degenerate)?;
                let w = det / 24.0;
                for a in 0..10 {
                    for b in 0..10 {
                        let d = g[a].dot(&g[b]);
                        k[a][b] += (g[a] * g[b].transpose() * lame
                            + (g[b] * g[a].transpose() + Matrix3::identity() * d) * mu)
                            * w;
                    }
                }
            }
            stiffness.push(k);
            let (g, _) = gradients(&xe, [0.25; 4]).ok_or_else(degenerate)?;
            centroid_grads.push(g);
        }
        Ok(Self {
            rest: rest.to_vec(),
            elements: elements.to_vec(),
            stiffness,
            centroid_grads,
        })
    }

    /// Rest positions X \[m\].
    pub fn rest_positions(&self) -> &[Vector3<f64>] {
        &self.rest
    }

    /// The elements.
    pub fn elements(&self) -> &[[usize; 10]] {
        &self.elements
    }

    /// Number of nodes.
    pub fn num_nodes(&self) -> usize {
        self.rest.len()
    }

    /// Rotation R_e of the polar decomposition of the deformation gradient at element `e`'s
    /// centroid.
    pub fn rotation(&self, e: usize, x: &[Vector3<f64>]) -> Matrix3<f64> {
        let mut f = Matrix3::zeros();
        for (a, g) in self.centroid_grads[e].iter().enumerate() {
            f += x[self.elements[e][a]] * g.transpose();
        }
        crate::element::corotated_strain(&f).0
    }

    /// Forces f_e = R K_e (Rᵀ x_e − X_e) of element `e` (per element node), its rotation and
    /// its energy ½ ũᵀ K_e ũ.
    fn element_forces(
        &self,
        e: usize,
        x: &[Vector3<f64>],
    ) -> ([Vector3<f64>; 10], Matrix3<f64>, f64) {
        let r = self.rotation(e, x);
        let el = &self.elements[e];
        // Relative to the first node (K annihilates translations): Rᵀ x − X in absolute
        // coordinates loses digits far from the origin.
        let (x0, rest0) = (x[el[0]], self.rest[el[0]]);
        let u: [Vector3<f64>; 10] =
            std::array::from_fn(|a| r.transpose() * (x[el[a]] - x0) - (self.rest[el[a]] - rest0));
        let k = &self.stiffness[e];
        let mut energy = 0.0;
        let f = std::array::from_fn(|a| {
            let mut s = Vector3::zeros();
            for b in 0..10 {
                s += k[a][b] * u[b];
            }
            energy += 0.5 * u[a].dot(&s);
            r * s
        });
        (f, r, energy)
    }

    /// Elastic energy Σ_e ½ ũᵀ K_e ũ at `x`.
    pub fn energy(&self, x: &[Vector3<f64>]) -> f64 {
        (0..self.elements.len())
            .map(|e| self.element_forces(e, x).2)
            .sum()
    }

    /// Global internal forces f_int(x).
    pub fn internal_forces(&self, x: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        let mut out = vec![Vector3::zeros(); self.rest.len()];
        for e in 0..self.elements.len() {
            let (f, _, _) = self.element_forces(e, x);
            for (a, fa) in f.iter().enumerate() {
                out[self.elements[e][a]] += fa;
            }
        }
        out
    }
}

/// Implicit dynamics, statics and modes of a [`QuadraticModel`] with lumped masses and a fixed
/// constrained-dof set (see the module docs).
#[derive(Debug)]
pub struct QuadraticSolver {
    pattern: SystemPattern,
    cholesky: SparseCholesky,
    masses_kg: Vec<f64>,
    length_scale_m: f64,
}

/// Outcome of [`QuadraticSolver::solve_static`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StaticReport {
    /// Residual below the tolerance.
    pub converged: bool,
    /// Newton iterations taken.
    pub iterations: usize,
    /// ‖f_ext − f_int‖ / ‖f_ext‖ on the free dofs at the end.
    pub relative_residual: f64,
}

fn norm(r: &[f64]) -> f64 {
    r.iter().map(|v| v * v).sum::<f64>().sqrt()
}

/// One pass over the elements: the assembled a_stiff Σ R K Rᵀ (free dofs), f_int and β K v.
struct Pass {
    values: Vec<f64>,
    fi: Vec<Vector3<f64>>,
    kv: Vec<Vector3<f64>>,
}

impl QuadraticSolver {
    /// Pattern and symbolic factorization; `masses_kg` one per node.
    pub fn new(
        model: &QuadraticModel,
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
        let (pattern, cholesky, length_scale_m) =
            quadratic_solver_setup(&model.elements, &model.rest, constrained_dofs)?;
        Ok(Self {
            pattern,
            cholesky,
            masses_kg,
            length_scale_m,
        })
    }

    /// The dof map.
    pub fn dofs(&self) -> &DofMap {
        self.pattern.dofs()
    }

    fn pass(
        &self,
        model: &QuadraticModel,
        x: &[Vector3<f64>],
        v: Option<&[Vector3<f64>]>,
        a_stiff: f64,
    ) -> Pass {
        let n = model.num_nodes();
        let mut values = self.pattern.zeros();
        let mut fi = vec![Vector3::zeros(); n];
        let mut kv = vec![Vector3::zeros(); n];
        for e in 0..model.elements.len() {
            let el = &model.elements[e];
            let (f, r, _) = model.element_forces(e, x);
            let k = &model.stiffness[e];
            for a in 0..10 {
                fi[el[a]] += f[a];
                for b in 0..10 {
                    let kw = r * k[a][b] * r.transpose();
                    if let Some(v) = v {
                        kv[el[a]] += kw * v[el[b]];
                    }
                    if a == b {
                        self.pattern
                            .add_node_block(el[a], &(kw * a_stiff), &mut values);
                    } else if a < b {
                        self.pattern
                            .add_pair_block(el[a], el[b], &(kw * a_stiff), &mut values);
                    }
                }
            }
        }
        Pass { values, fi, kv }
    }

    /// The assembled warped stiffness Σ_e R K_e Rᵀ at `x` times `v` on the free dofs (zero on
    /// the constrained ones): the tangent the Newton steps use.
    pub fn stiffness_times(
        &self,
        model: &QuadraticModel,
        x: &[Vector3<f64>],
        v: &[Vector3<f64>],
    ) -> Vec<Vector3<f64>> {
        let p = self.pass(model, x, None, 1.0);
        let kv = self.pattern.mul_vec(&p.values, &self.dofs().gather(v));
        let mut out = vec![Vector3::zeros(); v.len()];
        self.dofs().scatter_add(&kv, 1.0, &mut out);
        out
    }

    /// a₀ = M⁻¹ (f_ext − f_int(x₀) − D v₀) on the free dofs: the consistent start of a Newmark run.
    pub fn initialize_acceleration(
        &self,
        model: &QuadraticModel,
        state: &mut DynamicState,
        external_forces_n: &[Vector3<f64>],
        settings: &DynamicsSettings,
    ) {
        let p = self.pass(model, &state.positions_m, Some(&state.velocities_m_s), 1.0);
        let d = settings.damping;
        for (i, a) in state.accelerations_m_s2.iter_mut().enumerate() {
            let m = self.masses_kg[i];
            *a = Vector3::zeros();
            if m > 0.0 {
                let r = external_forces_n[i]
                    - p.fi[i]
                    - state.velocities_m_s[i] * (d.alpha_per_s * m)
                    - p.kv[i] * d.beta_s;
                for c in 0..3 {
                    if self.dofs().free_index(3 * i + c).is_some() {
                        a[c] = r[c] / m;
                    }
                }
            }
        }
    }

    /// Advances `state` by one step (as [`DynamicSolver::step_with`] without contact or node
    /// terms): Newton on x_{n+1} with A = c_x M + c_v D + K, K the warped stiffness.
    pub fn step(
        &mut self,
        model: &QuadraticModel,
        state: &mut DynamicState,
        external_forces_n: &[Vector3<f64>],
        prescribed: Option<&DirichletBc>,
        initial_guess: Option<&[Vector3<f64>]>,
        settings: &DynamicsSettings,
    ) -> DynamicStepReport {
        let mut report = DynamicStepReport {
            status: DynamicStepStatus::MaxIterations,
            iterations: 0,
            residual_norm_n: f64::NAN,
            contact: Default::default(),
        };
        let n = model.num_nodes();
        let h = settings.time_step_s;
        if state.positions_m.len() != n
            || external_forces_n.len() != n
            || !(h > 0.0 && h.is_finite())
        {
            report.status = DynamicStepStatus::Failed {
                reason: "length mismatch of state / forces, or time step not positive".into(),
            };
            return report;
        }
        let crate::dynamics::Kinematics { cx, cv } = DynamicSolver::kinematics(settings);
        let damping = settings.damping;
        let a_mass = cx + damping.alpha_per_s * cv;
        let a_stiff = 1.0 + damping.beta_s * cv;
        let mut x: Vec<Vector3<f64>> = match initial_guess {
            Some(g) => g.to_vec(),
            None => state.predicted_positions(h, settings.integrator),
        };
        for d in 0..3 * n {
            if self.dofs().free_index(d).is_none() {
                x[d / 3][d % 3] = state.positions_m[d / 3][d % 3];
            }
        }
        if let Some(bc) = prescribed {
            bc.apply(&mut x);
        }
        let norm = |v: &[Vector3<f64>]| v.iter().map(|a| a.norm_squared()).sum::<f64>().sqrt();
        let tol_x = settings.displacement_tol_rel * self.length_scale_m;
        for it in 0..settings.max_iterations.max(1) + 1 {
            let (v, a) = DynamicSolver::velocity_acceleration(settings, state, &x);
            let Pass { mut values, fi, kv } = self.pass(model, &x, Some(&v), a_stiff);
            for (i, &m) in self.masses_kg.iter().enumerate() {
                self.pattern
                    .add_node_block(i, &(Matrix3::identity() * (a_mass * m)), &mut values);
            }
            let inertia: Vec<Vector3<f64>> = a
                .iter()
                .zip(&self.masses_kg)
                .map(|(ai, m)| ai * *m)
                .collect();
            let r: Vec<Vector3<f64>> = (0..n)
                .map(|i| {
                    external_forces_n[i]
                        - fi[i]
                        - v[i] * (damping.alpha_per_s * self.masses_kg[i])
                        - kv[i] * damping.beta_s
                        - inertia[i]
                })
                .collect();
            let rf = self.dofs().gather(&r);
            let rn = rf.iter().map(|v| v * v).sum::<f64>().sqrt();
            report.residual_norm_n = rn;
            if !rn.is_finite() {
                report.status = DynamicStepStatus::Failed {
                    reason: "non-finite residual".into(),
                };
                return report;
            }
            let scale = norm(external_forces_n).max(norm(&fi)).max(norm(&inertia));
            let diag_max = entry_max(&values);
            if finish_iteration(settings, it, rn, scale, diag_max, tol_x, &mut report.status) {
                state.advance(h, x, v, a);
                return report;
            }
            match self.solve(&values, rf) {
                Ok(dx) => self.dofs().scatter_add(&dx, 1.0, &mut x),
                Err(reason) => {
                    report.status = DynamicStepStatus::Failed { reason };
                    return report;
                }
            }
            report.iterations = it + 1;
        }
        report
    }

    fn solve(&mut self, values: &[f64], mut rhs: Vec<f64>) -> Result<Vec<f64>, String> {
        self.cholesky
            .factor(&self.pattern, values)
            .map_err(|e| e.to_string())?;
        self.cholesky
            .solve_in_place(&mut rhs)
            .map_err(|e| e.to_string())?;
        if rhs.iter().all(|v| v.is_finite()) {
            Ok(rhs)
        } else {
            Err("non-finite update".into())
        }
    }

    /// Static equilibrium f_int(x) = f_ext by Newton with the warped stiffness R K Rᵀ (which
    /// leaves out ∂R/∂x: the iterations converge linearly, fast for moderate rotations) and full
    /// steps, from `x` (constrained dofs as given).
    /// Converged when the residual is below `tolerance` × ‖f_ext‖ on the free dofs.
    pub fn solve_static(
        &mut self,
        model: &QuadraticModel,
        x: &mut [Vector3<f64>],
        external_forces_n: &[Vector3<f64>],
        tolerance: f64,
        max_iterations: usize,
    ) -> StaticReport {
        let dofs = self.dofs().clone();
        let load = norm(&dofs.gather(external_forces_n)).max(f64::MIN_POSITIVE);
        let residual = |x: &[Vector3<f64>]| -> Vec<f64> {
            let fi = model.internal_forces(x);
            let r: Vec<Vector3<f64>> = external_forces_n
                .iter()
                .zip(&fi)
                .map(|(a, b)| a - b)
                .collect();
            dofs.gather(&r)
        };
        let mut report = StaticReport {
            converged: false,
            iterations: 0,
            relative_residual: norm(&residual(x)) / load,
        };
        while report.iterations < max_iterations {
            if !report.relative_residual.is_finite() {
                return report;
            }
            if report.relative_residual <= tolerance {
                report.converged = true;
                return report;
            }
            let p = self.pass(model, x, None, 1.0);
            let r: Vec<Vector3<f64>> = external_forces_n
                .iter()
                .zip(&p.fi)
                .map(|(a, b)| a - b)
                .collect();
            let rf = dofs.gather(&r);
            let Ok(dx) = self.solve(&p.values, rf) else {
                return report;
            };
            // Full steps: the first one from a rotated state leaves a large residual (the
            // linear solution rotates the elements), the next ones converge it; a line search on
            // the residual or the energy would cut the first step and stall.
            dofs.scatter_add(&dx, 1.0, x);
            report.relative_residual = norm(&residual(x)) / load;
            report.iterations += 1;
        }
        report.converged = report.relative_residual <= tolerance;
        report
    }

    /// The `count` smallest modes of K φ = λ M φ at the rest shape (K = K_e assembled, the
    /// constrained dofs fixed), M-orthonormal, by subspace iteration with a block of
    /// 2·count + 4 vectors and Rayleigh–Ritz until the eigenvalues settle to 1e-10.
    pub fn modes(&mut self, model: &QuadraticModel, count: usize) -> Result<Modes, FemError> {
        let p = self.pass(model, &model.rest, None, 1.0);
        let nf = self.dofs().num_free();
        let m_free: Vec<f64> = (0..nf)
            .map(|f| self.masses_kg[self.dofs().dof(f) / 3])
            .collect();
        if let Some(&m) = m_free.iter().find(|m| m.is_nan() || **m <= 0.0) {
            return Err(FemError::InvalidSetting {
                what: "nodal mass kg of a free dof",
                value: m,
            });
        }
        self.cholesky.factor(&self.pattern, &p.values)?;
        let block = (2 * count + 4).min(nf);
        // Deterministic start: smooth and rough node-position patterns.
        let mut y = DMatrix::<f64>::from_fn(nf, block, |f, j| {
            let d = self.dofs().dof(f);
            let x = model.rest[d / 3];
            ((j + 1) as f64 * (x.x + 1.7 * x.y + 2.3 * x.z) * 37.0 + (d % 3 + j) as f64).sin()
        });
        let mut previous = vec![f64::INFINITY; count];
        let mut eig = (Vec::new(), DMatrix::zeros(0, 0));
        for _ in 0..200 {
            // Y ← K⁻¹ M Y.
            for j in 0..block {
                let mut col: Vec<f64> = (0..nf).map(|f| m_free[f] * y[(f, j)]).collect();
                self.cholesky.solve_in_place(&mut col)?;
                y.column_mut(j).copy_from_slice(&col);
            }
            // Rayleigh–Ritz on span Y.
            let mut ky = DMatrix::<f64>::zeros(nf, block);
            for j in 0..block {
                let col: Vec<f64> = y.column(j).iter().copied().collect();
                ky.column_mut(j)
                    .copy_from_slice(&self.pattern.mul_vec(&p.values, &col));
            }
            let my = DMatrix::from_fn(nf, block, |f, j| m_free[f] * y[(f, j)]);
            let kr = y.transpose() * &ky;
            let mr = y.transpose() * &my;
            let kr = (&kr + kr.transpose()) * 0.5;
            let mr = (&mr + mr.transpose()) * 0.5;
            let l = mr.cholesky().ok_or(FemError::Factorization {
                reason: "subspace mass matrix not positive definite".into(),
            })?;
            let linv = l.l().try_inverse().ok_or(FemError::Factorization {
                reason: "subspace mass factor singular".into(),
            })?;
            let s = &linv * kr * linv.transpose();
            let se = nalgebra::SymmetricEigen::new((&s + s.transpose()) * 0.5);
            let mut order: Vec<usize> = (0..block).collect();
            order.sort_by(|&a, &b| se.eigenvalues[a].total_cmp(&se.eigenvalues[b]));
            let q = linv.transpose() * &se.eigenvectors;
            let vals: Vec<f64> = order.iter().map(|&k| se.eigenvalues[k]).collect();
            let yq = &y * &q;
            y = DMatrix::from_fn(nf, block, |f, j| yq[(f, order[j])]);
            let settled = vals[..count]
                .iter()
                .zip(&previous)
                .all(|(a, b)| (a - b).abs() <= 1e-10 * a.abs());
            previous = vals[..count].to_vec();
            eig = (vals, y.clone());
            if settled {
                break;
            }
        }
        let (vals, vecs) = eig;
        let shapes = (0..count)
            .map(|j| {
                let mut s = vec![Vector3::zeros(); model.num_nodes()];
                let col: Vec<f64> = vecs.column(j).iter().copied().collect();
                self.dofs().scatter_add(&col, 1.0, &mut s);
                s
            })
            .collect();
        let residuals = (0..count)
            .map(|j| {
                let col: Vec<f64> = vecs.column(j).iter().copied().collect();
                let kphi = self.pattern.mul_vec(&p.values, &col);
                let (mut num, mut den) = (0.0, 0.0);
                for f in 0..nf {
                    let mphi = m_free[f] * col[f];
                    num += (kphi[f] - vals[j] * mphi).powi(2);
                    den += mphi * mphi;
                }
                num.sqrt() / (vals[j].abs().max(f64::MIN_POSITIVE) * den.sqrt())
            })
            .collect();
        Ok(Modes {
            eigenvalues: vals[..count].to_vec(),
            shapes,
            relative_residuals: residuals,
        })
    }
}
