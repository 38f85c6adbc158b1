//! The extended models of [`Extension`] re-simulated over a recording in time order on
//! [`FemProbeSimulator`] (the table in [`crate::sim`]): history committed after every frame
//! (creep, plastic flow, stick of the support and of the tip), force-driven or as a rigid-tip
//! replay at the measured poses.

use super::contract::{Extension, SequenceFrame, SimLoad};
use super::fem::FemProbeSimulator;
use super::resolution::{friction_refinement, friction_slip_distance_m, tip_radius_m};
use crate::{DiagnoseError, Result};
use nalgebra::{Isometry3, Translation3, Unit, UnitQuaternion, Vector3};
use softcap_fem::{
    AnisotropicModel, ContactProblem, DynamicSolver, DynamicState, DynamicStepStatus,
    DynamicsSettings, ElasticModel, ElastoplasticModel, EquilibriumReport, EquilibriumSettings,
    FibreFamily, FrictionParams, FrictionalContact, Integrator, J2PlasticityParams,
    LaggedIterations, LinearParams, NodalSolver, NodalTerm, NormalForceLag, Probe, PronySeries,
    RayleighDamping, StaticSolver, StepLoads, StiffnessKind, SupportPlane, SupportTangential,
    TransverselyIsotropicParams, ViscoelasticModel, lumped_masses, solve_lagged,
};
use softcap_probing::probe_pose;

fn fem(e: softcap_fem::FemError) -> DiagnoseError {
    DiagnoseError::Fem(Box::new(e))
}

fn not_converged(k: usize, what: String) -> DiagnoseError {
    DiagnoseError::Simulation {
        frame: k as u64,
        reason: what,
    }
}

/// The spread of the support springs' area shares w_i against the equal split 1/n (profile
/// output): n, min and max of n w_i and the coefficient of variation of w.
fn area_share_spread(w: &[f64]) -> String {
    let n = w.len().max(1) as f64;
    let scaled: Vec<f64> = w.iter().map(|wi| wi * n).collect();
    let (lo, hi) = scaled.iter().fold((f64::INFINITY, 0.0f64), |(lo, hi), &s| {
        (lo.min(s), hi.max(s))
    });
    let var = scaled.iter().map(|s| (s - 1.0).powi(2)).sum::<f64>() / n;
    format!(
        "[profile] support springs: {} attached nodes, area share x n: min {lo:.3}, max {hi:.3}, CV {:.3} (equal split: 1, 1, 0)",
        w.len(),
        var.sqrt()
    )
}

impl FemProbeSimulator {
    fn nodal_load(&self, load: &SimLoad) -> Vec<Vector3<f64>> {
        let n = self.setup().mesh.vertices.len();
        let mut f = if load.body_force_n_m3 != Vector3::zeros() {
            self.body_forces(&load.body_force_n_m3)
        } else {
            vec![Vector3::zeros(); n]
        };
        if let Some(p) = &load.probe {
            for (a, b) in f.iter_mut().zip(self.probe_forces(p)) {
                *a += b;
            }
        }
        f
    }

    /// The support of [`Extension::SupportSprings`]: the attached nodes on the recorded support
    /// plane with tangential springs of total stiffness `stiffness_n_per_m` shared by the nodes'
    /// lumped areas of the attached face (`softcap_fem::SupportPlane`, bilateral normal
    /// penalty); `None` without a support plane.
    pub(super) fn support_springs(&self, stiffness_n_per_m: f64) -> Result<Option<SupportPlane>> {
        let Some(plane) = self.support_plane() else {
            return Ok(None);
        };
        let mesh = &self.setup().mesh;
        let support = SupportPlane::new(
            plane.0,
            plane.1,
            self.setup().attached_nodes.clone(),
            &mesh.vertices,
            &mesh.boundary_faces(),
            SupportTangential::Springs { stiffness_n_per_m },
        )
        .map_err(fem)?;
        if crate::profile::enabled() {
            static SPREAD: std::sync::Once = std::sync::Once::new();
            SPREAD.call_once(|| eprintln!("{}", area_share_spread(support.area_shares())));
        }
        Ok(Some(support))
    }

    fn run_static<M: ElasticModel>(
        &self,
        mut model: M,
        frames: &[SequenceFrame],
        mut before: impl FnMut(&mut M, f64) -> Result<()>,
        mut commit: impl FnMut(&mut M, &[Vector3<f64>]),
    ) -> Result<Vec<Vec<Vector3<f64>>>> {
        let setup = self.setup();
        let mut solver: StaticSolver = setup.solver(&model).map_err(Box::new)?;
        let settings = EquilibriumSettings {
            refactorization: self.settings().sequence_refactorization,
            ..self.settings().equilibrium.clone()
        };
        let mut x = setup.mesh.vertices.clone();
        let mut out = Vec::with_capacity(frames.len());
        let mut t_prev = frames.first().map(|f| f.time_s).unwrap_or(0.0);
        let _profile =
            crate::profile::sequence("force-driven", setup.mesh.tets.len(), frames.len());
        for (k, fr) in frames.iter().enumerate() {
            before(&mut model, (fr.time_s - t_prev).max(0.0))?;
            t_prev = fr.time_s;
            let f = self.nodal_load(&fr.load);
            let rep = setup.simulate(&mut solver, &mut model, &mut x, &f, &settings);
            crate::profile::solve(rep.iterations, setup.mesh.tets.len());
            if !rep.converged() {
                return Err(not_converged(
                    k,
                    format!("{:?} after {} iterations", rep.status, rep.iterations),
                ));
            }
            commit(&mut model, &x);
            out.push(setup.marker_positions(&x));
        }
        Ok(out)
    }

    /// The default model's sequence when it is the strain-space basis: every frame solved by
    /// `StrainSpaceModel::solve_continued`, loaded incrementally from the previous frame's
    /// equilibrium (from rest for a jump or when that does not converge), starting at rest.
    fn run_strain_space(
        &self,
        mut model: softcap_probing::StrainSpaceModel,
        frames: &[SequenceFrame],
    ) -> Result<Vec<Vec<Vector3<f64>>>> {
        let setup = self.setup();
        let mut solver: StaticSolver = setup.solver(&model).map_err(Box::new)?;
        let mut x = setup.mesh.vertices.clone();
        let mut previous = vec![Vector3::zeros(); x.len()];
        let mut out = Vec::with_capacity(frames.len());
        let _profile =
            crate::profile::sequence("strain-space", setup.mesh.tets.len(), frames.len());
        for (k, fr) in frames.iter().enumerate() {
            let f = self.nodal_load(&fr.load);
            let solve = model
                .solve_continued(
                    setup,
                    &mut solver,
                    &mut x,
                    &previous,
                    &f,
                    &self.settings().equilibrium,
                    &self.settings().strain_space,
                )
                .map_err(fem)?;
            crate::profile::solve(solve.iterations, setup.mesh.tets.len());
            if !solve.converged() {
                return Err(not_converged(
                    k,
                    format!(
                        "strain-space basis: {:?} after {} iterations",
                        solve.report.status, solve.iterations
                    ),
                ));
            }
            previous = f;
            out.push(setup.marker_positions(&x));
        }
        Ok(out)
    }

