//! The forward model of the spacetime objective: every free-motion segment simulated from the
//! tracked state and velocity at its start with wang2015 eq. 3,
//!
//! M ẍ + (αM + βK) ẋ + R K (Rᵀx − X) = M g,
//!
//! (corotational tets over the rest shape X, lumped masses, Rayleigh damping, the support
//! prescribed to its tracked positions; `softcap_fem::DynamicSolver`, Newmark average
//! acceleration with `substeps` steps per frame interval), and the residuals x_t(p) − x̂_t of
//! eq. 9 over the segments' later frames and the unsupported nodes.

use nalgebra::Vector3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use softcap_fem::{
    CorotationalModel, DirichletBc, DynamicSolver, DynamicState, DynamicStepStatus,
    DynamicsSettings, Integrator, LinearParams, RayleighDamping, StiffnessKind,
};
use softcap_mesh::TetMesh;

use super::sequence::{Segment, TrackedSequence, smoothed_state};
use crate::error::Result;

/// Material, damping (and the rest shape, passed separately) of one forward run.
#[derive(Clone, Debug, PartialEq)]
pub struct DynamicParams {
    /// Young's modulus per tet, Pa.
    pub young_pa: Vec<f64>,
    /// Poisson ratio (shared).
    pub poisson: f64,
    /// Rayleigh damping.
    pub damping: RayleighDamping,
}

/// Settings of the segment simulations.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ForwardSettings {
    /// Time steps per frame interval.
    pub substeps: usize,
    /// Newton iterations per step at most.
    pub newton_iterations: usize,
    /// Half width (frames) of the polynomial fit that gives a segment's initial state.
    pub velocity_half_window: usize,
    /// Degree of that polynomial.
    pub velocity_degree: usize,
}

impl Default for ForwardSettings {
    fn default() -> Self {
        Self {
            substeps: 4,
            newton_iterations: 12,
            velocity_half_window: 2,
            velocity_degree: 4,
        }
    }
}

/// The simulated positions of one segment's frames `start + 1 ..= end`.
#[derive(Clone, Debug, PartialEq)]
pub struct SegmentRun {
    /// The segment.
    pub segment: Segment,
    /// Positions per frame after the start, m.
    pub positions_m: Vec<Vec<Vector3<f64>>>,
    /// Steps whose Newton iterations hit their limit.
    pub max_iteration_steps: usize,
    /// Set when a step failed (the run stopped there).
    pub failure: Option<String>,
}

/// Segments, initial states, masses and loads of a sequence on a mesh: evaluates the forward
/// model for any (p, X).
#[derive(Clone, Debug)]
pub struct Forward {
    mesh: TetMesh,
    seq: TrackedSequence,
    segments: Vec<Segment>,
    starts: Vec<(Vec<Vector3<f64>>, Vec<Vector3<f64>>)>,
    masses_kg: Vec<f64>,
    gravity_n: Vec<Vector3<f64>>,
    free_nodes: Vec<usize>,
    observed: Vec<bool>,
    settings: ForwardSettings,
}

impl Forward {
    /// `mesh` (frame-0 shape; topology and masses), the sequence on its nodes, the segments,
    /// and which nodes are observations (residuals are taken on those that are unsupported).
    pub fn new(
        mesh: &TetMesh,
        seq: &TrackedSequence,
        segments: Vec<Segment>,
        observed: Vec<bool>,
        settings: &ForwardSettings,
    ) -> Result<Self> {
        let frame0 = CorotationalModel::homogeneous(mesh, LinearParams::from_young_poisson(1e5, 0.3)?)?;
        let masses_kg = softcap_fem::lumped_masses(&frame0, seq.density_kg_m3);
        let gravity_n = softcap_fem::gravity_forces(&masses_kg, seq.gravity_m_s2);
        let starts = segments
            .iter()
            .map(|s| smoothed_state(seq, s.start, settings.velocity_half_window, settings.velocity_degree))
            .collect();
        let mut supported = vec![false; mesh.vertices.len()];
        for &i in &seq.support_nodes {
            supported[i] = true;
        }
        let free_nodes = (0..mesh.vertices.len())
            .filter(|&i| !supported[i] && observed[i])
            .collect();
        Ok(Self {
            mesh: mesh.clone(),
            seq: seq.clone(),
            segments,
            starts,
            masses_kg,
            gravity_n,
            free_nodes,
            observed,
            settings: settings.clone(),
        })
    }

    /// The segments.
    pub fn segments(&self) -> &[Segment] {
        &self.segments
    }

    /// The sequence.
    pub fn sequence(&self) -> &TrackedSequence {
        &self.seq
    }

    /// The mesh (frame-0 shape).
    pub fn mesh(&self) -> &TetMesh {
        &self.mesh
    }

    /// Lumped masses, kg.
    pub fn masses_kg(&self) -> &[f64] {
        &self.masses_kg
    }

    /// Gravity loads M g, N.
    pub fn gravity_n(&self) -> &[Vector3<f64>] {
        &self.gravity_n
    }

    /// Which nodes are observations.
    pub fn observed(&self) -> &[bool] {
        &self.observed
    }

    /// Number of residuals (3 per unsupported observed node per simulated frame).
    pub fn num_residuals(&self) -> usize {
        let frames: usize = self.segments.iter().map(|s| s.end - s.start).sum();
        3 * self.free_nodes.len() * frames
    }

