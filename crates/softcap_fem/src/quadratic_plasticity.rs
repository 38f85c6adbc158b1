//! J2 plasticity on the 10-node tet: the truth's element order for rigid-tip replays of a
//! permanent set (docs/notes/2026-12-01-plasticity-element-floor.md: linear tets lock under the
//! isochoric plastic flow at ν ≈ 0.45; the third-party truth is FElupe's quadratic tets).
//!
//! Element: the isoparametric 10-node tet of [`crate::quadratic`] (4-point rule of degree 2),
//! with the additive small-strain J2 law of [`crate::plasticity`] at every quadrature point:
//! ε_q = sym(Rᵀ F_q) − I, F_q = Σ_a x_a ⊗ ∇_X N_a(ξ_q), R the rotation of the polar decomposition
//! of F at the centroid (corotation as [`crate::QuadraticModel`], Mezger et al. 2008; identity when
//! `corotated` is false: the small-strain kinematics ε = sym ∇u of the truth), radial return
//! (Simo & Hughes 1998 Box 3.1) from the committed (ε_p, ᾱ) of the point, forces
//!
//! f_a = R Σ_q w_q det J_q σ_q ∇N_a(ξ_q),  w_q = 1/24,
//!
//! and the tangent R K_ep Rᵀ with K_ep,ab e_k = Σ_q w_q det J_q (C_ep : sym(e_k ⊗ g_b)) g_a, C_ep the
//! algorithmic tangent (Simo & Hughes Box 3.2, [`crate::plasticity::ReturnMapping::tangent_apply`]);
//! ∂R/∂x is left out (exact for the small-strain kinematics; linear convergence for moderate
//! rotations with corotation).
//!
//! [`QuadraticRigidTipSolver`] finds equilibrium f_int(x) = f_ext + f_c with the rigid probe's
//! penalty springs on candidate nodes (corners and edge midpoints of the surface; the springs,
//! hysteresis and penalty scale of [`crate::contact`], node stiffness fixed at the first
//! iteration) by Newton with a backtracking line search on the residual norm (the path-dependent
//! model has no potential in x alone).

use crate::assembly::{
    DofMap, SparseCholesky, SystemPattern, contact_residual, quadratic_solver_setup,
};
use crate::contact::{ContactProblem, ContactReport, ContactSpring};
use crate::plasticity::{J2PlasticityParams, PlasticState, ReturnMapping, radial_return};
use crate::quadratic::{gradients, quadrature};
use crate::statics::EquilibriumSettings;
use crate::{FemError, LinearParams};
use nalgebra::{Matrix3, Vector3};

/// Per quadrature point: ∇_X N_a and w det J.
type PointGeometry = ([Vector3<f64>; 10], f64);

/// 10-node tets with J2 plasticity at their quadrature points (module docs).
#[derive(Clone, Debug)]
pub struct QuadraticElastoplasticModel {
    rest: Vec<Vector3<f64>>,
    elements: Vec<[usize; 10]>,
    params: Vec<LinearParams>,
    plasticity: Vec<J2PlasticityParams>,
    points: Vec<[PointGeometry; 4]>,
    centroid_grads: Vec<[Vector3<f64>; 10]>,
    committed: Vec<[PlasticState; 4]>,
    corotated: bool,
}