    /// The `AnisotropicModel` of an anisotropy extension over the default model's (λ, α).
    fn anisotropic_model(&self, ext: &Extension) -> Result<AnisotropicModel> {
        let base = self.model();
        if let Extension::FibreFamilies {
            fibres,
            ratio,
            poisson,
        } = *ext
        {
            let dirs = fibres.map(|a| Unit::try_new(a, 1e-12));
            let [Some(a0), Some(a1)] = dirs else {
                return Err(DiagnoseError::BadRecording {
                    what: "fibre families: zero fibre direction".into(),
                });
            };
            let mut params = Vec::with_capacity(base.params().len());
            let mut families = Vec::with_capacity(base.params().len());
            for p in base.params() {
                let (e, nu) = p.to_young_poisson().map_err(fem)?;
                let matrix =
                    LinearParams::from_young_poisson(e, poisson.unwrap_or(nu)).map_err(fem)?;
                params.push(TransverselyIsotropicParams::from_isotropic(&matrix));
                let k1_pa = 0.25 * ratio * e;
                families.push(vec![
                    FibreFamily {
                        direction: a0,
                        k1_pa,
                    },
                    FibreFamily {
                        direction: a1,
                        k1_pa,
                    },
                ]);
            }
            let nt = params.len();
            return AnisotropicModel::with_fibre_families(
                &self.setup().mesh,
                params,
                vec![a0; nt],
                &families,
            )
            .map_err(fem);
        }
        let (fibre, params) = match *ext {
            Extension::TransverselyIsotropic {
                fibre,
                ratio,
                nu_transverse,
                nu_fibre,
            } => (
                fibre,
                base.params()
                    .iter()
                    .map(|p| transverse_with_poisson(p, ratio, nu_transverse, nu_fibre))
                    .collect::<std::result::Result<Vec<_>, _>>()
                    .map_err(fem)?,
            ),
            Extension::Anisotropic { fibre, ratio } => (
                fibre,
                base.params()
                    .iter()
                    .map(|p| transverse_from_isotropic(p, ratio))
                    .collect::<std::result::Result<Vec<_>, _>>()
                    .map_err(fem)?,
            ),
            other => {
                return Err(DiagnoseError::BadRecording {
                    what: format!("{other:?} is not an anisotropy extension"),
                });
            }
        };
        let a = Unit::try_new(fibre, 1e-12).ok_or_else(|| DiagnoseError::BadRecording {
            what: "anisotropy: zero fibre direction".into(),
        })?;
        let nt = params.len();
        AnisotropicModel::new(&self.setup().mesh, params, vec![a; nt]).map_err(fem)
    }

    /// The `ElastoplasticModel` of a plasticity extension over the default model's (λ, α) — with
    /// the Poisson ratio replaced for [`Extension::PlasticPoisson`].
    fn plastic_model(&self, ext: &Extension) -> Result<ElastoplasticModel> {
        let (params, q) = self.plastic_params(ext)?;
        let nt = self.setup().mesh.tets.len();
        ElastoplasticModel::new(&self.setup().mesh, params, vec![q; nt]).map_err(fem)
    }

    /// The per-element elastic parameters and the J2 parameters of a plasticity extension: the
    /// default model's (λ, α), with the Poisson ratio replaced for
    /// [`Extension::PlasticPoisson`].
    pub(super) fn plastic_params(
        &self,
        ext: &Extension,
    ) -> Result<(Vec<LinearParams>, J2PlasticityParams)> {
        let base = self.model();
        let (yield_stress_pa, hardening_pa, params) = match *ext {
            Extension::Plastic {
                yield_stress_pa,
                hardening_pa,
            } => (yield_stress_pa, hardening_pa, base.params().to_vec()),
            Extension::PlasticPoisson {
                yield_stress_pa,
                hardening_pa,
                poisson,
            } => (
                yield_stress_pa,
                hardening_pa,
                base.params()
                    .iter()
                    .map(|p| {
                        let (e, _) = p.to_young_poisson()?;
                        LinearParams::from_young_poisson(e, poisson)
                    })
                    .collect::<std::result::Result<Vec<_>, _>>()
                    .map_err(fem)?,
            ),
            other => {
                return Err(DiagnoseError::BadRecording {
                    what: format!("{other:?} is not a plasticity extension"),
                });
            }
        };
        let q = J2PlasticityParams {
            yield_stress_pa,
            hardening_modulus_pa: hardening_pa,
        };
        Ok((params, q))
    }

    /// Marker positions of every frame of `frames` (time order) under the default model extended
    /// by `ext`, each frame warm-started from the previous one and history committed after it.
    pub fn simulate_sequence(
        &self,
        ext: &Extension,
        frames: &[SequenceFrame],
    ) -> Result<Vec<Vec<Vector3<f64>>>> {
        let base = self.model().clone();
        let mesh = &self.setup().mesh;
        match *ext {
            Extension::Elastic => match self.strain_space_model() {
                Some(model) => self.run_strain_space(model, frames),
                None => self.run_static(base, frames, |_, _| Ok(()), |_, _| {}),
            },
            Extension::Viscoelastic { g, tau_s } => {
                let prony = PronySeries::standard_linear_solid(g, tau_s).map_err(fem)?;
                // the Prony branch over the default model: the strain-space basis when it is
                // the default (its parameters follow the strain in every iteration)
                match self.strain_space_model() {
                    Some(m) => self.run_static(
                        ViscoelasticModel::new(m, prony).map_err(fem)?,
                        frames,
                        |m, dt| m.set_time_step(dt).map_err(fem),
                        |m, x| m.commit(x),
                    ),
                    None => self.run_static(
                        ViscoelasticModel::new(base, prony).map_err(fem)?,
                        frames,
                        |m, dt| m.set_time_step(dt).map_err(fem),
                        |m, x| m.commit(x),
                    ),
                }
            }
            Extension::Plastic { .. } | Extension::PlasticPoisson { .. } => {
                let ep = self.plastic_model(ext)?;
                self.run_static(
                    ep,
                    frames,
                    |_, _| Ok(()),
                    |m, x| {
                        m.commit(x);
                    },
                )
            }
            Extension::Anisotropic { .. }
            | Extension::TransverselyIsotropic { .. }
            | Extension::FibreFamilies { .. } => {
                let an = self.anisotropic_model(ext)?;
                self.run_static(an, frames, |_, _| Ok(()), |_, _| {})
            }
            Extension::ProbeFriction { .. } => Err(DiagnoseError::BadRecording {
                what: "probe friction is simulated only by the rigid-tip replay".into(),
            }),
            Extension::Dynamic {
                density_kg_m3,
                alpha_per_s,
                beta_s,
                lame_ratio_factor,
            } => self.run_dynamic(
                with_lame_ratio(&base, lame_ratio_factor)?,
                density_kg_m3,
                RayleighDamping {
                    alpha_per_s,
                    beta_s,
                },
                frames,
            ),
            Extension::SupportSprings { stiffness_n_per_m } => {
                let setup = self.setup();
                let Some(mut sup) = self.support_springs(stiffness_n_per_m)? else {
                    return Err(DiagnoseError::BadRecording {
                        what: "support-slip: the simulator has no support plane".into(),
                    });
                };
                let mut model = base;
                let mut solver = NodalSolver::new(&model, &[]).map_err(fem)?;
                let settings = EquilibriumSettings {
                    refactorization: self.settings().sequence_refactorization,
                    ..self.settings().equilibrium.clone()
                };
                let mut x = mesh.vertices.clone();
                let mut out = Vec::with_capacity(frames.len());
                let _profile =
                    crate::profile::sequence("support springs", mesh.tets.len(), frames.len());
                for (k, fr) in frames.iter().enumerate() {
                    let f = self.nodal_load(&fr.load);
                    let rep = solver.solve(&mut model, &mut x, &f, &mut [&mut sup], &settings);
                    crate::profile::solve(rep.iterations, mesh.tets.len());
                    if !rep.converged() {
                        return Err(not_converged(
                            k,
                            format!("{:?} after {} iterations", rep.status, rep.iterations),
                        ));
                    }
                    softcap_fem::NodalTerm::commit(&mut sup, &x);
                    out.push(setup.marker_positions(&x));
                }
                Ok(out)
            }
        }
    }
}

