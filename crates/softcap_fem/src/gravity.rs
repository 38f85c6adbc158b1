//! Body force from density with lumped masses, and the rest (reference) shape that explains an
//! observed static shape under gravity (wang2015 §6.1, eq. 7–8).
//!
//! **Lumped mass** (wang2015 §3, "the lumped mass at each node"): every tet gives a quarter of its
//! mass ρ_e V_e to each of its four nodes, m_a = Σ_{e ∋ a} ρ_e V_e / 4. For a uniform body force
//! this equals the consistent load of the linear tet, so [`gravity_forces`] f_a = m_a g is exact
//! for the element.
//!
//! **Rest shape** (wang2015 eq. 7): a static shape x_s observed under gravity satisfies
//!
//! R K (Rᵀ x_s − X) = M g,
//!
//! i.e. the internal force f_int(x_s; X) of the body *with rest shape X*, evaluated at x_s, balances
//! the weight. wang2015 eq. 8 poses this as min_X ‖R K (Rᵀ x_s − X) − M g‖² and minimises it by a
//! virtual-force simulation (§6.1, [`solve_rest_shape_virtual_force`]); [`solve_rest_shape`]
//! solves the same equations (the minimum is a root when the observed shape is an equilibrium) by
//! Newton's method on X. Both need the exact Jacobian ∂f_int/∂X, which the paper's appendix
//! derives for its implicit solver. The Jacobian is
//! obtained for *any* element whose force is f_a = V(X) P(F) g_a(X) with F = D_s D_m(X)⁻¹:
//!
//! ∂f/∂X · δX = K_x · (−F δX_a)_a + δV P G + V P δG,
//! δV = V tr(D_m⁻¹ δD_m),  G = [g₁ g₂ g₃] = D_m⁻ᵀ,  δG = −(D_m⁻¹ δD_m D_m⁻¹)ᵀ,
//!
//! where K_x = ∂f/∂x is the model's consistent tangent (the term with −F δX_a is the change of F,
//! δF = −F δD_m D_m⁻¹, pushed through K_x). It therefore works unchanged for the corotational model
//! (wang2015's model, whose R and K both depend on X) and for the stable neo-Hookean model: for the
//! latter eq. 7 reads f_int^NH(x_s; X) = M g and the same Newton iteration is the inverse solve
//! (a fixed-point iteration would need the tangent anyway). The nodes fixed to a support keep their
//! observed positions (X = x_s there). The load M g is held fixed during the solve: mass is
//! conserved, so compute it once from the density and the configuration in which the density was
//! measured.

use crate::FemError;
use crate::assembly::{DofMap, SystemPattern, solver_setup};
use crate::element::{Matrix12, StiffnessKind};
use crate::model::{
    CorotationalModel, ELEMENT_CHUNK, ElasticModel, NeoHookeanModel, fill_elements,
};
use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};
use softcap_mesh::TetMesh;

/// Standard gravity [m/s²] along −z: the default `gravity_m_s2`.
pub const STANDARD_GRAVITY_M_S2: Vector3<f64> = Vector3::new(0.0, 0.0, -9.80665);

/// Lumped nodal masses m_a = Σ_{e ∋ a} ρ V_e / 4 \[kg\] of a uniform density `density_kg_m3`
/// (volumes from the model's rest shape).
pub fn lumped_masses<M: ElasticModel + ?Sized>(model: &M, density_kg_m3: f64) -> Vec<f64> {
    let mut m = vec![0.0; model.num_nodes()];
    for g in model.elements() {
        for &a in &g.nodes {
            m[a] += 0.25 * density_kg_m3 * g.volume_m3;
        }
    }
    m
}

/// Lumped nodal masses with one density per element [kg/m³].
pub fn lumped_masses_per_element<M: ElasticModel + ?Sized>(
    model: &M,
    density_kg_m3: &[f64],
) -> Result<Vec<f64>, FemError> {
    if density_kg_m3.len() != model.elements().len() {
        return Err(FemError::LengthMismatch {
            what: "per-element densities",
            expected: model.elements().len(),
            got: density_kg_m3.len(),
        });
    }
    let mut m = vec![0.0; model.num_nodes()];
    for (g, rho) in model.elements().iter().zip(density_kg_m3) {
        for &a in &g.nodes {
            m[a] += 0.25 * rho * g.volume_m3;
        }
    }
    Ok(m)
}

/// Nodal body forces f_a = m_a g \[N\] (the M g of wang2015 eq. 3 and 7).
pub fn gravity_forces(masses_kg: &[f64], gravity_m_s2: Vector3<f64>) -> Vec<Vector3<f64>> {
    masses_kg.iter().map(|&m| gravity_m_s2 * m).collect()
}