impl QuadraticElastoplasticModel {
    /// Model over `rest` and 10-node `elements` (as [`crate::quadratic_tets`]) with per-element
    /// elastic and plastic parameters, virgin state; `corotated`: kinematics (module docs).
    pub fn new(
        rest: &[Vector3<f64>],
        elements: &[[usize; 10]],
        params: Vec<LinearParams>,
        plasticity: Vec<J2PlasticityParams>,
        corotated: bool,
    ) -> Result<Self, FemError> {
        for (what, len) in [
            ("per-element parameters", params.len()),
            ("per-element plasticity", plasticity.len()),
        ] {
            if len != elements.len() {
                return Err(FemError::LengthMismatch {
                    what,
                    expected: elements.len(),
                    got: len,
                });
            }
        }
        let mut points = Vec::with_capacity(elements.len());
        let mut centroid_grads = Vec::with_capacity(elements.len());
        for (e, el) in elements.iter().enumerate() {
            params[e].validate(e)?;
            plasticity[e].validate(e)?;
            if let Some(&v) = el.iter().find(|&&v| v >= rest.len()) {
                return Err(FemError::VertexOutOfRange {
                    tet: e,
                    vertex: v,
                    num_vertices: rest.len(),
                });
            }
            let xe: [Vector3<f64>; 10] = std::array::from_fn(|a| rest[el[a]]);
            let degenerate = || {
                let volume_m3 = (xe[1] - xe[0]).dot(&(xe[2] - xe[0]).cross(&(xe[3] - xe[0]))) / 6.0;
                FemError::DegenerateElement { tet: e, volume_m3 }
            };
            let q = quadrature();
            let mut pts = [([Vector3::zeros(); 10], 0.0); 4];
            for (p, l) in pts.iter_mut().zip(q) {
                let (g, det) = gradients(&xe, l).ok_or_else(degenerate)?;
                *p = (g, det / 24.0);
            }
            points.push(pts);
            centroid_grads.push(gradients(&xe, [0.25; 4]).ok_or_else(degenerate)?.0);
        }
        Ok(Self {
            rest: rest.to_vec(),
            elements: elements.to_vec(),
            committed: vec![[PlasticState::default(); 4]; elements.len()],
            params,
            plasticity,
            points,
            centroid_grads,
            corotated,
        })
    }

    /// Rest positions.
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

    /// Committed states, four quadrature points per element.
    pub fn plastic_states(&self) -> &[[PlasticState; 4]] {
        &self.committed
    }

    /// Element rotation (identity without corotation).
    fn rotation(&self, e: usize, x: &[Vector3<f64>]) -> Matrix3<f64> {
        if !self.corotated {
            return Matrix3::identity();
        }
        let mut f = Matrix3::zeros();
        for (a, g) in self.centroid_grads[e].iter().enumerate() {
            f += x[self.elements[e][a]] * g.transpose();
        }
        crate::element::corotated_strain(&f).0
    }

    /// Rotation and the return mappings of element `e`'s four points at `x`.
    fn element_returns(&self, e: usize, x: &[Vector3<f64>]) -> (Matrix3<f64>, [ReturnMapping; 4]) {
        let r = self.rotation(e, x);
        let el = &self.elements[e];
        // relative to node 0 (the gradients annihilate translations): digits far from the origin
        let (x0, rest0) = (x[el[0]], self.rest[el[0]]);
        let u: [Vector3<f64>; 10] =
            std::array::from_fn(|a| r.transpose() * (x[el[a]] - x0) - (self.rest[el[a]] - rest0));
        let rm = std::array::from_fn(|q| {
            let (g, _) = &self.points[e][q];
            let mut h = Matrix3::zeros();
            for a in 0..10 {
                h += u[a] * g[a].transpose();
            }
            let eps = (h + h.transpose()) * 0.5;
            radial_return(
                &self.params[e],
                &self.plasticity[e],
                &eps,
                &self.committed[e][q],
            )
        });
        (r, rm)
    }

    /// Forces of element `e` per element node.
    fn forces_of(&self, e: usize, r: &Matrix3<f64>, rm: &[ReturnMapping; 4]) -> [Vector3<f64>; 10] {
        std::array::from_fn(|a| {
            let mut s = Vector3::zeros();
            for (q, (g, w)) in self.points[e].iter().enumerate() {
                s += rm[q].stress_pa * g[a] * *w;
            }
            r * s
        })
    }

    /// Global internal forces f_int(x) from the committed state.
    pub fn internal_forces(&self, x: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        let mut out = vec![Vector3::zeros(); self.rest.len()];
        for e in 0..self.elements.len() {
            let (r, rm) = self.element_returns(e, x);
            for (a, f) in self.forces_of(e, &r, &rm).iter().enumerate() {
                out[self.elements[e][a]] += f;
            }
        }
        out
    }