/// `model` with every element's Lamé ratio λ_L/μ scaled by `factor` at its Young's modulus E
/// ([`Extension::Dynamic`]'s `lame_ratio_factor`): λ_L/μ = 2ν/(1 − 2ν) becomes r' = `factor` ·
/// λ_L/μ, i.e. ν' = r' / (2 (1 + r')), which stays in (0, 1/2) for every positive factor and
/// ν ≥ 0 (a negative ν keeps its sign). E is kept so that under position control the
/// dynamics still sees the fitted E only through E/ρ, ρ fitted beside it; ν is the one
/// material parameter left, one for the whole body as wang2015 §6.2 fits p = (E, ν, α, β) of a
/// homogeneous material to the motion trajectories (eq. 9). A factor of exactly 1 returns the
/// model unchanged.
pub fn with_lame_ratio(
    model: &softcap_fem::CorotationalModel,
    factor: f64,
) -> Result<softcap_fem::CorotationalModel> {
    if factor == 1.0 {
        return Ok(model.clone());
    }
    if !(factor > 0.0 && factor.is_finite()) {
        return Err(DiagnoseError::BadRecording {
            what: format!("dynamic replay: Lamé ratio factor {factor} is not positive"),
        });
    }
    let params = model
        .params()
        .iter()
        .map(|p| {
            let (e, nu) = p.to_young_poisson()?;
            let r = factor * 2.0 * nu / (1.0 - 2.0 * nu);
            LinearParams::from_young_poisson(e, r / (2.0 * (1.0 + r)))
        })
        .collect::<std::result::Result<Vec<_>, _>>()
        .map_err(fem)?;
    let mut out = model.clone();
    out.set_params(&params).map_err(fem)?;
    Ok(out)
}

/// Implicit time steps of the dynamic replay ([`Extension::Dynamic`]) per frame interval. With
/// Newmark average acceleration the period of a mode sampled by n steps is lengthened by
/// ≈ (2π/n)²/12: 4 steps per frame keep it below 1 % for every mode that rings slower than
/// 6 frames per period — faster ones are not resolved by the frames themselves.
pub const DYNAMIC_STEPS_PER_FRAME: usize = 4;

/// The dynamic replays' factorization reuse (`softcap_fem::DynamicSolver::set_refactor_ratio`, a
/// modified Newton method): a step's later Newton updates reuse its first update's factor while
/// each cuts the residual at least 1/ratio-fold, and every step still converges to its
/// tolerance on the current residual (fit-dynamic's `refactor_ratio`, the same 0.3). The
/// rigid-tip replay reuses it in the steps without the tip only. On the suite's inertia-damping
/// session (5184-tet refined mesh, 440 steps) a replay's free steps took 1.69 Newton updates and
/// one factorization each, the replay about 20 % fewer CPU-s; the fitted ρ, α, β were the same
/// and the held-out error the same to 10⁻⁶ mm.
pub const REPLAY_REFACTOR_RATIO: f64 = 0.3;

impl FemProbeSimulator {
    /// The dynamic replay of [`Extension::Dynamic`]: wang2015 eq. 3, M ü + D u̇ + f_int(x) = f_ext
    /// with the lumped mass M of density `density_kg_m3` on the default model's mesh
    /// (`softcap_fem::lumped_masses`, m_a = Σ ρ V_e / 4) and Rayleigh damping D = α M + β K,
    /// integrated by `softcap_fem::DynamicSolver` (Newmark average acceleration, Newton per step)
    /// in [`DYNAMIC_STEPS_PER_FRAME`] steps per frame interval. The external force of every frame
    /// is its load as in the quasi-static default model (the measured probe force over its
    /// footprint, bickel2009 §4.1, plus any body force), interpolated linearly between frames.
    /// The first frame is solved quasi-statically and the motion starts there at rest.
    fn run_dynamic(
        &self,
        mut model: softcap_fem::CorotationalModel,
        density_kg_m3: f64,
        damping: RayleighDamping,
        frames: &[SequenceFrame],
    ) -> Result<Vec<Vec<Vector3<f64>>>> {
        let setup = self.setup();
        let Some(first) = frames.first() else {
            return Ok(Vec::new());
        };
        if !(density_kg_m3 > 0.0 && density_kg_m3.is_finite()) {
            return Err(DiagnoseError::BadRecording {
                what: format!("dynamic replay: density {density_kg_m3} kg/m^3 is not positive"),
            });
        }
        // frame 0: quasi-static equilibrium (the recording starts at rest)
        let mut f_prev = self.nodal_load(&first.load);
        let mut x = setup.mesh.vertices.clone();
        let mut solver: StaticSolver = setup.solver(&model).map_err(Box::new)?;
        let rep = setup.simulate(
            &mut solver,
            &mut model,
            &mut x,
            &f_prev,
            &self.settings().equilibrium,
        );
        if !rep.converged() {
            return Err(not_converged(
                0,
                format!("{:?} after {} iterations", rep.status, rep.iterations),
            ));
        }
        let masses = lumped_masses(&model, density_kg_m3);
        let mut dynamic =
            DynamicSolver::with_bc(&model, masses, &setup.dirichlet()).map_err(fem)?;
        dynamic.set_refactor_ratio(Some(REPLAY_REFACTOR_RATIO));
        let mut state = DynamicState::at_rest(x);
        state.time_s = first.time_s;
        let mut settings = replay_dynamics_settings(damping, &self.settings().equilibrium);
        let mut out = Vec::with_capacity(frames.len());
        out.push(setup.marker_positions(&state.positions_m));
        let mut t_prev = first.time_s;
        for (k, fr) in frames.iter().enumerate().skip(1) {
            let f = self.nodal_load(&fr.load);
            let dt = fr.time_s - t_prev;
            t_prev = fr.time_s;
            if dt > 0.0 {
                let n = DYNAMIC_STEPS_PER_FRAME;
                settings.time_step_s = dt / n as f64;
                for j in 1..=n {
                    let w = j as f64 / n as f64;
                    let fj: Vec<Vector3<f64>> = f_prev
                        .iter()
                        .zip(&f)
                        .map(|(a, b)| a + (b - a) * w)
                        .collect();
                    let rep = dynamic.step(&mut model, &mut state, &fj, None, None, &settings);
                    if rep.status != DynamicStepStatus::Converged {
                        return Err(not_converged(
                            k,
                            format!(
                                "dynamic replay: {:?} after {} iterations",
                                rep.status, rep.iterations
                            ),
                        ));
                    }
                }
            }
            f_prev = f;
            out.push(setup.marker_positions(&state.positions_m));
        }
        Ok(out)
    }
}

