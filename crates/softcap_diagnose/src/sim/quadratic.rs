//! Rigid-tip J2 replays on the 10-node tets of the fit mesh ([`FemProbeSimulator::quadratic`]):
//! the truth's element order for a permanent set (docs/notes/2026-12-01-plasticity-element-floor.md:
//! linear tets lock under the isochoric plastic flow at ν ≈ 0.45, refined or not).
//!
//! The replay is [`FemProbeSimulator::simulate_sequence_rigid_tip`]'s frame loop
//! (`RigidReplay::frames`: the same frames, carried poses, flat-punch tip, touch test, 1 / 4 / 16
//! sub-steps, commit after every converged sub-step, rest frames not solved again) stepping
//! [`QuadraticTip`] with `softcap_fem::QuadraticElastoplasticModel` (small-strain
//! kinematics ε = sym ∇u, the 4-point rule) and `QuadraticRigidTipSolver` in place of the linear
//! model and its solver. The 10-node tets' nodes are the fit mesh refined 1 → 8's vertices
//! (`softcap_fem::quadratic_tets`), so that copy's attached nodes, free surface nodes (the tip's
//! candidate nodes: corners and edge midpoints) and lumped body forces are the replay's; the markers
//! are read by the 10-node shape functions at their barycentric coordinates in the fit mesh's tets.

use super::contract::{Extension, SequenceFrame};
use super::extend::{RigidReplay, TipStepper};
use super::fem::FemProbeSimulator;
use crate::{DiagnoseError, Result};
use nalgebra::{Isometry3, Vector3};
use softcap_fem::{
    DirichletBc, EquilibriumSettings, QuadraticElastoplasticModel, QuadraticRigidTipSolver,
    QuadraticTetMesh, TipShape, shape_functions,
};

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

/// The 10-node replay's displacement tolerance (`EquilibriumSettings::displacement_tol_rel`, of
/// the model's size; the linear replays' 1e-8). Third-party `plasticity` (two 10-node replays of
/// 223 frames on 1,666 tets): 1446 / 1462 → 1336 / 1383 Newton iterations, 131 / 126 → 120 / 119
/// thread CPU-s, held-out 0.1248 → 0.1244 mm.
const QUADRATIC_DISPLACEMENT_TOL_REL: f64 = 1e-6;

/// The [`TipStepper`] of the 10-node tets: `QuadraticRigidTipSolver` on the model's state, the
/// contact problem those of the refined copy's [`RigidReplay`], its settings with
/// [`QUADRATIC_DISPLACEMENT_TOL_REL`].
struct QuadraticTip<'r, 'a> {
    replay: &'r RigidReplay<'a>,
    q: &'r QuadraticMesh,
    /// The fit mesh's simulator (its markers' tets and weights).
    sim: &'r FemProbeSimulator,
    dirichlet: DirichletBc,
    settings: EquilibriumSettings,
    model: QuadraticElastoplasticModel,
    solver: QuadraticRigidTipSolver,
    x: Vec<Vector3<f64>>,
    saved: Option<(Vec<Vector3<f64>>, QuadraticElastoplasticModel)>,
}

impl TipStepper for QuadraticTip<'_, '_> {
    fn positions(&self) -> &[Vector3<f64>] {
        &self.x
    }

    fn save(&mut self) {
        self.saved = Some((self.x.clone(), self.model.clone()));
    }

    fn restore(&mut self) {
        if let Some((x, model)) = &self.saved {
            self.x.clone_from(x);
            self.model = model.clone();
        }
    }

    fn sub_step(
        &mut self,
        f: &[Vector3<f64>],
        iso: Option<Isometry3<f64>>,
        _dt: f64,
        _last: bool,
    ) -> Result<std::result::Result<(), String>> {
        let problem = iso.map(|iso| self.replay.problem_at(iso)).transpose()?;
        self.dirichlet.apply(&mut self.x);
        let rep = self.solver.solve(
            &self.model,
            &mut self.x,
            f,
            problem.as_ref(),
            &self.settings,
        );
        crate::profile::solve(rep.iterations, self.q.tets.elements.len());
        if !rep.converged {
            return Ok(Err(format!(
                "quadratic rigid-tip replay: {} iterations, residual {:.3e} N",
                rep.iterations, rep.residual_norm_n
            )));
        }
        self.model.commit(&self.x);
        Ok(Ok(()))
    }

    fn markers(&self) -> Vec<Vector3<f64>> {
        self.sim
            .setup()
            .markers
            .iter()
            .map(|m| {
                let n = shape_functions(m.weights);
                let el = &self.q.tets.elements[m.tet];
                (0..10).map(|a| self.x[el[a]] * n[a]).sum()
            })
            .collect()
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
        let model = QuadraticElastoplasticModel::new(
            &q.tets.nodes,
            &q.tets.elements,
            params,
            vec![plastic; n_el],
            false,
        )
        .map_err(fem)?;
        let fine = q.nodes_sim.as_ref();
        let dirichlet = fine.setup().dirichlet();
        let solver = QuadraticRigidTipSolver::new(&model, &dirichlet.dofs()).map_err(fem)?;
        // the refined copy's replay: its nodes are the 10-node tets' (`QuadraticMesh::of`)
        let replay = RigidReplay::new(fine, tip, false);
        let mut stepper = QuadraticTip {
            replay: &replay,
            q,
            sim: self,
            dirichlet,
            settings: EquilibriumSettings {
                displacement_tol_rel: QUADRATIC_DISPLACEMENT_TOL_REL,
                ..replay.settings.clone()
            },
            model,
            solver,
            x: q.tets.nodes.clone(),
            saved: None,
        };
        replay.frames(
            &mut stepper,
            frames,
            true,
            "quadratic rigid-tip replay",
            n_el,
            None,
        )
    }
}
