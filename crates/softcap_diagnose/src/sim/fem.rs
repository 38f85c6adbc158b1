//! [`FemProbeSimulator`]: the [`ProbeSimulator`] contract on a `softcap_fem` corotational model
//! (or the strain-space basis), through the shared probing kernels of `softcap_probing` (the
//! ones the tissue fit uses): marker embedding, attached region, contact patch and area-weighted
//! nodal forces; the tangent response ∂x/∂f of the converged state.

use super::contract::{
    Extension, Field, LoadPoint, MarkerMode, MaterialRefit, MaterialRefitOutcome, ProbeLoad,
    ProbeSimulator, SequenceFrame, SequenceJob, SimLoad, SimOutput,
};
use super::quadratic::QuadraticMesh;
use crate::{DiagnoseError, Result};
use nalgebra::{Unit, Vector3};
use serde::{Deserialize, Serialize};
use softcap_fem::{
    ContactDiscretisation, ContactSettings, CorotationalModel, ElasticModel, EquilibriumSettings,
    LinearParams, ModalSettings, Refactorization, StaticSolver, TipShape, lanczos_modes,
    lumped_masses,
};
use softcap_mesh::{RefineBall, RefinedTetMesh, TetMesh};
use softcap_probing::{
    HomogeneousFitSettings, PatchSettings, ProbeExample, ProbingSetup, StrainSpaceMaterial,
    StrainSpaceModel, StrainSpaceSolveSettings, fit_homogeneous, fit_homogeneous_on_support,
    support_nodes,
};
use std::sync::Arc;

/// Settings of [`FemProbeSimulator`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FemSimSettings {
    /// The contact patch the probe force is spread over (`softcap_probing::PatchSettings`,
    /// `ProbingSetup::load_weights`: lumped on the boundary nodes inside the footprint, or the
    /// consistent loads of a uniform, a rigid flat punch's (Sneddon) or a rigid sphere's (Hertz)
    /// pressure over it). Must match the tissue fit's.
    pub patch: PatchSettings,
    /// Equilibrium iterations.
    pub equilibrium: EquilibriumSettings,
    /// The strain-space default model's parameter iteration (relaxation ω, incremental loading
    /// from rest as the fallback; `softcap_probing::StrainSpaceModel::solve_continued`).
    pub strain_space: StrainSpaceSolveSettings,
    /// How [`ProbeSimulator::refined`] refines the fit mesh.
    pub refinement: RefinementSettings,
    /// How the frictional rigid-tip replay (`Extension::ProbeFriction`) samples the surface: at
    /// the boundary nodes, or at quadrature points on the boundary triangles
    /// (`softcap_fem::ContactDiscretisation`; docs/diagnose.md session 14 (fric)).
    pub friction_contact: ContactDiscretisation,
    /// The rigid-tip replays' penalty contact (`softcap_fem::ContactSettings`: the penalty
    /// stiffness as a multiple of a contact node's mean diagonal stiffness, bickel2009 §3.4),
    /// frictionless and frictional alike. The default factor 10⁴ makes the tip rigid (the
    /// penetration is a few % of the depth on the suite's meshes); a soft factor stands for a
    /// compliant tip (a rubber cap) — the measurement of docs/diagnose.md "Session 14 (fric2)".
    pub rigid_tip_contact: ContactSettings,
    /// The frictional replay's regularization slip ε (`softcap_fem::FrictionParams::
    /// slip_distance_m`, the slip below which a contact node sticks elastically) as a fraction of
    /// the replayed mesh's surface node spacing near the tips
    /// (`crate::sim::friction_slip_distance_m`: why; never below `FrictionParams`' 10 µm).
    pub friction_slip_fraction: f64,
    /// Equilibrium iterations of one solve of the frictional rigid-tip replay
    /// (`Extension::ProbeFriction`; regularized Coulomb with lagged normal forces converges more
    /// slowly than the frictionless replay's 80: stick stiffness 2μf_n/ε). A solve that does not
    /// converge within them is retried from the frame's start in 4, then 16 sub-steps.
    pub friction_max_iterations: usize,
    /// Equilibrium iterations of one solve of the frictional rigid-tip replay in the attempts
    /// that are not the last (1 and 4 sub-steps; the 16-sub-step attempt keeps
    /// `friction_max_iterations`): a solve that has not converged within them is retried in
    /// more sub-steps at once instead of running out its iterations.
    pub friction_attempt_max_iterations: usize,
    /// The frictional rigid-tip replay's contact active set is re-queried in the first this many
    /// equilibrium iterations of each solve, then frozen (`EquilibriumSettings::
    /// contact_freeze_after`). A set that still changes after them is a cycle: a flat punch keeps a
    /// point that slid past its rim on its face plane (`softcap_fem::Probe::kept_projection`), so
    /// on the third-party probe-friction session most solves settle in 4–10 iterations; before,
    /// the rim edge pushed such a point out and up and the set cycled with period 3 until it was
    /// frozen here.
    pub friction_contact_freeze_after: usize,
    /// When the frictionless rigid-tip replays (`Extension::{Elastic, Plastic, Anisotropic, …}`
    /// replayed at the measured poses) refactor their system matrix
    /// (`softcap_fem::Refactorization`): at every iterate that takes a Newton step (the default,
    /// `EveryStep`: the converged iterate is tested with its forces alone — the iterates of
    /// `EveryIteration`, one assembly and factorization fewer per frame), at every iterate
    /// (`EveryIteration`), or only when the factor stops contracting or the contact set changes
    /// (`WhenStale`, modified Newton: other iterates, and through the contact set's hysteresis
    /// and the plastic history other equilibria). No tangent response is read from a replay.
    pub replay_refactorization: Refactorization,
    /// When the force-driven re-simulations of the extended models (`Extension::{Elastic,
    /// Viscoelastic, Plastic, Anisotropic, …}` under the measured force over the patch, one
    /// frame after another) refactor their system matrix (`softcap_fem::Refactorization`): only
    /// when the factor stops contracting (`WhenStale`, the default; modified Newton: the factor
    /// kept across iterations and frames; without contact a frame's equilibrium is the one full
    /// Newton finds, to the same convergence test), or at every iterate (`EveryIteration`).
    /// Measured with `WhenStale` on the own rig's viscoelasticity case: the diagnosis 109.4 →
    /// 48.6 CPU-s, its compliance scale moved by 1e-8 relative and its held-out RMS by 3e-12 m;
    /// every own-rig and third-party suite case keeps its verdict and held-out numbers to
    /// 4 decimals (docs/diagnose.md, where the time goes). The baseline's single solves refactor
    /// at every iterate (their tangent response is read from the factor); no tangent response
    /// is read from a sequence. The support springs' replays (`Extension::SupportSprings`) and
    /// the homogeneous refits on the springs (`ProbeSimulator::refit_homogeneous`, a Jacobian by
    /// forward differences) follow it too (`softcap_fem::NodalSolver`).
    pub sequence_refactorization: Refactorization,
}