impl FemProbeSimulator {
    /// The rigid-tip dynamic replay of [`Extension::Dynamic`]: wang2015 eq. 3,
    /// M ü + D u̇ + f_int(x) = f_ext + f_c with the lumped mass M of density `density_kg_m3`
    /// (m_a = Σ ρ V_e / 4) and Rayleigh damping D = α M + β K, integrated by
    /// `softcap_fem::DynamicSolver` (Newmark average acceleration) in
    /// [`DYNAMIC_STEPS_PER_FRAME`] steps per frame interval, with the probe as the rigid tip at
    /// its measured poses (penalty contact f_c, bickel2009 §3.4) instead of the measured force.
    /// A frame whose tip penetrates the surface (at rest or where it is now) moves the tip from
    /// the previous frame's pose to its own over the frame's steps; any other frame is solved
    /// without the tip, so the contact is lost at once when the probe lets go and the body rings
    /// freely (a force-driven replay ramps the force down over the frame instead). The first
    /// frame is solved quasi-statically and the motion starts there at rest.
    fn run_rigid_dynamic(
        &self,
        model: softcap_fem::CorotationalModel,
        tip: &softcap_fem::TipShape,
        density_kg_m3: f64,
        damping: RayleighDamping,
        frames: &[SequenceFrame],
    ) -> Result<Vec<Vec<Vector3<f64>>>> {
        if !(density_kg_m3 > 0.0 && density_kg_m3.is_finite()) {
            return Err(DiagnoseError::BadRecording {
                what: format!("dynamic replay: density {density_kg_m3} kg/m^3 is not positive"),
            });
        }
        let Some(first) = frames.first() else {
            return Ok(Vec::new());
        };
        let replay = RigidReplay::new(self, tip, false);
        let body_load = |fr: &SequenceFrame| {
            self.nodal_load(&SimLoad {
                probe: None,
                body_force_n_m3: fr.load.body_force_n_m3,
            })
        };
        // frame 0: quasi-static equilibrium with the tip at its pose (the recording starts at rest)
        let mut poses = CarriedPoses::default();
        let mut stepper = replay.linear_tip(
            model,
            None,
            |_: &mut softcap_fem::CorotationalModel, _| Ok(()),
            |_: &mut softcap_fem::CorotationalModel, _: &[Vector3<f64>]| {},
        )?;
        let pose0 = poses.pose(first);
        let probe0 = pose0.map(|iso| replay.probe(iso)).transpose()?;
        let path0 = pose0
            .filter(|_| replay.touches(probe0.as_ref(), &stepper.state.x))
            .map(|p| (p, p));
        replay
            .step(&mut stepper, &body_load(first), path0, 0.0)?
            .map_err(|status| not_converged(0, status))?;
        let RigidState { mut model, x, .. } = stepper.state;
        let setup = self.setup();
        let masses = lumped_masses(&model, density_kg_m3);
        let mut dynamic =
            DynamicSolver::with_bc(&model, masses, &setup.dirichlet()).map_err(fem)?;
        let mut dyn_state = DynamicState::at_rest(x);
        dyn_state.time_s = first.time_s;
        // the tip's frictionless penalty contact with the active-set hysteresis of the static
        // replays (a node stays in the patch while it is still pressed against the tip's
        // surface): the plain re-queried springs let a node that Newton placed on the tip's
        // tangent plane drop out and back in, and the step ended on either side
        let mut contact = FrictionalContact::new(
            replay.problem_at(Isometry3::identity())?,
            FrictionParams {
                mu: 0.0,
                slip_distance_m: 1e-3,
            },
        )
        .map_err(fem)?;
        contact.active_set_hysteresis = true;
        let mut settings = replay_dynamics_settings(damping, &replay.settings);
        let mut out = Vec::with_capacity(frames.len());
        out.push(setup.marker_positions(&dyn_state.positions_m));
        let (mut t_prev, mut prev_pose) = (first.time_s, pose0);
        for (k, fr) in frames.iter().enumerate().skip(1) {
            let f = body_load(fr);
            let pose = poses.pose(fr);
            let probe = pose.map(|iso| replay.probe(iso)).transpose()?;
            let path = pose
                .filter(|_| replay.touches(probe.as_ref(), &dyn_state.positions_m))
                .map(|to| (prev_pose.unwrap_or(to), to));
            let dt = fr.time_s - t_prev;
            t_prev = fr.time_s;
            prev_pose = pose;
            if dt > 0.0 {
                let n = DYNAMIC_STEPS_PER_FRAME;
                settings.time_step_s = dt / n as f64;
                for j in 1..=n {
                    let t = j as f64 / n as f64;
                    let iso = path.map(|path| pose_along(path, t));
                    let loads = StepLoads {
                        external_forces_n: &f,
                        prescribed: None,
                        contact: None,
                        initial_guess: None,
                    };
                    // the factor is reused in the free steps only: with the tip's penalty
                    // springs a reused factor did not converge (suite inertia-damping, frame 1:
                    // 100 iterations)
                    dynamic.set_refactor_ratio(iso.is_none().then_some(REPLAY_REFACTOR_RATIO));
                    let rep = match iso {
                        Some(iso) => {
                            contact.move_probe(&mut dyn_state.positions_m, iso);
                            let rep = dynamic.step_with(
                                &mut model,
                                &mut dyn_state,
                                &loads,
                                &mut [&mut contact],
                                &settings,
                            );
                            NodalTerm::commit(&mut contact, &dyn_state.positions_m);
                            rep
                        }
                        None => {
                            contact.reset_history();
                            dynamic.step_with(
                                &mut model,
                                &mut dyn_state,
                                &loads,
                                &mut [],
                                &settings,
                            )
                        }
                    };
                    if rep.status != DynamicStepStatus::Converged {
                        return Err(not_converged(
                            k,
                            format!(
                                "rigid-tip dynamic replay: {:?} after {} iterations",
                                rep.status, rep.iterations
                            ),
                        ));
                    }
                }
            }
            out.push(setup.marker_positions(&dyn_state.positions_m));
        }
        Ok(out)
    }
}

/// The dynamic replays' step settings: Newmark average acceleration with warped stiffness and
/// Rayleigh `damping`, the tolerances of the static solves `eq` (at least 20 iterations). The
/// time step is the caller's to set per frame interval.
fn replay_dynamics_settings(
    damping: RayleighDamping,
    eq: &EquilibriumSettings,
) -> DynamicsSettings {
    DynamicsSettings {
        integrator: Integrator::NewmarkAverageAcceleration,
        time_step_s: 1.0,
        damping,
        stiffness: StiffnessKind::Warped,
        max_iterations: eq.max_iterations.max(20),
        displacement_tol_rel: eq.displacement_tol_rel,
        residual_tol_rel: eq.residual_tol_rel,
        contact_freeze_after: 8,
    }
}

/// Rigid-tip replay: the settings of one frame's contact solve.
pub(super) const RIGID_MAX_ITERATIONS: usize = 80;

