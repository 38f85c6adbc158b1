//! Time stepping of the ground truth: one engine per kind of physics, so the frame loop of
//! [`crate::truth::simulate`] is the same for every effect.
//!
//! | engine | effects | per step |
//! |---|---|---|
//! | elastic | clean, controls, anisotropy, gravity-preload | `StaticSolver` + rigid-probe penalty contact (bickel2009 §3.4); memoryless |
//! | viscoelastic | viscoelasticity | `ViscoelasticModel` (Prony series on the neo-Hookean truth, Simo & Hughes §10.3 recurrence): set Δt, solve, commit |
//! | plastic | plasticity | `ElastoplasticModel` (J2 radial return on the corotational element): solve, commit |
//! | nodal | probe-friction, support-slip | `NodalSolver` with `FrictionalContact` (regularized Coulomb, IPC f₁) and `SupportPlane` (tangential springs): solve, commit anchors |
//! | dynamic | inertia-damping | `DynamicSolver` (wang2015 eq. 3, Newmark average acceleration, Rayleigh D = αM + βK) |
//!
//! History-carrying engines are solved in every frame (also with the probe lifted: creep
//! recovery, permanent set, ringing), and [`Engine::save`] / [`Engine::restore`] let a failed
//! frame be retried with more sub-steps from the same history.

use nalgebra::Vector3;
use softcap_fem::{
    ContactProblem, ContactSettings, DirichletBc, DynamicSolver, DynamicState, DynamicStepStatus,
    DynamicsSettings, ElasticModel, ElastoplasticModel, EquilibriumReport, EquilibriumSettings,
    FrictionalContact, LaggedIterations, NodalSolver, NodalTerm, Probe, StaticSolver, SupportPlane,
    ViscoelasticModel, solve_lagged,
};

use crate::error::Result;
use crate::truth::TruthModel;

/// Outcome of one (sub-)step.
#[derive(Clone, Debug)]
pub(crate) struct StepOutcome {
    /// Converged (the state was committed).
    pub converged: bool,
    /// Solver status for error messages.
    pub status: String,
    /// Iterations used.
    pub iterations: usize,
    /// Force of the probe on the object, N (world).
    pub force_n: Vector3<f64>,
    /// Tangential (friction) part of `force_n`, N.
    pub friction_force_n: Vector3<f64>,
    /// Mean tangential slip of the support nodes, m (support-slip only).
    pub support_slip_m: Vector3<f64>,
    /// Lagged normal forces (probe-friction): the last outer iteration's max_n |Δf_n| / Σ f_n.
    pub friction_lag_mismatch: f64,
}

impl StepOutcome {
    fn from_static(rep: &EquilibriumReport) -> Self {
        Self {
            converged: rep.converged(),
            status: format!(
                "{:?} after {} iterations, residual {:.3e} N",
                rep.status, rep.iterations, rep.residual_norm_n
            ),
            iterations: rep.iterations,
            force_n: rep.contact.contact_force_n,
            friction_force_n: Vector3::zeros(),
            support_slip_m: Vector3::zeros(),
            friction_lag_mismatch: 0.0,
        }
    }
}

/// The simulation engine of one scenario.
pub(crate) enum Engine {
    /// Hyperelastic (or anisotropic) quasi-statics.
    Elastic {
        model: Box<dyn ElasticModel>,
        solver: StaticSolver,
    },
    /// Quasi-static viscoelasticity.
    Viscoelastic {
        model: Box<ViscoelasticModel<TruthModel>>,
        solver: StaticSolver,
        saved: Option<Box<ViscoelasticModel<TruthModel>>>,
    },
    /// Quasi-static elastoplasticity.
    Plastic {
        model: Box<ElastoplasticModel>,
        solver: StaticSolver,
        saved: Option<Box<ElastoplasticModel>>,
    },
    /// Quasi-statics with node-level terms (frictional probe, compliant support).
    Nodal {
        model: Box<dyn ElasticModel>,
        solver: NodalSolver,
        contact: Box<FrictionalContact>,
        support: Option<Box<SupportPlane>>,
        saved: Option<(Box<FrictionalContact>, Option<Box<SupportPlane>>)>,
    },
    /// Implicit dynamics.
    Dynamic {
        model: Box<dyn ElasticModel>,
        solver: Box<DynamicSolver>,
        state: Box<DynamicState>,
        settings: DynamicsSettings,
        saved: Option<Box<DynamicState>>,
    },
}

impl Engine {
    /// Elastic engine with the bottom face fixed by `bc`.
    pub fn elastic(model: Box<dyn ElasticModel>, bc: &DirichletBc) -> Result<Self> {
        let solver = StaticSolver::with_bc(&*model, bc)?;
        Ok(Self::Elastic { model, solver })
    }