/// A model that can be rebuilt over a different rest shape with the same topology and parameters
/// (what the rest-shape solve iterates over).
pub trait RestShapeModel: ElasticModel + Sized + Sync {
    /// The same model with rest positions `rest_m`.
    fn with_rest_positions(&self, rest_m: &[Vector3<f64>]) -> Result<Self, FemError>;
}

fn mesh_over(model: &impl ElasticModel, rest_m: &[Vector3<f64>]) -> Result<TetMesh, FemError> {
    if rest_m.len() != model.num_nodes() {
        return Err(FemError::LengthMismatch {
            what: "rest positions",
            expected: model.num_nodes(),
            got: rest_m.len(),
        });
    }
    Ok(TetMesh {
        vertices: rest_m.to_vec(),
        tets: model.elements().iter().map(|g| g.nodes).collect(),
    })
}

impl RestShapeModel for CorotationalModel {
    /// Note: a strain-dependence hook is not carried over (the rebuilt model has the current
    /// per-element parameters, frozen).
    fn with_rest_positions(&self, rest_m: &[Vector3<f64>]) -> Result<Self, FemError> {
        CorotationalModel::new(&mesh_over(self, rest_m)?, self.params().to_vec())
    }
}

impl RestShapeModel for NeoHookeanModel {
    fn with_rest_positions(&self, rest_m: &[Vector3<f64>]) -> Result<Self, FemError> {
        NeoHookeanModel::new(&mesh_over(self, rest_m)?, self.params().to_vec())
    }
}

/// Settings of [`solve_rest_shape`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RestShapeSettings {
    /// Maximum Newton iterations.
    pub max_iterations: usize,
    /// Converged when ‖r‖₂ ≤ this × ‖f_ext‖₂ over the free dofs (r = f_int(x_s; X) − f_ext), the
    /// load being the scale of the forces the rest shape must balance; or when ‖r‖₂ is at the
    /// round-off floor of the force sum ([`RestShapeReport::roundoff_floor_n`]), below which no
    /// Newton step can lower it.
    pub residual_tol_rel: f64,
    /// Maximum step halvings of the backtracking on ‖r‖ (a step that degenerates a tet is halved too).
    pub max_halvings: usize,
    /// A Newton step is accepted when its rest shape keeps every tet valid and ‖r‖₂ stays below
    /// this × the least ‖r‖₂ so far (non-monotone); otherwise it is halved. From X = x_s the
    /// full step linearises the rotations of a bending body, stretching its elements, and raises
    /// ‖r‖ by 10²–10³ before the next steps converge quadratically; a monotone backtracking on
    /// ‖r‖ (this = 1) cuts every step to a sliver and stalls (example `rest_shape_table2`). The
    /// best X is returned.
    pub max_growth: f64,
}

impl Default for RestShapeSettings {
    fn default() -> Self {
        Self {
            max_iterations: 50,
            residual_tol_rel: 1e-9,
            max_halvings: 20,
            max_growth: 1e4,
        }
    }
}

/// Outcome of [`solve_rest_shape`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum RestShapeStatus {
    /// The residual tolerance was met.
    Converged,
    /// Iteration limit reached (the best X so far is returned).
    MaxIterations,
    /// No step along the Newton direction reduced the residual (or, in the virtual-force
    /// simulation, no halved time step kept every tet of the rest shape valid).
    LineSearchFailed,
    /// The Jacobian could not be factored.
    FactorizationFailed {
        /// faer's message
        reason: String,
    },
}

/// Report of [`solve_rest_shape`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RestShapeReport {
    /// Status.
    pub status: RestShapeStatus,
    /// Newton iterations performed.
    pub iterations: usize,
    /// Final ‖R K (Rᵀ x_s − X) − M g‖₂ over the free dofs \[N\] (square root of wang2015 eq. 8's
    /// objective restricted to unsupported dofs).
    pub residual_norm_n: f64,
    /// ‖M g‖₂ over the free dofs \[N\] (scale of the residual).
    pub load_norm_n: f64,
    /// The residual's round-off floor \[N\]: [`ROUNDOFF_FACTOR`] × ε × the norm over the free
    /// dofs of Σ_e |f_e| (the magnitudes of the element forces summed into each dof, at the
    /// last rest shape). Where the stresses are large against the load (a long cantilever near
    /// its clamp) the element forces cancel to a residual far below them and this floor, not the
    /// load, bounds how small the residual can get.
    pub roundoff_floor_n: f64,
    /// Residual norm per iteration (entry 0 = initial guess).
    pub history_n: Vec<f64>,
}

impl RestShapeReport {
    /// True if converged.
    pub fn converged(&self) -> bool {
        self.status == RestShapeStatus::Converged
    }
}