    /// The support dofs.
    pub fn support_dofs(&self) -> Vec<usize> {
        self.seq
            .support_nodes
            .iter()
            .flat_map(|&i| [3 * i, 3 * i + 1, 3 * i + 2])
            .collect()
    }

    /// The corotational model of `params` over the rest shape `rest_m`.
    pub fn model(&self, params: &DynamicParams, rest_m: &[Vector3<f64>]) -> Result<CorotationalModel> {
        let lp = params
            .young_pa
            .iter()
            .map(|&e| LinearParams::from_young_poisson(e, params.poisson))
            .collect::<std::result::Result<Vec<_>, _>>()?;
        Ok(CorotationalModel::new(
            &TetMesh {
                vertices: rest_m.to_vec(),
                tets: self.mesh.tets.clone(),
            },
            lp,
        )?)
    }

    /// Runs every segment (in parallel; results in segment order).
    pub fn simulate(&self, params: &DynamicParams, rest_m: &[Vector3<f64>]) -> Result<Vec<SegmentRun>> {
        let model = self.model(params, rest_m)?;
        let runs = (0..self.segments.len())
            .into_par_iter()
            .map(|k| self.run_segment(k, &model, params.damping))
            .collect::<Vec<_>>();
        runs.into_iter().collect()
    }

    fn dynamics_settings(&self, h: f64, damping: RayleighDamping) -> DynamicsSettings {
        DynamicsSettings {
            integrator: Integrator::NewmarkAverageAcceleration,
            time_step_s: h,
            damping,
            stiffness: StiffnessKind::Warped,
            max_iterations: self.settings.newton_iterations.max(1),
            ..DynamicsSettings::default()
        }
    }

    fn run_segment(
        &self,
        k: usize,
        model: &CorotationalModel,
        damping: RayleighDamping,
    ) -> Result<SegmentRun> {
        let seg = self.segments[k].clone();
        let mut model = model.clone();
        let mut solver = DynamicSolver::new(&model, self.masses_kg.clone(), &self.support_dofs())?;
        let (x0, v0) = &self.starts[k];
        let mut state = DynamicState::at_rest(x0.clone());
        state.time_s = self.seq.times_s[seg.start];
        state.velocities_m_s = v0.clone();
        for &i in &self.seq.support_nodes {
            state.velocities_m_s[i] = Vector3::zeros();
        }
        let substeps = self.settings.substeps.max(1);
        let first_h = (self.seq.times_s[seg.start + 1] - self.seq.times_s[seg.start]) / substeps as f64;
        solver.initialize_acceleration(&model, &mut state, &self.gravity_n, &self.dynamics_settings(first_h, damping));
        let mut run = SegmentRun {
            segment: seg.clone(),
            positions_m: Vec::with_capacity(seg.end - seg.start),
            max_iteration_steps: 0,
            failure: None,
        };
        for j in seg.start..seg.end {
            let (ta, tb) = (self.seq.times_s[j], self.seq.times_s[j + 1]);
            let h = (tb - ta) / substeps as f64;
            let settings = self.dynamics_settings(h, damping);
            for s in 1..=substeps {
                let w = s as f64 / substeps as f64;
                let mut bc = DirichletBc::new();
                for &i in &self.seq.support_nodes {
                    let p = self.seq.positions_m[j][i] * (1.0 - w) + self.seq.positions_m[j + 1][i] * w;
                    bc.fix_node(i, p);
                }
                let report = solver.step(&mut model, &mut state, &self.gravity_n, Some(&bc), None, &settings);
                match report.status {
                    DynamicStepStatus::Converged => {}
                    DynamicStepStatus::MaxIterations => {
                        if std::env::var("FD_DEBUG").is_ok() && run.max_iteration_steps < 3 {
                            eprintln!("frame {j} sub {s}: {report:?} vmax {:?}", state.velocities_m_s.iter().map(|v| v.norm()).fold(0.0f64, f64::max));
                        }
                        run.max_iteration_steps += 1
                    }
                    DynamicStepStatus::Failed { reason } => {
                        run.failure = Some(format!("frame {}: {reason}", j + 1));
                        return Ok(run);
                    }
                }
            }
            run.positions_m.push(state.positions_m.clone());
        }
        Ok(run)
    }

    /// Residuals x_t(p) − x̂_t (eq. 9) of `runs`, in segment, frame, node, axis order; a failed
    /// segment's missing frames count as non-finite.
    pub fn residuals(&self, runs: &[SegmentRun]) -> Vec<f64> {
        let mut r = Vec::with_capacity(self.num_residuals());
        for run in runs {
            let seg = &run.segment;
            for (o, j) in (seg.start + 1..=seg.end).enumerate() {
                let sim = run.positions_m.get(o);
                for &i in &self.free_nodes {
                    let d = match sim {
                        Some(x) => x[i] - self.seq.positions_m[j][i],
                        None => Vector3::repeat(f64::NAN),
                    };
                    r.extend([d.x, d.y, d.z]);
                }
            }
        }
        r
    }

    /// Root-mean-square node distance of `runs` to the tracked positions, m (over the residuals).
    pub fn rms_m(&self, runs: &[SegmentRun]) -> f64 {
        let r = self.residuals(runs);
        let ss: f64 = r.iter().map(|v| v * v).sum();
        (3.0 * ss / r.len().max(1) as f64).sqrt()
    }
}
