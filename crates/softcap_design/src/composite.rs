//! Composites (thesis §8.4.1): a 4 × 5 × 2.5 cm block made of N stacked layers ("cells"), each
//! one base material, resting on a table (bottom face fixed) and pressed at the centre of its top
//! face by a probe with the forces of the force–displacement examples. A design m = (m₁ … m_N)
//! is simulated with the quasi-static corotational FEM of thesis §8.2 / §7.2 (incremental
//! loading, per-element E(p(ε)) refreshed every equilibrium iteration), and its response x is the
//! displacement of the top-surface nodes (the "surface displacements") of every example, grouped
//! into one vector as in §8.4.1.
//!
//! Speed: the layered block with a central load is symmetric about the planes x = W/2 and
//! y = L/2, so by default only the quarter x ≤ W/2, y ≤ L/2 is meshed, with the normal
//! displacement fixed on both symmetry planes; the patch load on the planes is split
//! accordingly. This is still the full non-linear FEM of the composite (no linearization);
//! comparisons against the full block are in the tests and in
//! docs/design.md. The sparsity pattern and symbolic Cholesky are built once per simulator and
//! reused for every design.

use crate::error::{DesignError, Result};
use crate::material::BaseMaterial;
use crate::model::CompositeModel;
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use softcap_fem::{DirichletBc, EquilibriumSettings, StaticSolver};
use softcap_mesh::TetMesh;
use std::sync::Arc;

/// Geometry, discretization and load of the composite simulation.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct CompositeSettings {
    /// Block width × length × height [m] (thesis §8.5: 4 × 5 × 2.5 cm).
    pub block_size_m: [f64; 3],
    /// Number of layers N (cells of the design).
    pub layers: usize,
    /// Element cells across the simulated domain (x, y).
    pub lateral_cells: [usize; 2],
    /// Element cells through each layer.
    pub cells_per_layer: usize,
    /// Simulate the symmetric quarter (see module docs).
    pub quarter_symmetry: bool,
    /// Radius of the probe's contact patch [m]; the force is shared equally by the top nodes
    /// within it.
    pub probe_radius_m: f64,
    /// Probe forces of the examples [N], ascending.
    pub forces_n: Vec<f64>,
    /// Load increments between consecutive examples (incremental loading, bickel2009 §3.4).
    pub increments: usize,
    /// Equilibrium iterations.
    pub equilibrium: EquilibriumSettings,
}

impl Default for CompositeSettings {
    fn default() -> Self {
        Self {
            block_size_m: [0.04, 0.05, 0.025],
            layers: 5,
            lateral_cells: [2, 3],
            cells_per_layer: 1,
            quarter_symmetry: true,
            probe_radius_m: 0.009,
            forces_n: vec![2.0, 4.0, 6.0, 8.0, 10.0],
            increments: 1,
            equilibrium: EquilibriumSettings {
                max_iterations: 200,
                displacement_tol_rel: 1e-6,
                residual_tol_rel: 1e-6,
                line_search: false,
                ..EquilibriumSettings::default()
            },
        }
    }
}

/// The meshed layered block with its boundary conditions and probe patch.
#[derive(Clone, Debug)]
pub struct LayeredBlock {
    /// Tet mesh [m].
    pub mesh: TetMesh,
    /// Layer (cell) index of every element, 0 = bottom.
    pub element_layer: Vec<usize>,
    /// Top-surface nodes whose displacements form the response, sorted.
    pub top_nodes: Vec<usize>,
    /// Probe patch: (node, share of the example force).
    pub patch: Vec<(usize, f64)>,
    /// Bottom fixed, symmetry planes' normal components fixed.
    pub bc: DirichletBc,
    /// Number of layers.
    pub layers: usize,
}