/// Multiple of ε × Σ_e |f_e| at which the rest-shape residual counts as round-off (see
/// [`RestShapeReport::roundoff_floor_n`]): each dof sums a few tens of element forces, each the
/// result of a few hundred floating-point operations.
pub const ROUNDOFF_FACTOR: f64 = 1.0e3;

/// ‖(Σ_e |f_e,i|)_i‖₂ over the free dofs \[N\]: the size of the forces that cancel in f_int.
fn force_magnitude_norm<M: ElasticModel + ?Sized>(
    model: &M,
    x: &[Vector3<f64>],
    dofs: &DofMap,
) -> f64 {
    let mut abs = vec![Vector3::zeros(); model.num_nodes()];
    for (e, g) in model.elements().iter().enumerate() {
        let f = model.element_forces(e, x);
        for (a, fa) in g.nodes.iter().zip(&f) {
            abs[*a] += fa.abs();
        }
    }
    dofs.gather(&abs).iter().map(|v| v * v).sum::<f64>().sqrt()
}

/// Rest shape and model with that rest shape (the model is what the forward simulation needs).
#[derive(Clone, Debug)]
pub struct RestShape<M> {
    /// Rest positions X \[m\].
    pub rest_positions_m: Vec<Vector3<f64>>,
    /// `model` rebuilt over X.
    pub model: M,
    /// Solve report.
    pub report: RestShapeReport,
}

/// Element Jacobian ∂f_e/∂X_e (12×12, node-major) of the internal forces with respect to the rest
/// positions at deformed positions `x`, for any element whose forces are V P(F) g_a (see the module
/// docs for the formula).
pub fn element_rest_jacobian<M: ElasticModel + ?Sized>(
    model: &M,
    e: usize,
    x: &[Vector3<f64>],
) -> crate::element::Matrix12 {
    let g = &model.elements()[e];
    let rest = model.rest_positions();
    let f = model.element_forces(e, x);
    let kx = model.element_matrix(e, x, StiffnessKind::Consistent);
    let def = g.deformation_gradient(x);
    let x0 = rest[g.nodes[0]];
    let dm = Matrix3::from_columns(&[
        rest[g.nodes[1]] - x0,
        rest[g.nodes[2]] - x0,
        rest[g.nodes[3]] - x0,
    ]);
    let d = Matrix3::from_columns(&[g.grads[1], g.grads[2], g.grads[3]]).transpose(); // D_m⁻¹
    let v = g.volume_m3;
    let gmat = Matrix3::from_columns(&[g.grads[1], g.grads[2], g.grads[3]]); // D_m⁻ᵀ
    let p = Matrix3::from_columns(&[f[1], f[2], f[3]]) * dm.transpose() / v;
    let mut out = crate::element::Matrix12::zeros();
    for b in 0..4 {
        for j in 0..3 {
            // δX = e_j at node b.
            let mut ddm = Matrix3::zeros();
            if b == 0 {
                for c in 0..3 {
                    ddm[(j, c)] = -1.0;
                }
            } else {
                ddm[(j, b - 1)] = 1.0;
            }
            // K_x · (−F δX_a)_a: only node b moves, by −F e_j.
            let dxb = -def.column(j).into_owned();
            let mut col = nalgebra::SVector::<f64, 12>::zeros();
            for r in 0..12 {
                col[r] = kx[(r, 3 * b)] * dxb.x
                    + kx[(r, 3 * b + 1)] * dxb.y
                    + kx[(r, 3 * b + 2)] * dxb.z;
            }
            let dv = v * (d * ddm).trace();
            let dg = -(d * ddm * d).transpose();
            let dfm = p * gmat * dv + p * dg * v;
            for a in 1..4 {
                for i in 0..3 {
                    col[3 * a + i] += dfm[(i, a - 1)];
                    col[i] -= dfm[(i, a - 1)];
                }
            }
            for r in 0..12 {
                out[(r, 3 * b + j)] = col[r];
            }
        }
    }
    out
}

/// J = ∂r/∂X of [`solve_rest_shape`] in `pattern`'s lower layout: (lower, upper) as
/// [`crate::SparseCholesky::factor_general`] takes them. Element Jacobians in parallel chunks, scattered
/// serially in element order.
fn rest_jacobian<M: ElasticModel + Sync + ?Sized>(
    model: &M,
    x: &[Vector3<f64>],
    pattern: &SystemPattern,
) -> (Vec<f64>, Vec<f64>) {
    let n_el = model.elements().len();
    let (mut lower, mut upper) = (pattern.zeros(), pattern.zeros());
    let mut buf = vec![Matrix12::zeros(); ELEMENT_CHUNK.min(n_el)];
    for first in (0..n_el).step_by(ELEMENT_CHUNK) {
        let len = ELEMENT_CHUNK.min(n_el - first);
        fill_elements(&mut buf[..len], |k, je| {
            *je = element_rest_jacobian(model, first + k, x);
        });
        for (k, je) in buf[..len].iter().enumerate() {
            pattern.add_element(first + k, je, &mut lower);
            pattern.add_element_transposed(first + k, je, &mut upper);
        }
    }
    (lower, upper)
}

