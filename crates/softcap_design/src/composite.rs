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
//! comparisons against the full block are in the tests and in docs/design.md.
//!
//! Equilibrium is solved by Newton's method on the free degrees of freedom with the exact
//! element tangent ([`CompositeModel::state_tangent`]: material-consistent C_t = ∂σ/∂ε in
//! closed form, plus the rotation derivative), a band LU of the (≈ 150-dof) system per
//! iteration, the residual checked before the tangent is built, and a linear predictor from the
//! previous two load levels (the rest state included). The converged state is the same fixed
//! point as the §8.2 "refresh E, re-solve" iteration of `softcap_fem::StaticSolver` (tested to
//! 1e-9 m), at a fraction of the iterations.

use crate::error::{DesignError, Result};
use crate::material::BaseMaterial;
use crate::model::CompositeModel;
use nalgebra::{DMatrix, DVector, Vector3};
use serde::{Deserialize, Serialize};
use softcap_fem::{DirichletBc, EquilibriumSettings};
use softcap_mesh::TetMesh;
use std::sync::Arc;

/// Geometry, discretization and load of the composite simulation.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CompositeSettings {
    /// Block width × length × height \[m\] (thesis §8.5: 4 × 5 × 2.5 cm).
    pub block_size_m: [f64; 3],
    /// Number of layers N (cells of the design).
    pub layers: usize,
    /// Element cells across the simulated domain (x, y).
    pub lateral_cells: [usize; 2],
    /// Element cells through each layer.
    pub cells_per_layer: usize,
    /// Simulate the symmetric quarter (see module docs).
    pub quarter_symmetry: bool,
    /// Radius of the probe's contact patch \[m\]; the force is shared equally by the top nodes
    /// within it.
    pub probe_radius_m: f64,
    /// Probe forces of the examples \[N\], ascending.
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
    /// Tet mesh \[m\].
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
        Self::with_boundary(settings, mesh, element_layer, n, settings.quarter_symmetry)
    }

    /// Boundary conditions, top nodes and probe patch of a meshed block (`quarter`: the mesh
    /// is the quarter x ≤ W/2, y ≤ L/2 with symmetry planes).
    fn with_boundary(
        settings: &CompositeSettings,
        mesh: TetMesh,
        element_layer: Vec<usize>,
        n: usize,
        quarter: bool,
    ) -> Result<Self> {
        let [w, l, _] = settings.block_size_m;
        let (w_dom, l_dom) = if quarter { (0.5 * w, 0.5 * l) } else { (w, l) };
        let top = mesh
            .vertices
            .iter()
            .map(|v| v.z)
            .fold(f64::NEG_INFINITY, f64::max);
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
            if quarter {
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
                    let copies = if quarter {
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
                let share = if quarter {
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

    /// The full block meshed as the quarter of [`LayeredBlock::new`] and its mirror images
    /// about x = W/2 and y = L/2 (reflected tets re-oriented), without symmetry planes: the
    /// full-block twin of the quarter model, equal to it up to solver tolerance when the
    /// materials are symmetric about both planes (isotropic, or transversely isotropic about z).
    /// `settings.lateral_cells` are the cells of the quarter.
    pub fn mirrored_full(settings: &CompositeSettings, layer_thickness_m: &[f64]) -> Result<Self> {
        let quarter = Self::new(
            &CompositeSettings {
                quarter_symmetry: true,
                ..settings.clone()
            },
            layer_thickness_m,
        )?;
        let [w, l, _] = settings.block_size_m;
        let mut vertices: Vec<Vector3<f64>> = Vec::new();
        let mut index: std::collections::BTreeMap<[i64; 3], usize> = Default::default();
        let mut tets = Vec::new();
        let mut element_layer = Vec::new();
        for (mx, my) in [(false, false), (true, false), (false, true), (true, true)] {
            let map: Vec<usize> = quarter
                .mesh
                .vertices
                .iter()
                .map(|v| {
                    let p = Vector3::new(
                        if mx { w - v.x } else { v.x },
                        if my { l - v.y } else { v.y },
                        v.z,
                    );
                    let key = [p.x, p.y, p.z].map(|c| (c * 1e9).round() as i64);
                    *index.entry(key).or_insert_with(|| {
                        vertices.push(p);
                        vertices.len() - 1
                    })
                })
                .collect();
            for (t, &layer) in quarter.mesh.tets.iter().zip(&quarter.element_layer) {
                let mut tet = t.map(|i| map[i]);
                if mx != my {
                    tet.swap(1, 2); // one reflection flips the orientation
                }
                tets.push(tet);
                element_layer.push(layer);
            }
        }
        let mesh = TetMesh { vertices, tets };
        Self::with_boundary(settings, mesh, element_layer, quarter.layers, false)
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
    /// Top-node displacements \[m\], example-major: (example, top node, xyz).
    pub displacements_m: Vec<f64>,
    /// Probe indentation per example \[m\]: patch-share-weighted mean of −u_z over the patch.
    pub probe_displacement_m: Vec<f64>,
    /// Equilibrium iterations used in total.
    pub iterations: usize,
}

/// Simulates designs on one mesh; owns the symbolic factorization (create one per thread).
pub struct CompositeSimulator {
    block: Arc<LayeredBlock>,
    settings: CompositeSettings,
    model: CompositeModel,
    /// Global dof 3·node + c → index among the free dofs (`usize::MAX`: Dirichlet).
    free_index: Vec<usize>,
    n_free: usize,
    length_scale_m: f64,
    /// Half-bandwidth of the free-dof system (max |i − j| of coupled free dofs).
    band: usize,
    /// Free-dof index of every element's 12 dofs (`usize::MAX`: Dirichlet).
    element_dofs: Vec<[usize; 12]>,
    /// Tangent in compact band storage: row i holds columns i − band … i + band
    /// (`band_index`), n_free × (2 band + 1).
    matrix: Vec<f64>,
    /// Copy of the assembled band (dense-LU fallback).
    matrix_copy: Vec<f64>,
    rhs: Vec<f64>,
    /// Per-element state of the current iterate.
    states: Vec<crate::model::ElementState>,
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
        let n_dof = 3 * block.mesh.vertices.len();
        let mut fixed = vec![false; n_dof];
        for d in block.bc.dofs() {
            if d < n_dof {
                fixed[d] = true;
            }
        }
        let mut free_index = vec![usize::MAX; n_dof];
        let mut n_free = 0;
        for (d, f) in fixed.iter().enumerate() {
            if !f {
                free_index[d] = n_free;
                n_free += 1;
            }
        }
        let (mut lo, mut hi) = (
            Vector3::repeat(f64::INFINITY),
            Vector3::repeat(f64::NEG_INFINITY),
        );
        for v in &block.mesh.vertices {
            lo = lo.inf(v);
            hi = hi.sup(v);
        }
        let mut band = 0;
        let mut element_dofs = Vec::with_capacity(block.mesh.tets.len());
        for t in &block.mesh.tets {
            let mut dofs = [usize::MAX; 12];
            for (a, &v) in t.iter().enumerate() {
                for c in 0..3 {
                    dofs[3 * a + c] = free_index[3 * v + c];
                }
            }
            let free = dofs.iter().copied().filter(|&i| i != usize::MAX);
            if let (Some(a), Some(b)) = (free.clone().min(), free.max()) {
                band = band.max(b - a);
            }
            element_dofs.push(dofs);
        }
        let width = 2 * band + 1;
        let state = crate::model::ElementState {
            rotation: nalgebra::Matrix3::identity(),
            stretch: nalgebra::Matrix3::identity(),
            sigma: nalgebra::Matrix3::zeros(),
            tangent: nalgebra::Matrix6::zeros(),
        };
        Ok(Self {
            block,
            settings: settings.clone(),
            free_index,
            n_free,
            length_scale_m: (hi - lo).norm(),
            band,
            element_dofs,
            matrix: vec![0.0; n_free * width],
            matrix_copy: vec![0.0; n_free * width],
            rhs: vec![0.0; n_free],
            states: vec![state; model.num_elements()],
            model,
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
        // Previous two converged states and their loads (linear predictor).
        // The rest state (zero load) is the first entry, so the second level is extrapolated too.
        let mut history: Vec<(f64, Vec<Vector3<f64>>)> = vec![(0.0, x.clone())];
        let forces = self.settings.forces_n.clone();
        for &force in &forces {
            for s in 1..=inc {
                let f = prev + (force - prev) * s as f64 / inc as f64;
                for &(node, share) in &self.block.patch {
                    f_ext[node] = Vector3::new(0.0, 0.0, -f * share);
                }
                if let [.., (f0, x0), (f1, x1)] = history.as_slice() {
                    let t = (f - f1) / (f1 - f0);
                    for (i, xi) in x.iter_mut().enumerate() {
                        *xi = x1[i] + (x1[i] - x0[i]) * t;
                    }
                }
                match self.equilibrium(&mut x, &f_ext) {
                    Ok(it) => out.iterations += it,
                    Err(status) => {
                        return Err(DesignError::NotConverged {
                            what: format!("design {design:?} at {f:.3} N"),
                            status,
                        });
                    }
                }
                if history.len() == 2 {
                    history.remove(0);
                }
                history.push((f, x.clone()));
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

impl CompositeSimulator {
    /// Newton iterations to equilibrium f_int(x) = f_ext on the free dofs (see module docs);
    /// converged when the last update is ≤ `displacement_tol_rel` × the mesh diagonal and the
    /// residual ≤ `residual_tol_rel` × ‖f_ext‖. Each iteration evaluates the element states and
    /// the residual first and assembles the (exact) tangent only if not yet converged, so the
    /// final check costs no tangent. Returns the Newton steps taken, or the failure status.
    fn equilibrium(
        &mut self,
        x: &mut [Vector3<f64>],
        f_ext: &[Vector3<f64>],
    ) -> std::result::Result<usize, String> {
        let eq = &self.settings.equilibrium;
        let (max_iterations, tol_x) = (
            eq.max_iterations.max(1),
            eq.displacement_tol_rel * self.length_scale_m,
        );
        let f_norm = f_ext.iter().map(|f| f.norm_squared()).sum::<f64>().sqrt();
        let tol_r = eq.residual_tol_rel * f_norm.max(f64::MIN_POSITIVE);
        let mut last_dx = f64::INFINITY;
        let (n, band) = (self.n_free, self.band);
        let width = 2 * band + 1;
        for it in 0..max_iterations {
            // Residual r = f_ext − f_int on the free dofs.
            self.rhs.fill(0.0);
            for (node, f) in f_ext.iter().enumerate() {
                for c in 0..3 {
                    let i = self.free_index[3 * node + c];
                    if i != usize::MAX {
                        self.rhs[i] += f[c];
                    }
                }
            }
            for e in 0..self.states.len() {
                let st = self.model.element_state(e, x);
                let fe = self.model.state_forces(e, &st);
                self.states[e] = st;
                let dofs = &self.element_dofs[e];
                for a in 0..4 {
                    for c in 0..3 {
                        let i = dofs[3 * a + c];
                        if i != usize::MAX {
                            self.rhs[i] -= fe[a][c];
                        }
                    }
                }
            }
            let r_norm = self.rhs.iter().map(|v| v * v).sum::<f64>().sqrt();
            if !r_norm.is_finite() {
                return Err("non-finite residual".into());
            }
            if it > 0 && last_dx <= tol_x && r_norm <= tol_r.max(1e-12 * f_norm) {
                return Ok(it);
            }
            // Tangent in band storage.
            self.matrix.fill(0.0);
            for e in 0..self.states.len() {
                let ke = self.model.state_tangent(e, &self.states[e]);
                let dofs = &self.element_dofs[e];
                for p in 0..12 {
                    let i = dofs[p];
                    if i == usize::MAX {
                        continue;
                    }
                    let row = i * width + band - i;
                    for q in 0..12 {
                        let j = dofs[q];
                        if j != usize::MAX {
                            self.matrix[row + j] += ke[(p, q)];
                        }
                    }
                }
            }
            if !banded_solve(
                &mut self.matrix,
                &mut self.matrix_copy,
                &mut self.rhs,
                n,
                band,
            ) {
                return Err(format!("singular tangent at iteration {it}"));
            }
            let dx = &self.rhs;
            last_dx = dx.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            if !last_dx.is_finite() {
                return Err("non-finite update".into());
            }
            for (node, xi) in x.iter_mut().enumerate() {
                for c in 0..3 {
                    let i = self.free_index[3 * node + c];
                    if i != usize::MAX {
                        xi[c] += dx[i];
                    }
                }
            }
        }
        Err(format!(
            "no convergence in {max_iterations} Newton iterations (last update {last_dx:.3e} m)"
        ))
    }

    /// Number of free degrees of freedom of the equilibrium system.
    pub fn free_dofs(&self) -> usize {
        self.n_free
    }
}

/// Solves A x = b in place for an n × n matrix in compact band storage (row i holds the
/// columns i − band … i + band at `i·(2 band + 1) + (j + band − i)`): Gaussian elimination
/// restricted to the band, n·band² operations on contiguous rows. Partial pivoting would widen
/// the upper band, so pivots are not exchanged: the composite tangent is close to symmetric
/// positive definite (stiffness of a stable material plus a small stress/rotation term), for
/// which elimination without pivoting is stable. A pivot ≤ 1e-14 × the largest diagonal entry
/// falls back to nalgebra's dense LU with partial pivoting on the original matrix (saved in
/// `copy`). Returns false if that is singular too.
fn banded_solve(a: &mut [f64], copy: &mut [f64], b: &mut [f64], n: usize, band: usize) -> bool {
    let w = 2 * band + 1;
    copy.copy_from_slice(a);
    let diag_max = (0..n).fold(0.0f64, |m, i| m.max(a[i * w + band].abs()));
    let mut ok = diag_max > 0.0 && diag_max.is_finite();
    if ok {
        'elim: for k in 0..n {
            let pivot = a[k * w + band];
            if pivot.abs() <= 1e-14 * diag_max || !pivot.is_finite() {
                ok = false;
                break 'elim;
            }
            let end = (k + band + 1).min(n);
            let len = end - k - 1;
            let rk = k * w + band + 1; // row k, column k + 1
            for i in k + 1..end {
                let lik = i * w + k + band - i; // row i, column k
                let l = a[lik] / pivot;
                if l == 0.0 {
                    continue;
                }
                a[lik] = l;
                let (head, tail) = a.split_at_mut(lik + 1); // row i, columns k + 1 … start tail
                let row_k = &head[rk..rk + len];
                for (t, v) in tail[..len].iter_mut().zip(row_k) {
                    *t -= l * v;
                }
                b[i] -= l * b[k];
            }
        }
    }
    if ok {
        for k in (0..n).rev() {
            let end = (k + band + 1).min(n);
            let rk = k * w + band + 1;
            let mut s = b[k];
            for (v, bj) in a[rk..rk + (end - k - 1)].iter().zip(&b[k + 1..end]) {
                s -= v * bj;
            }
            b[k] = s / a[k * w + band];
        }
        return true;
    }
    let mut m = DMatrix::zeros(n, n);
    for i in 0..n {
        for j in i.saturating_sub(band)..(i + band + 1).min(n) {
            m[(i, j)] = copy[i * w + j + band - i];
        }
    }
    match m.lu().solve(&DVector::from_column_slice(b)) {
        Some(x) => {
            b.copy_from_slice(x.as_slice());
            true
        }
        None => false,
    }
}

/// RMS displacement error over markers: √(‖x − x̄‖² / (examples · markers)) \[m\].
pub fn rms_displacement_error(x: &[f64], target: &[f64]) -> f64 {
    let n = (x.len() / 3).max(1) as f64;
    (x.iter()
        .zip(target)
        .map(|(a, b)| (a - b) * (a - b))
        .sum::<f64>()
        / n)
        .sqrt()
}