/// The solver of a rigid-tip replay: penalty contact, or penalty contact with friction.
enum RigidSolver {
    Frictionless(StaticSolver),
    Frictional {
        solver: NodalSolver,
        contact: Box<FrictionalContact>,
    },
}

impl FemProbeSimulator {
    /// Rigid-tip replay of `frames` (time order) under `ext`: every frame whose probe pose
    /// (`load.probe`: measured `tip_m` and `axis`; the force is not used) makes the session's tip
    /// penetrate the surface is solved with the rigid probe as penalty contact (bickel2009 §3.4;
    /// a disk as a flat punch, `softcap_fem::Probe::with_punch_face`),
    /// moved there from the previous frame's pose in 1, then 4, then 16 sub-steps (state restored
    /// between attempts); other frames are solved without the probe. History (plastic strain,
    /// Prony state, stick anchors) is committed after every converged frame; the stick history
    /// is forgotten when the tip leaves the surface. [`Extension::Dynamic`] is replayed with
    /// inertia and damping instead (`run_rigid_dynamic`). `Ok(None)` without a recorded tip or for
    /// the support springs (a `NodalSolver` term, no rigid replay).
    pub fn simulate_sequence_rigid_tip(
        &self,
        ext: &Extension,
        frames: &[SequenceFrame],
    ) -> Result<Option<Vec<Vec<Vector3<f64>>>>> {
        self.simulate_sequences_rigid_tip(std::slice::from_ref(ext), frames)
            .pop()
            .unwrap_or(Ok(None))
    }

    /// [`Self::simulate_sequence_rigid_tip`] of every extension of `exts` over the same `frames`,
    /// in parallel (rayon; every replay has its own model state, solver and contact history, so
    /// each result is the one replay's bit for bit), results in the order of `exts`. The
    /// frictional replays share one copy of the fit mesh refined [`friction_refinement`] times,
    /// built once for all of them.
    pub fn simulate_sequences_rigid_tip(
        &self,
        exts: &[Extension],
        frames: &[SequenceFrame],
    ) -> Vec<Result<Option<Vec<Vec<Vector3<f64>>>>>> {
        use rayon::prelude::*;
        let Some(tip) = self.rigid_tip().cloned() else {
            return exts.iter().map(|_| Ok(None)).collect();
        };
        let frictional = |e: &Extension| matches!(e, Extension::ProbeFriction { .. });
        // the simulator itself (None), or its copy on the fit mesh refined `levels` times
        let fine = if exts.iter().any(frictional) {
            let tips: Vec<Vector3<f64>> = frames
                .iter()
                .filter_map(|f| f.load.probe.map(|p| p.tip_m))
                .collect();
            (0..friction_refinement(&self.setup().mesh, &tip, &tips))
                .try_fold(None, |f: Option<Self>, _| {
                    f.as_ref().unwrap_or(self).refined().map(Some)
                })
        } else {
            Ok(None)
        };
        let (fine, fine_error) = match fine {
            Ok(f) => (f, None),
            Err(e) => (None, Some(e)),
        };
        let failed = fine_error.as_ref().map(|e| e.to_string());
        let mut out: Vec<_> = exts
            .par_iter()
            .map(|ext| match &failed {
                Some(_) if frictional(ext) => Ok(None), // replaced by the error below
                _ => {
                    let _profile = crate::profile::sequence(
                        "rigid-tip replay",
                        fine.as_ref().unwrap_or(self).setup().mesh.tets.len(),
                        frames.len(),
                    );
                    self.replay_rigid(ext, &tip, frames, fine.as_ref())
                }
            })
            .collect();
        // Every frictional replay fails with the refinement's error (the first with the error
        // itself, as that replay alone would).
        if let (Some(e), Some(what)) = (fine_error, failed) {
            let mut first = Some(e);
            for (r, ext) in out.iter_mut().zip(exts) {
                if frictional(ext) {
                    *r = Err(first
                        .take()
                        .unwrap_or_else(|| DiagnoseError::BadRecording { what: what.clone() }));
                }
            }
        }
        out
    }

    /// One rigid-tip replay of [`Self::simulate_sequences_rigid_tip`]; `fine` is the simulator
    /// the frictional replay runs on (`None`: this one).
    fn replay_rigid(
        &self,
        ext: &Extension,
        tip: &softcap_fem::TipShape,
        frames: &[SequenceFrame],
        fine: Option<&Self>,
    ) -> Result<Option<Vec<Vec<Vector3<f64>>>>> {
        let base = self.model().clone();
        Ok(Some(match *ext {
            Extension::Elastic => {
                self.run_rigid(base, tip, None, frames, true, |_, _| Ok(()), |_, _| {})?
            }
            Extension::ProbeFriction { mu } => {
                let sim = fine.unwrap_or(self);
                let tips: Vec<Vector3<f64>> = frames
                    .iter()
                    .filter_map(|f| f.load.probe.map(|p| p.tip_m))
                    .collect();
                let friction = FrictionParams {
                    mu,
                    slip_distance_m: friction_slip_distance_m(
                        &sim.setup().mesh,
                        tip_radius_m(tip).unwrap_or(0.0),
                        &tips,
                        sim.settings().friction_slip_fraction,
                    ),
                };
                sim.run_rigid(
                    sim.model().clone(),
                    tip,
                    Some(friction),
                    frames,
                    true,
                    |_, _| Ok(()),
                    |_, _| {},
                )?
            }
            Extension::Viscoelastic { g, tau_s } => {
                let prony = PronySeries::standard_linear_solid(g, tau_s).map_err(fem)?;
                let ve = ViscoelasticModel::new(base, prony).map_err(fem)?;
                self.run_rigid(
                    ve,
                    tip,
                    None,
                    frames,
                    false,
                    |m, dt| m.set_time_step(dt).map_err(fem),
                    |m, x| m.commit(x),
                )?
            }
            Extension::Plastic { .. } | Extension::PlasticPoisson { .. } => {
                match self.quadratic_mesh() {
                    Some(q) => self.replay_plastic_quadratic(q, ext, tip, frames)?,
                    None => self.run_rigid(
                        self.plastic_model(ext)?,
                        tip,
                        None,
                        frames,
                        true,
                        |_, _| Ok(()),
                        |m, x| {
                            m.commit(x);
                        },
                    )?,
                }
            }
            Extension::Anisotropic { .. }
            | Extension::TransverselyIsotropic { .. }
            | Extension::FibreFamilies { .. } => {
                let an = self.anisotropic_model(ext)?;
                self.run_rigid(an, tip, None, frames, true, |_, _| Ok(()), |_, _| {})?
            }
            Extension::Dynamic {
                density_kg_m3,
                alpha_per_s,
                beta_s,
                lame_ratio_factor,
            } => self.run_rigid_dynamic(
                with_lame_ratio(&base, lame_ratio_factor)?,
                tip,
                density_kg_m3,
                RayleighDamping {
                    alpha_per_s,
                    beta_s,
                },
                frames,
            )?,
            Extension::SupportSprings { .. } => return Ok(None),
        }))
    }