/// How [`ProbeSimulator::refined`] refines the fit mesh for the spatial hypotheses' replays.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RefinementSettings {
    /// Refine only inside the touched balls (`softcap_mesh::refine_near`, longest-edge
    /// bisection) instead of every tet 1 → 8 (`softcap_mesh::refine_tets`).
    pub local: bool,
    /// Local: the target longest edge inside the balls as a fraction of the fit mesh's longest
    /// edge (½: the uniform refinement's edge length; ¼: a second uniform level's).
    pub edge_fraction: f64,
    /// Local: the touched balls' radii (the contact radius, `spatial::contact_radius_m`) scaled
    /// by this.
    pub radius_scale: f64,
    /// Local: at most this many tets (an error beyond).
    pub max_tets: usize,
}

impl Default for RefinementSettings {
    fn default() -> Self {
        Self {
            local: false,
            edge_fraction: 0.5,
            radius_scale: 1.0,
            max_tets: 200_000,
        }
    }
}

impl Default for FemSimSettings {
    fn default() -> Self {
        Self {
            patch: PatchSettings::default(),
            // Newton (consistent tangent): quadratic convergence; 1e-8 of the bounding-box
            // diagonal is far below marker noise.
            equilibrium: EquilibriumSettings {
                displacement_tol_rel: 1e-8,
                residual_tol_rel: 1e-6,
                ..EquilibriumSettings::newton()
            },
            strain_space: StrainSpaceSolveSettings::default(),
            refinement: RefinementSettings::default(),
            friction_contact: ContactDiscretisation::Nodes,
            rigid_tip_contact: ContactSettings::default(),
            friction_slip_fraction: 0.1,
            friction_max_iterations: 150,
            friction_attempt_max_iterations: 40,
            friction_contact_freeze_after: 12,
            replay_refactorization: Refactorization::EveryStep,
            sequence_refactorization: Refactorization::WhenStale,
        }
    }
}

