//! The average-fit homogeneous linear corotational model of bickel2009 §6 (Fig. 8 baseline):
//! one (E, ν) for every tet and every example, by Levenberg–Marquardt over (ln E, ν) — with the
//! attached nodes fixed ([`fit_homogeneous`]) or with the attached face on a support plane with
//! tangential springs ([`fit_homogeneous_on_support`]).

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use softcap_fem::{
    CorotationalModel, EquilibriumReport, EquilibriumSettings, FemError, LinearParams, NodalSolver,
    Sensitivity, SolveStatus, StaticSolver, StiffnessKind, SupportPlane,
};

use crate::setup::{marker_residuals, rms_of};
use crate::{ExampleFitSettings, PatchSettings, ProbeExample, ProbingSetup, probing_error};

/// Simulates `example` with `params` from the warm start `x`; returns the equilibrium report.
fn simulate_params(
    setup: &ProbingSetup,
    solver: &mut StaticSolver,
    model: &mut CorotationalModel,
    params: &[LinearParams],
    forces: &[Vector3<f64>],
    x: &mut [Vector3<f64>],
    settings: &EquilibriumSettings,
) -> Result<EquilibriumReport, FemError> {
    model.set_params(params)?;
    Ok(setup.simulate(solver, model, x, forces, settings))
}

/// Settings of [`fit_homogeneous`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HomogeneousFitSettings {
    /// Starting Young's modulus, Pa (rescaled by a first linear estimate).
    pub initial_young_pa: f64,
    /// Starting Poisson ratio.
    pub initial_nu: f64,
    /// Bounds on ν.
    pub nu_bounds: (f64, f64),
    /// LM settings.
    pub lm: softcap_core::LevenbergMarquardtSettings,
    /// Equilibrium settings.
    pub equilibrium: EquilibriumSettings,
    /// Patch of the force boundary condition.
    pub patch: PatchSettings,
}

impl Default for HomogeneousFitSettings {
    fn default() -> Self {
        Self {
            initial_young_pa: 3.0e4,
            initial_nu: 0.4,
            nu_bounds: (0.0, 0.49),
            lm: softcap_core::LevenbergMarquardtSettings {
                max_iterations: 20,
                relative_cost_tolerance: 1e-6,
                gradient_tolerance: 0.0,
                ..Default::default()
            },
            equilibrium: ExampleFitSettings::default().equilibrium,
            patch: PatchSettings::default(),
        }
    }
}

/// Result of [`fit_homogeneous`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct HomogeneousFit {
    /// The one (λ, α) of every tet.
    pub params: LinearParams,
    /// RMS marker error of each example, m.
    pub example_rms_m: Vec<f64>,
    /// RMS marker error over all examples, m.
    pub rms_m: f64,
    /// LM iterations.
    pub iterations: usize,
    /// Equilibrium solves of the fit (every residual and Jacobian evaluation, the start
    /// included) that stopped at the iteration cap (`EquilibriumSettings::max_iterations`): their
    /// residuals were NaN, so Levenberg–Marquardt rejected that trial point.
    #[serde(default)]
    pub stalled_solves: usize,
}

/// How the examples are simulated: the attached nodes fixed (the default model), or the
/// attached face on a support plane (`SupportPlane`: bilateral normal penalty, its tangential
/// law) with no node fixed.
enum Boundary {
    Fixed(StaticSolver),
    Support {
        solver: NodalSolver,
        plane: SupportPlane,
    },
}

/// Forward-difference step in (ln E, ν) of the Jacobian on a support plane: 10⁻⁴ changes the
/// displacements by ~10⁻⁴ of themselves, far above the equilibrium tolerance (10⁻⁹ of the
/// length scale) and small enough that the curvature in (ln E, ν) is negligible for LM.
const SUPPORT_FD_STEP: f64 = 1e-4;