    /// The replay loop of [`Self::simulate_sequence_rigid_tip`]; with `friction`, the tip carries
    /// regularized Coulomb friction (`FrictionalContact` with lagged normal forces and hysteresis
    /// of the active set, solved by `softcap_fem::solve_lagged`). With `rate_independent` (no
    /// time in the model: elastic, plastic, anisotropic, frictional), a frame off the surface
    /// after a frame off the surface under the same body force is the previous equilibrium and is
    /// not solved again (the hover and lifted frames between presses: a fifth of a session).
    #[allow(clippy::too_many_arguments)]
    fn run_rigid<M: ElasticModel + Clone>(
        &self,
        model: M,
        tip: &softcap_fem::TipShape,
        friction: Option<FrictionParams>,
        frames: &[SequenceFrame],
        rate_independent: bool,
        before: impl FnMut(&mut M, f64) -> Result<()>,
        commit: impl FnMut(&mut M, &[Vector3<f64>]),
    ) -> Result<Vec<Vec<Vector3<f64>>>> {
        let replay = RigidReplay::new(self, tip, friction.is_some());
        let mut stepper = replay.linear_tip(model, friction, before, commit)?;
        replay.frames(
            &mut stepper,
            frames,
            rate_independent,
            "rigid-tip replay",
            self.setup().mesh.tets.len(),
            friction.map(|f| f.mu),
        )
    }
}

/// The tip's pose a fraction `t` ∈ [0, 1] along a frame's `(from, to)` path: the position
/// interpolated linearly, the rotation along the shortest arc (slerp) — the sub-steps of a
/// rigid-tip replay.
pub(super) fn pose_along((from, to): (Isometry3<f64>, Isometry3<f64>), t: f64) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::from(from.translation.vector.lerp(&to.translation.vector, t)),
        from.rotation.slerp(&to.rotation, t),
    )
}

/// The tip frame at the measured `tip_m` and `axis`, carried from the last frame's rotation by
/// the smallest rotation that turns its axis onto the measured one (parallel transport).
/// `probe_pose` alone fixes the rotation about the axis arbitrarily: near an axis pointing
/// straight down, µrad jitter of the measured axis turns it by up to 180° between frames —
/// invisible to a sphere or a disk, but the stick anchors of friction live in the tip frame and
/// would be swung around the axis with it.
fn carried_pose(
    tip_m: &Vector3<f64>,
    axis: &Vector3<f64>,
    last_rotation: Option<UnitQuaternion<f64>>,
) -> Isometry3<f64> {
    let iso = probe_pose(tip_m, axis);
    match (last_rotation, axis.try_normalize(1e-12)) {
        (Some(r), Some(axis)) => {
            let turn = UnitQuaternion::rotation_between(&(r * Vector3::z()), &axis)
                .unwrap_or_else(UnitQuaternion::identity);
            Isometry3::from_parts(iso.translation, turn * r)
        }
        _ => iso,
    }
}

/// The tip frames of a replay's frames in order, each carried from the last one's rotation
/// ([`carried_pose`]).
#[derive(Default)]
struct CarriedPoses {
    last_rotation: Option<UnitQuaternion<f64>>,
}

impl CarriedPoses {
    /// The tip frame of `frame` (`None` without a probe, which leaves the carried rotation as is).
    fn pose(&mut self, frame: &SequenceFrame) -> Option<Isometry3<f64>> {
        let pose = frame
            .load
            .probe
            .map(|p| carried_pose(&p.tip_m, &p.axis, self.last_rotation));
        if let Some(p) = pose {
            self.last_rotation = Some(p.rotation);
        }
        pose
    }
}

/// What a rigid-tip replay holds fixed: the simulator, the session's tip, the rest shape, the
/// surface nodes the tip may touch (boundary nodes off the attached region) and the
/// equilibrium settings.
pub(super) struct RigidReplay<'a> {
    pub(super) sim: &'a FemProbeSimulator,
    tip: &'a softcap_fem::TipShape,
    rest: Vec<Vector3<f64>>,
    candidates: Vec<usize>,
    pub(super) settings: EquilibriumSettings,
    /// `settings` for the attempts of a frame that are not its last (fewer iterations for the
    /// frictional replay: `FemSimSettings::friction_attempt_max_iterations`).
    attempt_settings: EquilibriumSettings,
}

/// What a rigid-tip replay carries from frame to frame: the solver (with the friction history),
/// the material model (with its history) and the node positions.
struct RigidState<M> {
    solver: RigidSolver,
    model: M,
    x: Vec<Vector3<f64>>,
}

/// One rigid-tip replay's solver and the state it steps (model history, node positions,
/// contact history): "step the tip to pose P from state S". [`RigidReplay::frames`] is the one
/// frame loop (touch test, frames at rest not solved again, 1 / 4 / 16 sub-step attempts) for
/// the linear, frictional ([`LinearTip`]) and 10-node (`super::quadratic`) replays.
pub(super) trait TipStepper {
    /// The node positions now.
    fn positions(&self) -> &[Vector3<f64>];
    /// Keeps the state as the start of a frame's attempts.
    fn save(&mut self);
    /// Restores the state kept by [`Self::save`].
    fn restore(&mut self);
    /// One sub-step: equilibrium under the nodal body load `f` with the tip at `iso` (`None`: no
    /// contact) after `dt` s, the history committed when it converged; `Ok(Err(status))` when it
    /// did not. `last`: the frame's last attempt (a stepper may give the others fewer
    /// iterations).
    fn sub_step(
        &mut self,
        f: &[Vector3<f64>],
        iso: Option<Isometry3<f64>>,
        dt: f64,
        last: bool,
    ) -> Result<std::result::Result<(), String>>;
    /// The tip is off the surface this frame (no stick history carries over to the next touch).
    fn lifted(&mut self) {}
    /// The markers at the node positions now.
    fn markers(&self) -> Vec<Vector3<f64>>;
}

/// The [`TipStepper`] of the linear tets: the static solver or the frictional nodal solver
/// ([`RigidReplay::solve`]), `before` each sub-step (the time step of rate-dependent models)
/// and `commit` after it.
struct LinearTip<'r, 'a, M, B, C> {
    replay: &'r RigidReplay<'a>,
    state: RigidState<M>,
    saved: Option<(Vec<Vector3<f64>>, M, Option<FrictionalContact>)>,
    before: B,
    commit: C,
}

impl<M, B, C> TipStepper for LinearTip<'_, '_, M, B, C>
where
    M: ElasticModel + Clone,
    B: FnMut(&mut M, f64) -> Result<()>,
    C: FnMut(&mut M, &[Vector3<f64>]),
{
    fn positions(&self) -> &[Vector3<f64>] {
        &self.state.x
    }

    fn save(&mut self) {
        let contact = match &self.state.solver {
            RigidSolver::Frictional { contact, .. } => Some((**contact).clone()),
            RigidSolver::Frictionless(_) => None,
        };
        self.saved = Some((self.state.x.clone(), self.state.model.clone(), contact));
    }

    fn restore(&mut self) {
        let Some((x, model, contact)) = &self.saved else {
            return;
        };
        self.state.x.clone_from(x);
        self.state.model = model.clone();
        if let (RigidSolver::Frictional { contact: c, .. }, Some(saved)) =
            (&mut self.state.solver, contact)
        {
            (**c).clone_from(saved);
        }
    }

    fn sub_step(
        &mut self,
        f: &[Vector3<f64>],
        iso: Option<Isometry3<f64>>,
        dt: f64,
        last: bool,
    ) -> Result<std::result::Result<(), String>> {
        (self.before)(&mut self.state.model, dt)?;
        let settings = if last {
            &self.replay.settings
        } else {
            &self.replay.attempt_settings
        };
        let rep = self.replay.solve(&mut self.state, f, iso, settings)?;
        if !rep.converged() {
            return Ok(Err(format!(
                "rigid-tip replay: {:?} after {} iterations",
                rep.status, rep.iterations
            )));
        }
        (self.commit)(&mut self.state.model, &self.state.x);
        Ok(Ok(()))
    }

    fn lifted(&mut self) {
        if let RigidSolver::Frictional { contact, .. } = &mut self.state.solver {
            contact.reset_history();
        }
    }

    fn markers(&self) -> Vec<Vector3<f64>> {
        self.replay.sim.setup().marker_positions(&self.state.x)
    }
}