/// The strain-space default model and the equilibrium its next solve continues from.
#[derive(Clone)]
struct StrainSpaceState {
    model: StrainSpaceModel,
    /// Node positions of the last equilibrium (the rest shape before the first solve).
    x: Vec<Vector3<f64>>,
    /// The nodal forces of that equilibrium.
    forces: Vec<Vector3<f64>>,
}

/// [`ProbeSimulator`] on a corotational tet model (bickel2009 §3.2–3.4) over a
/// [`ProbingSetup`]: attached (support) nodes fixed, markers embedded barycentrically, the probe
/// force spread over the footprint (bickel2009 §4.1 force boundary condition,
/// `ProbingSetup::{load_weights, nodal_forces}`).
pub struct FemProbeSimulator {
    setup: ProbingSetup,
    model: CorotationalModel,
    solver: StaticSolver,
    lumped_volume_m3: Vec<f64>,
    settings: FemSimSettings,
    support_plane: Option<(Unit<Vector3<f64>>, f64)>,
    rigid_tip: Option<TipShape>,
    strain_space: Option<StrainSpaceState>,
    /// The 10-node tets the rigid-tip replays of plasticity run on ([`Self::quadratic`]).
    quadratic: Option<Box<QuadraticMesh>>,
}

impl FemProbeSimulator {
    /// Builds the simulator; `fixed_nodes` are held at their rest positions (the support).
    pub fn new(
        mesh: &TetMesh,
        model: CorotationalModel,
        fixed_nodes: &[usize],
        markers_m: &[Vector3<f64>],
        settings: FemSimSettings,
    ) -> Result<Self> {
        let n = mesh.vertices.len();
        if let Some(&v) = fixed_nodes.iter().find(|&&v| v >= n) {
            return Err(DiagnoseError::BadRecording {
                what: format!("fixed node {v} out of range ({n} nodes)"),
            });
        }
        let setup =
            ProbingSetup::new(mesh.clone(), markers_m, fixed_nodes.to_vec()).map_err(|e| {
                DiagnoseError::BadRecording {
                    what: format!("markers / mesh: {e}"),
                }
            })?;
        Self::from_setup(setup, model, settings)
    }

    /// Builds the simulator over an existing probing setup (its attached nodes are the support).
    pub fn from_setup(
        setup: ProbingSetup,
        model: CorotationalModel,
        settings: FemSimSettings,
    ) -> Result<Self> {
        let solver = setup.solver(&model).map_err(Box::new)?;
        let mut lumped_volume_m3 = vec![0.0; setup.mesh.vertices.len()];
        for g in model.elements() {
            for &v in &g.nodes {
                lumped_volume_m3[v] += g.volume_m3 / 4.0;
            }
        }
        Ok(Self {
            setup,
            model,
            solver,
            lumped_volume_m3,
            settings,
            support_plane: None,
            rigid_tip: None,
            strain_space: None,
            quadratic: None,
        })
    }

    /// Makes the default model the strain-space material `material` (bickel2009 eq. 8 and §3.4:
    /// the parameters of every element follow its strain, p_e = p_e(ε_e) at equilibrium), one
    /// element per tet of the mesh. [`ProbeSimulator::simulate`] then solves it with the relaxed
    /// parameter iteration continued from the previous simulation's equilibrium
    /// (`softcap_probing::StrainSpaceModel::solve_continued`: the material is elastic, so the
    /// previous equilibrium is only the start of the iterations; when that does not converge the
    /// load is applied from rest in increments). The per-element parameters [`Self::model`]
    /// becomes p(0): the extended models built from constant per-element parameters
    /// (plasticity, anisotropy, support springs, probe friction, the refined mesh) take the
    /// basis at zero strain; the elastic and viscoelastic sequences keep the strain dependence.
    pub fn with_strain_space(mut self, material: Arc<StrainSpaceMaterial>) -> Result<Self> {
        let fem = |e: softcap_fem::FemError| DiagnoseError::Fem(Box::new(e));
        let model = StrainSpaceModel::new(
            material,
            &self.setup.mesh,
            self.settings.strain_space.relaxation,
        )
        .map_err(fem)?;
        self.model.set_params(model.params()).map_err(fem)?;
        self.strain_space = Some(StrainSpaceState {
            model,
            x: self.setup.mesh.vertices.clone(),
            forces: vec![Vector3::zeros(); self.setup.mesh.vertices.len()],
        });
        Ok(self)
    }