/// The rest-shape problem both solvers iterate on: the observed static shape, the load, the
/// free dofs and the convergence test (wang2015 eq. 7 over the unsupported dofs).
struct RestProblem<'a> {
    xs: &'a [Vector3<f64>],
    external_forces_n: &'a [Vector3<f64>],
    pattern: SystemPattern,
    factor: crate::assembly::SparseCholesky,
    load_norm_n: f64,
    load_tolerance_n: f64,
}

impl<'a> RestProblem<'a> {
    /// Checks the lengths, sets up the pattern and returns the problem with the initial rest
    /// shape (the model's, or `initial_rest_m`, with X = x_s on the constrained dofs).
    fn new<M: RestShapeModel>(
        model: &M,
        static_positions_m: &'a [Vector3<f64>],
        external_forces_n: &'a [Vector3<f64>],
        constrained_dofs: &[usize],
        initial_rest_m: Option<&[Vector3<f64>]>,
        residual_tol_rel: f64,
    ) -> Result<(Self, Vec<Vector3<f64>>), FemError> {
        let n = model.num_nodes();
        for (what, len) in [
            ("static positions", static_positions_m.len()),
            ("external forces", external_forces_n.len()),
        ] {
            if len != n {
                return Err(FemError::LengthMismatch {
                    what,
                    expected: n,
                    got: len,
                });
            }
        }
        let (pattern, factor, _) = solver_setup(model, constrained_dofs)?;
        let mut rest: Vec<Vector3<f64>> = initial_rest_m
            .map(<[_]>::to_vec)
            .unwrap_or_else(|| model.rest_positions().to_vec());
        if rest.len() != n {
            return Err(FemError::LengthMismatch {
                what: "initial rest positions",
                expected: n,
                got: rest.len(),
            });
        }
        for &d in constrained_dofs {
            rest[d / 3][d % 3] = static_positions_m[d / 3][d % 3];
        }
        let load_norm_n = norm(&pattern.dofs().gather(external_forces_n));
        Ok((
            Self {
                xs: static_positions_m,
                external_forces_n,
                pattern,
                factor,
                load_norm_n,
                load_tolerance_n: (residual_tol_rel * load_norm_n).max(f64::MIN_POSITIVE),
            },
            rest,
        ))
    }

    /// r = f_int(x_s; X) − f_ext over the free dofs of the body `m` (rest shape X).
    fn residual<M: ElasticModel + ?Sized>(&self, m: &M) -> Vec<f64> {
        let r: Vec<Vector3<f64>> = m
            .internal_forces(self.xs)
            .iter()
            .zip(self.external_forces_n)
            .map(|(a, b)| a - b)
            .collect();
        self.pattern.dofs().gather(&r)
    }

    /// The round-off floor of the residual of `m` ([`RestShapeReport::roundoff_floor_n`]).
    fn floor<M: ElasticModel + ?Sized>(&self, m: &M) -> f64 {
        ROUNDOFF_FACTOR * f64::EPSILON * force_magnitude_norm(m, self.xs, self.pattern.dofs())
    }

    /// The report of the initial guess `m` with residual norm `rn`.
    fn report<M: ElasticModel + ?Sized>(&self, m: &M, rn: f64) -> RestShapeReport {
        RestShapeReport {
            status: RestShapeStatus::MaxIterations,
            iterations: 0,
            residual_norm_n: rn,
            load_norm_n: self.load_norm_n,
            roundoff_floor_n: self.floor(m),
            history_n: vec![rn],
        }
    }

    /// Converged: the residual at the load tolerance or at the round-off floor.
    fn converged(&self, report: &RestShapeReport) -> bool {
        report.residual_norm_n <= self.load_tolerance_n.max(report.roundoff_floor_n)
    }

    /// Records the accepted iterate `m` (iteration count `iterations`, residual norm `rn`).
    fn record<M: ElasticModel + ?Sized>(
        &self,
        m: &M,
        iterations: usize,
        rn: f64,
        report: &mut RestShapeReport,
    ) {
        report.roundoff_floor_n = self.floor(m);
        report.iterations = iterations;
        report.residual_norm_n = rn;
        report.history_n.push(rn);
    }