impl<'a> RigidReplay<'a> {
    pub(super) fn new(
        sim: &'a FemProbeSimulator,
        tip: &'a softcap_fem::TipShape,
        frictional: bool,
    ) -> Self {
        let setup = sim.setup();
        let candidates: Vec<usize> = setup.free_boundary_nodes();
        let max_iterations = if frictional {
            sim.settings().friction_max_iterations
        } else {
            RIGID_MAX_ITERATIONS
        };
        let settings = EquilibriumSettings {
            max_iterations: sim
                .settings()
                .equilibrium
                .max_iterations
                .max(max_iterations),
            refactorization: sim.settings().replay_refactorization,
            contact_freeze_after: if frictional {
                sim.settings().friction_contact_freeze_after
            } else {
                sim.settings().equilibrium.contact_freeze_after
            },
            ..sim.settings().equilibrium.clone()
        };
        let attempt_settings = if frictional {
            EquilibriumSettings {
                max_iterations: settings
                    .max_iterations
                    .min(sim.settings().friction_attempt_max_iterations),
                ..settings.clone()
            }
        } else {
            settings.clone()
        };
        Self {
            sim,
            tip,
            rest: setup.mesh.vertices.clone(),
            candidates,
            settings,
            attempt_settings,
        }
    }

    /// The tip at `iso`. A disk is replayed as a flat punch: penetrations leave through its
    /// face, never its rim (`Probe::with_punch_face`; the closest-feature projection pushed a
    /// node just inside the rim out sideways and the replay jumped to a second equilibrium
    /// mid-hold).
    fn probe(&self, iso: Isometry3<f64>) -> Result<Probe> {
        Probe::new(self.tip.clone(), iso)
            .map(Probe::with_punch_face)
            .map_err(fem)
    }

    /// The contact problem of the tip at `iso`.
    pub(super) fn problem_at(&self, iso: Isometry3<f64>) -> Result<ContactProblem> {
        Ok(ContactProblem {
            probe: self.probe(iso)?,
            candidate_nodes: self.candidates.clone(),
            settings: self.sim.settings().rigid_tip_contact.clone(),
        })
    }

    /// The [`LinearTip`] of `model` at rest (with `friction`: the frictional solver).
    fn linear_tip<M: ElasticModel + Clone, B, C>(
        &self,
        model: M,
        friction: Option<FrictionParams>,
        before: B,
        commit: C,
    ) -> Result<LinearTip<'_, 'a, M, B, C>> {
        Ok(LinearTip {
            state: RigidState {
                solver: self.solver(&model, friction)?,
                model,
                x: self.rest.clone(),
            },
            replay: self,
            saved: None,
            before,
            commit,
        })
    }

    /// The static solver, or with `friction` the nodal solver and its frictional contact.
    fn solver<M: ElasticModel>(
        &self,
        model: &M,
        friction: Option<FrictionParams>,
    ) -> Result<RigidSolver> {
        let setup = self.sim.setup();
        let Some(params) = friction else {
            return Ok(RigidSolver::Frictionless(
                setup.solver(model).map_err(Box::new)?,
            ));
        };
        let mut contact = FrictionalContact::new(self.problem_at(Isometry3::identity())?, params)
            .and_then(|c| {
                c.with_discretisation(
                    self.sim.settings().friction_contact,
                    &setup.mesh.boundary_faces(),
                    &self.rest,
                )
            })
            .map_err(fem)?;
        contact.active_set_hysteresis = true;
        contact.normal_force_lag = NormalForceLag::Solve;
        Ok(RigidSolver::Frictional {
            solver: NodalSolver::new(model, &setup.dirichlet().dofs()).map_err(fem)?,
            contact: Box::new(contact),
        })
    }

    /// The tip penetrates a candidate node at rest or where it is now.
    fn touches(&self, probe: Option<&Probe>, x: &[Vector3<f64>]) -> bool {
        probe.is_some_and(|p| {
            self.candidates
                .iter()
                .any(|&i| p.penetration(&self.rest[i]).is_some() || p.penetration(&x[i]).is_some())
        })
    }

    /// The frames of a replay (time order) stepped by `stepper`: a frame whose pose (carried,
    /// [`CarriedPoses`]) makes the tip penetrate a candidate node at rest or where it is now
    /// moves the tip there from the previous frame's pose ([`Self::step`]); any other frame is
    /// solved without the tip. With `rate_independent`, a frame off the surface after a frame off
    /// the surface under the same body force is the previous equilibrium and is not solved
    /// again. The markers of every frame; `kind`, `tets` and `mu` label the profile lines.
    pub(super) fn frames<S: TipStepper>(
        &self,
        stepper: &mut S,
        frames: &[SequenceFrame],
        rate_independent: bool,
        kind: &'static str,
        tets: usize,
        mu: Option<f64>,
    ) -> Result<Vec<Vec<Vector3<f64>>>> {
        let _profile = crate::profile::sequence(kind, tets, frames.len());
        let mut out = Vec::with_capacity(frames.len());
        let mut t_prev = frames.first().map(|f| f.time_s).unwrap_or(0.0);
        let mut prev_pose: Option<Isometry3<f64>> = None;
        let mut poses = CarriedPoses::default();
        // the body force of the previous frame when it was solved off the surface
        let mut previous_at_rest: Option<Vector3<f64>> = None;
        // (frame, thread CPU-s of its step) for the profile
        let mut frame_cpu: Vec<(usize, f64)> = Vec::new();
        for (k, fr) in frames.iter().enumerate() {
            let f = self.sim.nodal_load(&SimLoad {
                probe: None,
                body_force_n_m3: fr.load.body_force_n_m3,
            });
            let pose = poses.pose(fr);
            let probe = pose.map(|iso| self.probe(iso)).transpose()?;
            let touches = self.touches(probe.as_ref(), stepper.positions());
            let dt = (fr.time_s - t_prev).max(0.0);
            t_prev = fr.time_s;
            if !touches {
                stepper.lifted();
            }
            let path = match (touches, pose) {
                (true, Some(to)) => Some((prev_pose.unwrap_or(to), to)),
                _ => None,
            };
            let at_rest = path.is_none() && rate_independent;
            let unchanged = at_rest
                && previous_at_rest.as_ref() == Some(&fr.load.body_force_n_m3)
                && !out.is_empty();
            if !unchanged {
                let t0 = crate::profile::thread_cpu();
                let stepped = self.step(stepper, &f, path, dt)?;
                frame_cpu.push((k, crate::profile::thread_cpu() - t0));
                if let Err(status) = stepped {
                    crate::profile::replay_frames(
                        mu,
                        tets,
                        &frame_cpu,
                        frames.len(),
                        Some(&status),
                    );
                    return Err(not_converged(k, status));
                }
            }
            previous_at_rest = at_rest.then_some(fr.load.body_force_n_m3);
            prev_pose = pose;
            out.push(stepper.markers());
        }
        crate::profile::replay_frames(mu, tets, &frame_cpu, frames.len(), None);
        Ok(out)
    }