    /// The strain-space material when the default model is the basis.
    pub fn strain_space_material(&self) -> Option<&Arc<StrainSpaceMaterial>> {
        self.strain_space.as_ref().map(|s| s.model.material())
    }

    /// A fresh strain-space model (zero-strain parameters) for a sequence of its own, when the
    /// default model is the basis.
    pub(crate) fn strain_space_model(&self) -> Option<StrainSpaceModel> {
        self.strain_space.as_ref().map(|s| {
            let mut m = s.model.clone();
            m.reset();
            m
        })
    }

    /// Records the support plane `normal · x = offset_m` (unit normal into the body) the attached
    /// nodes lie on; the support-slip extension replaces their fixed boundary condition by
    /// tangential springs on it.
    pub fn with_support_plane(mut self, normal: &Vector3<f64>, offset_m: f64) -> Self {
        self.support_plane = Unit::try_new(*normal, 1e-12).map(|n| (n, offset_m));
        self
    }

    /// Records the probe's tip geometry (the session's `tip_shape` / `tip_radius_m`), which enables
    /// the rigid-tip replay of [`ProbeSimulator::simulate_sequence_rigid_tip`].
    pub fn with_rigid_tip(mut self, tip: TipShape) -> Self {
        self.rigid_tip = Some(tip);
        self
    }

    /// The probe's tip geometry, if recorded.
    pub fn rigid_tip(&self) -> Option<&TipShape> {
        self.rigid_tip.as_ref()
    }

    /// The support plane, if recorded.
    pub fn support_plane(&self) -> Option<(Unit<Vector3<f64>>, f64)> {
        self.support_plane
    }

    /// Nodes within `tolerance_m` of the plane `normal · x = offset_m`
    /// (`softcap_probing::support_nodes`).
    pub fn nodes_on_plane(
        mesh: &TetMesh,
        normal: &Vector3<f64>,
        offset_m: f64,
        tolerance_m: f64,
    ) -> Vec<usize> {
        support_nodes(mesh, normal, offset_m, tolerance_m)
    }

    /// The probing setup (mesh, marker embedding, attached nodes).
    pub fn setup(&self) -> &ProbingSetup {
        &self.setup
    }

    /// The default model.
    pub fn model(&self) -> &CorotationalModel {
        &self.model
    }

    /// The simulator settings.
    pub fn settings(&self) -> &FemSimSettings {
        &self.settings
    }

    /// Marker positions of the unloaded model, m.
    pub fn rest_markers_m(&self) -> Vec<Vector3<f64>> {
        self.setup.marker_positions(&self.setup.mesh.vertices)
    }

    /// This simulator on the mesh refined 1 → 8 (`softcap_mesh::refine_tets`): each child tet
    /// carries its parent's (λ, α) — for the strain-space basis its zero-strain p(0); the strain
    /// dependence is not carried over (the extended models are built from the per-element
    /// parameters alone); the attached nodes are the attached vertices and every new vertex both
    /// of whose endpoints are attached (in creation order, so nested midpoints of a local
    /// refinement follow their endpoints); the markers are re-embedded at their rest positions;
    /// support plane, rigid tip and settings are kept.
    pub fn refined(&self) -> Result<Self> {
        self.refined_from(softcap_mesh::refine_tets(&self.setup.mesh))
    }