struct HomogeneousProblem<'a> {
    setup: &'a ProbingSetup,
    examples: &'a [ProbeExample],
    forces: Vec<Vec<Vector3<f64>>>,
    warm: Vec<Vec<Vector3<f64>>>,
    boundary: Boundary,
    model: CorotationalModel,
    young_ref: f64,
    settings: &'a HomogeneousFitSettings,
    m: usize,
    /// Equilibrium solves that stopped at the iteration cap so far.
    stalled: usize,
}

impl HomogeneousProblem<'_> {
    fn params(&self, q: &[f64]) -> Option<LinearParams> {
        LinearParams::from_young_poisson(self.young_ref * q[0].exp(), q[1]).ok()
    }

    fn run(&mut self, q: &[f64], r: &mut [f64], mut jac: Option<&mut nalgebra::DMatrix<f64>>) {
        let Some(p) = self.params(q) else {
            r.iter_mut().for_each(|v| *v = f64::NAN);
            return;
        };
        let t = self.setup.num_elements();
        let mut row0 = 0;
        for (k, ex) in self.examples.iter().enumerate() {
            let mut x = self.warm[k].clone();
            let ok = match &mut self.boundary {
                Boundary::Fixed(solver) => simulate_params(
                    self.setup,
                    solver,
                    &mut self.model,
                    &vec![p; t],
                    &self.forces[k],
                    &mut x,
                    &self.settings.equilibrium,
                ),
                Boundary::Support { solver, plane } => {
                    self.model.set_params(&vec![p; t]).map(|()| {
                        solver.solve(
                            &mut self.model,
                            &mut x,
                            &self.forces[k],
                            &mut [plane],
                            &self.settings.equilibrium,
                        )
                    })
                }
            }
            .map(|rep| {
                self.stalled += usize::from(rep.status == SolveStatus::MaxIterations);
                rep.converged()
            })
            .unwrap_or(false);
            let rk = marker_residuals(self.setup, ex, &x);
            for (i, v) in rk.iter().enumerate() {
                r[row0 + i] = if ok { *v } else { f64::NAN };
            }
            if let (Some(j), Boundary::Fixed(solver)) = (jac.as_deref_mut(), &mut self.boundary) {
                // Forward sensitivities (appendix eq. 11) along "every λ_e" and "every α_e": two
                // solves per example instead of one adjoint solve per marker coordinate.
                let columns =
                    Sensitivity::new(solver, &self.model, &x, StiffnessKind::Consistent, None)
                        .and_then(|sens| {
                            let mut v = vec![0.0; 2 * t];
                            v.iter_mut().step_by(2).for_each(|a| *a = 1.0);
                            let dl = sens.jacobian_times(&v)?;
                            v.iter_mut().for_each(|a| *a = 1.0 - *a);
                            let da = sens.jacobian_times(&v)?;
                            Ok((dl, da))
                        });
                if let Ok((dl, da)) = columns {
                    // (E, ν) ↦ (λ, α): λ = E/((1+ν)(1−2ν)), α = νλ; q0 = ln E/E_ref.
                    let (e_pa, nu) = (self.young_ref * q[0].exp(), q[1]);
                    let den = (1.0 + nu) * (1.0 - 2.0 * nu);
                    let lam = e_pa / den;
                    let dlam_dnu = e_pa * (1.0 + 4.0 * nu) / (den * den);
                    let dalpha_dnu = lam + nu * dlam_dnu;
                    let mut i = 0;
                    for o in &ex.observed {
                        let emb = &self.setup.markers[o.marker];
                        let tet = self.setup.mesh.tets[emb.tet];
                        for c in 0..3 {
                            let (mut jl, mut ja) = (0.0, 0.0);
                            for a in 0..4 {
                                jl += emb.weights[a] * dl[3 * tet[a] + c];
                                ja += emb.weights[a] * da[3 * tet[a] + c];
                            }
                            // ∂/∂q0 = E ∂/∂E = λ ∂/∂λ + α ∂/∂α.
                            j[(row0 + i, 0)] = lam * jl + nu * lam * ja;
                            j[(row0 + i, 1)] = dlam_dnu * jl + dalpha_dnu * ja;
                            i += 1;
                        }
                    }
                }
            }
            if ok {
                self.warm[k] = x;
            }
            row0 += rk.len();
        }
    }
}