    /// One frame: the tip moved along `path` (from, to; `None`: off the surface) over `dt` in 1,
    /// else 4, else 16 sub-steps, each solved to equilibrium and committed; a failed attempt
    /// restarts from the frame's start. `Ok(Err(status))` when no attempt converged.
    fn step<S: TipStepper>(
        &self,
        stepper: &mut S,
        f: &[Vector3<f64>],
        path: Option<(Isometry3<f64>, Isometry3<f64>)>,
        dt: f64,
    ) -> Result<std::result::Result<(), String>> {
        stepper.save();
        let mut status = String::new();
        const ATTEMPTS: [usize; 3] = [1, 4, 16];
        'attempts: for substeps in ATTEMPTS {
            let last = substeps == ATTEMPTS[ATTEMPTS.len() - 1];
            stepper.restore();
            for s in 1..=substeps {
                let t = s as f64 / substeps as f64;
                let iso = path.map(|path| pose_along(path, t));
                let t0 = crate::profile::thread_cpu();
                if let Err(why) = stepper.sub_step(f, iso, dt / substeps as f64, last)? {
                    status = format!("{why} ({substeps} sub-steps)");
                    crate::profile::failed_attempt(&status, crate::profile::thread_cpu() - t0);
                    continue 'attempts;
                }
            }
            return Ok(Ok(()));
        }
        Ok(Err(status))
    }

    /// Equilibrium with the tip at `iso` (`None`: no contact); the friction history is
    /// committed when it converged in contact.
    fn solve<M: ElasticModel>(
        &self,
        state: &mut RigidState<M>,
        f: &[Vector3<f64>],
        iso: Option<Isometry3<f64>>,
        settings: &EquilibriumSettings,
    ) -> Result<EquilibriumReport> {
        let RigidState { solver, model, x } = state;
        self.sim.setup().dirichlet().apply(x);
        let rep = match solver {
            RigidSolver::Frictionless(solver) => {
                let problem = iso.map(|iso| self.problem_at(iso)).transpose()?;
                solver.solve(model, x, f, problem.as_ref(), settings)
            }
            RigidSolver::Frictional { solver, contact } => {
                if let Some(iso) = iso {
                    contact.move_probe(x, iso);
                }
                let lagged = solve_lagged(
                    solver,
                    model,
                    x,
                    f,
                    iso.is_some().then_some(&mut **contact),
                    &mut [],
                    settings,
                    &LaggedIterations::default(),
                );
                let rep = lagged.equilibrium;
                if rep.converged() && iso.is_some() {
                    NodalTerm::commit(&mut **contact, x);
                }
                rep
            }
        };
        crate::profile::solve(rep.iterations, self.sim.setup().mesh.tets.len());
        Ok(rep)
    }
}

/// Transversely isotropic parameters with the isotropic (E, ν) of `p` across the fibre and
/// E_a = `ratio` · E along it (thesis eq. 8.5 via `TransverselyIsotropicParams::from_engineering`):
/// ν_t = ν, fibre Poisson ratio ν_a = ν (capped so the compliance stays positive definite),
/// fibre shear G_a = E / (2(1 + ν)) (the isotropic shear modulus).
pub fn transverse_from_isotropic(
    p: &LinearParams,
    ratio: f64,
) -> std::result::Result<TransverselyIsotropicParams, softcap_fem::FemError> {
    let (e, nu) = p.to_young_poisson()?;
    let nu_t = nu.min(0.45);
    // PD of the compliance needs 1 − ν_t − 2 ν_a² E_t/E_a > 0.
    let nu_a_max = ((1.0 - nu_t) * ratio / 2.0).sqrt() * 0.95;
    let nu_a = nu_t.min(nu_a_max);
    TransverselyIsotropicParams::from_engineering(e, ratio * e, nu_t, nu_a, e / (2.0 * (1.0 + nu)))
}

/// Transversely isotropic parameters with the isotropic Young's modulus E of `p` across the fibre,
/// E_a = `ratio` · E along it, in-plane Poisson ratio ν_t = `nu_transverse`, fibre Poisson ratio
/// ν_a = `nu_fibre` (capped so the compliance stays positive definite, 1 − ν_t − 2ν_a² E_t/E_a > 0)
/// and fibre shear modulus G_a = E / (2(1 + ν_t)) (thesis eq. 8.5 via
/// `TransverselyIsotropicParams::from_engineering`).
pub fn transverse_with_poisson(
    p: &LinearParams,
    ratio: f64,
    nu_transverse: f64,
    nu_fibre: f64,
) -> std::result::Result<TransverselyIsotropicParams, softcap_fem::FemError> {
    let (e, _) = p.to_young_poisson()?;
    let nu_t = nu_transverse.clamp(0.0, 0.49);
    let nu_a_max = ((1.0 - nu_t) * ratio / 2.0).sqrt() * 0.95;
    let nu_a = nu_fibre.clamp(0.0, nu_a_max);
    TransverselyIsotropicParams::from_engineering(
        e,
        ratio * e,
        nu_t,
        nu_a,
        e / (2.0 * (1.0 + nu_t)),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The Lamé ratio factor scales λ_L/μ of every element and keeps its E: the suite's tissue
    /// fit (E 8.0 kPa, ν 0.4235) at factor 2 has ν 0.4586; factor 1 is the model itself.
    #[test]
    fn lame_ratio_factor_scales_lambda_over_mu_at_the_fitted_young_modulus() {
        let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [0.02, 0.02, 0.01], [2, 2, 1]);
        let p = LinearParams::from_young_poisson(8004.4, 0.423512).unwrap();
        let model = softcap_fem::CorotationalModel::homogeneous(&mesh, p).unwrap();
        assert_eq!(
            with_lame_ratio(&model, 1.0).unwrap().params(),
            model.params()
        );
        let (l0, m0) = p.lame();
        for factor in [0.5, 2.0, 4.0] {
            let scaled = with_lame_ratio(&model, factor).unwrap();
            for q in scaled.params() {
                let (l, m) = q.lame();
                assert!(
                    ((l / m) / (l0 / m0) / factor - 1.0).abs() < 1e-12,
                    "{factor}"
                );
                let (e, _) = q.to_young_poisson().unwrap();
                assert!((e / 8004.4 - 1.0).abs() < 1e-12, "{factor}: E {e}");
            }
        }
        let (_, nu) = with_lame_ratio(&model, 2.0).unwrap().params()[0]
            .to_young_poisson()
            .unwrap();
        assert!((nu - 0.4586).abs() < 5e-5, "{nu}");
        assert!(with_lame_ratio(&model, 0.0).is_err());
    }
}