    /// This simulator with its rigid-tip replays of the plasticity extensions
    /// ([`Extension::Plastic`], [`Extension::PlasticPoisson`]) on the 10-node tets of its mesh,
    /// small-strain J2 at their quadrature points (`super::quadratic`); everything else as this
    /// one. The rigid-tip replay of the linear tets cannot form the truth's permanent set even
    /// refined 1 → 8 (their isochoric flow locks at ν ≈ 0.45): third-party `plasticity`, ν 0.45,
    /// H/E 0.08, released near cells at compliance 1 — σ_y/E 0.090 / 0.0975 / 0.103: 0.174 /
    /// 0.118 / 0.113 mm, where the 1 → 8 replays stay at 0.168 even with the compliance fitted.
    pub fn quadratic(&self) -> Result<Self> {
        let quadratic = QuadraticMesh::of(self)?;
        let mut sim = Self::from_setup(
            self.setup.clone(),
            self.model.clone(),
            self.settings.clone(),
        )?;
        sim.support_plane = self.support_plane;
        sim.rigid_tip = self.rigid_tip.clone();
        sim.strain_space = self.strain_space.clone();
        sim.quadratic = Some(Box::new(quadratic));
        Ok(sim)
    }

    /// The 10-node tets of [`Self::quadratic`], if this is such a simulator.
    pub(crate) fn quadratic_mesh(&self) -> Option<&QuadraticMesh> {
        self.quadratic.as_deref()
    }

    /// This simulator on the mesh refined inside `balls` until the longest edge there is at most
    /// `max_edge_m` (`softcap_mesh::refine_near`, conforming longest-edge bisection; material,
    /// attached nodes, markers, support, tip and settings as in [`Self::refined`]); at most
    /// `max_tets` tets.
    pub fn refined_near(
        &self,
        balls: &[RefineBall],
        max_edge_m: f64,
        max_tets: usize,
    ) -> Result<Self> {
        let r = softcap_mesh::refine_near(&self.setup.mesh, balls, max_edge_m, max_tets)
            .map_err(|e| DiagnoseError::Mesh(Box::new(e)))?;
        self.refined_from(r)
    }

    /// The longest edge of the mesh, m.
    pub fn longest_edge_m(&self) -> f64 {
        self.setup.mesh.longest_edge()
    }

    /// This simulator on its mesh refined everywhere by conforming longest-edge bisection until it
    /// has at least `tet_factor` × its tets (`ProbeSimulator::bisected`: the target longest edge
    /// lowered from the longest edge by 5 % a step; material, attached nodes, markers, support,
    /// tip and settings as in [`Self::refined`]). An error when 60 steps (a target edge of 5 % of
    /// the longest) or `RefinementSettings::max_tets` do not reach the count.
    pub fn bisected(&self, tet_factor: usize) -> Result<Self> {
        let mesh = &self.setup.mesh;
        let want = tet_factor.saturating_mul(mesh.tets.len());
        let longest = self.longest_edge_m();
        // one ball holding every vertex: the whole mesh is refined
        let centre_m = mesh
            .vertices
            .first()
            .copied()
            .unwrap_or_else(Vector3::zeros);
        let radius_m = 2.0
            * mesh
                .vertices
                .iter()
                .map(|v| (v - centre_m).norm())
                .fold(0.0, f64::max);
        let all = [RefineBall { centre_m, radius_m }];
        let max_tets = self.settings.refinement.max_tets;
        let mut fraction = 1.0;
        for _ in 0..60 {
            fraction *= 0.95;
            let r = softcap_mesh::refine_near(mesh, &all, fraction * longest, max_tets)
                .map_err(|e| DiagnoseError::Mesh(Box::new(e)))?;
            if r.mesh.tets.len() >= want {
                return self.refined_from(r);
            }
        }
        Err(DiagnoseError::Mesh(Box::new(
            softcap_mesh::MeshError::Refinement {
                message: format!(
                    "bisecting the mesh ({} tets) to {tet_factor}x its tets: not reached at 5 % of its longest edge",
                    mesh.tets.len()
                ),
            },
        )))
    }

    /// This simulator on a refinement `r` of its mesh (material, attached nodes, markers,
    /// support, tip and settings as [`Self::refined`] says).
    fn refined_from(&self, r: RefinedTetMesh) -> Result<Self> {
        let fem = |e: softcap_fem::FemError| DiagnoseError::Fem(Box::new(e));
        let n = self.setup.mesh.vertices.len();
        let mut attached = vec![false; r.mesh.vertices.len()];
        for &v in &self.setup.attached_nodes {
            attached[v] = true;
        }
        for (k, &[a, b]) in r.midpoint_of.iter().enumerate() {
            attached[n + k] = attached[a] && attached[b];
        }
        let fixed: Vec<usize> = (0..attached.len()).filter(|&v| attached[v]).collect();
        let params: Vec<LinearParams> = r
            .parent_tet
            .iter()
            .map(|&t| self.model.params()[t])
            .collect();
        let model = CorotationalModel::new(&r.mesh, params).map_err(fem)?;
        let mut sim = FemProbeSimulator::new(
            &r.mesh,
            model,
            &fixed,
            &self.rest_markers_m(),
            self.settings.clone(),
        )?;
        sim.support_plane = self.support_plane;
        sim.rigid_tip = self.rigid_tip.clone();
        Ok(sim)
    }