impl softcap_core::LeastSquaresProblem for HomogeneousProblem<'_> {
    fn num_params(&self) -> usize {
        2
    }
    fn num_residuals(&self) -> usize {
        self.m
    }
    fn residuals(&mut self, params: &[f64], residuals: &mut [f64]) {
        self.run(params, residuals, None);
    }
    fn jacobian(&mut self, params: &[f64], jacobian: &mut nalgebra::DMatrix<f64>) -> bool {
        let mut r = vec![0.0; self.m];
        self.run(params, &mut r, Some(jacobian));
        if matches!(self.boundary, Boundary::Support { .. }) {
            // No sensitivity of the support plane's solver: forward differences, stepping into
            // the ν bounds (the springs do not scale with E, so the columns are not 1/E-scaled).
            // Each column starts from the equilibria at `params` (kept, then restored: no
            // re-solve at `params` afterwards).
            let at_params = self.warm.clone();
            let mut q = params.to_vec();
            let mut rq = vec![0.0; self.m];
            for c in 0..2 {
                let h = if c == 1 && params[1] + SUPPORT_FD_STEP > self.settings.nu_bounds.1 {
                    -SUPPORT_FD_STEP
                } else {
                    SUPPORT_FD_STEP
                };
                q.copy_from_slice(params);
                q[c] += h;
                self.warm.clone_from(&at_params);
                self.run(&q, &mut rq, None);
                for i in 0..self.m {
                    jacobian[(i, c)] = (rq[i] - r[i]) / h;
                }
            }
            // the warm starts back at `params`
            self.warm = at_params;
        }
        true
    }
}

/// The average-fit homogeneous linear corotational model (bickel2009 §6, Fig. 8 baseline): one
/// (E, ν) for every tet that best fits all examples' markers in the least-squares sense,
/// by Levenberg–Marquardt over (ln E, ν) with the adjoint Jacobian summed over the tets. The
/// start E is first rescaled by the linear estimate E ← E·(u_sim·u_sim)/(u_sim·u_meas).
pub fn fit_homogeneous(
    setup: &ProbingSetup,
    examples: &[ProbeExample],
    settings: &HomogeneousFitSettings,
) -> Result<HomogeneousFit, FemError> {
    fit_with(setup, examples, settings, None)
}

/// [`fit_homogeneous`] with the attached face on the support plane `plane` instead of fixed
/// (`softcap_fem::SupportPlane`, e.g. tangential springs: the support-slip extension): the same
/// (E, ν) least squares with every node free and the plane's forces in each equilibrium
/// (`softcap_fem::NodalSolver`), the Jacobian by forward differences in (ln E, ν). A stiff
/// support reproduces [`fit_homogeneous`]; a compliant one lets the slip carry the part of the
/// markers' motion the fixed support gives to a softer material.
pub fn fit_homogeneous_on_support(
    setup: &ProbingSetup,
    examples: &[ProbeExample],
    settings: &HomogeneousFitSettings,
    plane: SupportPlane,
) -> Result<HomogeneousFit, FemError> {
    fit_with(setup, examples, settings, Some(plane))
}