    /// Element forces and the 10×10 blocks of its tangent R K_ep Rᵀ (module docs).
    #[allow(clippy::type_complexity)]
    fn linearize(
        &self,
        e: usize,
        x: &[Vector3<f64>],
    ) -> ([Vector3<f64>; 10], Box<[[Matrix3<f64>; 10]; 10]>) {
        let (r, rm) = self.element_returns(e, x);
        let f = self.forces_of(e, &r, &rm);
        let mut k = Box::new([[Matrix3::zeros(); 10]; 10]);
        let p = &self.params[e];
        for (q, (g, w)) in self.points[e].iter().enumerate() {
            for b in 0..10 {
                for c in 0..3 {
                    let mut d = Matrix3::zeros();
                    for j in 0..3 {
                        d[(c, j)] += 0.5 * g[b][j];
                        d[(j, c)] += 0.5 * g[b][j];
                    }
                    let ds = rm[q].tangent_apply(p, &d) * *w;
                    for a in 0..10 {
                        let col = ds * g[a];
                        for i in 0..3 {
                            k[a][b][(i, c)] += col[i];
                        }
                    }
                }
            }
        }
        if self.corotated {
            for row in k.iter_mut() {
                for m in row.iter_mut() {
                    *m = r * *m * r.transpose();
                }
            }
        }
        (f, k)
    }

    /// Commits the return-mapped states at the converged `x` (end of a load step); returns the
    /// number of quadrature points that yielded in the step.
    pub fn commit(&mut self, x: &[Vector3<f64>]) -> usize {
        let mut yielded = 0;
        let states: Vec<[PlasticState; 4]> = (0..self.elements.len())
            .map(|e| {
                let (_, rm) = self.element_returns(e, x);
                yielded += rm.iter().filter(|m| m.delta_gamma > 0.0).count();
                std::array::from_fn(|q| rm[q].state)
            })
            .collect();
        self.committed = states;
        yielded
    }
}

/// Outcome of [`QuadraticRigidTipSolver::solve`].
#[derive(Clone, Debug, Default)]
pub struct QuadraticSolveReport {
    /// Residual and last update below the tolerances.
    pub converged: bool,
    /// Newton iterations taken.
    pub iterations: usize,
    /// ‖r‖ on the free dofs at the end, N.
    pub residual_norm_n: f64,
    /// The probe's contact at the end.
    pub contact: ContactReport,
    /// Per Newton iteration: ‖r‖ on the free dofs (N), the contact springs it used and the
    /// largest update before it (m; infinite at the first).
    pub history: Vec<(f64, usize, f64)>,
}

/// Equilibrium of a [`QuadraticElastoplasticModel`] with a rigid probe (module docs).
#[derive(Debug)]
pub struct QuadraticRigidTipSolver {
    pattern: SystemPattern,
    cholesky: SparseCholesky,
    length_scale_m: f64,
}

impl QuadraticRigidTipSolver {
    /// Pattern and symbolic factorization; `constrained_dofs` held as given.
    pub fn new(
        model: &QuadraticElastoplasticModel,
        constrained_dofs: &[usize],
    ) -> Result<Self, FemError> {
        let (pattern, cholesky, length_scale_m) =
            quadratic_solver_setup(&model.elements, &model.rest, constrained_dofs)?;
        Ok(Self {
            pattern,
            cholesky,
            length_scale_m,
        })
    }

    /// The dof map.
    pub fn dofs(&self) -> &DofMap {
        self.pattern.dofs()
    }

    /// Assembled element tangent (free dofs) and f_int at `x`.
    fn assemble(
        &self,
        model: &QuadraticElastoplasticModel,
        x: &[Vector3<f64>],
    ) -> (Vec<f64>, Vec<Vector3<f64>>) {
        let mut values = self.pattern.zeros();
        let mut fi = vec![Vector3::zeros(); model.num_nodes()];
        for (e, el) in model.elements.iter().enumerate() {
            let (f, k) = model.linearize(e, x);
            for a in 0..10 {
                fi[el[a]] += f[a];
                self.pattern.add_node_block(el[a], &k[a][a], &mut values);
                for b in a + 1..10 {
                    self.pattern
                        .add_pair_block(el[a], el[b], &k[a][b], &mut values);
                }
            }
        }
        (values, fi)
    }

    fn residual(
        &self,
        fi: &[Vector3<f64>],
        x: &[Vector3<f64>],
        f_ext: &[Vector3<f64>],
        springs: &[ContactSpring],
    ) -> (Vec<f64>, f64) {
        contact_residual(self.dofs(), f_ext, fi, x, springs)
    }

