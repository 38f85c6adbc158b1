//! The probing setup of bickel2009 §4.1: a tet mesh with embedded markers, its attached,
//! boundary and load regions, the umbrella adjacency of eq. 9, and the elastostatic response to
//! an example's force ([`ProbingSetup::simulate`]).

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use softcap_fem::{
    DirichletBc, ElasticModel, EquilibriumReport, EquilibriumSettings, FemError, StaticSolver,
};
use softcap_mesh::{TetEmbedding, TetLocator, TetMesh};

use crate::probing_error;

/// A marker observed in one example.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ObservedMarker {
    /// Marker index (into the markers given to [`ProbingSetup::new`]).
    pub marker: usize,
    /// Measured position, m, world frame.
    pub position_m: Vector3<f64>,
}

/// One captured probing deformation (bickel2009 §4.1).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ProbeExample {
    /// Capture frame.
    pub frame: u64,
    /// Time, s.
    pub time_s: f64,
    /// Probe tip (leading point of the tip), m, world frame.
    pub tip_m: Vector3<f64>,
    /// Unit approach axis (handle → tip), world frame.
    pub axis: Vector3<f64>,
    /// Force exerted by the probe on the object, N, world frame.
    pub force_n: Vector3<f64>,
    /// Observed markers.
    pub observed: Vec<ObservedMarker>,
}

/// A tet mesh prepared for probing examples: marker embedding, regions, adjacency.
#[derive(Clone, Debug)]
pub struct ProbingSetup {
    /// The mesh (rest = capture frame 0), m.
    pub mesh: TetMesh,
    /// Barycentric embedding of every marker at rest.
    pub markers: Vec<TetEmbedding>,
    /// Attached nodes (fixed at rest), increasing.
    pub attached_nodes: Vec<usize>,
    /// Boundary nodes, increasing.
    pub boundary_nodes: Vec<usize>,
    /// Lumped boundary area per node (⅓ of each incident boundary triangle), m² (0 inside).
    pub node_areas_m2: Vec<f64>,
    /// Tets sharing a vertex with each tet (umbrella operator of eq. 9).
    pub adjacency: Vec<Vec<usize>>,
    /// Boundary triangles (outward) that can carry a probe load: all but those with every
    /// vertex attached (the support face).
    pub load_faces: Vec<[usize; 3]>,
}

/// Boundary nodes within `tolerance_m` of the plane n·x = `offset_m` (the attached region of
/// bickel2009 §4.1 from the session's support plane).
pub fn support_nodes(
    mesh: &TetMesh,
    normal: &Vector3<f64>,
    offset_m: f64,
    tolerance_m: f64,
) -> Vec<usize> {
    let n = normal.normalize();
    mesh.vertices
        .iter()
        .enumerate()
        .filter(|(_, x)| (n.dot(x) - offset_m).abs() <= tolerance_m)
        .map(|(i, _)| i)
        .collect()
}

