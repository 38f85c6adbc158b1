//! The model simulator the diagnosis compares a recording with.
//!
//! [`ProbeSimulator`] is the contract: quasi-static marker positions under one probe load (force
//! applied over the contact patch around the tip, bickel2009 §4.1 force boundary condition) plus an
//! optional body force (gravity, wang2015 eq. 7), and the tangent response ∂x_markers/∂f of the
//! converged state (three columns, one per force axis), which the hypothesis machinery uses for its
//! linearised refits. [`FemProbeSimulator`] implements it on a `softcap_fem` corotational model.

use crate::{DiagnoseError, Result};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use softcap_fem::{
    CorotationalModel, ElasticModel, EquilibriumSettings, StaticSolver, TetGeometry,
};
use softcap_mesh::{TetEmbedding, TetMesh};

/// A probe load: force `force_n` (by the probe on the object) spread over the contact patch around
/// `tip_m`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ProbeLoad {
    /// Tip position, m.
    pub tip_m: Vector3<f64>,
    /// Force on the object, N.
    pub force_n: Vector3<f64>,
}

/// Everything applied in one quasi-static simulation.
#[derive(Clone, Copy, Debug, PartialEq, Default, Serialize, Deserialize)]
pub struct SimLoad {
    /// Probe load, if any.
    pub probe: Option<ProbeLoad>,
    /// Body-force density ρ g, N/m³ (zero: no body force).
    pub body_force_n_m3: Vector3<f64>,
}

/// Result of one simulation.
#[derive(Clone, Debug, PartialEq)]
pub struct SimOutput {
    /// Marker positions, m.
    pub markers_m: Vec<Vector3<f64>>,
    /// ∂x_marker/∂f_k (m/N) for k = x, y, z when requested and a probe load was given.
    pub force_response: Option<[Vec<Vector3<f64>>; 3]>,
}

/// A model that can simulate a probing frame.
pub trait ProbeSimulator {
    /// Number of markers.
    fn num_markers(&self) -> usize;
    /// Marker positions under `load`; with `want_response`, also the tangent response to the probe
    /// force. Non-convergence is an error carrying the solver status.
    fn simulate(&mut self, load: &SimLoad, want_response: bool) -> Result<SimOutput>;
}

/// Settings of [`FemProbeSimulator`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct FemSimSettings {
    /// Radius of the contact patch the probe force is spread over, m (at least the closest
    /// surface node is loaded).
    pub patch_radius_m: f64,
    /// Equilibrium iterations.
    pub equilibrium: EquilibriumSettings,
}

impl Default for FemSimSettings {
    fn default() -> Self {
        Self {
            patch_radius_m: 0.003,
            // Newton (consistent tangent): quadratic convergence; 1e-8 of the bounding-box
            // diagonal is far below marker noise.
            equilibrium: EquilibriumSettings {
                displacement_tol_rel: 1e-8,
                residual_tol_rel: 1e-6,
                ..EquilibriumSettings::newton()
            },
        }
    }
}