    /// The solve's result: the status is `Converged` when the final iterate meets the test.
    fn finish<M>(
        &self,
        rest_positions_m: Vec<Vector3<f64>>,
        model: M,
        mut report: RestShapeReport,
    ) -> RestShape<M> {
        if self.converged(&report) {
            report.status = RestShapeStatus::Converged;
        }
        RestShape {
            rest_positions_m,
            model,
            report,
        }
    }

    /// Assembles J = ∂r/∂X at `current` (lower and transposed-upper arrays, [`rest_jacobian`]).
    fn jacobian<M: ElasticModel + Sync + ?Sized>(&self, current: &M) -> (Vec<f64>, Vec<f64>) {
        rest_jacobian(current, self.xs, &self.pattern)
    }

    /// Factors `lower`/`upper` and solves A d = `rhs` in place; the failure as a status.
    fn solve(
        &mut self,
        lower: &[f64],
        upper: &[f64],
        rhs: &mut [f64],
    ) -> Result<(), RestShapeStatus> {
        let failed = |reason: String| RestShapeStatus::FactorizationFailed { reason };
        self.factor
            .factor_general(&self.pattern, lower, Some(upper))
            .map_err(|e| failed(e.to_string()))?;
        self.factor
            .solve_in_place(rhs)
            .map_err(|e| failed(e.to_string()))?;
        if rhs.iter().all(|v| v.is_finite()) {
            Ok(())
        } else {
            Err(failed("non-finite step".into()))
        }
    }
}

fn norm(v: &[f64]) -> f64 {
    v.iter().map(|a| a * a).sum::<f64>().sqrt()
}

/// Rest shape X such that the body rebuilt over X and evaluated at the observed static shape
/// `static_positions_m` is in equilibrium with `external_forces_n` on every unconstrained dof
/// (wang2015 eq. 7; eq. 8 as its least-squares form). `constrained_dofs` (3·node + axis) keep
/// X = x_s (the nodes held by the support). `model` supplies topology and parameters; its own rest
/// shape is the initial guess if `initial_rest_m` is `None` (x_s is a good one too).
///
/// Newton's method with the exact Jacobian ([`element_rest_jacobian`], nonsymmetric, faer sparse
/// LU over the tet pattern, its symbolic analysis once per solve) and backtracking on ‖r‖₂.
/// Failures are reported in the status, never a panic; errors only for inconsistent input
/// lengths or a degenerate initial rest shape. [`solve_rest_shape_virtual_force`] is wang2015
/// §6.1's own solve of the same equations.
pub fn solve_rest_shape<M: RestShapeModel>(
    model: &M,
    static_positions_m: &[Vector3<f64>],
    external_forces_n: &[Vector3<f64>],
    constrained_dofs: &[usize],
    initial_rest_m: Option<&[Vector3<f64>]>,
    settings: &RestShapeSettings,
) -> Result<RestShape<M>, FemError> {
    let (mut problem, mut rest) = RestProblem::new(
        model,
        static_positions_m,
        external_forces_n,
        constrained_dofs,
        initial_rest_m,
        settings.residual_tol_rel,
    )?;
    let dofs = problem.pattern.dofs().clone();
    let mut current = model.with_rest_positions(&rest)?;
    let mut r = problem.residual(&current);
    let mut report = problem.report(&current, norm(&r));
    // The iteration is non-monotone: `least` is the least ‖r‖ of the iterates so far (the
    // current one included), `best` the best one left behind for a worse one.
    let mut best: Option<(Vec<Vector3<f64>>, M, f64, f64)> = None;
    let mut rn = report.residual_norm_n;
    let mut least = rn;
    for it in 0..settings.max_iterations {
        if problem.converged(&report) {
            break;
        }
        // J = ∂r/∂X over the free dofs, factored by sparse LU (symbolic analysis once).
        let (lower, upper) = problem.jacobian(&current);
        let mut dx: Vec<f64> = r.iter().map(|v| -v).collect();
        if let Err(status) = problem.solve(&lower, &upper, &mut dx) {
            report.status = status;
            break;
        }
        let mut step = 1.0;
        let mut accepted = None;
        for _ in 0..=settings.max_halvings {
            let mut trial = rest.clone();
            dofs.scatter_add(&dx, step, &mut trial);
            if let Ok(m) = current.with_rest_positions(&trial) {
                let rt = problem.residual(&m);
                let rtn = norm(&rt);
                if rtn.is_finite() && rtn < settings.max_growth * least {
                    accepted = Some((trial, m, rt, rtn));
                    break;
                }
            }
            step *= 0.5;
        }
        let Some((trial, m, rt, rtn)) = accepted else {
            report.status = RestShapeStatus::LineSearchFailed;
            break;
        };
        if rtn > rn && rn <= least {
            best = Some((rest, current, rn, report.roundoff_floor_n));
        }
        least = least.min(rtn);
        rest = trial;
        current = m;
        r = rt;
        rn = rtn;
        problem.record(&current, it + 1, rn, &mut report);
    }
    if let Some((x, m, bn, floor)) = best
        && bn < rn
    {
        (rest, current) = (x, m);
        report.residual_norm_n = bn;
        report.roundoff_floor_n = floor;
    }
    Ok(problem.finish(rest, current, report))
}