    fn example(load: &ProbeLoad) -> ProbeExample {
        ProbeExample {
            frame: 0,
            time_s: 0.0,
            tip_m: load.tip_m,
            axis: load
                .axis
                .try_normalize(1e-12)
                .or_else(|| load.force_n.try_normalize(1e-12))
                .unwrap_or_else(|| -Vector3::z()),
            force_n: load.force_n,
            observed: Vec::new(),
        }
    }

    /// Share of the probe force of `load` per loaded surface node (`ProbingSetup::load_weights`).
    pub fn load_weights(&self, load: &ProbeLoad) -> Vec<(usize, f64)> {
        self.setup
            .load_weights(&Self::example(load), &self.settings.patch)
    }

    /// Nodal forces of `load` over its footprint (consistent loads, `ProbingSetup::nodal_forces`).
    pub fn probe_forces(&self, load: &ProbeLoad) -> Vec<Vector3<f64>> {
        self.setup
            .nodal_forces(&Self::example(load), &self.settings.patch)
    }

    /// Body force of density ρ g (N/m³) lumped to the nodes (wang2015 §3, m_a = Σ ρ V_e / 4).
    pub fn body_forces(&self, body_force_n_m3: &Vector3<f64>) -> Vec<Vector3<f64>> {
        self.lumped_volume_m3
            .iter()
            .map(|v| body_force_n_m3 * *v)
            .collect()
    }
}

impl ProbeSimulator for FemProbeSimulator {
    fn num_markers(&self) -> usize {
        self.setup.markers.len()
    }

    fn refit_homogeneous(
        &self,
        examples: &[ProbeExample],
        ext: &Extension,
        start: Option<(f64, f64)>,
    ) -> Result<MaterialRefitOutcome> {
        let fem = |e: softcap_fem::FemError| DiagnoseError::Fem(Box::new(e));
        let declined = |why: String| Ok(MaterialRefitOutcome::Declined(why));
        let Some(p0) = self.model.params().first() else {
            return declined("the model has no material parameters".into());
        };
        let defaults = HomogeneousFitSettings::default();
        let (initial_young_pa, initial_nu) = match start {
            Some((e, nu)) => (e, nu.clamp(defaults.nu_bounds.0, defaults.nu_bounds.1)),
            None => {
                let (e0, nu0) = p0.to_young_poisson().map_err(fem)?;
                (e0, nu0.clamp(0.05, 0.45))
            }
        };
        let settings = HomogeneousFitSettings {
            initial_young_pa,
            initial_nu,
            patch: self.settings.patch.clone(),
            ..defaults
        };
        let fit = match *ext {
            Extension::Elastic => fit_homogeneous(&self.setup, examples, &settings),
            Extension::SupportSprings { stiffness_n_per_m } => {
                let Some(plane) = self.support_springs(stiffness_n_per_m)? else {
                    return declined("no support plane for the springs".into());
                };
                // no tangent response is read from these solves (forward differences)
                let settings = HomogeneousFitSettings {
                    equilibrium: EquilibriumSettings {
                        refactorization: self.settings.sequence_refactorization,
                        ..settings.equilibrium
                    },
                    ..settings
                };
                fit_homogeneous_on_support(&self.setup, examples, &settings, plane)
            }
            _ => return declined(format!("no material refit under {ext:?}")),
        };
        let fit = match fit {
            Ok(fit) => fit,
            Err(e) => return declined(e.to_string()),
        };
        let (young_pa, poisson) = fit.params.to_young_poisson().map_err(fem)?;
        let model = CorotationalModel::homogeneous(&self.setup.mesh, fit.params).map_err(fem)?;
        let mut sim =
            FemProbeSimulator::from_setup(self.setup.clone(), model, self.settings.clone())?;
        sim.support_plane = self.support_plane;
        sim.rigid_tip = self.rigid_tip.clone();
        Ok(MaterialRefitOutcome::Refitted(MaterialRefit {
            sim: Box::new(sim),
            young_pa,
            poisson,
            iterations: fit.iterations,
            stalled_solves: fit.stalled_solves,
        }))
    }