impl LayeredBlock {
    /// Meshes the block with layer thicknesses `layer_thickness_m` (bottom first; their sum is
    /// the block height). Equal thicknesses: [`LayeredBlock::uniform`].
    pub fn new(settings: &CompositeSettings, layer_thickness_m: &[f64]) -> Result<Self> {
        let n = layer_thickness_m.len();
        if n == 0
            || layer_thickness_m
                .iter()
                .any(|t| !(t.is_finite() && *t > 0.0))
        {
            return Err(DesignError::Invalid {
                field: "layer thicknesses",
                reason: format!("need ≥ 1 positive thickness, got {layer_thickness_m:?}"),
            });
        }
        let [w, l, _] = settings.block_size_m;
        let (w_dom, l_dom) = if settings.quarter_symmetry {
            (0.5 * w, 0.5 * l)
        } else {
            (w, l)
        };
        let cpl = settings.cells_per_layer.max(1);
        let nz = n * cpl;
        let [nx, ny] = settings.lateral_cells.map(|c| c.max(1));
        // z = k exactly, then mapped to the layer boundaries.
        let mut mesh =
            softcap_mesh::box_tet_mesh([0.0; 3], [w_dom, l_dom, nz as f64], [nx, ny, nz]);
        let mut z_level = vec![0.0; nz + 1];
        for k in 1..=nz {
            z_level[k] = z_level[k - 1] + layer_thickness_m[(k - 1) / cpl] / cpl as f64;
        }
        for v in &mut mesh.vertices {
            let k = v.z.round() as usize;
            v.z = z_level[k.min(nz)];
        }
        let element_layer = mesh
            .tets
            .iter()
            .map(|t| {
                let zc: f64 = t.iter().map(|&i| mesh.vertices[i].z).sum::<f64>() / 4.0;
                let mut layer = 0;
                while layer + 1 < n && zc > z_level[(layer + 1) * cpl] {
                    layer += 1;
                }
                layer
            })
            .collect();
        let top = z_level[nz];
        let eps = 1e-9;
        let mut bc = DirichletBc::new();
        let mut top_nodes = Vec::new();
        let centre = (0.5 * w, 0.5 * l);
        let mut patch_nodes = Vec::new();
        for (i, v) in mesh.vertices.iter().enumerate() {
            if v.z.abs() < eps {
                bc.fix_node(i, *v);
                continue;
            }
            if settings.quarter_symmetry {
                if (v.x - w_dom).abs() < eps {
                    bc.fix_dof(3 * i, v.x);
                }
                if (v.y - l_dom).abs() < eps {
                    bc.fix_dof(3 * i + 1, v.y);
                }
            }
            if (v.z - top).abs() < eps {
                top_nodes.push(i);
                let r = ((v.x - centre.0).powi(2) + (v.y - centre.1).powi(2)).sqrt();
                if r <= settings.probe_radius_m + eps {
                    // Copies of this node in the full block (symmetry multiplicity).
                    let copies = if settings.quarter_symmetry {
                        let on_x = (v.x - w_dom).abs() < eps;
                        let on_y = (v.y - l_dom).abs() < eps;
                        match (on_x, on_y) {
                            (true, true) => 1.0,
                            (true, false) | (false, true) => 2.0,
                            _ => 4.0,
                        }
                    } else {
                        1.0
                    };
                    patch_nodes.push((i, copies));
                }
            }
        }
        if patch_nodes.is_empty() {
            return Err(DesignError::Invalid {
                field: "probe_radius_m",
                reason: "no top node lies under the probe".into(),
            });
        }
        // Full-block patch: every copy carries F / N_full; a quarter node carries its share
        // copies/4 of that (the quarter carries a quarter of the load).
        let n_full: f64 = patch_nodes.iter().map(|p| p.1).sum();
        let patch = patch_nodes
            .into_iter()
            .map(|(i, c)| {
                let share = if settings.quarter_symmetry {
                    c / (4.0 * n_full)
                } else {
                    1.0 / n_full
                };
                (i, share)
            })
            .collect();
        Ok(Self {
            mesh,
            element_layer,
            top_nodes,
            patch,
            bc,
            layers: n,
        })
    }

    /// Equal layer thicknesses.
    pub fn uniform(settings: &CompositeSettings) -> Result<Self> {
        let n = settings.layers.max(1);
        Self::new(settings, &vec![settings.block_size_m[2] / n as f64; n])
    }

    /// Per-element material indices of `design` (material per layer).
    pub fn element_materials(&self, design: &[usize]) -> Vec<usize> {
        self.element_layer.iter().map(|&l| design[l]).collect()
    }

    /// Total probe force carried by the simulated domain for an example force `force_n`.
    pub fn domain_force(&self, force_n: f64) -> f64 {
        force_n * self.patch.iter().map(|p| p.1).sum::<f64>()
    }
}

/// Response of one design to all examples.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CompositeResponse {
    /// Top-node displacements [m], example-major: (example, top node, xyz).
    pub displacements_m: Vec<f64>,
    /// Probe indentation per example [m]: patch-share-weighted mean of −u_z over the patch.
    pub probe_displacement_m: Vec<f64>,
    /// Equilibrium iterations used in total.
    pub iterations: usize,
}