/// Derivatives dX/dp_k of the rest shape of eq. 7 (wang2015 §6.1) with respect to parameters
/// p_k of the material: differentiating r(X, p) = f_int(x_s; X, p) − f_ext = 0 at the solution
/// X (`model`'s rest shape) gives J dX_k = −∂f_int(x_s; X)/∂p_k over the free dofs, J = ∂r/∂X
/// the exact Jacobian of [`solve_rest_shape`] ([`element_rest_jacobian`], one sparse LU for all
/// k); dX_k = 0 on `constrained_dofs` (X = x_s there). `force_derivatives` holds
/// ∂f_int(x_s; X)/∂p_k per node for each k. Errors for inconsistent lengths or a singular J.
pub fn rest_shape_sensitivities<M: ElasticModel + Sync + ?Sized>(
    model: &M,
    static_positions_m: &[Vector3<f64>],
    constrained_dofs: &[usize],
    force_derivatives: &[Vec<Vector3<f64>>],
) -> Result<Vec<Vec<Vector3<f64>>>, FemError> {
    let n = model.num_nodes();
    for (what, len) in std::iter::once(("static positions", static_positions_m.len())).chain(
        force_derivatives
            .iter()
            .map(|d| ("force derivative", d.len())),
    ) {
        if len != n {
            return Err(FemError::LengthMismatch {
                what,
                expected: n,
                got: len,
            });
        }
    }
    let (pattern, mut factor, _) = solver_setup(model, constrained_dofs)?;
    let (lower, upper) = rest_jacobian(model, static_positions_m, &pattern);
    factor.factor_general(&pattern, &lower, Some(&upper))?;
    force_derivatives
        .iter()
        .map(|d| {
            let mut rhs: Vec<f64> = pattern.dofs().gather(d).iter().map(|v| -v).collect();
            factor.solve_in_place(&mut rhs)?;
            let mut dx = vec![Vector3::zeros(); n];
            pattern.dofs().scatter_add(&rhs, 1.0, &mut dx);
            Ok(dx)
        })
        .collect()
}

/// Settings of [`solve_rest_shape_virtual_force`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VirtualForceSettings {
    /// Artificial time step h \[s\] of the mock-physics simulation.
    pub time_step_s: f64,
    /// Mass-proportional damping c \[1/s\] of the mock motion (D = c M).
    pub damping_per_s: f64,
    /// Maximum artificial time steps.
    pub max_steps: usize,
    /// Converged when ‖r‖₂ ≤ this × ‖f_ext‖₂ over the free dofs, or at the round-off floor (as
    /// [`RestShapeSettings::residual_tol_rel`]).
    pub residual_tol_rel: f64,
    /// Maximum halvings of a step whose rest shape degenerates a tet.
    pub max_halvings: usize,
}

impl Default for VirtualForceSettings {
    fn default() -> Self {
        Self {
            time_step_s: 0.05,
            damping_per_s: 20.0,
            max_steps: 200,
            residual_tol_rel: 1e-9,
            max_halvings: 20,
        }
    }
}