    fn natural_modes(&self, density_kg_m3: f64, count: usize) -> Result<Option<Vec<MarkerMode>>> {
        let fem = |e: softcap_fem::FemError| DiagnoseError::Fem(Box::new(e));
        let masses = lumped_masses(&self.model, density_kg_m3);
        let settings = ModalSettings {
            num_modes: count,
            ..ModalSettings::default()
        };
        let fixed = self.setup.dirichlet().dofs();
        let modes = lanczos_modes(&self.model, &masses, &fixed, &settings)
            .map_err(fem)?
            .modes;
        Ok(Some(
            modes
                .frequencies_hz()
                .into_iter()
                .zip(&modes.shapes)
                // the embedding is linear in the node field: the markers' share of the shape
                .map(|(frequency_hz, shape)| MarkerMode {
                    frequency_hz,
                    markers: self.setup.marker_positions(shape),
                })
                .collect(),
        ))
    }

    fn young_pa(&self) -> Option<f64> {
        let (mut sum, mut volume) = (0.0, 0.0);
        for (g, p) in self.model.elements().iter().zip(self.model.params()) {
            let (e, _) = p.to_young_poisson().ok()?;
            sum += e * g.volume_m3;
            volume += g.volume_m3;
        }
        (volume > 0.0).then(|| sum / volume)
    }

    fn resolves_footprint(&self, tip_radius_m: f64, tips_m: &[Vector3<f64>]) -> bool {
        let tip = TipShape::Sphere {
            radius_m: tip_radius_m,
        };
        super::resolution::friction_refinement(&self.setup.mesh, &tip, tips_m) == 0
    }

    fn refined(&self, touched: &[RefineBall]) -> Result<Option<Box<dyn ProbeSimulator>>> {
        let r = &self.settings.refinement;
        Ok(Some(Box::new(if r.local {
            let balls: Vec<RefineBall> = touched
                .iter()
                .map(|b| RefineBall {
                    radius_m: b.radius_m * r.radius_scale,
                    ..*b
                })
                .collect();
            self.refined_near(&balls, r.edge_fraction * self.longest_edge_m(), r.max_tets)?
        } else {
            FemProbeSimulator::refined(self)?
        })))
    }

    fn quadratic(&self) -> Result<Option<Box<dyn ProbeSimulator>>> {
        Ok(Some(Box::new(FemProbeSimulator::quadratic(self)?)))
    }

    fn bisected(&self, tet_factor: usize) -> Result<Option<Box<dyn ProbeSimulator>>> {
        if tet_factor <= 1 {
            return Ok(None);
        }
        Ok(Some(Box::new(FemProbeSimulator::bisected(
            self, tet_factor,
        )?)))
    }

    fn simulate_sequence(
        &mut self,
        ext: &Extension,
        frames: &[SequenceFrame],
    ) -> Result<Vec<Vec<Vector3<f64>>>> {
        FemProbeSimulator::simulate_sequence(self, ext, frames)
    }

    fn simulate_sequence_rigid_tip(
        &mut self,
        ext: &Extension,
        frames: &[SequenceFrame],
    ) -> Result<Option<Vec<Vec<Vector3<f64>>>>> {
        FemProbeSimulator::simulate_sequence_rigid_tip(self, ext, frames)
    }

    fn simulate_sequences_rigid_tip(
        &mut self,
        exts: &[Extension],
        frames: &[SequenceFrame],
    ) -> Vec<Result<Option<Field>>> {
        FemProbeSimulator::simulate_sequences_rigid_tip(self, exts, frames)
    }

    fn simulate_sequences(&mut self, jobs: &[SequenceJob]) -> Vec<Result<Field>> {
        use rayon::prelude::*;
        jobs.par_iter()
            .map(|(e, f)| FemProbeSimulator::simulate_sequence(self, e, f))
            .collect()
    }