    /// Viscoelastic engine.
    pub fn viscoelastic(model: ViscoelasticModel<TruthModel>, bc: &DirichletBc) -> Result<Self> {
        let solver = StaticSolver::with_bc(&model, bc)?;
        Ok(Self::Viscoelastic {
            model: Box::new(model),
            solver,
            saved: None,
        })
    }

    /// Elastoplastic engine.
    pub fn plastic(model: ElastoplasticModel, bc: &DirichletBc) -> Result<Self> {
        let solver = StaticSolver::with_bc(&model, bc)?;
        Ok(Self::Plastic {
            model: Box::new(model),
            solver,
            saved: None,
        })
    }

    /// Nodal engine: frictional probe contact, optional support plane replacing `bc`.
    pub fn nodal(
        model: Box<dyn ElasticModel>,
        bc: &DirichletBc,
        contact: FrictionalContact,
        support: Option<SupportPlane>,
    ) -> Result<Self> {
        let constrained = if support.is_some() {
            Vec::new()
        } else {
            bc.dofs()
        };
        let solver = NodalSolver::new(&*model, &constrained)?;
        Ok(Self::Nodal {
            model,
            solver,
            contact: Box::new(contact),
            support: support.map(Box::new),
            saved: None,
        })
    }

    /// Dynamic engine starting at rest at `x0`.
    pub fn dynamic(
        model: Box<dyn ElasticModel>,
        masses_kg: Vec<f64>,
        bc: &DirichletBc,
        x0: Vec<Vector3<f64>>,
        settings: DynamicsSettings,
    ) -> Result<Self> {
        let solver = Box::new(DynamicSolver::with_bc(&*model, masses_kg, bc)?);
        Ok(Self::Dynamic {
            model,
            solver,
            state: Box::new(DynamicState::at_rest(x0)),
            settings,
            saved: None,
        })
    }

    /// The element model (geometry, internal forces).
    pub fn model(&self) -> &dyn ElasticModel {
        match self {
            Engine::Elastic { model, .. }
            | Engine::Nodal { model, .. }
            | Engine::Dynamic { model, .. } => &**model,
            Engine::Viscoelastic { model, .. } => &**model,
            Engine::Plastic { model, .. } => &**model,
        }
    }

    /// True when the state without probe contact is always the unloaded one (no history).
    pub fn memoryless(&self) -> bool {
        matches!(self, Engine::Elastic { .. } | Engine::Nodal { .. })
    }

    /// The probe left the surface: forget the stick history under the tip.
    pub fn lift_off(&mut self) {
        if let Engine::Nodal { contact, .. } = self {
            contact.reset_history();
        }
    }

    /// Remembers the history state (before a frame).
    pub fn save(&mut self) {
        match self {
            Engine::Elastic { .. } => {}
            Engine::Viscoelastic { model, saved, .. } => *saved = Some(model.clone()),
            Engine::Plastic { model, saved, .. } => *saved = Some(model.clone()),
            Engine::Nodal {
                contact,
                support,
                saved,
                ..
            } => *saved = Some((contact.clone(), support.clone())),
            Engine::Dynamic { state, saved, .. } => *saved = Some(state.clone()),
        }
    }

    /// Goes back to the state of the last [`Engine::save`].
    pub fn restore(&mut self) {
        match self {
            Engine::Elastic { .. } => {}
            Engine::Viscoelastic { model, saved, .. } => {
                if let Some(m) = saved {
                    *model = m.clone();
                }
            }
            Engine::Plastic { model, saved, .. } => {
                if let Some(m) = saved {
                    *model = m.clone();
                }
            }
            Engine::Nodal {
                contact,
                support,
                saved,
                ..
            } => {
                if let Some((c, s)) = saved {
                    *contact = c.clone();
                    *support = s.clone();
                }
            }
            Engine::Dynamic { state, saved, .. } => {
                if let Some(s) = saved {
                    *state = s.clone();
                }
            }
        }
    }

