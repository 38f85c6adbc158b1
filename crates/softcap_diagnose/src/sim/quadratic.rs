//! Rigid-tip J2 replays on the 10-node tets of the fit mesh ([`FemProbeSimulator::quadratic`]):
//! the truth's element order for a permanent set (docs/notes/2026-12-01-plasticity-element-floor.md:
//! linear tets lock under the isochoric plastic flow at ν ≈ 0.45, refined or not).
//!
//! The replay is [`FemProbeSimulator::simulate_sequence_rigid_tip`]'s (the same frames, poses,
//! flat-punch tip, touch test, 1 / 4 / 16 sub-steps, commit after every converged sub-step, rest
//! frames not solved again) with `softcap_fem::QuadraticElastoplasticModel` (small-strain
//! kinematics ε = sym ∇u, the 4-point rule) and `QuadraticRigidTipSolver` in place of the linear
//! model and its solver. The 10-node tets' nodes are the fit mesh refined 1 → 8's vertices
//! (`softcap_fem::quadratic_tets`), so that copy's attached nodes, free surface nodes (the tip's
//! candidate nodes: corners and edge midpoints) and lumped body forces are the replay's; the markers
//! are read by the 10-node shape functions at their barycentric coordinates in the fit mesh's tets.

use super::contract::{Extension, SequenceFrame};
use super::extend::pose_along;
use super::fem::FemProbeSimulator;
use crate::{DiagnoseError, Result};
use nalgebra::{Isometry3, Vector3};
use softcap_fem::{
    ContactProblem, EquilibriumSettings, Probe, QuadraticElastoplasticModel,
    QuadraticRigidTipSolver, QuadraticTetMesh, TipShape, shape_functions,
};
use softcap_probing::probe_pose;

fn fem(e: softcap_fem::FemError) -> DiagnoseError {
    DiagnoseError::Fem(Box::new(e))
}

/// The 10-node tets of a fit mesh and the fit mesh refined 1 → 8 (the same nodes) whose attached
/// nodes, candidate surface nodes and lumped body forces the quadratic replay uses.
pub(crate) struct QuadraticMesh {
    tets: QuadraticTetMesh,
    nodes_sim: Box<FemProbeSimulator>,
}

impl QuadraticMesh {
    /// The 10-node tets of `sim`'s mesh; an error when their nodes are not the refined mesh's.
    pub(crate) fn of(sim: &FemProbeSimulator) -> Result<Self> {
        let nodes_sim = sim.refined()?;
        let tets = softcap_fem::quadratic_tets(&sim.setup().mesh);
        if tets.nodes != nodes_sim.setup().mesh.vertices {
            return Err(DiagnoseError::BadRecording {
                what: "quadratic tets: nodes differ from the refined mesh's vertices".into(),
            });
        }
        Ok(Self {
            tets,
            nodes_sim: Box::new(nodes_sim),
        })
    }
}

impl FemProbeSimulator {
    /// The rigid-tip replay of a plasticity extension ([`Extension::Plastic`],
    /// [`Extension::PlasticPoisson`]) on the 10-node tets `q` (module docs): the elastic
    /// parameters per element as [`FemProbeSimulator::simulate_sequence_rigid_tip`]'s.
    pub(crate) fn replay_plastic_quadratic(
        &self,
        q: &QuadraticMesh,
        ext: &Extension,
        tip: &TipShape,
        frames: &[SequenceFrame],
    ) -> Result<Vec<Vec<Vector3<f64>>>> {
        let (params, plastic) = self.plastic_params(ext)?;
        let n_el = q.tets.elements.len();
        let mut model = QuadraticElastoplasticModel::new(
            &q.tets.nodes,
            &q.tets.elements,
            params,
            vec![plastic; n_el],
            false,
        )
        .map_err(fem)?;
        let fine = q.nodes_sim.as_ref();
        let dirichlet = fine.setup().dirichlet();
        let mut solver = QuadraticRigidTipSolver::new(&model, &dirichlet.dofs()).map_err(fem)?;
        let candidates = fine.setup().free_boundary_nodes();
        let settings = EquilibriumSettings {
            max_iterations: self
                .settings()
                .equilibrium
                .max_iterations
                .max(super::extend::RIGID_MAX_ITERATIONS),
            ..self.settings().equilibrium.clone()
        };
        let contact = &self.settings().rigid_tip_contact;
        let problem = |iso: Isometry3<f64>| -> Result<ContactProblem> {
            Ok(ContactProblem {
                probe: Probe::new(tip.clone(), iso).map_err(fem)?.with_punch_face(),
                candidate_nodes: candidates.clone(),
                settings: contact.clone(),
            })
        };
        let rest = q.tets.nodes.clone();
        let markers = |x: &[Vector3<f64>]| -> Vec<Vector3<f64>> {
            self.setup()
                .markers
                .iter()
                .map(|m| {
                    let n = shape_functions(m.weights);
                    let el = &q.tets.elements[m.tet];
                    (0..10).map(|a| x[el[a]] * n[a]).sum()
                })
                .collect()
        };
        let _profile = crate::profile::sequence("quadratic rigid-tip replay", n_el, frames.len());
        let mut x = rest.clone();
        let mut out = Vec::with_capacity(frames.len());
        let mut prev_pose: Option<Isometry3<f64>> = None;
        let mut previous_at_rest: Option<Vector3<f64>> = None;
        for (k, fr) in frames.iter().enumerate() {
            let f = fine.body_forces(&fr.load.body_force_n_m3);
            let pose = fr.load.probe.map(|p| probe_pose(&p.tip_m, &p.axis));
            let touches = match pose {
                Some(iso) => {
                    let p = problem(iso)?;
                    candidates.iter().any(|&i| {
                        p.probe.penetration(&rest[i]).is_some()
                            || p.probe.penetration(&x[i]).is_some()
                    })
                }
                None => false,
            };
            let path = match (touches, pose) {
                (true, Some(to)) => Some((prev_pose.unwrap_or(to), to)),
                _ => None,
            };
            let at_rest = path.is_none();
            let unchanged = at_rest
                && previous_at_rest.as_ref() == Some(&fr.load.body_force_n_m3)
                && !out.is_empty();
            if !unchanged {
                let (start_x, start_model) = (x.clone(), model.clone());
                let mut status = None;
                'attempts: for substeps in [1usize, 4, 16] {
                    x.clone_from(&start_x);
                    model = start_model.clone();
                    for s in 1..=substeps {
                        let t = s as f64 / substeps as f64;
                        let pr = path.map(|path| problem(pose_along(path, t))).transpose()?;
                        dirichlet.apply(&mut x);
                        let rep = solver.solve(&model, &mut x, &f, pr.as_ref(), &settings);
                        crate::profile::solve(rep.iterations, n_el);
                        if !rep.converged {
                            status = Some(format!(
                                "quadratic rigid-tip replay: {} iterations, residual {:.3e} N ({substeps} sub-steps)",
                                rep.iterations, rep.residual_norm_n
                            ));
                            continue 'attempts;
                        }
                        model.commit(&x);
                    }
                    status = None;
                    break;
                }
                if let Some(reason) = status {
                    return Err(DiagnoseError::Simulation {
                        frame: k as u64,
                        reason,
                    });
                }
            }
            previous_at_rest = at_rest.then_some(fr.load.body_force_n_m3);
            prev_pose = pose;
            out.push(markers(&x));
        }
        Ok(out)
    }
}