    fn simulate(&mut self, load: &SimLoad, want_response: bool) -> Result<SimOutput> {
        let n = self.setup.mesh.vertices.len();
        let mut f = if load.body_force_n_m3 != Vector3::zeros() {
            self.body_forces(&load.body_force_n_m3)
        } else {
            vec![Vector3::zeros(); n]
        };
        let weights = load
            .probe
            .map(|p| self.load_weights(&p))
            .unwrap_or_default();
        if let Some(p) = &load.probe {
            for &(v, w) in &weights {
                f[v] += p.force_n * w;
            }
        }
        let x = match &mut self.strain_space {
            Some(state) => {
                let solve = state
                    .model
                    .solve_continued(
                        &self.setup,
                        &mut self.solver,
                        &mut state.x,
                        &state.forces,
                        &f,
                        &self.settings.equilibrium,
                        &self.settings.strain_space,
                    )
                    .map_err(|e| DiagnoseError::Fem(Box::new(e)))?;
                crate::profile::solve(solve.iterations, self.setup.mesh.tets.len());
                if solve.converged() {
                    state.forces.clone_from(&f);
                } else {
                    return Err(DiagnoseError::Simulation {
                        frame: u64::MAX,
                        reason: format!(
                            "strain-space basis: {:?} after {} iterations (incremental loading from the previous equilibrium, then from rest with ω down to {})",
                            solve.report.status,
                            solve.iterations,
                            self.settings.strain_space.relaxation
                                * 0.5f64.powi(self.settings.strain_space.relaxation_retries as i32)
                        ),
                    });
                }
                state.x.clone()
            }
            None => {
                let mut x = self.setup.mesh.vertices.clone();
                let report = self.setup.simulate(
                    &mut self.solver,
                    &mut self.model,
                    &mut x,
                    &f,
                    &self.settings.equilibrium,
                );
                crate::profile::solve(report.iterations, self.setup.mesh.tets.len());
                if !report.converged() {
                    return Err(DiagnoseError::Simulation {
                        frame: u64::MAX,
                        reason: format!(
                            "{:?} after {} iterations",
                            report.status, report.iterations
                        ),
                    });
                }
                x
            }
        };
        let markers_m = self.setup.marker_positions(&x);
        // T = ∂x/∂f: the right-hand side of unit force k is the load's share on every loaded
        // node (the same weights as the load itself, so T·f reproduces the load's response).
        // The factor is the consistent tangent of the last equilibrium iteration; for the
        // strain-space basis its parameters are frozen at p(ε) of the equilibrium (the response
        // leaves out ∂p/∂ε — a secant-in-parameters tangent, used by the linearised refits only).
        let force_response = match (&load.probe, want_response && !weights.is_empty()) {
            (Some(_), true) => {
                let dofs = self.solver.dofs().clone();
                let nf = dofs.num_free();
                let mut rhs = vec![0.0; 3 * nf];
                for k in 0..3 {
                    for &(v, w) in &weights {
                        if let Some(i) = dofs.free_index(3 * v + k) {
                            rhs[k * nf + i] += w;
                        }
                    }
                }
                self.solver
                    .cholesky()
                    .solve_in_place(&mut rhs)
                    .map_err(Box::new)?;
                let mut point = [Vector3::zeros(); 3];
                let cols = [0, 1, 2].map(|k| {
                    let mut dx = vec![Vector3::zeros(); n];
                    dofs.scatter_add(&rhs[k * nf..(k + 1) * nf], 1.0, &mut dx);
                    point[k] = load_point(&weights, &dx);
                    self.setup.marker_positions(&dx)
                });
                Some((cols, point))
            }
            _ => None,
        };
        let load_point = (load.probe.is_some() && !weights.is_empty()).then(|| LoadPoint {
            position_m: load_point(&weights, &x),
            response_m_per_n: force_response.as_ref().map(|r| r.1),
        });
        Ok(SimOutput {
            markers_m,
            force_response: force_response.map(|r| r.0),
            load_point,
        })
    }
}

/// The load-weighted mean Σ w_i v_i / Σ w_i of the nodal vectors `v` over the loaded nodes
/// (`LoadPoint`).
fn load_point(weights: &[(usize, f64)], v: &[Vector3<f64>]) -> Vector3<f64> {
    let total: f64 = weights.iter().map(|w| w.1).sum();
    let sum: Vector3<f64> = weights.iter().map(|&(i, w)| v[i] * w).sum();
    sum / total.max(1e-300)
}