    /// One step of length `dt_s` ending with the probe at `probe` (None: not in contact) and
    /// external forces `f_ext`; `x` is the start (warm start for the static engines) and receives
    /// the end state. History is committed only when the step converged.
    #[allow(clippy::too_many_arguments)]
    pub fn step(
        &mut self,
        x: &mut [Vector3<f64>],
        f_ext: &[Vector3<f64>],
        probe: Option<&Probe>,
        candidates: &[usize],
        contact_settings: &ContactSettings,
        dt_s: f64,
        settings: &EquilibriumSettings,
    ) -> Result<StepOutcome> {
        let problem = probe.map(|p| ContactProblem {
            probe: p.clone(),
            candidate_nodes: candidates.to_vec(),
            settings: contact_settings.clone(),
        });
        Ok(match self {
            Engine::Elastic { model, solver } => {
                let rep = static_solve(solver, &mut **model, x, f_ext, problem.as_ref(), settings);
                StepOutcome::from_static(&rep)
            }
            Engine::Viscoelastic { model, solver, .. } => {
                model.set_time_step(dt_s)?;
                let rep = static_solve(solver, &mut **model, x, f_ext, problem.as_ref(), settings);
                if rep.converged() {
                    model.commit(x);
                }
                StepOutcome::from_static(&rep)
            }
            Engine::Plastic { model, solver, .. } => {
                let rep = static_solve(solver, &mut **model, x, f_ext, problem.as_ref(), settings);
                if rep.converged() {
                    model.commit(x);
                }
                StepOutcome::from_static(&rep)
            }
            Engine::Nodal {
                model,
                solver,
                contact,
                support,
                ..
            } => {
                // Regularized Coulomb friction converges more slowly (lagged normal forces, stick
                // stiffness 2μf_n/ε): more iterations, residual 1e-6 of the force scale.
                let nodal_settings = EquilibriumSettings {
                    max_iterations: settings.max_iterations.max(150),
                    residual_tol_rel: settings.residual_tol_rel.max(1e-6),
                    ..settings.clone()
                };
                if let Some(p) = probe {
                    contact.move_probe(x, p.world_from_probe);
                }
                // Lagged normal forces (NormalForceLag::Solve): solve with f_n held, re-lag f_n
                // from the converged springs, repeat until f_n settles (IPC's lagged iterations).
                let mut others: Vec<&mut dyn NodalTerm> = Vec::with_capacity(1);
                if let Some(s) = support.as_mut() {
                    others.push(&mut **s);
                }
                let lagged = solve_lagged(
                    solver,
                    &mut **model,
                    x,
                    f_ext,
                    probe.is_some().then_some(&mut **contact),
                    &mut others,
                    &nodal_settings,
                    &LaggedIterations::default(),
                );
                drop(others);
                let (rep, lag_mismatch) = (lagged.equilibrium, lagged.lag_mismatch);
                let mut out = StepOutcome::from_static(&rep);
                if rep.converged() {
                    if probe.is_some() {
                        contact.commit(x);
                        let r = contact.report(x);
                        out.friction_lag_mismatch = lag_mismatch;
                        out.force_n = r.contact_force_n;
                        out.friction_force_n = r.friction_force_n;
                    }
                    if let Some(s) = support.as_mut() {
                        s.commit(x);
                        out.support_slip_m = s.report(x).mean_slip_m;
                    }
                }
                out
            }
            Engine::Dynamic {
                model,
                solver,
                state,
                settings: dyn_settings,
                ..
            } => {
                let step_settings = DynamicsSettings {
                    time_step_s: dt_s,
                    ..dyn_settings.clone()
                };
                let rep = solver.step(
                    &mut **model,
                    state,
                    f_ext,
                    None,
                    problem.as_ref(),
                    &step_settings,
                );
                x.copy_from_slice(&state.positions_m);
                StepOutcome {
                    converged: rep.status == DynamicStepStatus::Converged,
                    status: format!("{:?}", rep.status),
                    iterations: rep.iterations,
                    force_n: rep.contact.contact_force_n,
                    friction_force_n: Vector3::zeros(),
                    support_slip_m: Vector3::zeros(),
                    friction_lag_mismatch: 0.0,
                }
            }
        })
    }
}

/// Static solve with probe contact; the active set is frozen late in the iterations, so re-solve
/// from the converged state until no node of the patch is held in tension.
fn static_solve<M: ElasticModel + ?Sized>(
    solver: &mut StaticSolver,
    model: &mut M,
    x: &mut [Vector3<f64>],
    f_ext: &[Vector3<f64>],
    problem: Option<&ContactProblem>,
    settings: &EquilibriumSettings,
) -> EquilibriumReport {
    let mut rep = solver.solve(model, x, f_ext, problem, settings);
    if let Some(problem) = problem {
        for _ in 0..4 {
            if !rep.converged()
                || rep
                    .contact
                    .patch_nodes
                    .iter()
                    .all(|&n| problem.probe.penetration(&x[n]).is_some())
            {
                break;
            }
            rep = solver.solve(model, x, f_ext, Some(problem), settings);
        }
    }
    rep
}