/// [`fit_homogeneous`] (`plane` None) or [`fit_homogeneous_on_support`].
fn fit_with(
    setup: &ProbingSetup,
    examples: &[ProbeExample],
    settings: &HomogeneousFitSettings,
    plane: Option<SupportPlane>,
) -> Result<HomogeneousFit, FemError> {
    let t = setup.num_elements();
    let p0 = LinearParams::from_young_poisson(settings.initial_young_pa, settings.initial_nu)?;
    let model = CorotationalModel::homogeneous(&setup.mesh, p0)?;
    let boundary = match plane {
        None => Boundary::Fixed(setup.solver(&model)?),
        Some(plane) => Boundary::Support {
            solver: NodalSolver::new(&model, &[])?,
            plane,
        },
    };
    let forces: Vec<_> = examples
        .iter()
        .map(|ex| setup.nodal_forces(ex, &settings.patch))
        .collect();
    let m: usize = examples.iter().map(|e| 3 * e.observed.len()).sum();
    let mut problem = HomogeneousProblem {
        setup,
        examples,
        forces,
        warm: vec![setup.mesh.vertices.clone(); examples.len()],
        boundary,
        model,
        young_ref: settings.initial_young_pa,
        settings,
        m,
        stalled: 0,
    };
    // The start must reach equilibrium on every example: otherwise its residuals are NaN, the
    // linear rescaling below is skipped and Levenberg–Marquardt cannot leave the start, so the
    // "fit" is the initial guess (measured: a relaxing soft block under the lumped patch force,
    // 30 kPa start, marker RMS 1.6 mm). A stiffer material deforms less, so E is doubled until
    // every example converges (at most `START_DOUBLINGS` times; the rescaling then undoes it).
    const START_DOUBLINGS: usize = 16;
    let mut r = vec![0.0; m];
    for doubling in 0..=START_DOUBLINGS {
        problem.run(&[0.0, settings.initial_nu], &mut r, None);
        if r.iter().all(|v| v.is_finite()) || doubling == START_DOUBLINGS {
            break;
        }
        problem.young_ref *= 2.0;
        problem.warm = vec![setup.mesh.vertices.clone(); examples.len()];
    }
    // Linear rescaling of the start: displacements scale like 1/E.
    let (mut uu, mut um) = (0.0, 0.0);
    let mut row = 0;
    for ex in examples {
        for o in &ex.observed {
            let rest = setup.markers[o.marker].position(&setup.mesh.tets, &setup.mesh.vertices);
            for c in 0..3 {
                let meas = o.position_m[c] - rest[c];
                let sim = r[row] + meas;
                uu += sim * sim;
                um += sim * meas;
                row += 1;
            }
        }
    }
    if um > 0.0 && uu.is_finite() {
        problem.young_ref *= uu / um;
    }
    problem.warm = vec![setup.mesh.vertices.clone(); examples.len()];
    let bounds = softcap_core::Bounds::new(
        vec![-5.0, settings.nu_bounds.0],
        vec![5.0, settings.nu_bounds.1],
    )
    .map_err(|e| probing_error(e.to_string()))?;
    let report = softcap_core::levenberg_marquardt(
        &mut problem,
        &[0.0, settings.initial_nu],
        Some(&bounds),
        &settings.lm,
    )
    .map_err(|e| probing_error(e.to_string()))?;
    if !report.residuals.iter().all(|v| v.is_finite()) {
        return Err(probing_error(format!(
            "homogeneous fit: an example does not reach equilibrium at the fitted material \
             ({} equilibrium solves of the fit stopped at the {}-iteration cap)",
            problem.stalled, settings.equilibrium.max_iterations
        )));
    }
    let params = problem
        .params(&report.params)
        .ok_or_else(|| probing_error("homogeneous fit left the valid parameter range"))?;
    let mut example_rms_m = Vec::with_capacity(examples.len());
    let mut row = 0;
    let mut total = 0.0;
    for ex in examples {
        let k = 3 * ex.observed.len();
        let rk = &report.residuals[row..row + k];
        total += rk.iter().map(|v| v * v).sum::<f64>();
        example_rms_m.push(rms_of(rk));
        row += k;
    }
    let _ = t;
    Ok(HomogeneousFit {
        params,
        example_rms_m,
        rms_m: (total / (m / 3).max(1) as f64).sqrt(),
        iterations: report.iterations,
        stalled_solves: problem.stalled,
    })
}