/// Simulates designs on one mesh; owns the symbolic factorization (create one per thread).
pub struct CompositeSimulator {
    block: Arc<LayeredBlock>,
    settings: CompositeSettings,
    model: CompositeModel,
    solver: StaticSolver,
}

impl std::fmt::Debug for CompositeSimulator {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CompositeSimulator")
            .field("nodes", &self.block.mesh.vertices.len())
            .field("elements", &self.block.mesh.tets.len())
            .finish()
    }
}

impl CompositeSimulator {
    /// Simulator of `block` with the base-material library `materials`.
    pub fn new(
        block: Arc<LayeredBlock>,
        materials: Arc<Vec<BaseMaterial>>,
        settings: &CompositeSettings,
    ) -> Result<Self> {
        if settings.forces_n.is_empty()
            || settings
                .forces_n
                .windows(2)
                .any(|w| w[1] <= w[0] || w[1].is_nan())
            || settings
                .forces_n
                .iter()
                .any(|f| !(f.is_finite() && *f > 0.0))
        {
            return Err(DesignError::Invalid {
                field: "forces_n",
                reason: format!(
                    "need positive ascending forces, got {:?}",
                    settings.forces_n
                ),
            });
        }
        let model = CompositeModel::new(&block.mesh, materials, vec![0; block.mesh.tets.len()])?;
        let solver = StaticSolver::new(&model, &block.bc.dofs())?;
        Ok(Self {
            block,
            settings: settings.clone(),
            model,
            solver,
        })
    }

    /// The block.
    pub fn block(&self) -> &LayeredBlock {
        &self.block
    }

    /// Settings.
    pub fn settings(&self) -> &CompositeSettings {
        &self.settings
    }

    /// Simulates `design` (one material index per layer) under every example force.
    pub fn simulate(&mut self, design: &[usize]) -> Result<CompositeResponse> {
        if design.len() != self.block.layers {
            return Err(DesignError::Invalid {
                field: "design",
                reason: format!("{} cells for {} layers", design.len(), self.block.layers),
            });
        }
        let em = self.block.element_materials(design);
        self.model.set_element_materials(&em);
        let rest = self.block.mesh.vertices.clone();
        let mut x = rest.clone();
        self.block.bc.apply(&mut x);
        let n_top = self.block.top_nodes.len();
        let mut out = CompositeResponse {
            displacements_m: Vec::with_capacity(self.settings.forces_n.len() * n_top * 3),
            probe_displacement_m: Vec::with_capacity(self.settings.forces_n.len()),
            iterations: 0,
        };
        let mut f_ext = vec![Vector3::zeros(); rest.len()];
        let mut prev = 0.0;
        let inc = self.settings.increments.max(1);
        for &force in &self.settings.forces_n {
            for s in 1..=inc {
                let f = prev + (force - prev) * s as f64 / inc as f64;
                for &(node, share) in &self.block.patch {
                    f_ext[node] = Vector3::new(0.0, 0.0, -f * share);
                }
                let rep = self.solver.solve(
                    &mut self.model,
                    &mut x,
                    &f_ext,
                    None,
                    &self.settings.equilibrium,
                );
                out.iterations += rep.iterations;
                if !rep.converged() {
                    return Err(DesignError::NotConverged {
                        what: format!("design {design:?} at {f:.3} N"),
                        status: format!("{:?}", rep.status),
                    });
                }
            }
            prev = force;
            for &i in &self.block.top_nodes {
                let u = x[i] - rest[i];
                out.displacements_m.extend_from_slice(&[u.x, u.y, u.z]);
            }
            let total: f64 = self.block.patch.iter().map(|p| p.1).sum();
            let d: f64 = self
                .block
                .patch
                .iter()
                .map(|&(i, s)| -(x[i].z - rest[i].z) * s)
                .sum::<f64>()
                / total;
            out.probe_displacement_m.push(d);
        }
        Ok(out)
    }
}

/// RMS displacement error over markers: √(‖x − x̄‖² / (examples · markers)) [m].
pub fn rms_displacement_error(x: &[f64], target: &[f64]) -> f64 {
    let n = (x.len() / 3).max(1) as f64;
    (x.iter()
        .zip(target)
        .map(|(a, b)| (a - b) * (a - b))
        .sum::<f64>()
        / n)
        .sqrt()
}