/// wang2015 §6.1's reference-shape optimization: the rest shape X of eq. 7 found by an
/// artificial-time simulation in which the current force residual r(X) = f_int(x_s; X) − M g
/// acts on every node as a virtual force and moves X ("we apply the current force residual as
/// virtual forces to each node, and rely on the mock-physics simulation to update the reference
/// shape"), until the residual is small and the motion has settled. The mock physics is
///
/// M Ẍ + c M Ẋ = r(X),
///
/// with the body's lumped masses `masses_kg` and mass-proportional damping c, integrated by
/// linearly implicit backward Euler ("we use an implicit ODE solver when updating the reference
/// shape", which needs ∂f/∂X — the appendix's Jacobian, [`element_rest_jacobian`]):
///
/// ((1/h + c) M − h J) V_{n+1} = M V_n / h + r(X_n),  X_{n+1} = X_n + h V_{n+1},  J = ∂r/∂X.
///
/// J ≈ −K near equilibrium, so the motion is a damped oscillation about the rest shape; as h → ∞
/// the step tends to Newton's ([`solve_rest_shape`]). A step whose X degenerates a tet is halved.
/// Same inputs, outputs and convergence test as [`solve_rest_shape`]; `iterations` counts the
/// time steps.
pub fn solve_rest_shape_virtual_force<M: RestShapeModel>(
    model: &M,
    masses_kg: &[f64],
    static_positions_m: &[Vector3<f64>],
    external_forces_n: &[Vector3<f64>],
    constrained_dofs: &[usize],
    initial_rest_m: Option<&[Vector3<f64>]>,
    settings: &VirtualForceSettings,
) -> Result<RestShape<M>, FemError> {
    let (mut problem, mut rest) = RestProblem::new(
        model,
        static_positions_m,
        external_forces_n,
        constrained_dofs,
        initial_rest_m,
        settings.residual_tol_rel,
    )?;
    if masses_kg.len() != rest.len() {
        return Err(FemError::LengthMismatch {
            what: "nodal masses",
            expected: rest.len(),
            got: masses_kg.len(),
        });
    }
    let dofs = problem.pattern.dofs().clone();
    let mass_free: Vec<f64> = (0..dofs.num_free())
        .map(|f| masses_kg[dofs.dof(f) / 3])
        .collect();
    let mut current = model.with_rest_positions(&rest)?;
    let mut r = problem.residual(&current);
    let mut report = problem.report(&current, norm(&r));
    let mut velocity = vec![0.0; dofs.num_free()];
    for step in 0..settings.max_steps {
        if problem.converged(&report) {
            break;
        }
        let (jl, ju) = problem.jacobian(&current);
        let mut h = settings.time_step_s;
        let mut accepted = None;
        for _ in 0..=settings.max_halvings {
            // A = (1/h + c) M − h J
            let (mut lower, mut upper): (Vec<f64>, Vec<f64>) = (
                jl.iter().map(|v| -h * v).collect(),
                ju.iter().map(|v| -h * v).collect(),
            );
            for node in 0..rest.len() {
                let m =
                    Matrix3::identity() * ((1.0 / h + settings.damping_per_s) * masses_kg[node]);
                problem.pattern.add_node_block(node, &m, &mut lower);
                problem.pattern.add_node_block(node, &m, &mut upper);
            }
            let mut v_new: Vec<f64> = velocity
                .iter()
                .zip(&mass_free)
                .zip(&r)
                .map(|((v, m), r)| m * v / h + r)
                .collect();
            if let Err(status) = problem.solve(&lower, &upper, &mut v_new) {
                report.status = status;
                break;
            }
            let mut trial = rest.clone();
            dofs.scatter_add(&v_new, h, &mut trial);
            if let Ok(m) = current.with_rest_positions(&trial) {
                accepted = Some((trial, m, v_new));
                break;
            }
            h *= 0.5;
        }
        let Some((trial, m, v_new)) = accepted else {
            if report.status == RestShapeStatus::MaxIterations {
                report.status = RestShapeStatus::LineSearchFailed;
            }
            break;
        };
        rest = trial;
        current = m;
        velocity = v_new;
        r = problem.residual(&current);
        problem.record(&current, step + 1, norm(&r), &mut report);
    }
    Ok(problem.finish(rest, current, report))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{LinearParams, NeoHookeanParams};

    fn sheared_single_tet() -> (TetMesh, Vec<Vector3<f64>>) {
        let mesh = TetMesh {
            vertices: vec![
                Vector3::new(0.1, 0.0, 0.0),
                Vector3::new(1.0, 0.2, 0.1),
                Vector3::new(0.2, 1.1, 0.0),
                Vector3::new(0.0, 0.3, 0.9),
            ],
            tets: vec![[0, 1, 2, 3]],
        };
        let rot = nalgebra::Rotation3::from_euler_angles(0.3, -0.2, 0.5);
        let x = mesh
            .vertices
            .iter()
            .enumerate()
            .map(|(i, v)| rot * (v * (1.0 + 0.05 * i as f64)) + Vector3::new(0.01, 0.0, 0.02))
            .collect();
        (mesh, x)
    }

    fn check_fd<M: RestShapeModel>(model: &M, x: &[Vector3<f64>]) -> f64 {
        let j = element_rest_jacobian(model, 0, x);
        let h = 1e-6;
        let mut err: f64 = 0.0;
        for c in 0..12 {
            let mut rp = model.rest_positions().to_vec();
            let mut rm = rp.clone();
            rp[c / 3][c % 3] += h;
            rm[c / 3][c % 3] -= h;
            let fp = model.with_rest_positions(&rp).unwrap().element_forces(0, x);
            let fm = model.with_rest_positions(&rm).unwrap().element_forces(0, x);
            for r in 0..12 {
                let fd = (fp[r / 3][r % 3] - fm[r / 3][r % 3]) / (2.0 * h);
                err = err.max((fd - j[(r, c)]).abs());
            }
        }
        err / j.norm()
    }

    #[test]
    fn rest_jacobian_matches_finite_differences() {
        let (mesh, x) = sheared_single_tet();
        let co = CorotationalModel::homogeneous(
            &mesh,
            LinearParams::from_young_poisson(1e4, 0.3).unwrap(),
        )
        .unwrap();
        let e_co = check_fd(&co, &x);
        assert!(e_co < 1e-7, "corotational rel err {e_co:e}");
        let nh = NeoHookeanModel::homogeneous(
            &mesh,
            NeoHookeanParams::from_young_poisson(1e4, 0.3).unwrap(),
        )
        .unwrap();
        let e_nh = check_fd(&nh, &x);
        assert!(e_nh < 1e-7, "neo-Hookean rel err {e_nh:e}");
    }

    /// wang2015 Table 2 on known truth: a 200 × 30 × 20 mm cantilever (E 1 MPa, 288 tets)
    /// with rest shape X* sags by 17 mm under gravity to x_s; both solves of eq. 7 recover X*
    /// from x_s alone (the body's masses held fixed) — Newton in a few iterations, wang2015
    /// §6.1's virtual-force simulation in a few tens of artificial time steps.
    #[test]
    fn both_solves_recover_the_rest_shape_of_a_sagging_cantilever() {
        use crate::{DirichletBc, EquilibriumSettings, StaticSolver};
        let mesh = softcap_mesh::box_tet_mesh([0.0, -0.015, -0.01], [0.2, 0.015, 0.01], [12, 2, 2]);
        let params = LinearParams::from_young_poisson(1e6, 0.45).unwrap();
        let mut truth = CorotationalModel::homogeneous(&mesh, params).unwrap();
        let held: Vec<usize> = (0..mesh.vertices.len())
            .filter(|&i| mesh.vertices[i].x <= 1e-9)
            .collect();
        let masses = lumped_masses(&truth, 1100.0);
        let load = gravity_forces(&masses, STANDARD_GRAVITY_M_S2);
        let mut bc = DirichletBc::new();
        for &i in &held {
            bc.fix_node(i, mesh.vertices[i]);
        }
        let mut xs = mesh.vertices.clone();
        let sag = StaticSolver::with_bc(&truth, &bc).unwrap().solve(
            &mut truth,
            &mut xs,
            &load,
            None,
            &EquilibriumSettings::newton(),
        );
        assert!(sag.converged());
        let mean = |a: &[Vector3<f64>], b: &[Vector3<f64>]| {
            a.iter().zip(b).map(|(p, q)| (p - q).norm()).sum::<f64>() / a.len() as f64
        };
        assert!(mean(&xs, &mesh.vertices) > 5e-3, "the beam sags");
        let dofs: Vec<usize> = held
            .iter()
            .flat_map(|&i| [3 * i, 3 * i + 1, 3 * i + 2])
            .collect();
        let observed = TetMesh {
            vertices: xs.clone(),
            tets: mesh.tets.clone(),
        };
        let model = CorotationalModel::homogeneous(&observed, params).unwrap();
        let newton = solve_rest_shape(
            &model,
            &xs,
            &load,
            &dofs,
            None,
            &RestShapeSettings::default(),
        )
        .unwrap();
        assert!(newton.report.converged(), "{:?}", newton.report);
        assert!(
            newton.report.iterations <= 8,
            "{}",
            newton.report.iterations
        );
        let dx = mean(&newton.rest_positions_m, &mesh.vertices);
        assert!(dx < 1e-10, "Newton ΔX {dx:e} m");
        let virtual_force = solve_rest_shape_virtual_force(
            &model,
            &masses,
            &xs,
            &load,
            &dofs,
            None,
            &VirtualForceSettings::default(),
        )
        .unwrap();
        assert!(
            virtual_force.report.converged(),
            "{:?}",
            virtual_force.report
        );
        assert!(virtual_force.report.iterations <= 60);
        let dx = mean(&virtual_force.rest_positions_m, &mesh.vertices);
        assert!(dx < 1e-10, "virtual-force ΔX {dx:e} m");
    }

    #[test]
    fn lumped_mass_sums_to_total() {
        let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [0.2, 0.1, 0.3], [2, 2, 3]);
        let model = CorotationalModel::homogeneous(
            &mesh,
            LinearParams::from_young_poisson(1e4, 0.3).unwrap(),
        )
        .unwrap();
        let m = lumped_masses(&model, 1000.0);
        let total: f64 = m.iter().sum();
        assert!((total - 1000.0 * 0.2 * 0.1 * 0.3).abs() < 1e-12);
        let f = gravity_forces(&m, STANDARD_GRAVITY_M_S2);
        let fz: f64 = f.iter().map(|v| v.z).sum();
        assert!((fz + total * 9.80665).abs() < 1e-10);
    }
}