    /// Solves f_int(x) = f_ext + f_c from `x` (constrained components as given): Newton with the
    /// consistent tangent plus the springs' n nᵀ k_c, the active set re-queried with hysteresis
    /// every iteration until `settings.contact_freeze_after` iterations or until it comes back to
    /// a set it left (a cycle), then frozen; backtracking (`settings.max_halvings`) on ‖r‖ with
    /// the iteration's springs. Converged when ‖r‖ ≤ `residual_tol_rel` × the force scale and
    /// the last update ≤ `displacement_tol_rel` × the model's size. An iterate reached by the line search is tested with the forces the
    /// search computed there and the previous iterate's tangent (with this iterate's springs):
    /// the converged iterate is not assembled again.
    pub fn solve(
        &mut self,
        model: &QuadraticElastoplasticModel,
        x: &mut [Vector3<f64>],
        f_ext: &[Vector3<f64>],
        contact: Option<&ContactProblem>,
        settings: &EquilibriumSettings,
    ) -> QuadraticSolveReport {
        let mut report = QuadraticSolveReport::default();
        let tol_x = settings.displacement_tol_rel * self.length_scale_m;
        let mut table: Vec<f64> = Vec::new();
        let mut last: Vec<ContactSpring> = Vec::new();
        let mut last_update = f64::INFINITY;
        // f_int at x when the line search computed it, and the last assembled tangent
        let mut known: Option<Vec<Vector3<f64>>> = None;
        let mut tangent: Vec<f64> = Vec::new();
        // the active sets (nodes) met so far, and whether the set is frozen
        let mut sets: Vec<Vec<usize>> = Vec::new();
        let mut cycled = false;
        for it in 0..settings.max_iterations {
            let (fi, assembled) = match known.take() {
                Some(fi) => (fi, false),
                None => {
                    let (values, fi) = self.assemble(model, x);
                    tangent = values;
                    (fi, true)
                }
            };
            if table.is_empty() {
                table = (0..x.len())
                    .map(|n| self.pattern.node_stiffness(n, &tangent))
                    .collect();
            }
            // the active set re-queried (with hysteresis) up to `contact_freeze_after`
            // iterations or until it cycles, then frozen as a linear force field (as
            // `StaticSolver::solve`)
            let frozen = (it >= settings.contact_freeze_after || cycled) && it > 0;
            let springs = if frozen {
                last.clone()
            } else {
                contact.map_or(Vec::new(), |c| {
                    c.springs_with_hysteresis(x, |n| table[n], &last, false)
                })
            };
            if !frozen {
                // a set met before, other than the last one, is a cycle: frozen from here on
                let set: Vec<usize> = springs.iter().map(|s| s.node).collect();
                let n = sets.len();
                cycled = n >= 2 && sets[n - 1] != set && sets[..n - 1].contains(&set);
                sets.push(set);
            }
            let (r, scale) = self.residual(&fi, x, f_ext, &springs);
            let rn = r.iter().map(|v| v * v).sum::<f64>().sqrt();
            report.history.push((rn, springs.len(), last_update));
            report.residual_norm_n = rn;
            if let Some(c) = contact {
                report.contact = c.report(&springs, x);
            }
            if !rn.is_finite() {
                return report;
            }
            // the matrix with its springs, as `StaticSolver::solve` tests: a residual below what
            // a displacement of tol_x causes against the penalty-stiffened diagonal
            let mut values = tangent.clone();
            for s in &springs {
                self.pattern
                    .add_node_block(s.node, &s.matrix(), &mut values);
            }
            let diag_max = values.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let res_ok = rn <= settings.residual_tol_rel * scale || rn <= diag_max * tol_x;
            if it > 0 && res_ok && last_update <= tol_x {
                report.converged = true;
                return report;
            }
            if !assembled {
                let (fresh, _) = self.assemble(model, x);
                tangent = fresh;
                values.clone_from(&tangent);
                for s in &springs {
                    self.pattern
                        .add_node_block(s.node, &s.matrix(), &mut values);
                }
            }
            if self.cholesky.factor(&self.pattern, &values).is_err() {
                return report;
            }
            let mut dx = r.clone();
            if self.cholesky.solve_in_place(&mut dx).is_err() || dx.iter().any(|v| !v.is_finite()) {
                return report;
            }
            // backtracking on ‖r‖ with the iteration's springs, a linear force field: a node the
            // step pushes into the tip joins the set at the next iteration (fresh springs in the
            // trials cut the step to what keeps the set, 0.1–1 % of it, for ~10 iterations)
            let mut step = 1.0;
            if settings.line_search {
                let mut s = 1.0;
                let mut accepted = None;
                let mut full = None;
                for _ in 0..=settings.max_halvings {
                    let mut xt = x.to_vec();
                    self.dofs().scatter_add(&dx, s, &mut xt);
                    let fit = model.internal_forces(&xt);
                    let (rt, _) = self.residual(&fit, &xt, f_ext, &springs);
                    let rtn = rt.iter().map(|v| v * v).sum::<f64>().sqrt();
                    if rtn.is_finite() && rtn <= (1.0 - 1e-4 * s) * rn {
                        accepted = Some(fit);
                        break;
                    }
                    if full.is_none() {
                        full = Some(fit);
                    }
                    s *= 0.5;
                }
                step = if accepted.is_some() { s } else { 1.0 };
                known = accepted.or(full);
            }
            self.dofs().scatter_add(&dx, step, x);
            last_update = dx.iter().fold(0.0f64, |m, v| m.max(v.abs())) * step;
            last = springs;
            report.iterations = it + 1;
        }
        report
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::quadratic_tets;
    use softcap_mesh::box_tet_mesh;

    fn model(corotated: bool) -> QuadraticElastoplasticModel {
        model_on([1, 1, 1], corotated)
    }

    /// A 1 cm cube of `cells` Kuhn cells as 10-node tets, E 50 kPa, ν 0.45, σ_y 4.5 kPa, H 4 kPa.
    fn model_on(cells: [usize; 3], corotated: bool) -> QuadraticElastoplasticModel {
        let q = quadratic_tets(&box_tet_mesh([0.0; 3], [0.01; 3], cells));
        let n = q.elements.len();
        QuadraticElastoplasticModel::new(
            &q.nodes,
            &q.elements,
            vec![LinearParams::from_young_poisson(50e3, 0.45).unwrap(); n],
            vec![
                J2PlasticityParams {
                    yield_stress_pa: 4.5e3,
                    hardening_modulus_pa: 4e3,
                };
                n
            ],
            corotated,
        )
        .unwrap()
    }

    /// Homogeneous deformation x = A X: every point's strain is sym(A) − I.
    fn deformed(m: &QuadraticElastoplasticModel, a: &Matrix3<f64>) -> Vec<Vector3<f64>> {
        m.rest.iter().map(|p| a * p).collect()
    }

    #[test]
    fn tangent_matches_finite_differences_in_the_plastic_range() {
        for corotated in [false, true] {
            let m = model(corotated);
            // yielded: a shear of 0.15 (von Mises stress ≈ 2 × σ_y)
            let a = Matrix3::new(1.0, 0.15, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0);
            let mut x = deformed(&m, &a);
            x[9] += Vector3::new(1e-5, -2e-5, 3e-5);
            let (_, rm) = m.element_returns(0, &x);
            assert!(rm.iter().all(|r| r.delta_gamma > 0.0));
            let (_, k) = m.linearize(0, &x);
            let el = m.elements[0];
            let h = 1e-9;
            let mut worst: f64 = 0.0;
            let scale = k[0][0].norm();
            for b in 0..10 {
                for c in 0..3 {
                    let mut xp = x.clone();
                    let mut xm = x.clone();
                    xp[el[b]][c] += h;
                    xm[el[b]][c] -= h;
                    let (rp, rmp) = m.element_returns(0, &xp);
                    let (rn, rmn) = m.element_returns(0, &xm);
                    let (fp, fm) = (m.forces_of(0, &rp, &rmp), m.forces_of(0, &rn, &rmn));
                    for a in 0..10 {
                        let fd = (fp[a] - fm[a]) / (2.0 * h);
                        let an = k[a][b].column(c).into_owned();
                        worst = worst.max((fd - an).norm() / scale);
                    }
                }
            }
            // without ∂R the corotated tangent differs by O(rotation · stress / modulus)
            let tol = if corotated { 0.1 } else { 1e-5 };
            assert!(worst < tol, "corotated {corotated}: worst {worst}");
        }
    }

    #[test]
    fn uniaxial_path_follows_the_analytic_curve() {
        // Strain-controlled uniaxial stress: the stress at ε follows σ_y + H ε_p on the plastic
        // branch, σ = E ε below; here the lateral strain is set by incompressible plastic flow.
        // The homogeneous state is the one-point return: check against radial_return directly,
        // and that every quadrature point of every element carries it (patch test).
        let mut m = model(false);
        let p = LinearParams::from_young_poisson(50e3, 0.45).unwrap();
        let q = J2PlasticityParams {
            yield_stress_pa: 4.5e3,
            hardening_modulus_pa: 4e3,
        };
        let mut state = PlasticState::default();
        for k in 1..=5 {
            let e = 0.04 * k as f64;
            let a = Matrix3::new(1.0, e, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0);
            let x = deformed(&m, &a);
            let eps = (a - Matrix3::identity() + (a - Matrix3::identity()).transpose()) * 0.5;
            let want = radial_return(&p, &q, &eps, &state);
            for e in 0..m.elements.len() {
                let (_, rm) = m.element_returns(e, &x);
                for r in rm {
                    assert!((r.stress_pa - want.stress_pa).norm() < 1e-6 * want.stress_pa.norm());
                }
            }
            m.commit(&x);
            state = want.state;
        }
        // pure shear γ: τ = σ_y/√3 + (H/3) γ_p-ish; at least yielded and hardening
        assert!(state.equivalent_plastic_strain > 0.0);
        // nodal forces of a homogeneous stress balance inside: interior-free cube, Σ f = 0
        let x = deformed(&m, &Matrix3::identity());
        let f = m.internal_forces(&x);
        let sum: Vector3<f64> = f.iter().sum();
        assert!(sum.norm() < 1e-9);
    }

    #[test]
    fn compressed_block_leaves_a_set_and_unloads_to_equilibrium() {
        // Cube on the plane z = 0 (bottom nodes fixed), top nodes pushed down 15 % (yield) and
        // released: the solver converges both ways and a permanent set remains.
        let mut m = model(true);
        let n = m.num_nodes();
        let bottom: Vec<usize> = (0..n).filter(|&i| m.rest[i].z < 1e-9).collect();
        let top: Vec<usize> = (0..n).filter(|&i| m.rest[i].z > 0.01 - 1e-9).collect();
        let mut dofs: Vec<usize> = bottom
            .iter()
            .flat_map(|&i| [3 * i, 3 * i + 1, 3 * i + 2])
            .collect();
        dofs.extend(top.iter().map(|&i| 3 * i + 2));
        dofs.sort_unstable();
        let mut solver = QuadraticRigidTipSolver::new(&m, &dofs).unwrap();
        let settings = EquilibriumSettings::default();
        let mut x = m.rest.clone();
        let f = vec![Vector3::zeros(); n];
        for k in 1..=3 {
            for &i in &top {
                x[i].z = 0.01 * (1.0 - 0.05 * k as f64);
            }
            let rep = solver.solve(&m, &mut x, &f, None, &settings);
            assert!(rep.converged, "{rep:?}");
            m.commit(&x);
        }
        // release: only the bottom fixed
        let dofs: Vec<usize> = bottom
            .iter()
            .flat_map(|&i| [3 * i, 3 * i + 1, 3 * i + 2])
            .collect();
        let mut solver = QuadraticRigidTipSolver::new(&m, &dofs).unwrap();
        let rep = solver.solve(&m, &mut x, &f, None, &settings);
        assert!(rep.converged, "{rep:?}");
        let set = 0.01 - top.iter().map(|&i| x[i].z).sum::<f64>() / top.len() as f64;
        assert!(set > 1e-4 && set < 1.5e-3, "permanent set {set}");
    }

    #[test]
    fn flat_punch_contact_converges_to_its_unilateral_limit() {
        // A cube (2 × 2 × 1 cells, bottom fixed) pressed 5, 10, 15 % by a frictionless flat punch
        // wider than its top, then released. Every contact step must converge, and as the penalty
        // grows the solution tends to the unilateral one (the KKT conditions): the same model
        // with the z of the contact patch's nodes prescribed at the punch face and everything
        // else free (x, y of the patch frictionless). Checked: the positions and yielded points
        // of both agree to the penalty's error (k_c = 10⁴ × the node stiffness), the punch only
        // pushes (compressive reaction on every patch node of the prescribed solution), no free
        // top node penetrates, and the permanent sets after release agree. On 10-node faces the
        // corner nodes carry tensile consistent loads under a uniform push, so part of them
        // leave the patch: the unilateral limit differs from prescribing the whole top.
        use crate::contact::{ContactSettings, Probe, TipShape};
        use nalgebra::{Isometry3, Translation3, UnitQuaternion};
        let (mut mc, mut md) = (model_on([2, 2, 1], true), model_on([2, 2, 1], true));
        let rest = mc.rest.clone();
        let n = rest.len();
        let bottom: Vec<usize> = (0..n).filter(|&i| rest[i].z < 1e-9).collect();
        let top: Vec<usize> = (0..n).filter(|&i| rest[i].z > 0.01 - 1e-9).collect();
        let fixed: Vec<usize> = bottom
            .iter()
            .flat_map(|&i| [3 * i, 3 * i + 1, 3 * i + 2])
            .collect();
        let settings = EquilibriumSettings::default();
        let f = vec![Vector3::zeros(); n];
        let mut sc = QuadraticRigidTipSolver::new(&mc, &fixed).unwrap();
        let (mut xc, mut xd) = (rest.clone(), rest.clone());
        let mut yielded = 0;
        // probe +z (approach) along world −z, leading face at the pressed height
        let down = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI);
        for k in 1..=3 {
            let depth = 0.0005 * k as f64;
            let z = 0.01 - depth;
            let probe = Probe::new(
                TipShape::Disk {
                    radius_m: 0.02,
                    thickness_m: 0.01,
                },
                Isometry3::from_parts(Translation3::new(0.005, 0.005, z), down),
            )
            .unwrap()
            .with_punch_face();
            let contact = ContactProblem {
                probe,
                candidate_nodes: top.clone(),
                settings: ContactSettings::default(),
            };
            let rep = sc.solve(&mc, &mut xc, &f, Some(&contact), &settings);
            assert!(rep.converged, "contact step {k}: {rep:?}");
            assert!(rep.contact.axial_force_n > 0.0);
            let patch = rep.contact.patch_nodes.clone();
            assert!(
                !patch.is_empty() && patch.len() < top.len(),
                "patch {patch:?}"
            );
            // the prescribed-patch solution from the previous prescribed state
            let mut prescribed = fixed.clone();
            prescribed.extend(patch.iter().map(|&i| 3 * i + 2));
            prescribed.sort_unstable();
            let mut sd = QuadraticRigidTipSolver::new(&md, &prescribed).unwrap();
            for &i in &patch {
                xd[i].z = z;
            }
            let rep = sd.solve(&md, &mut xd, &f, None, &settings);
            assert!(rep.converged, "prescribed step {k}: {rep:?}");
            let fi = md.internal_forces(&xd);
            // the punch's force on a node is f_int (equilibrium f_int = f_ext + f_c, no other
            // load): downward, up to the penalty's error at the patch's rim
            let mean = patch.iter().map(|&i| fi[i].z).sum::<f64>() / patch.len() as f64;
            assert!(mean < 0.0, "step {k}: mean punch force {mean} N");
            for &i in &patch {
                assert!(
                    fi[i].z < -1e-3 * mean,
                    "step {k}: node {i} pulled, {} N (mean {mean})",
                    fi[i].z
                );
            }
            for &i in top.iter().filter(|i| !patch.contains(i)) {
                assert!(xd[i].z <= z + 1e-12, "step {k}: node {i} penetrates");
            }
            let worst = (0..n).map(|i| (xc[i] - xd[i]).norm()).fold(0.0, f64::max);
            assert!(worst < 1e-3 * depth, "step {k}: {worst} m apart");
            let (yc, yd) = (mc.commit(&xc), md.commit(&xd));
            assert_eq!(yc, yd, "step {k}: yielded points");
            yielded += yc;
        }
        assert!(yielded > 0);
        let mut sd = QuadraticRigidTipSolver::new(&md, &fixed).unwrap();
        let rc = sc.solve(&mc, &mut xc, &f, None, &settings);
        let rd = sd.solve(&md, &mut xd, &f, None, &settings);
        assert!(rc.converged && rd.converged, "{rc:?} {rd:?}");
        let set =
            |x: &[Vector3<f64>]| 0.01 - top.iter().map(|&i| x[i].z).sum::<f64>() / top.len() as f64;
        let (a, b) = (set(&xc), set(&xd));
        assert!(b > 1e-4, "permanent set {b}");
        assert!(
            (a - b).abs() < 1e-3 * b,
            "permanent set {a} (contact) vs {b}"
        );
    }
}