impl ProbingSetup {
    /// Embeds the markers' rest positions in `mesh` and records the attached nodes. Markers
    /// slightly outside the mesh (paint on a coarse surface) are embedded in the closest tet
    /// with extrapolating barycentric weights.
    pub fn new(
        mesh: TetMesh,
        marker_rest_m: &[Vector3<f64>],
        attached_nodes: Vec<usize>,
    ) -> Result<Self, FemError> {
        // Validate the mesh (degenerate / inverted tets) through the element geometry.
        softcap_fem::tet_geometries(&mesh.vertices, &mesh.tets)?;
        let locator = TetLocator::new(&mesh);
        let markers = marker_rest_m
            .iter()
            .enumerate()
            .map(|(i, p)| {
                if !p.iter().all(|c| c.is_finite()) {
                    return Err(probing_error(format!(
                        "marker {i}: non-finite rest position"
                    )));
                }
                locator
                    .locate(p)
                    .ok_or_else(|| probing_error(format!("marker {i}: cannot embed in the mesh")))
            })
            .collect::<Result<Vec<_>, _>>()?;
        let mut attached_nodes = attached_nodes;
        attached_nodes.sort_unstable();
        attached_nodes.dedup();
        if let Some(&n) = attached_nodes.last()
            && n >= mesh.vertices.len()
        {
            return Err(FemError::VertexOutOfRange {
                tet: usize::MAX,
                vertex: n,
                num_vertices: mesh.vertices.len(),
            });
        }
        let faces = mesh.boundary_faces();
        let mut node_areas_m2 = vec![0.0; mesh.vertices.len()];
        for f in &faces {
            let [a, b, c] = f.map(|i| mesh.vertices[i]);
            let area = 0.5 * (b - a).cross(&(c - a)).norm();
            for &i in f {
                node_areas_m2[i] += area / 3.0;
            }
        }
        let mut boundary_nodes: Vec<usize> = faces.iter().flatten().copied().collect();
        boundary_nodes.sort_unstable();
        boundary_nodes.dedup();
        let adjacency = softcap_mesh::tet_vertex_adjacency(mesh.vertices.len(), &mesh.tets);
        let load_faces = faces
            .into_iter()
            .filter(|f| f.iter().any(|n| attached_nodes.binary_search(n).is_err()))
            .collect();
        Ok(Self {
            mesh,
            markers,
            attached_nodes,
            boundary_nodes,
            node_areas_m2,
            adjacency,
            load_faces,
        })
    }

    /// Number of tets.
    pub fn num_elements(&self) -> usize {
        self.mesh.tets.len()
    }

    /// Boundary nodes that are not attached (increasing): the nodes a probe tip can touch.
    pub fn free_boundary_nodes(&self) -> Vec<usize> {
        self.boundary_nodes
            .iter()
            .copied()
            .filter(|n| self.attached_nodes.binary_search(n).is_err())
            .collect()
    }

    /// Dirichlet conditions: the attached nodes at rest.
    pub fn dirichlet(&self) -> DirichletBc {
        let mut bc = DirichletBc::new();
        for &n in &self.attached_nodes {
            bc.fix_node(n, self.mesh.vertices[n]);
        }
        bc
    }

    /// A static solver (pattern and symbolic factorization, reused by every solve) for `model`.
    pub fn solver<M: ElasticModel + ?Sized>(&self, model: &M) -> Result<StaticSolver, FemError> {
        StaticSolver::with_bc(model, &self.dirichlet())
    }

    /// Marker positions for node positions `x`.
    pub fn marker_positions(&self, x: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        self.markers
            .iter()
            .map(|e| e.position(&self.mesh.tets, x))
            .collect()
    }

    /// Simulates an example under `model`: the force boundary condition of
    /// [`Self::nodal_forces`] on the patch, attached nodes fixed, equilibrium iterated from `x`
    /// (warm start; attached components are reset to rest).
    pub fn simulate<M: ElasticModel + ?Sized>(
        &self,
        solver: &mut StaticSolver,
        model: &mut M,
        x: &mut [Vector3<f64>],
        forces: &[Vector3<f64>],
        settings: &EquilibriumSettings,
    ) -> EquilibriumReport {
        self.dirichlet().apply(x);
        solver.solve(model, x, forces, None, settings)
    }
}

/// Marker residual r = x_markers(x) − x̄ (3 per observed marker) and its RMS, m.
pub(crate) fn marker_residuals(
    setup: &ProbingSetup,
    example: &ProbeExample,
    x: &[Vector3<f64>],
) -> Vec<f64> {
    let mut r = Vec::with_capacity(3 * example.observed.len());
    for o in &example.observed {
        let p = setup.markers[o.marker].position(&setup.mesh.tets, x);
        r.extend((p - o.position_m).iter());
    }
    r
}

pub(crate) fn rms_of(r: &[f64]) -> f64 {
    if r.is_empty() {
        0.0
    } else {
        (r.iter().map(|v| v * v).sum::<f64>() / (r.len() / 3).max(1) as f64).sqrt()
    }
}