/// [`ProbeSimulator`] on a corotational tet model (bickel2009 §3.2–3.4) with fixed support nodes,
/// markers embedded barycentrically in the tets, and the probe force as a uniform traction over the
/// surface nodes of the contact patch (bickel2009 §4.1).
pub struct FemProbeSimulator {
    model: CorotationalModel,
    solver: StaticSolver,
    tets: Vec<[usize; 4]>,
    rest_m: Vec<Vector3<f64>>,
    fixed: Vec<bool>,
    surface_nodes: Vec<usize>,
    lumped_volume_m3: Vec<f64>,
    embedding: Vec<TetEmbedding>,
    settings: FemSimSettings,
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
        let mut fixed = vec![false; n];
        let mut dofs = Vec::new();
        for &v in fixed_nodes {
            if v >= n {
                return Err(DiagnoseError::BadRecording {
                    what: format!("fixed node {v} out of range ({n} nodes)"),
                });
            }
            fixed[v] = true;
            dofs.extend([3 * v, 3 * v + 1, 3 * v + 2]);
        }
        let solver = StaticSolver::new(&model, &dofs).map_err(Box::new)?;
        let loc = softcap_mesh::TetLocator::new(mesh);
        let embedding = markers_m
            .iter()
            .enumerate()
            .map(|(i, p)| {
                loc.locate(p).ok_or_else(|| DiagnoseError::BadRecording {
                    what: format!("marker {i} cannot be embedded in the mesh"),
                })
            })
            .collect::<Result<Vec<_>>>()?;
        let mut surface_nodes: Vec<usize> = mesh.boundary_faces().into_iter().flatten().collect();
        surface_nodes.sort_unstable();
        surface_nodes.dedup();
        let mut lumped_volume_m3 = vec![0.0; n];
        for g in model.elements() {
            let g: &TetGeometry = g;
            for &v in &g.nodes {
                lumped_volume_m3[v] += g.volume_m3 / 4.0;
            }
        }
        Ok(Self {
            model,
            solver,
            tets: mesh.tets.clone(),
            rest_m: mesh.vertices.clone(),
            fixed,
            surface_nodes,
            lumped_volume_m3,
            embedding,
            settings,
        })
    }

    /// Nodes within `tolerance_m` of the plane `normal · x = offset_m`.
    pub fn nodes_on_plane(
        mesh: &TetMesh,
        normal: &Vector3<f64>,
        offset_m: f64,
        tolerance_m: f64,
    ) -> Vec<usize> {
        (0..mesh.vertices.len())
            .filter(|&i| (normal.dot(&mesh.vertices[i]) - offset_m).abs() <= tolerance_m)
            .collect()
    }

    /// Marker positions of the unloaded model, m.
    pub fn rest_markers_m(&self) -> Vec<Vector3<f64>> {
        self.markers_of(&self.rest_m)
    }

    fn markers_of(&self, x: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        self.embedding
            .iter()
            .map(|e| e.position(&self.tets, x))
            .collect()
    }

    /// Free surface nodes the probe force is spread over: those within the patch radius of the
    /// surface node closest to the tip (at least that node).
    pub fn patch_nodes(&self, tip_m: &Vector3<f64>) -> Vec<usize> {
        let free: Vec<usize> = self
            .surface_nodes
            .iter()
            .copied()
            .filter(|&v| !self.fixed[v])
            .collect();
        let Some(&c) = free.iter().min_by(|&&a, &&b| {
            (self.rest_m[a] - tip_m)
                .norm()
                .total_cmp(&(self.rest_m[b] - tip_m).norm())
        }) else {
            return Vec::new();
        };
        let centre = self.rest_m[c];
        let mut nodes: Vec<usize> = free
            .into_iter()
            .filter(|&v| (self.rest_m[v] - centre).norm() <= self.settings.patch_radius_m)
            .collect();
        if nodes.is_empty() {
            nodes.push(c);
        }
        nodes
    }
}

impl ProbeSimulator for FemProbeSimulator {
    fn num_markers(&self) -> usize {
        self.embedding.len()
    }

    fn simulate(&mut self, load: &SimLoad, want_response: bool) -> Result<SimOutput> {
        let n = self.rest_m.len();
        let mut f = vec![Vector3::zeros(); n];
        if load.body_force_n_m3 != Vector3::zeros() {
            for v in 0..n {
                f[v] += load.body_force_n_m3 * self.lumped_volume_m3[v];
            }
        }
        let patch = load
            .probe
            .map(|p| self.patch_nodes(&p.tip_m))
            .unwrap_or_default();
        if let Some(p) = &load.probe {
            let share = p.force_n / patch.len().max(1) as f64;
            for &v in &patch {
                f[v] += share;
            }
        }
        let mut x = self.rest_m.clone();
        let report = self.solver.solve(
            &mut self.model,
            &mut x,
            &f,
            None,
            &self.settings.equilibrium,
        );
        if !report.converged() {
            return Err(DiagnoseError::Simulation {
                frame: u64::MAX,
                reason: format!("{:?} after {} iterations", report.status, report.iterations),
            });
        }
        let markers_m = self.markers_of(&x);
        let force_response = if want_response && !patch.is_empty() {
            let dofs = self.solver.dofs().clone();
            let nf = dofs.num_free();
            let mut rhs = vec![0.0; 3 * nf];
            for k in 0..3 {
                for &v in &patch {
                    if let Some(i) = dofs.free_index(3 * v + k) {
                        rhs[k * nf + i] += 1.0 / patch.len() as f64;
                    }
                }
            }
            self.solver
                .cholesky()
                .solve_in_place(&mut rhs)
                .map_err(Box::new)?;
            let cols = [0, 1, 2].map(|k| {
                let mut dx = vec![Vector3::zeros(); n];
                dofs.scatter_add(&rhs[k * nf..(k + 1) * nf], 1.0, &mut dx);
                self.markers_of(&dx)
            });
            Some(cols)
        } else {
            None
        };
        Ok(SimOutput {
            markers_m,
            force_response,
        })
    }
}
