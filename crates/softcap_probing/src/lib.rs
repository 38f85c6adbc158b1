//! # softcap_probing — the probing layer the stages share
//!
//! Probing examples: the one simulator and fitter of bickel2009 §3–4 that every stage uses
//! (tissue, diagnose), between the FEM kernels of `softcap_fem` and the stage crates.
//!
//! * [`ProbingSetup`] — a tet mesh with embedded markers (barycentric, [`softcap_mesh::TetLocator`]),
//!   its surface regions (bickel2009 §4.1: *attached* nodes from the support plane, the
//!   *probed* patch under the tip of each example, the rest *free*), the umbrella adjacency of
//!   eq. 9 and a factorization pattern reused by every solve.
//! * [`ProbeExample`] — one captured deformation: frame, time, probe pose, measured force and
//!   observed markers.
//! * [`ProbingSetup::simulate`] — the elastostatic response to the measured force spread over the
//!   contact patch as nodal forces (force boundary condition of §4.1; Fig. 7 "distribute it
//!   uniformly"), with any [`ElasticModel`].
//! * [`fit_example`] — per-example (λ_e, α_e) by Levenberg–Marquardt on eq. 9,
//!   `min_p Σ‖x_i(p, F̄) − x̄_i‖² + γ‖Lp‖²`, with the adjoint Jacobian of the appendix (eq. 10–12,
//!   [`Sensitivity::jt_times`]: one solve per observed marker coordinate with one factorization),
//!   the umbrella Laplacian L over tets sharing a vertex, and Poisson's ratio kept physically
//!   valid by box bounds on the parameterization (log λ_e, ν_e = α_e/λ_e).
//! * [`fit_homogeneous`] — the average-fit homogeneous linear corotational model (bickel2009
//!   Fig. 8 baseline): one (λ, α) for all tets and all examples.
//! * [`StrainSpaceMaterial`] — the per-element strain-space RBF p(ε) = Σ wᵢ φ(‖ε − εᵢ‖), φ(r) = r
//!   (eq. 8), with greedy basis selection (§4.2, [`softcap_core::greedy_rbf`]), implementing
//!   [`StrainDependentParams`] for synthesis by incremental loading (§3.4).
//! * [`simulate_probe_contact`] — synthesis of a novel probe (shape, pose, force) with rigid-probe
//!   contact (§3.4): incremental loading in depth, then a secant search on the depth until the
//!   axial contact force equals the requested force.

use std::sync::Arc;

use nalgebra::{Isometry3, Vector3, Vector6};
use serde::{Deserialize, Serialize};
use softcap_mesh::{TetEmbedding, TetLocator, TetMesh};

use softcap_fem::{
    ContactProblem, ContactSettings, CorotationalModel, DirichletBc, ElasticModel,
    EquilibriumReport, EquilibriumSettings, FemError, LinearParams, Probe, Sensitivity,
    SolveStatus, StaticSolver, StiffnessKind, StrainDependentParams, TipShape,
};

fn probing_error(what: impl Into<String>) -> FemError {
    FemError::Probing { what: what.into() }
}

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

/// How the measured probe force is spread over the footprint (bickel2009 §4.1, Fig. 7:
/// "distribute it uniformly" over the contact area).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FootprintLoad {
    /// On the boundary nodes inside the footprint ([`ProbingSetup::patch_nodes`]), in
    /// proportion to their lumped boundary areas.
    #[default]
    Lumped,
    /// The consistent nodal loads of a uniform pressure over the footprint disk
    /// ([`ProbingSetup::load_weights`]): centred on the probe axis whatever the mesh.
    Consistent,
    /// The consistent nodal loads of the contact pressure of a rigid flat punch of radius a
    /// (a disk tip) on an elastic half-space, p(r) = F / (2πa·√(a² − r²)) (Boussinesq; Sneddon
    /// 1946; Johnson, *Contact Mechanics* 1985, ch. 3, axisymmetric pressures): rim-concentrated,
    /// the pressure under which the surface displacement is uniform over the footprint — the
    /// flat dent a rigid disk makes. Sampled with rings of equal load
    /// ([`Self::load_fraction_inside`]).
    FlatPunch,
    /// The consistent nodal loads of the Hertz pressure of a rigid sphere with contact radius a,
    /// p(r) = 3F / (2πa²) · √(1 − r²/a²) (Hertz 1882; Johnson, *Contact Mechanics* 1985, §4.2):
    /// centre-concentrated, vanishing at the rim — the sphere tip's
    /// analogue of [`Self::FlatPunch`].
    Hertz,
}

impl FootprintLoad {
    /// Every load, in declaration order.
    pub const ALL: [Self; 4] = [Self::Lumped, Self::Consistent, Self::FlatPunch, Self::Hertz];

    /// The name of the load in settings files (serde's kebab-case name) and reports.
    pub fn name(self) -> &'static str {
        match self {
            Self::Lumped => "lumped",
            Self::Consistent => "consistent",
            Self::FlatPunch => "flat-punch",
            Self::Hertz => "hertz",
        }
    }

    /// The load named `name` ([`Self::name`]), `None` for an unknown name.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|l| l.name() == name)
    }

    /// Share of the probe force inside radius ρ·a of the footprint centre, ρ ∈ [0, 1], for the
    /// pressure distributions over a disk (`Lumped` counts as uniform pressure):
    /// uniform ρ²; flat punch 1 − √(1 − ρ²); Hertz 1 − (1 − ρ²)^{3/2} (the integrals
    /// ∫₀^{ρa} p(r) 2πr dr / F of the pressures of [`Self::Consistent`], [`Self::FlatPunch`],
    /// [`Self::Hertz`]).
    pub fn load_fraction_inside(self, rho: f64) -> f64 {
        let rho2 = rho.clamp(0.0, 1.0).powi(2);
        match self {
            Self::Lumped | Self::Consistent => rho2,
            Self::FlatPunch => 1.0 - (1.0 - rho2).sqrt(),
            Self::Hertz => 1.0 - (1.0 - rho2).powf(1.5),
        }
    }

    /// The radius fraction ρ ∈ [0, 1] inside which the share `u` ∈ [0, 1] of the force lies:
    /// the inverse of [`Self::load_fraction_inside`] — uniform √u; flat punch √(u(2 − u));
    /// Hertz √(1 − (1 − u)^{2/3}). Ring k of R sits at ρ(u = (k + ½)/R), the midpoint in load
    /// of its share 1/R, so every sample carries the same load.
    pub fn ring_radius_fraction(self, u: f64) -> f64 {
        let u = u.clamp(0.0, 1.0);
        match self {
            Self::Lumped | Self::Consistent => u.sqrt(),
            Self::FlatPunch => (u * (2.0 - u)).sqrt(),
            Self::Hertz => (1.0 - (1.0 - u).powf(2.0 / 3.0)).max(0.0).sqrt(),
        }
    }
}

/// Settings of the contact patch of a force boundary condition.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct PatchSettings {
    /// Radius of the probe footprint, m (disk radius, or the contact radius of a sphere).
    pub radius_m: f64,
    /// Boundary nodes up to this far (along the axis) behind the first surface met by the probe
    /// belong to the patch, as a fraction of `radius_m` ([`FootprintLoad::Lumped`]).
    pub depth_window: f64,
    /// The load distribution.
    pub load: FootprintLoad,
    /// Rings of equal load the footprint disk is sampled with (every load but
    /// [`FootprintLoad::Lumped`]; of equal area under the uniform pressure of
    /// [`FootprintLoad::Consistent`]).
    pub rings: usize,
    /// Samples per ring (equally spaced in angle, every other ring turned by half a step).
    pub samples_per_ring: usize,
}

impl Default for PatchSettings {
    fn default() -> Self {
        Self {
            radius_m: 0.005,
            depth_window: 0.5,
            load: FootprintLoad::Lumped,
            // 192 samples: the load's first moment is exact for any count (symmetric rings);
            // 8 × 24 resolves the footprint's partition among triangles of a mesh whose surface
            // spacing is about the tip radius to ≈ 1/192 of the force.
            rings: 8,
            samples_per_ring: 24,
        }
    }
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

    /// The probed region of an example (bickel2009 §4.1 region (i)): boundary nodes whose rest
    /// position lies within `radius_m` of the probe axis line and at most
    /// `depth_window · radius_m` behind the first boundary node the probe meets. When no node
    /// lies inside the footprint (coarse mesh) the boundary node closest to the axis is used.
    pub fn patch_nodes(&self, example: &ProbeExample, patch: &PatchSettings) -> Vec<usize> {
        let axis = example.axis.normalize();
        let coords: Vec<(usize, f64, f64)> = self
            .boundary_nodes
            .iter()
            .filter(|n| self.attached_nodes.binary_search(n).is_err())
            .map(|&n| {
                let d = self.mesh.vertices[n] - example.tip_m;
                let along = d.dot(&axis);
                (n, along, (d - axis * along).norm())
            })
            .collect();
        let inside: Vec<&(usize, f64, f64)> =
            coords.iter().filter(|c| c.2 <= patch.radius_m).collect();
        if inside.is_empty() {
            return coords
                .iter()
                .min_by(|a, b| a.2.total_cmp(&b.2).then(a.0.cmp(&b.0)))
                .map(|c| vec![c.0])
                .unwrap_or_default();
        }
        let first = inside.iter().map(|c| c.1).fold(f64::INFINITY, f64::min);
        let window = patch.depth_window * patch.radius_m;
        inside
            .iter()
            .filter(|c| c.1 <= first + window)
            .map(|c| c.0)
            .collect()
    }

    /// The share of the probe force each surface node carries (node, weight; increasing
    /// nodes, weights sum to 1) under `patch.load`: [`FootprintLoad::Lumped`] — the patch
    /// nodes ([`Self::patch_nodes`]) in proportion to their lumped boundary areas (uniform
    /// pressure, bickel2009 §4.1 / Fig. 7); [`FootprintLoad::Consistent`],
    /// [`FootprintLoad::FlatPunch`], [`FootprintLoad::Hertz`] — below.
    ///
    /// Consistent: the nodal loads of a uniform pressure over the probe's footprint disk, the
    /// probed region of bickel2009 §4.1 (Fig. 7: the measured force "distributed uniformly"
    /// over the contact area). FlatPunch / Hertz: the same with the rigid flat punch's
    /// (Sneddon) or the rigid sphere's (Hertz) axisymmetric pressure in place of the uniform
    /// one; only the ring radii differ.
    ///
    /// For a pressure p over the footprint D on the surface S the consistent load of node i is
    /// f_i = ∫_D N_i p dA (N_i the linear surface shape functions), so Σ_i f_i = F and
    /// Σ_i f_i x_i = ∫_D x p dA: the load has the tip's resultant AND its first moment, centred
    /// on the probe axis whatever the mesh. The lumped load puts it on the 1–3 nodes that fall
    /// inside the footprint of a mesh whose spacing is about the tip radius, off the axis by up
    /// to half a spacing — a dent of the wrong shape in the wrong place, which the material fit
    /// then compensates; against a rigid-tip truth (the e2e suite) it is most of the elastic
    /// default model's error near the probe (docs/diagnose.md, "footprint loads").
    ///
    /// Quadrature: `rings` × `samples_per_ring` points of equal load on the disk of radius
    /// `radius_m` around the tip in the plane normal to the axis: ring k of R at radius
    /// a·ρ((k + ½)/R), ρ the inverse cumulative load of the pressure
    /// ([`FootprintLoad::ring_radius_fraction`]; a·√((k + ½)/R), equal area, for the uniform
    /// pressure). Each is cast along the probe axis onto the outward-facing
    /// (n·axis < 0) load triangle whose hit lies nearest the tip (the surface the tip presses,
    /// also on a curved or folded surface), and its share 1/(R·S) goes to that triangle's three
    /// vertices by the hit's barycentric weights. Samples that miss the surface (a footprint
    /// over the object's edge) carry nothing and the rest is rescaled to the whole force (the
    /// measured force is carried by the part in contact). When every sample misses, the force
    /// goes to the closest surface point to the tip. Shares on attached vertices are taken up
    /// by the support.
    pub fn load_weights(&self, example: &ProbeExample, patch: &PatchSettings) -> Vec<(usize, f64)> {
        if patch.load == FootprintLoad::Lumped {
            let mut nodes = self.patch_nodes(example, patch);
            nodes.sort_unstable();
            let total: f64 = nodes.iter().map(|&n| self.node_areas_m2[n]).sum();
            let count = nodes.len() as f64;
            return nodes
                .into_iter()
                .map(|n| {
                    let w = if total > 0.0 {
                        self.node_areas_m2[n] / total
                    } else {
                        1.0 / count
                    };
                    (n, w)
                })
                .collect();
        }
        let axis = example.axis.try_normalize(1e-12).unwrap_or(-Vector3::z());
        let radius = patch.radius_m.max(0.0);
        let v = &self.mesh.vertices;
        // Front-facing load triangles that can meet a line parallel to the axis within the
        // footprint: lateral distance of the centroid ≤ radius + the triangle's extent.
        let lateral = |x: &Vector3<f64>| {
            let d = x - example.tip_m;
            d - axis * d.dot(&axis)
        };
        let candidates: Vec<[usize; 3]> = self
            .load_faces
            .iter()
            .filter(|f| {
                let [a, b, c] = f.map(|i| v[i]);
                if (b - a).cross(&(c - a)).dot(&axis) >= 0.0 {
                    return false;
                }
                let g = (a + b + c) / 3.0;
                let extent = [a, b, c].iter().map(|x| (x - g).norm()).fold(0.0, f64::max);
                lateral(&g).norm() <= radius + extent
            })
            .copied()
            .collect();
        let (e1, e2) = {
            let t = if axis.x.abs() < 0.9 {
                Vector3::x()
            } else {
                Vector3::y()
            };
            let e1 = (t - axis * t.dot(&axis)).normalize();
            (e1, axis.cross(&e1))
        };
        let rings = patch.rings.max(1);
        let per_ring = patch.samples_per_ring.max(1);
        let mut acc: std::collections::BTreeMap<usize, f64> = std::collections::BTreeMap::new();
        let mut hit_samples = 0usize;
        for k in 0..rings {
            let r = radius
                * patch
                    .load
                    .ring_radius_fraction((k as f64 + 0.5) / rings as f64);
            let turn = if k % 2 == 1 { 0.5 } else { 0.0 };
            for j in 0..per_ring {
                let phi = std::f64::consts::TAU * (j as f64 + turn) / per_ring as f64;
                let origin = example.tip_m + (e1 * phi.cos() + e2 * phi.sin()) * r;
                let best = candidates
                    .iter()
                    .filter_map(|f| {
                        softcap_mesh::line_triangle(&origin, &axis, &f.map(|i| v[i])).map(
                            |(t, w)| {
                                // Clamp the edge tolerance away; keep Σw = 1.
                                let w = w.map(|c| c.clamp(0.0, 1.0));
                                let sum: f64 = w.iter().sum();
                                (t, w.map(|c| c / sum), f)
                            },
                        )
                    })
                    .min_by(|a, b| a.0.abs().total_cmp(&b.0.abs()));
                if let Some((_, w, f)) = best {
                    hit_samples += 1;
                    for (n, wn) in f.iter().zip(w) {
                        *acc.entry(*n).or_insert(0.0) += wn;
                    }
                }
            }
        }
        if hit_samples == 0 {
            let closest = self
                .load_faces
                .iter()
                .map(|f| {
                    let x = f.map(|i| v[i]);
                    let w = softcap_mesh::closest_point_on_triangle(
                        &example.tip_m,
                        &x[0],
                        &x[1],
                        &x[2],
                    );
                    let q = x[0] * w[0] + x[1] * w[1] + x[2] * w[2];
                    ((q - example.tip_m).norm(), f, w)
                })
                .min_by(|a, b| a.0.total_cmp(&b.0));
            return match closest {
                Some((_, f, w)) => {
                    let mut m = std::collections::BTreeMap::new();
                    for (n, wn) in f.iter().zip(w) {
                        *m.entry(*n).or_insert(0.0) += wn;
                    }
                    m.into_iter().filter(|e| e.1 != 0.0).collect()
                }
                None => Vec::new(),
            };
        }
        let scale = 1.0 / hit_samples as f64;
        acc.into_iter()
            .filter(|e| e.1 != 0.0)
            .map(|(n, w)| (n, w * scale))
            .collect()
    }

    /// Nodal forces of an example: the measured force spread over the footprint by
    /// [`Self::load_weights`] (bickel2009 §4.1 / Fig. 7).
    pub fn nodal_forces(&self, example: &ProbeExample, patch: &PatchSettings) -> Vec<Vector3<f64>> {
        let mut f = vec![Vector3::zeros(); self.mesh.vertices.len()];
        for (n, w) in self.load_weights(example, patch) {
            f[n] += example.force_n * w;
        }
        f
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
fn marker_residuals(setup: &ProbingSetup, example: &ProbeExample, x: &[Vector3<f64>]) -> Vec<f64> {
    let mut r = Vec::with_capacity(3 * example.observed.len());
    for o in &example.observed {
        let p = setup.markers[o.marker].position(&setup.mesh.tets, x);
        r.extend((p - o.position_m).iter());
    }
    r
}

fn rms_of(r: &[f64]) -> f64 {
    if r.is_empty() {
        0.0
    } else {
        (r.iter().map(|v| v * v).sum::<f64>() / (r.len() / 3).max(1) as f64).sqrt()
    }
}

/// Settings of the per-example fit (bickel2009 eq. 9).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct ExampleFitSettings {
    /// γ of eq. 9 on the log-stiffness field, m² (a unit jump of ln λ between neighbouring tets
    /// costs as much as √γ of marker error).
    pub gamma_m2: f64,
    /// γ on the Poisson-ratio field, m².
    pub gamma_nu_m2: f64,
    /// Bounds on λ_e relative to the initial value.
    pub lambda_factor_bounds: (f64, f64),
    /// Bounds on ν_e = α_e/λ_e (physically valid: within (−1, 0.5)).
    pub nu_bounds: (f64, f64),
    /// Levenberg–Marquardt iterations (accepted or rejected steps).
    pub max_iterations: usize,
    /// Stop when an accepted step lowers the cost by less than this fraction.
    pub relative_cost_tolerance: f64,
    /// Initial damping μ relative to the largest diagonal of JᵀJ.
    pub initial_damping: f64,
    /// Floor of the Marquardt scaling relative to its largest entry: D_i = max(diag_i,
    /// `min_scaling` · max diag) (Moré 1978 §5: a scaling that vanishes in parameters the
    /// markers barely see lets the damped step run off in them at any μ).
    pub min_scaling: f64,
    /// Largest trust radius ‖h‖∞ of a step in q = (ln λ, ν) units (Moré 1978 trust region on
    /// top of the Marquardt damping); 0 disables the trust region.
    pub max_step: f64,
    /// γ_p: Tikhonov shrinkage of the fit toward its start `initial`, cost
    /// γ_p · (1e-8 m²) · (rows / 2T) · ‖q − q₀‖²: with γ_p = 1, moving *every* tet by 1 in ln λ
    /// (or ν) costs as much as 0.1 mm RMS marker error; 0 = eq. 9 as printed.
    pub gamma_prior: f64,
    /// Matrix of the linearization: `Consistent` (exact ∂x/∂p of the corotational equilibrium)
    /// or `Warped` (bickel2009 eq. 11 with rotations held fixed).
    pub jacobian: StiffnessKind,
    /// Equilibrium iterations of every simulation.
    pub equilibrium: EquilibriumSettings,
    /// Conjugate-gradient iterations per damped normal-equation solve.
    pub cg_iterations: usize,
    /// Relative tolerance of that solve on the preconditioned residual (an inexact LM step,
    /// Steihaug 1983 / Dembo et al. 1982 inexact Newton: the step need not be exact far from the
    /// minimum).
    pub cg_tolerance: f64,
    /// Preconditioner of that conjugate-gradient solve.
    pub preconditioner: StepPreconditioner,
    /// Force boundary-condition patch.
    pub patch: PatchSettings,
}

/// Preconditioner of the conjugate-gradient solve of the damped LM normal equations
/// (J_mᵀJ_m + γLᵀL + γ_p I + μD) h = −g of [`fit_example`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum StepPreconditioner {
    /// The diagonal (Jacobi).
    #[default]
    Jacobi,
    /// The exact inverse of J_mᵀJ_m + Δ by the Woodbury identity, Δ = the diagonal of the rest
    /// (μD + γ_p + γ diag LᵀL): P⁻¹ = Δ⁻¹ − Δ⁻¹J_mᵀ(I + J_mΔ⁻¹J_mᵀ)⁻¹J_mΔ⁻¹, a k × k Cholesky
    /// for k observed marker coordinates (k ≪ 2T parameters; saito-barbic use the same
    /// identity for their Gauss–Newton steps). Only the off-diagonal part of γLᵀL is left to
    /// the iteration, so a step takes a few iterations instead of tens.
    Woodbury,
}

impl Default for ExampleFitSettings {
    fn default() -> Self {
        Self {
            gamma_m2: 1e-12,
            gamma_nu_m2: 1e-11,
            lambda_factor_bounds: (0.02, 50.0),
            nu_bounds: (0.0, 0.49),
            max_iterations: 12,
            relative_cost_tolerance: 1e-3,
            initial_damping: 1e-3,
            min_scaling: 1e-2,
            max_step: 1.0,
            gamma_prior: 0.0,
            jacobian: StiffnessKind::Consistent,
            equilibrium: EquilibriumSettings {
                max_iterations: 60,
                displacement_tol_rel: 1e-9,
                residual_tol_rel: 1e-7,
                ..EquilibriumSettings::default()
            },
            cg_iterations: 300,
            cg_tolerance: 1e-10,
            preconditioner: StepPreconditioner::default(),
            patch: PatchSettings::default(),
        }
    }
}

/// Result of one per-example fit.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ExampleFit {
    /// Fitted (λ_e, α_e) per tet.
    pub params: Vec<LinearParams>,
    /// Equilibrium node positions under the fitted parameters, m.
    pub positions_m: Vec<Vector3<f64>>,
    /// Corotated Voigt strain of each tet at that equilibrium (the strain-space sample ε_e).
    pub strains: Vec<Vector6<f64>>,
    /// RMS marker error before fitting (initial parameters), m.
    pub initial_rms_m: f64,
    /// RMS marker error after fitting, m.
    pub rms_m: f64,
    /// Cost Σ‖r‖² + γ‖Lp‖² after each accepted step (first entry: initial).
    pub cost_history: Vec<f64>,
    /// LM iterations performed.
    pub iterations: usize,
    /// Conjugate-gradient iterations of all damped steps (diagnostic).
    #[serde(default)]
    pub cg_iterations: usize,
    /// Equilibrium status of the final simulation.
    pub status: SolveStatus,
}

/// (log-λ, ν) parameterization of the per-tet material (λ_e = λ_ref,e · exp(s_e), α_e = ν_e λ_e).
fn params_from_q(lambda_ref: &[f64], q: &[f64]) -> Vec<LinearParams> {
    let t = lambda_ref.len();
    (0..t)
        .map(|e| {
            let lambda = lambda_ref[e] * q[e].exp();
            LinearParams {
                lambda,
                alpha: q[t + e] * lambda,
            }
        })
        .collect()
}

/// The umbrella operator L of eq. 9, (Lv)_i = Σ_j (v_i − v_j) over the tets j sharing a vertex
/// with tet i, in compressed rows (one flat neighbour array). The LM steps apply LᵀL = LL to the
/// log-stiffness and the Poisson-ratio blocks at every conjugate-gradient iteration, so both
/// blocks are applied in one pass over the ≈ 60 neighbours of each tet.
struct Umbrella {
    offsets: Vec<usize>,
    neighbours: Vec<usize>,
}

impl Umbrella {
    fn new(adjacency: &[Vec<usize>]) -> Self {
        let mut offsets = Vec::with_capacity(adjacency.len() + 1);
        offsets.push(0);
        let mut neighbours = Vec::with_capacity(adjacency.iter().map(Vec::len).sum());
        for nb in adjacency {
            neighbours.extend_from_slice(nb);
            offsets.push(neighbours.len());
        }
        Self {
            offsets,
            neighbours,
        }
    }

    /// Number of neighbours of tet `i`.
    fn degree(&self, i: usize) -> usize {
        self.offsets[i + 1] - self.offsets[i]
    }

    /// (L a, L b) for the two parameter blocks at once.
    fn apply_pair(&self, a: &[f64], b: &[f64], out_a: &mut [f64], out_b: &mut [f64]) {
        for (i, w) in self.offsets.windows(2).enumerate() {
            let nb = &self.neighbours[w[0]..w[1]];
            let deg = nb.len() as f64;
            let (mut sa, mut sb) = (deg * a[i], deg * b[i]);
            for &j in nb {
                sa -= a[j];
                sb -= b[j];
            }
            out_a[i] = sa;
            out_b[i] = sb;
        }
    }

    /// γ_s LLv_s and γ_ν LLv_ν added to `out` for v = (v_s, v_ν) (blocks of length T).
    fn add_smoothing(
        &self,
        v: &[f64],
        gammas: [f64; 2],
        scratch: &mut UmbrellaScratch,
        out: &mut [f64],
    ) {
        let t = self.offsets.len() - 1;
        let UmbrellaScratch { la, lb, lla, llb } = scratch;
        self.apply_pair(&v[..t], &v[t..2 * t], la, lb);
        self.apply_pair(la, lb, lla, llb);
        for i in 0..t {
            out[i] += gammas[0] * lla[i];
            out[t + i] += gammas[1] * llb[i];
        }
    }

    /// γ_s‖L v_s‖² + γ_ν‖L v_ν‖².
    fn smoothing_cost(&self, v: &[f64], gammas: [f64; 2], scratch: &mut UmbrellaScratch) -> f64 {
        let t = self.offsets.len() - 1;
        let UmbrellaScratch { la, lb, .. } = scratch;
        self.apply_pair(&v[..t], &v[t..2 * t], la, lb);
        gammas[0] * la.iter().map(|v| v * v).sum::<f64>()
            + gammas[1] * lb.iter().map(|v| v * v).sum::<f64>()
    }
}

/// Work vectors of [`Umbrella`] (length T each).
struct UmbrellaScratch {
    la: Vec<f64>,
    lb: Vec<f64>,
    lla: Vec<f64>,
    llb: Vec<f64>,
}

impl UmbrellaScratch {
    fn new(t: usize) -> Self {
        Self {
            la: vec![0.0; t],
            lb: vec![0.0; t],
            lla: vec![0.0; t],
            llb: vec![0.0; t],
        }
    }
}

/// Simulates `example` with `params` from the warm start `x`; returns the equilibrium report.
fn simulate_params(
    setup: &ProbingSetup,
    solver: &mut StaticSolver,
    model: &mut CorotationalModel,
    params: &[LinearParams],
    forces: &[Vector3<f64>],
    x: &mut [Vector3<f64>],
    settings: &EquilibriumSettings,
) -> Result<EquilibriumReport, FemError> {
    model.set_params(params)?;
    Ok(setup.simulate(solver, model, x, forces, settings))
}

/// Jᵀ w for every observed marker coordinate: the rows of J_m = ∂x_markers/∂p (3k × 2T,
/// parameters interleaved (λ_e, α_e)) by the adjoint method of the appendix (eq. 11–12): one
/// multi-column solve with the one factorization for all rows.
fn marker_jacobian_rows(
    setup: &ProbingSetup,
    example: &ProbeExample,
    sens: &Sensitivity<'_>,
) -> Result<Vec<Vec<f64>>, FemError> {
    let mut weights = Vec::with_capacity(3 * example.observed.len());
    for o in &example.observed {
        let emb = &setup.markers[o.marker];
        let tet = setup.mesh.tets[emb.tet];
        for c in 0..3 {
            weights.push((0..4).map(|a| (3 * tet[a] + c, emb.weights[a])).collect());
        }
    }
    sens.jt_times_sparse(&weights)
}

/// The rows of [`marker_jacobian_rows`] at the current equilibrium `x` of `model`.
pub fn marker_jacobian(
    setup: &ProbingSetup,
    solver: &mut StaticSolver,
    model: &CorotationalModel,
    example: &ProbeExample,
    x: &[Vector3<f64>],
    kind: StiffnessKind,
) -> Result<Vec<Vec<f64>>, FemError> {
    let sens = Sensitivity::new(solver, model, x, kind, None)?;
    marker_jacobian_rows(setup, example, &sens)
}

/// Per-example parameter estimation, bickel2009 eq. 9:
///
/// p̂ = argmin_p Σᵢ ‖xᵢ(p, F̄) − x̄ᵢ‖² + γ‖Lp‖²,
///
/// by a projected Levenberg–Marquardt iteration over q = (ln λ_e/λ_ref,e, ν_e) with box bounds
/// (Poisson's ratio stays in `nu_bounds`, so α = νλ is always physically valid). Each iteration
/// simulates the example ([`ProbingSetup::simulate`]), builds the marker Jacobian by the adjoint
/// method (appendix eq. 10–12, [`Sensitivity`], one factorization for all rows), and solves the
/// damped normal equations (J_mᵀJ_m + γLᵀL + γ_p I + μD) h = −g matrix-free by preconditioned
/// conjugate gradients (J_m is 3k × 2T and dense, L sparse). `initial` gives λ_ref and the start;
/// γ_p (`gamma_prior`, default 0) shrinks the fit toward it.
///
/// Step control: the Marquardt scaling D is floored at `min_scaling` × its largest entry, and
/// the step is cut to a trust radius ‖h‖∞ ≤ r (r ≤ `max_step`, ×2 after an accepted step, ×¼
/// of the tried length after a rejected one; Moré 1978). Without it, parameters the markers
/// barely see (tets far from the probe, deep tets) get steps of ≈ 6 in ln λ at any damping,
/// are clamped at the bounds, and every step of a small-force example is rejected (measured,
/// docs/tissue.md).
pub fn fit_example(
    setup: &ProbingSetup,
    example: &ProbeExample,
    initial: &[LinearParams],
    settings: &ExampleFitSettings,
) -> Result<ExampleFit, FemError> {
    let joint = fit_examples_jointly(setup, std::slice::from_ref(example), initial, settings)?;
    Ok(example_fit_of(joint))
}

/// Result of [`fit_examples_jointly`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct JointFit {
    /// Fitted (λ_e, α_e) per tet (one field for all examples).
    pub params: Vec<LinearParams>,
    /// Equilibrium node positions of each example under the fitted parameters, m.
    pub positions_m: Vec<Vec<Vector3<f64>>>,
    /// Corotated Voigt strains of each example at its equilibrium.
    pub strains: Vec<Vec<Vector6<f64>>>,
    /// RMS marker error of each example before fitting, m.
    pub initial_rms_m: Vec<f64>,
    /// RMS marker error of each example after fitting, m.
    pub example_rms_m: Vec<f64>,
    /// RMS marker error over all examples after fitting, m.
    pub rms_m: f64,
    /// Cost after each accepted step (first entry: initial).
    pub cost_history: Vec<f64>,
    /// LM iterations performed.
    pub iterations: usize,
    /// Conjugate-gradient iterations of all damped steps (diagnostic).
    #[serde(default)]
    pub cg_iterations: usize,
    /// Worst equilibrium status of the final simulations.
    pub status: SolveStatus,
}

/// Eq. 9 with the sum over the markers of *several* examples and one heterogeneous linear field
/// p for all of them: the heterogeneous counterpart of the average-fit homogeneous model
/// ([`fit_homogeneous`], bickel2009 Fig. 8). [`fit_example`] is the one-example case. Same
/// parameterization, Jacobian (one adjoint factorization per example), regularization and step
/// control as [`fit_example`].
pub fn fit_examples_jointly(
    setup: &ProbingSetup,
    examples: &[ProbeExample],
    initial: &[LinearParams],
    settings: &ExampleFitSettings,
) -> Result<JointFit, FemError> {
    fit_examples_from(setup, examples, initial, initial, settings)
}

/// [`fit_example`] started from `start` instead of the reference field: `reference` is λ_ref of
/// the parameterization and the target q₀ of the shrinkage γ_p, `start` only the first iterate
/// (a warm start, e.g. the fit of the same example at a neighbouring γ_p).
pub fn fit_example_from(
    setup: &ProbingSetup,
    example: &ProbeExample,
    reference: &[LinearParams],
    start: &[LinearParams],
    settings: &ExampleFitSettings,
) -> Result<ExampleFit, FemError> {
    let joint = fit_examples_from(
        setup,
        std::slice::from_ref(example),
        reference,
        start,
        settings,
    )?;
    Ok(example_fit_of(joint))
}

fn example_fit_of(joint: JointFit) -> ExampleFit {
    let JointFit {
        params,
        mut positions_m,
        mut strains,
        mut initial_rms_m,
        mut example_rms_m,
        cost_history,
        iterations,
        cg_iterations,
        status,
        ..
    } = joint;
    ExampleFit {
        params,
        positions_m: positions_m.pop().unwrap_or_default(),
        strains: strains.pop().unwrap_or_default(),
        initial_rms_m: initial_rms_m.pop().unwrap_or(0.0),
        rms_m: example_rms_m.pop().unwrap_or(0.0),
        cost_history,
        iterations,
        cg_iterations,
        status,
    }
}

/// [`fit_example_from`] warm-started from an earlier fit of the same example (e.g. at a
/// neighbouring γ_p): its parameters are the first iterate and its equilibrium positions the
/// start of the first equilibrium solve (instead of the rest shape), so the first simulation
/// costs a few Newton iterations. Same minimizer as [`fit_example_from`] with
/// `start = &previous.params` (the equilibrium is the same to the solver tolerance).
pub fn fit_example_warm(
    setup: &ProbingSetup,
    example: &ProbeExample,
    reference: &[LinearParams],
    previous: &ExampleFit,
    settings: &ExampleFitSettings,
) -> Result<ExampleFit, FemError> {
    let positions = std::slice::from_ref(&previous.positions_m);
    let joint = fit_examples_impl(
        setup,
        std::slice::from_ref(example),
        reference,
        &previous.params,
        Some(positions),
        settings,
    )?;
    Ok(example_fit_of(joint))
}

/// [`fit_examples_jointly`] started from `start` (see [`fit_example_from`]).
pub fn fit_examples_from(
    setup: &ProbingSetup,
    examples: &[ProbeExample],
    reference: &[LinearParams],
    start: &[LinearParams],
    settings: &ExampleFitSettings,
) -> Result<JointFit, FemError> {
    fit_examples_impl(setup, examples, reference, start, None, settings)
}

/// [`fit_examples_from`] with optional start positions of the first equilibrium solves (one
/// per example, node count of the mesh; the rest shape when `None` or mismatched).
fn fit_examples_impl(
    setup: &ProbingSetup,
    examples: &[ProbeExample],
    reference: &[LinearParams],
    start: &[LinearParams],
    start_positions: Option<&[Vec<Vector3<f64>>]>,
    settings: &ExampleFitSettings,
) -> Result<JointFit, FemError> {
    let t = setup.num_elements();
    let initial = reference;
    for (what, field) in [
        ("initial per-element parameters", reference),
        ("start per-element parameters", start),
    ] {
        if field.len() != t {
            return Err(FemError::LengthMismatch {
                what,
                expected: t,
                got: field.len(),
            });
        }
        for (e, p) in field.iter().enumerate() {
            p.validate(e)?;
        }
    }
    let lambda_ref: Vec<f64> = initial.iter().map(|p| p.lambda).collect();
    let n = 2 * t;
    let (nlo, nhi) = settings.nu_bounds;
    if !(nlo > -1.0 && nhi < 0.5 && nlo <= nhi) {
        return Err(FemError::InvalidPoissonRatio {
            nu: if nhi >= 0.5 { nhi } else { nlo },
        });
    }
    let (flo, fhi) = settings.lambda_factor_bounds;
    let lower: Vec<f64> = (0..n).map(|i| if i < t { flo.ln() } else { nlo }).collect();
    let upper: Vec<f64> = (0..n).map(|i| if i < t { fhi.ln() } else { nhi }).collect();
    let mut q: Vec<f64> = (0..n)
        .map(|i| {
            if i < t {
                0.0
            } else {
                let p = initial[i - t];
                p.alpha / p.lambda
            }
        })
        .collect();
    for i in 0..n {
        q[i] = q[i].clamp(lower[i], upper[i]);
    }
    let q0 = q.clone();
    // The first iterate: the start field in the same parameterization.
    for e in 0..t {
        let p = start[e];
        q[e] = (p.lambda / lambda_ref[e]).ln().clamp(lower[e], upper[e]);
        q[t + e] = (p.alpha / p.lambda).clamp(lower[t + e], upper[t + e]);
    }
    let prior = settings.gamma_prior.max(0.0);
    let gammas = [settings.gamma_m2, settings.gamma_nu_m2];
    let gam = |i: usize| gammas[usize::from(i >= t)];
    let umbrella = Umbrella::new(&setup.adjacency);
    let mut scratch = UmbrellaScratch::new(t);

    let mut model = CorotationalModel::new(&setup.mesh, params_from_q(&lambda_ref, &q))?;
    let mut solver = setup.solver(&model)?;
    let forces: Vec<Vec<Vector3<f64>>> = examples
        .iter()
        .map(|ex| setup.nodal_forces(ex, &settings.patch))
        .collect();
    let mut xs: Vec<Vec<Vector3<f64>>> = match start_positions {
        Some(p)
            if p.len() == examples.len()
                && p.iter().all(|x| x.len() == setup.mesh.vertices.len()) =>
        {
            p.to_vec()
        }
        _ => vec![setup.mesh.vertices.clone(); examples.len()],
    };

    // Cost = Σ‖r_m‖² + γ‖L s‖² + γ_ν‖L ν‖² + γ_p‖q − q₀‖² (scaled by the marker count).
    let num_rows: usize = examples.iter().map(|e| 3 * e.observed.len()).sum();
    let prior_scale = prior * 1e-8 * num_rows as f64 / n as f64;
    let reg_cost = |q: &[f64], scratch: &mut UmbrellaScratch| {
        umbrella.smoothing_cost(q, gammas, scratch)
            + prior_scale
                * q.iter()
                    .zip(&q0)
                    .map(|(a, b)| (a - b) * (a - b))
                    .sum::<f64>()
    };
    // Simulates every example with the parameters `q` warm-started from `xs`; residuals stacked.
    let run_all = |model: &mut CorotationalModel,
                   solver: &mut StaticSolver,
                   q: &[f64],
                   xs: &mut [Vec<Vector3<f64>>]|
     -> Result<(Vec<Vec<f64>>, SolveStatus, bool), FemError> {
        model.set_params(&params_from_q(&lambda_ref, q))?;
        let mut rs = Vec::with_capacity(examples.len());
        let mut status = SolveStatus::Converged;
        let mut ok = true;
        for (k, ex) in examples.iter().enumerate() {
            let rep = setup.simulate(solver, model, &mut xs[k], &forces[k], &settings.equilibrium);
            if !rep.converged() {
                ok = false;
                status = rep.status.clone();
            }
            rs.push(marker_residuals(setup, ex, &xs[k]));
        }
        Ok((rs, status, ok))
    };
    let (mut rs, mut status, _) = run_all(&mut model, &mut solver, &q, &mut xs)?;
    let initial_rms_m: Vec<f64> = rs.iter().map(|r| rms_of(r)).collect();
    let sq = |rs: &[Vec<f64>]| rs.iter().flatten().map(|v| v * v).sum::<f64>();
    let mut cost = sq(&rs) + reg_cost(&q, &mut scratch);
    let mut history = vec![cost];
    let mut iterations = 0;
    let mut mu_rel = settings.initial_damping;
    let mut radius = if settings.max_step > 0.0 {
        settings.max_step
    } else {
        f64::INFINITY
    };
    let mut jac_valid = false;
    let mut cg_iterations = 0;
    // J_m in q-space, one row after the other (= J_mᵀ column-major, n × rows).
    let mut jm: Vec<f64> = Vec::new();
    let mut diag_max = vec![0.0f64; n];
    let mut grad = vec![0.0; n];

    while iterations < settings.max_iterations && num_rows > 0 {
        iterations += 1;
        if !jac_valid {
            let params = model.params().to_vec();
            jm.clear();
            for (k, ex) in examples.iter().enumerate() {
                let rows =
                    marker_jacobian(setup, &mut solver, &model, ex, &xs[k], settings.jacobian)
                        .or_else(|_| {
                            marker_jacobian(
                                setup,
                                &mut solver,
                                &model,
                                ex,
                                &xs[k],
                                StiffnessKind::Warped,
                            )
                        })?;
                // Chain rule to q: ∂/∂s_e = λ_e (∂/∂λ_e + ν_e ∂/∂α_e), ∂/∂ν_e = λ_e ∂/∂α_e.
                for row in &rows {
                    let start = jm.len();
                    jm.resize(start + n, 0.0);
                    let out = &mut jm[start..];
                    for e in 0..t {
                        let (jl, ja) = (row[2 * e], row[2 * e + 1]);
                        let lam = params[e].lambda;
                        let nu = q[t + e];
                        out[e] = lam * (jl + nu * ja);
                        out[t + e] = lam * ja;
                    }
                }
            }
            // g = J_mᵀ r + γ Lᵀ L q + γ_p (q − q₀) (L symmetric); Σ_rows J_m² per column.
            grad.iter_mut().for_each(|g| *g = 0.0);
            let mut col_sq = vec![0.0; n];
            for (row, ri) in jm.chunks_exact(n).zip(rs.iter().flatten()) {
                for i in 0..n {
                    grad[i] += row[i] * ri;
                    col_sq[i] += row[i] * row[i];
                }
            }
            umbrella.add_smoothing(&q, gammas, &mut scratch, &mut grad);
            for i in 0..n {
                grad[i] += prior_scale * (q[i] - q0[i]);
                let deg = umbrella.degree(i % t) as f64;
                let d = col_sq[i] + gam(i) * (deg * deg + deg) + prior_scale;
                diag_max[i] = diag_max[i].max(d);
            }
            jac_valid = true;
        }
        // Free variables: not held at a bound by the gradient.
        let free: Vec<bool> = (0..n)
            .map(|i| !((q[i] <= lower[i] && grad[i] > 0.0) || (q[i] >= upper[i] && grad[i] < 0.0)))
            .collect();
        let dmax = diag_max.iter().copied().fold(0.0, f64::max).max(1e-300);
        let mu = mu_rel * dmax;
        let floor = settings.min_scaling.max(0.0) * dmax;
        let scaling: Vec<f64> = diag_max.iter().map(|d| d.max(floor)).collect();
        let (h, cg) = damped_step(
            &umbrella,
            &mut scratch,
            &jm,
            &grad,
            &free,
            &scaling,
            mu,
            prior_scale,
            gammas,
            settings.cg_iterations,
            settings.cg_tolerance,
            settings.preconditioner,
        );
        cg_iterations += cg;
        // Trust region ‖h‖∞ ≤ radius on top of the damping: shortens the step uniformly.
        let h_inf = h.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let shrink = if h_inf > radius { radius / h_inf } else { 1.0 };
        let mut q_trial: Vec<f64> = (0..n).map(|i| q[i] + shrink * h[i]).collect();
        for i in 0..n {
            q_trial[i] = q_trial[i].clamp(lower[i], upper[i]);
        }
        let mut xs_trial = xs.clone();
        let (rs_trial, st_trial, ok) = run_all(&mut model, &mut solver, &q_trial, &mut xs_trial)?;
        let cost_trial = sq(&rs_trial) + reg_cost(&q_trial, &mut scratch);
        if ok && cost_trial.is_finite() && cost_trial < cost {
            let decrease = (cost - cost_trial) / cost.max(f64::MIN_POSITIVE);
            q = q_trial;
            xs = xs_trial;
            rs = rs_trial;
            cost = cost_trial;
            status = st_trial;
            history.push(cost);
            jac_valid = false;
            mu_rel = (mu_rel / 3.0).max(1e-12);
            radius = (2.0 * radius).min(if settings.max_step > 0.0 {
                settings.max_step
            } else {
                f64::INFINITY
            });
            if decrease < settings.relative_cost_tolerance {
                break;
            }
        } else {
            // Restore the model to the accepted parameters.
            model.set_params(&params_from_q(&lambda_ref, &q))?;
            mu_rel *= 4.0;
            if settings.max_step > 0.0 {
                radius = 0.25 * radius.min(shrink * h_inf);
            }
            if mu_rel > 1e12 || radius < 1e-6 {
                break;
            }
        }
    }
    let params = params_from_q(&lambda_ref, &q);
    model.set_params(&params)?;
    let strains = xs.iter().map(|x| model.strains(x)).collect();
    let example_rms_m: Vec<f64> = rs.iter().map(|r| rms_of(r)).collect();
    let rms_m = rms_of(&rs.concat());
    Ok(JointFit {
        params,
        positions_m: xs,
        strains,
        initial_rms_m,
        example_rms_m,
        rms_m,
        cost_history: history,
        iterations,
        cg_iterations,
        status,
    })
}

/// Solves (J_mᵀJ_m + γLᵀL + γ_p I + μD) h = −g on the free variables by preconditioned CG
/// ([`StepPreconditioner`]).
#[allow(clippy::too_many_arguments)]
fn damped_step(
    umbrella: &Umbrella,
    scratch: &mut UmbrellaScratch,
    flat: &[f64],
    grad: &[f64],
    free: &[bool],
    diag: &[f64],
    mu: f64,
    prior: f64,
    gammas: [f64; 2],
    max_iter: usize,
    tolerance: f64,
    preconditioner: StepPreconditioner,
) -> (Vec<f64>, usize) {
    let n = grad.len();
    // J_m stored row by row = J_mᵀ column-major (n × m): J_mᵀ(J_m v) by `normal_product`.
    let m = flat.len() / n.max(1);
    let jt = faer::MatRef::from_column_major_slice(flat, n, m);
    let mut jv = vec![0.0; m];
    let mut apply = |v: &[f64], out: &mut [f64]| {
        normal_product(jt, v, &mut jv, out);
        umbrella.add_smoothing(v, gammas, scratch, out);
        for i in 0..n {
            out[i] += mu * diag[i] * v[i] + prior * v[i];
            if !free[i] {
                out[i] = 0.0;
            }
        }
    };
    let mut precondition: Box<dyn FnMut(&[f64], &mut [f64])> = match preconditioner {
        StepPreconditioner::Jacobi => {
            let inv: Vec<f64> = (0..n)
                .map(|i| {
                    if free[i] {
                        1.0 / (diag[i] * (1.0 + mu) + 1e-300)
                    } else {
                        0.0
                    }
                })
                .collect();
            Box::new(move |r: &[f64], z: &mut [f64]| {
                for i in 0..n {
                    z[i] = r[i] * inv[i];
                }
            })
        }
        StepPreconditioner::Woodbury => {
            woodbury_preconditioner(umbrella, flat, free, diag, mu, prior, gammas)
        }
    };
    let mut h = vec![0.0; n];
    let mut res: Vec<f64> = (0..n)
        .map(|i| if free[i] { -grad[i] } else { 0.0 })
        .collect();
    let mut z = vec![0.0; n];
    precondition(&res, &mut z);
    let mut p = z.clone();
    let mut rz: f64 = res.iter().zip(&z).map(|(a, b)| a * b).sum();
    let r0 = rz.abs().sqrt();
    let mut ap = vec![0.0; n];
    let mut iterations = 0;
    for _ in 0..max_iter {
        if rz.abs().sqrt() <= tolerance * r0 || r0 == 0.0 {
            break;
        }
        iterations += 1;
        apply(&p, &mut ap);
        let pap: f64 = p.iter().zip(&ap).map(|(a, b)| a * b).sum();
        if pap <= 0.0 || !pap.is_finite() {
            break;
        }
        let a = rz / pap;
        for i in 0..n {
            h[i] += a * p[i];
            res[i] -= a * ap[i];
        }
        precondition(&res, &mut z);
        let rz_new: f64 = res.iter().zip(&z).map(|(a, b)| a * b).sum();
        let beta = rz_new / rz;
        rz = rz_new;
        for i in 0..n {
            p[i] = z[i] + beta * p[i];
        }
    }
    (h, iterations)
}

/// Bytes of J_m rows [`normal_product`] multiplies per block: small enough that a block read
/// from memory for J_m v is still in the core's L2 cache (≥ 512 KiB on current x86-64 and
/// AArch64 cores, together with v and the output of length n) when J_mᵀ reads it again.
const NORMAL_PRODUCT_BLOCK_BYTES: usize = 256 * 1024;

/// The reference J_mᵀ(J_m v) that [`normal_product`] reproduces bit for bit: the two whole faer
/// products (session 12's LM step). Kept as the unit test's oracle and the bench's baseline.
#[doc(hidden)]
pub fn normal_product_unblocked(
    jt: faer::MatRef<'_, f64>,
    v: &[f64],
    jv: &mut [f64],
    out: &mut [f64],
) {
    let (n, m) = (jt.nrows(), jt.ncols());
    faer::linalg::matmul::matmul(
        faer::MatMut::from_column_major_slice_mut(jv, m, 1),
        faer::Accum::Replace,
        jt.transpose(),
        faer::MatRef::from_column_major_slice(v, n, 1),
        1.0,
        faer::Par::Seq,
    );
    faer::linalg::matmul::matmul(
        faer::MatMut::from_column_major_slice_mut(out, n, 1),
        faer::Accum::Replace,
        jt,
        faer::MatRef::from_column_major_slice(jv, m, 1),
        1.0,
        faer::Par::Seq,
    );
}

/// out = J_mᵀ (J_m v) for J_m stored row by row (`jt` = J_mᵀ, n × m column-major; `jv`: m
/// scratch), the dense part of the normal operator of the LM step (bickel2009 eq. 9's
/// Gauss–Newton matrix J_mᵀJ_m, applied at every CG iteration).
///
/// Blocked over the rows of J_m so that each row is read from memory once (J_m is 3k × 2T: 37 MB
/// on the 5,184-tet suite template, so two whole products stream it twice). Bit-identical to the
/// two whole products `J_m v` then `J_mᵀ (J_m v)`, which the fit's results depend on (docs/tissue.md,
/// "Rounding sensitivity"): faer's row-major product computes each entry of J_m v as one dot
/// product of one row, and its column-major product accumulates the columns of J_mᵀ in order
/// (`dst ← x_j · s_j + dst`, j = 0, 1, …), so continuing it block after block (`Accum::Add`)
/// performs the same operations in the same order (tested:
/// `normal_product_is_bitwise_the_two_products`). Bench: `lm_normal_product` in benches/fem.rs.
pub fn normal_product(jt: faer::MatRef<'_, f64>, v: &[f64], jv: &mut [f64], out: &mut [f64]) {
    let (n, m) = (jt.nrows(), jt.ncols());
    if m == 0 {
        out.fill(0.0);
        return;
    }
    let block = (NORMAL_PRODUCT_BLOCK_BYTES / (8 * n.max(1))).clamp(1, m);
    let vm = faer::MatRef::from_column_major_slice(v, n, 1);
    let mut outm = faer::MatMut::from_column_major_slice_mut(out, n, 1);
    for start in (0..m).step_by(block) {
        let len = block.min(m - start);
        let rows = jt.subcols(start, len);
        let s = &mut jv[start..start + len];
        faer::linalg::matmul::matmul(
            faer::MatMut::from_column_major_slice_mut(s, len, 1),
            faer::Accum::Replace,
            rows.transpose(),
            vm,
            1.0,
            faer::Par::Seq,
        );
        faer::linalg::matmul::matmul(
            outm.as_mut(),
            if start == 0 {
                faer::Accum::Replace
            } else {
                faer::Accum::Add
            },
            rows,
            faer::MatRef::from_column_major_slice(s, len, 1),
            1.0,
            faer::Par::Seq,
        );
    }
}

/// P⁻¹ of [`StepPreconditioner::Woodbury`] on the free variables: P = J_Fᵀ J_F + Δ with
/// Δᵢ = μDᵢ + γ_p + γᵢ (LᵀL)ᵢᵢ ((LᵀL)ᵢᵢ = deg² + deg for the umbrella operator), applied as
/// P⁻¹v = Δ⁻¹v − Δ⁻¹J_Fᵀ S⁻¹ J_F Δ⁻¹v with S = I + J_F Δ⁻¹ J_Fᵀ (k × k, Cholesky once per
/// step). Falls back to Δ⁻¹ (Jacobi) if S does not factor.
fn woodbury_preconditioner<'a>(
    umbrella: &Umbrella,
    jt_flat: &'a [f64],
    free: &'a [bool],
    diag: &[f64],
    mu: f64,
    prior: f64,
    gammas: [f64; 2],
) -> Box<dyn FnMut(&[f64], &mut [f64]) + 'a> {
    let n = free.len();
    let m = jt_flat.len() / n.max(1);
    let t = n / 2;
    let jt = faer::MatRef::from_column_major_slice(jt_flat, n, m);
    let inv_delta: Vec<f64> = (0..n)
        .map(|i| {
            if free[i] {
                let deg = umbrella.degree(i % t) as f64;
                let gam = gammas[usize::from(i >= t)];
                1.0 / (mu * diag[i] + prior + gam * (deg * deg + deg)).max(1e-300)
            } else {
                0.0
            }
        })
        .collect();
    // W = Δ^{-1/2} J_Fᵀ (n × m, column-major like `jt_flat`), S = I + WᵀW.
    let sqrt_inv: Vec<f64> = inv_delta.iter().map(|v| v.sqrt()).collect();
    let w: Vec<f64> = jt_flat
        .chunks_exact(n)
        .flat_map(|col| col.iter().zip(&sqrt_inv).map(|(j, s)| j * s))
        .collect();
    let w = faer::MatRef::from_column_major_slice(&w, n, m);
    let mut s = faer::Mat::<f64>::identity(m, m);
    faer::linalg::matmul::matmul(
        s.as_mut(),
        faer::Accum::Add,
        w.transpose(),
        w,
        1.0,
        faer::Par::Seq,
    );
    let s = nalgebra::DMatrix::<f64>::from_fn(m, m, |a, b| s[(a, b)]);
    let Some(chol) = s.cholesky() else {
        return Box::new(move |r: &[f64], z: &mut [f64]| {
            for i in 0..n {
                z[i] = r[i] * inv_delta[i];
            }
        });
    };
    let mut y = nalgebra::DVector::<f64>::zeros(m);
    let mut jy = vec![0.0; n];
    Box::new(move |r: &[f64], z: &mut [f64]| {
        for i in 0..n {
            z[i] = r[i] * inv_delta[i];
        }
        faer::linalg::matmul::matmul(
            faer::MatMut::from_column_major_slice_mut(y.as_mut_slice(), m, 1),
            faer::Accum::Replace,
            jt.transpose(),
            faer::MatRef::from_column_major_slice(z, n, 1),
            1.0,
            faer::Par::Seq,
        );
        chol.solve_mut(&mut y);
        // z ← z − Δ⁻¹ J_Fᵀ S⁻¹ J_F Δ⁻¹ r (entries of constrained variables stay 0).
        faer::linalg::matmul::matmul(
            faer::MatMut::from_column_major_slice_mut(&mut jy, n, 1),
            faer::Accum::Replace,
            jt,
            faer::MatRef::from_column_major_slice(y.as_slice(), m, 1),
            1.0,
            faer::Par::Seq,
        );
        for i in 0..n {
            z[i] -= inv_delta[i] * jy[i];
        }
    })
}

/// Settings of [`fit_homogeneous`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct HomogeneousFitSettings {
    /// Starting Young's modulus, Pa (rescaled by a first linear estimate).
    pub initial_young_pa: f64,
    /// Starting Poisson ratio.
    pub initial_nu: f64,
    /// Bounds on ν.
    pub nu_bounds: (f64, f64),
    /// LM settings.
    pub lm: softcap_core::LevenbergMarquardtSettings,
    /// Equilibrium settings.
    pub equilibrium: EquilibriumSettings,
    /// Patch of the force boundary condition.
    pub patch: PatchSettings,
}

impl Default for HomogeneousFitSettings {
    fn default() -> Self {
        Self {
            initial_young_pa: 3.0e4,
            initial_nu: 0.4,
            nu_bounds: (0.0, 0.49),
            lm: softcap_core::LevenbergMarquardtSettings {
                max_iterations: 20,
                relative_cost_tolerance: 1e-6,
                gradient_tolerance: 0.0,
                ..Default::default()
            },
            equilibrium: ExampleFitSettings::default().equilibrium,
            patch: PatchSettings::default(),
        }
    }
}

/// Result of [`fit_homogeneous`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct HomogeneousFit {
    /// The one (λ, α) of every tet.
    pub params: LinearParams,
    /// RMS marker error of each example, m.
    pub example_rms_m: Vec<f64>,
    /// RMS marker error over all examples, m.
    pub rms_m: f64,
    /// LM iterations.
    pub iterations: usize,
}

struct HomogeneousProblem<'a> {
    setup: &'a ProbingSetup,
    examples: &'a [ProbeExample],
    forces: Vec<Vec<Vector3<f64>>>,
    warm: Vec<Vec<Vector3<f64>>>,
    solver: StaticSolver,
    model: CorotationalModel,
    young_ref: f64,
    settings: &'a HomogeneousFitSettings,
    m: usize,
}

impl HomogeneousProblem<'_> {
    fn params(&self, q: &[f64]) -> Option<LinearParams> {
        LinearParams::from_young_poisson(self.young_ref * q[0].exp(), q[1]).ok()
    }

    fn run(&mut self, q: &[f64], r: &mut [f64], mut jac: Option<&mut nalgebra::DMatrix<f64>>) {
        let Some(p) = self.params(q) else {
            r.iter_mut().for_each(|v| *v = f64::NAN);
            return;
        };
        let t = self.setup.num_elements();
        let mut row0 = 0;
        for (k, ex) in self.examples.iter().enumerate() {
            let mut x = self.warm[k].clone();
            let ok = simulate_params(
                self.setup,
                &mut self.solver,
                &mut self.model,
                &vec![p; t],
                &self.forces[k],
                &mut x,
                &self.settings.equilibrium,
            )
            .map(|rep| rep.converged())
            .unwrap_or(false);
            let rk = marker_residuals(self.setup, ex, &x);
            for (i, v) in rk.iter().enumerate() {
                r[row0 + i] = if ok { *v } else { f64::NAN };
            }
            if let Some(j) = jac.as_deref_mut() {
                // Forward sensitivities (appendix eq. 11) along "every λ_e" and "every α_e": two
                // solves per example instead of one adjoint solve per marker coordinate.
                let columns = Sensitivity::new(
                    &mut self.solver,
                    &self.model,
                    &x,
                    StiffnessKind::Consistent,
                    None,
                )
                .and_then(|sens| {
                    let mut v = vec![0.0; 2 * t];
                    v.iter_mut().step_by(2).for_each(|a| *a = 1.0);
                    let dl = sens.jacobian_times(&v)?;
                    v.iter_mut().for_each(|a| *a = 1.0 - *a);
                    let da = sens.jacobian_times(&v)?;
                    Ok((dl, da))
                });
                if let Ok((dl, da)) = columns {
                    // (E, ν) ↦ (λ, α): λ = E/((1+ν)(1−2ν)), α = νλ; q0 = ln E/E_ref.
                    let (e_pa, nu) = (self.young_ref * q[0].exp(), q[1]);
                    let den = (1.0 + nu) * (1.0 - 2.0 * nu);
                    let lam = e_pa / den;
                    let dlam_dnu = e_pa * (1.0 + 4.0 * nu) / (den * den);
                    let dalpha_dnu = lam + nu * dlam_dnu;
                    let mut i = 0;
                    for o in &ex.observed {
                        let emb = &self.setup.markers[o.marker];
                        let tet = self.setup.mesh.tets[emb.tet];
                        for c in 0..3 {
                            let (mut jl, mut ja) = (0.0, 0.0);
                            for a in 0..4 {
                                jl += emb.weights[a] * dl[3 * tet[a] + c];
                                ja += emb.weights[a] * da[3 * tet[a] + c];
                            }
                            // ∂/∂q0 = E ∂/∂E = λ ∂/∂λ + α ∂/∂α.
                            j[(row0 + i, 0)] = lam * jl + nu * lam * ja;
                            j[(row0 + i, 1)] = dlam_dnu * jl + dalpha_dnu * ja;
                            i += 1;
                        }
                    }
                }
            }
            if ok {
                self.warm[k] = x;
            }
            row0 += rk.len();
        }
    }
}

impl softcap_core::LeastSquaresProblem for HomogeneousProblem<'_> {
    fn num_params(&self) -> usize {
        2
    }
    fn num_residuals(&self) -> usize {
        self.m
    }
    fn residuals(&mut self, params: &[f64], residuals: &mut [f64]) {
        self.run(params, residuals, None);
    }
    fn jacobian(&mut self, params: &[f64], jacobian: &mut nalgebra::DMatrix<f64>) -> bool {
        let mut r = vec![0.0; self.m];
        self.run(params, &mut r, Some(jacobian));
        true
    }
}

/// The average-fit homogeneous linear corotational model (bickel2009 §6, Fig. 8 baseline): one
/// (E, ν) for every tet that best fits all examples' markers in the least-squares sense,
/// by Levenberg–Marquardt over (ln E, ν) with the adjoint Jacobian summed over the tets. The
/// start E is first rescaled by the linear estimate E ← E·(u_sim·u_sim)/(u_sim·u_meas).
pub fn fit_homogeneous(
    setup: &ProbingSetup,
    examples: &[ProbeExample],
    settings: &HomogeneousFitSettings,
) -> Result<HomogeneousFit, FemError> {
    let t = setup.num_elements();
    let p0 = LinearParams::from_young_poisson(settings.initial_young_pa, settings.initial_nu)?;
    let model = CorotationalModel::homogeneous(&setup.mesh, p0)?;
    let solver = setup.solver(&model)?;
    let forces: Vec<_> = examples
        .iter()
        .map(|ex| setup.nodal_forces(ex, &settings.patch))
        .collect();
    let m: usize = examples.iter().map(|e| 3 * e.observed.len()).sum();
    let mut problem = HomogeneousProblem {
        setup,
        examples,
        forces,
        warm: vec![setup.mesh.vertices.clone(); examples.len()],
        solver,
        model,
        young_ref: settings.initial_young_pa,
        settings,
        m,
    };
    // The start must reach equilibrium on every example: otherwise its residuals are NaN, the
    // linear rescaling below is skipped and Levenberg–Marquardt cannot leave the start, so the
    // "fit" is the initial guess (measured: a relaxing soft block under the lumped patch force,
    // 30 kPa start, marker RMS 1.6 mm). A stiffer material deforms less, so E is doubled until
    // every example converges (at most `START_DOUBLINGS` times; the rescaling then undoes it).
    const START_DOUBLINGS: usize = 16;
    let mut r = vec![0.0; m];
    for doubling in 0..=START_DOUBLINGS {
        problem.run(&[0.0, settings.initial_nu], &mut r, None);
        if r.iter().all(|v| v.is_finite()) || doubling == START_DOUBLINGS {
            break;
        }
        problem.young_ref *= 2.0;
        problem.warm = vec![setup.mesh.vertices.clone(); examples.len()];
    }
    // Linear rescaling of the start: displacements scale like 1/E.
    let (mut uu, mut um) = (0.0, 0.0);
    let mut row = 0;
    for ex in examples {
        for o in &ex.observed {
            let rest = setup.markers[o.marker].position(&setup.mesh.tets, &setup.mesh.vertices);
            for c in 0..3 {
                let meas = o.position_m[c] - rest[c];
                let sim = r[row] + meas;
                uu += sim * sim;
                um += sim * meas;
                row += 1;
            }
        }
    }
    if um > 0.0 && uu.is_finite() {
        problem.young_ref *= uu / um;
    }
    problem.warm = vec![setup.mesh.vertices.clone(); examples.len()];
    let bounds = softcap_core::Bounds::new(
        vec![-5.0, settings.nu_bounds.0],
        vec![5.0, settings.nu_bounds.1],
    )
    .map_err(|e| probing_error(e.to_string()))?;
    let report = softcap_core::levenberg_marquardt(
        &mut problem,
        &[0.0, settings.initial_nu],
        Some(&bounds),
        &settings.lm,
    )
    .map_err(|e| probing_error(e.to_string()))?;
    if !report.residuals.iter().all(|v| v.is_finite()) {
        return Err(probing_error(
            "homogeneous fit: an example does not reach equilibrium at the fitted material",
        ));
    }
    let params = problem
        .params(&report.params)
        .ok_or_else(|| probing_error("homogeneous fit left the valid parameter range"))?;
    let mut example_rms_m = Vec::with_capacity(examples.len());
    let mut row = 0;
    let mut total = 0.0;
    for ex in examples {
        let k = 3 * ex.observed.len();
        let rk = &report.residuals[row..row + k];
        total += rk.iter().map(|v| v * v).sum::<f64>();
        example_rms_m.push(rms_of(rk));
        row += k;
    }
    let _ = t;
    Ok(HomogeneousFit {
        params,
        example_rms_m,
        rms_m: (total / (m / 3).max(1) as f64).sqrt(),
        iterations: report.iterations,
    })
}

/// One element's strain-space RBF (bickel2009 eq. 8 with the degree-0 polynomial term of
/// Carr et al. 2001): p(ε) = c + Σᵢ wᵢ ‖ε − εᵢ‖, wᵢ, c ∈ ℝ² (λ, α), with the side condition
/// Σᵢ wᵢ = 0 when c is fitted.
///
/// Why the constant term: eq. 8 alone (c = 0) cannot even reproduce a constant material, and
/// for ‖ε‖ → ∞ it grows like (Σᵢ wᵢ)‖ε‖ — a cone whose slope is set by how close the samples
/// are (two samples of the same λ at distance d extrapolate with slope 2λ/d). Samples of one
/// element cluster at small strains, so a novel deformation that leaves their span (a
/// different tip, a deeper press) meets parameters many times the measured ones (measured:
/// up to 13× on a three-layer block, docs/tissue.md). With c and Σwᵢ = 0 (Carr et al. 2001
/// §3, polynomial of degree 0 for the biharmonic kernel φ(r) = r), constants are reproduced
/// exactly and p is bounded: |p(ε) − c| ≤ Σᵢ |wᵢ| ‖εᵢ‖ for every ε. The linear polynomial
/// (1, ε₁ … ε₆) would need ≥ 7 unisolvent samples per element and extrapolates linearly
/// again, so it is not used.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ElementRbf {
    /// Sample indices of the centres (see [`StrainSpaceMaterial::fit`]).
    pub center_samples: Vec<usize>,
    /// Centres εᵢ (corotated Voigt strain).
    pub centers: Vec<[f64; 6]>,
    /// Weights wᵢ = (w_λ, w_α), Pa.
    pub weights: Vec<[f64; 2]>,
    /// Constant term c = (c_λ, c_α), Pa ([0, 0]: eq. 8 without polynomial term).
    #[serde(default)]
    pub constant: [f64; 2],
}

impl ElementRbf {
    /// p(ε) unclamped: (λ, α), Pa.
    pub fn evaluate(&self, strain: &[f64; 6]) -> [f64; 2] {
        let mut out = self.constant;
        for (c, w) in self.centers.iter().zip(&self.weights) {
            let r = strain_distance(c, strain);
            out[0] += w[0] * r;
            out[1] += w[1] * r;
        }
        out
    }
}

fn strain_distance(a: &[f64; 6], b: &[f64; 6]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y) * (x - y))
        .sum::<f64>()
        .sqrt()
}

/// Polynomial term of the strain-space RBF.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum StrainTail {
    /// bickel2009 eq. 8 as printed: no polynomial term.
    None,
    /// Constant c with Σwᵢ = 0 (Carr et al. 2001, degree 0): bounded extrapolation.
    #[default]
    Constant,
}

/// Settings of the strain-space basis (bickel2009 §4.2).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct StrainBasisSettings {
    /// Greedy stops when the RMS parameter error over the samples is below this fraction of the
    /// element's mean λ.
    pub relative_tolerance: f64,
    /// At most this many centres per element.
    pub max_centers: usize,
    /// Evaluated parameters are clamped to λ ≥ this fraction of the element's smallest sample λ …
    pub lambda_floor_fraction: f64,
    /// … λ ≤ this fraction of its largest sample λ (≤ 0: no ceiling) …
    pub lambda_ceiling_fraction: f64,
    /// … and ν = α/λ to these bounds.
    pub nu_bounds: (f64, f64),
    /// Polynomial term (default: the constant of Carr et al. 2001, see [`ElementRbf`]).
    pub tail: StrainTail,
}

impl Default for StrainBasisSettings {
    fn default() -> Self {
        Self {
            relative_tolerance: 0.02,
            max_centers: 12,
            lambda_floor_fraction: 0.5,
            lambda_ceiling_fraction: 1.0,
            nu_bounds: (0.0, 0.49),
            tail: StrainTail::Constant,
        }
    }
}

/// One greedy step summed over the elements: error against basis size (bickel2009 Fig. 5).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct BasisErrorStep {
    /// Basis size M.
    pub num_centers: usize,
    /// RMS over elements (those still growing use their error at M, finished ones their final
    /// error) of the relative parameter error ‖p(εₖ) − pₖ‖/λ̄_e.
    pub relative_rms_error: f64,
}

/// The strain-space material of bickel2009 §3.3: one RBF p_e(ε) per tet.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StrainSpaceMaterial {
    /// Per-element RBFs.
    pub elements: Vec<ElementRbf>,
    /// Lower bound on λ per element, Pa (validity clamp).
    pub lambda_floor_pa: Vec<f64>,
    /// ν bounds of the validity clamp.
    pub nu_bounds: (f64, f64),
    /// Upper bound on λ per element, Pa (empty: none): the material does not leave the range of
    /// parameters measured for the element.
    #[serde(default)]
    pub lambda_ceiling_pa: Vec<f64>,
}

/// A strain-space sample: one fitted example at one element.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StrainSample {
    /// ε.
    pub strain: [f64; 6],
    /// p = (λ, α).
    pub params: LinearParams,
}

/// Least-squares fit of one element's RBF with the given centres (bickel2009 §4.2: "compute the
/// RBF weights that best fit the parameter vectors for all N example deformations in a
/// least-squares manner", eq. 8): minimizes Σₖ ‖p(εₖ) − pₖ‖² over (w, c) subject to Σwᵢ = 0
/// (constant tail; w = Z v with Z = [I; −1ᵀ] spanning the side condition) or over w alone (no
/// tail). Dense SVD (M ≤ a few tens): the minimum-norm solution when samples are duplicated.
/// Written here rather than with `softcap_core::Rbf` because that offers no degree-0 tail.
fn fit_element_rbf(
    samples: &[StrainSample],
    centers: &[usize],
    tail: StrainTail,
) -> Result<ElementRbf, FemError> {
    let n = samples.len();
    let m = centers.len();
    let (free, has_c) = match tail {
        StrainTail::Constant => (m.saturating_sub(1), true),
        StrainTail::None => (m, false),
    };
    let cols = free + usize::from(has_c);
    let mut a = nalgebra::DMatrix::<f64>::zeros(n, cols.max(1));
    let mut b = nalgebra::DMatrix::<f64>::zeros(n, 2);
    for (k, s) in samples.iter().enumerate() {
        let phi: Vec<f64> = centers
            .iter()
            .map(|&c| strain_distance(&samples[c].strain, &s.strain))
            .collect();
        match tail {
            StrainTail::Constant => {
                for j in 0..free {
                    a[(k, j)] = phi[j] - phi[m - 1];
                }
                a[(k, free)] = 1.0;
            }
            StrainTail::None => {
                for j in 0..m {
                    a[(k, j)] = phi[j];
                }
            }
        }
        b[(k, 0)] = s.params.lambda;
        b[(k, 1)] = s.params.alpha;
    }
    let svd = a.svd(true, true);
    let tol = 1e-12 * svd.singular_values.max().max(f64::MIN_POSITIVE);
    let x = svd
        .solve(&b, tol)
        .map_err(|e| probing_error(format!("strain-space least squares: {e}")))?;
    let mut weights = vec![[0.0; 2]; m];
    let mut constant = [0.0; 2];
    for o in 0..2 {
        match tail {
            StrainTail::Constant => {
                let mut last = 0.0;
                for j in 0..free {
                    weights[j][o] = x[(j, o)];
                    last -= x[(j, o)];
                }
                if m > 0 {
                    weights[m - 1][o] = last;
                }
                constant[o] = x[(free, o)];
            }
            StrainTail::None => {
                for j in 0..m {
                    weights[j][o] = x[(j, o)];
                }
            }
        }
    }
    if weights
        .iter()
        .chain(std::iter::once(&constant))
        .flatten()
        .any(|v| !v.is_finite())
    {
        return Err(probing_error(
            "strain-space least squares: non-finite weights",
        ));
    }
    Ok(ElementRbf {
        center_samples: centers.to_vec(),
        centers: centers.iter().map(|&c| samples[c].strain).collect(),
        weights,
        constant,
    })
}

impl StrainSpaceMaterial {
    /// Builds the per-element RBFs from `samples[e]` (sample k of element e) by greedy selection
    /// (bickel2009 §4.2 after Carr et al. 2001): start with sample 0 (by convention the
    /// zero-strain sample with the average parameters; with the constant tail the one-centre fit
    /// is the least-squares constant, i.e. the average material), fit eq. 8 to all samples in
    /// the least-squares sense ([`fit_element_rbf`]), add the sample with the largest error,
    /// until the RMS error is below `relative_tolerance` × mean λ (`max_centers` at most).
    /// Evaluation clamps λ to [floor, ceiling] from the element's smallest / largest sample λ
    /// and ν = α/λ to `nu_bounds`, so the material stays physically valid at any strain.
    /// Returns the material and the error-vs-basis-size curve (bickel2009 Fig. 5).
    pub fn fit(
        samples: &[Vec<StrainSample>],
        settings: &StrainBasisSettings,
    ) -> Result<(Self, Vec<BasisErrorStep>), FemError> {
        let mut elements = Vec::with_capacity(samples.len());
        let mut floors = Vec::with_capacity(samples.len());
        let mut ceilings = Vec::with_capacity(samples.len());
        let mut histories: Vec<Vec<f64>> = Vec::with_capacity(samples.len());
        let max_centers = settings.max_centers.max(1);
        for (e, s) in samples.iter().enumerate() {
            if s.is_empty() {
                return Err(probing_error(format!("element {e}: no strain samples")));
            }
            if let Some(k) = s.iter().position(|p| {
                !(p.strain.iter().all(|v| v.is_finite())
                    && p.params.lambda.is_finite()
                    && p.params.alpha.is_finite())
            }) {
                return Err(probing_error(format!("element {e}: sample {k} not finite")));
            }
            let mean_lambda = s.iter().map(|p| p.params.lambda).sum::<f64>() / s.len() as f64;
            let tolerance = settings.relative_tolerance * mean_lambda.abs();
            let mut centers = vec![0usize];
            let mut history = Vec::new();
            let rbf = loop {
                let rbf = fit_element_rbf(s, &centers, settings.tail)
                    .map_err(|err| probing_error(format!("element {e}: {err}")))?;
                let errors: Vec<f64> = s
                    .iter()
                    .map(|p| {
                        let v = rbf.evaluate(&p.strain);
                        (v[0] - p.params.lambda).hypot(v[1] - p.params.alpha)
                    })
                    .collect();
                let rms = (errors.iter().map(|v| v * v).sum::<f64>() / s.len() as f64).sqrt();
                history.push(rms / mean_lambda.abs().max(f64::MIN_POSITIVE));
                // Worst sample among non-centres whose strain is not already a centre's.
                let worst = (0..s.len())
                    .filter(|k| {
                        centers
                            .iter()
                            .all(|&c| strain_distance(&s[c].strain, &s[*k].strain) > 0.0)
                    })
                    .max_by(|&a, &b| errors[a].total_cmp(&errors[b]).then(b.cmp(&a)));
                match worst {
                    Some(k) if rms > tolerance && centers.len() < max_centers => centers.push(k),
                    _ => break rbf,
                }
            };
            elements.push(rbf);
            let min_lambda = s
                .iter()
                .map(|p| p.params.lambda)
                .fold(f64::INFINITY, f64::min);
            let max_lambda = s.iter().map(|p| p.params.lambda).fold(0.0, f64::max);
            let floor = settings.lambda_floor_fraction * min_lambda;
            floors.push(floor);
            if settings.lambda_ceiling_fraction > 0.0 {
                ceilings.push((settings.lambda_ceiling_fraction * max_lambda).max(floor));
            }
            histories.push(history);
        }
        let longest = histories.iter().map(Vec::len).max().unwrap_or(0);
        let curve = (0..longest)
            .map(|k| {
                let sum2: f64 = histories
                    .iter()
                    .map(|h| {
                        let v = h[k.min(h.len() - 1)];
                        v * v
                    })
                    .sum();
                BasisErrorStep {
                    num_centers: k + 1,
                    relative_rms_error: (sum2 / histories.len().max(1) as f64).sqrt(),
                }
            })
            .collect();
        Ok((
            Self {
                elements,
                lambda_floor_pa: floors,
                nu_bounds: settings.nu_bounds,
                lambda_ceiling_pa: ceilings,
            },
            curve,
        ))
    }

    /// Rebuilds a material from the flat layout of `/tissue/basis` (docs/formats.md): T tets ×
    /// M padded centres, `centers_strain` T·M·6, `weights` T·M·2, `constants` T·2 (empty: no
    /// polynomial term), `centers_per_tet` T (empty: all M used), `center_samples` T·M (empty:
    /// 0..C), `lambda_floor_pa` T (empty: 1 Pa), `lambda_ceiling_pa` T or empty, ν bounds.
    #[allow(clippy::too_many_arguments)]
    pub fn from_flat(
        tets: usize,
        centers: usize,
        centers_strain: &[f64],
        weights: &[f64],
        constants: &[f64],
        centers_per_tet: &[u32],
        center_samples: &[u32],
        lambda_floor_pa: &[f64],
        lambda_ceiling_pa: &[f64],
        nu_bounds: (f64, f64),
    ) -> Result<Self, FemError> {
        let (t, m) = (tets, centers);
        let bad = |what: &str| Err(probing_error(format!("strain-space basis: {what}")));
        if centers_strain.len() != t * m * 6 || weights.len() != t * m * 2 {
            return bad("centres / weights length is not tets × M × 6 / 2");
        }
        if !(constants.is_empty() || constants.len() == 2 * t)
            || !(centers_per_tet.is_empty() || centers_per_tet.len() == t)
            || !(center_samples.is_empty() || center_samples.len() == t * m)
            || !(lambda_floor_pa.is_empty() || lambda_floor_pa.len() == t)
            || !(lambda_ceiling_pa.is_empty() || lambda_ceiling_pa.len() == t)
        {
            return bad("an array has neither 0 nor the per-tet length");
        }
        if centers_strain
            .iter()
            .chain(weights)
            .chain(constants)
            .chain(lambda_floor_pa)
            .chain(lambda_ceiling_pa)
            .any(|v| !v.is_finite())
        {
            return bad("non-finite value");
        }
        if !(nu_bounds.0 > -1.0 && nu_bounds.0 <= nu_bounds.1 && nu_bounds.1 < 0.5) {
            return bad("ν bounds outside (−1, 0.5)");
        }
        let mut elements = Vec::with_capacity(t);
        for e in 0..t {
            let c = centers_per_tet.get(e).map_or(m, |&c| c as usize);
            if c > m {
                return bad("centers_per_tet larger than M");
            }
            elements.push(ElementRbf {
                center_samples: if center_samples.is_empty() {
                    (0..c).collect()
                } else {
                    center_samples[e * m..e * m + c]
                        .iter()
                        .map(|&s| s as usize)
                        .collect()
                },
                centers: (0..c)
                    .map(|i| {
                        let s = &centers_strain[(e * m + i) * 6..(e * m + i + 1) * 6];
                        [s[0], s[1], s[2], s[3], s[4], s[5]]
                    })
                    .collect(),
                weights: (0..c)
                    .map(|i| [weights[(e * m + i) * 2], weights[(e * m + i) * 2 + 1]])
                    .collect(),
                constant: if constants.is_empty() {
                    [0.0; 2]
                } else {
                    [constants[2 * e], constants[2 * e + 1]]
                },
            });
        }
        let floors: Vec<f64> = (0..t)
            .map(|e| {
                lambda_floor_pa
                    .get(e)
                    .copied()
                    .filter(|v| *v > 0.0)
                    .unwrap_or(1.0)
            })
            .collect();
        Ok(Self {
            elements,
            lambda_floor_pa: floors,
            nu_bounds,
            lambda_ceiling_pa: lambda_ceiling_pa.to_vec(),
        })
    }

    /// p_e(ε) clamped to the valid region (floor ≤ λ ≤ ceiling, ν within bounds).
    pub fn evaluate(&self, element: usize, strain: &Vector6<f64>) -> LinearParams {
        let s = [
            strain[0], strain[1], strain[2], strain[3], strain[4], strain[5],
        ];
        let [l, a] = self.elements[element].evaluate(&s);
        let floor = self.lambda_floor_pa[element];
        let ceiling = self
            .lambda_ceiling_pa
            .get(element)
            .copied()
            .unwrap_or(f64::INFINITY)
            .max(floor);
        let lambda = if l.is_finite() {
            l.clamp(floor, ceiling)
        } else {
            floor
        };
        let nu = if a.is_finite() { a / lambda } else { 0.0 };
        let nu = nu.clamp(self.nu_bounds.0, self.nu_bounds.1);
        LinearParams {
            lambda,
            alpha: nu * lambda,
        }
    }

    /// Mean number of centres per element.
    pub fn mean_centers(&self) -> f64 {
        self.elements.iter().map(|e| e.centers.len()).sum::<usize>() as f64
            / self.elements.len().max(1) as f64
    }

    /// A corotational model over `mesh` whose parameters follow this material at every
    /// equilibrium iteration (bickel2009 §3.4).
    pub fn model(self: &Arc<Self>, mesh: &TetMesh) -> Result<CorotationalModel, FemError> {
        let zero = Vector6::zeros();
        let params = (0..mesh.tets.len())
            .map(|e| self.evaluate(e, &zero))
            .collect();
        Ok(CorotationalModel::new(mesh, params)?
            .with_strain_dependence(self.clone() as Arc<dyn StrainDependentParams>))
    }
}

impl StrainDependentParams for StrainSpaceMaterial {
    fn params(&self, element: usize, strain: &Vector6<f64>) -> LinearParams {
        self.evaluate(element, strain)
    }
}

/// The strain-space material as an [`ElasticModel`] for synthesis (bickel2009 §3.4: "at each
/// iteration ... we first compute the material parameters for the current configuration") with
/// under-relaxed parameter updates p ← p + ω (p(ε) − p).
///
/// The plain iteration (ω = 1, [`StrainSpaceMaterial::model`]) is a Picard (secant) iteration
/// on p(ε): where λ rises with strain a step from the soft parameters overshoots, the stiff
/// parameters of the overshoot pull back too far, and the equilibrium oscillates (measured: no
/// convergence in 300 iterations for the 1 N examples of a three-layer block, docs/tissue.md).
/// Damping the parameter update keeps the same fixed points — at equilibrium p = p(ε) — and
/// contracts the oscillation. The convex combination of two valid parameter sets is valid
/// (ν of the blend lies between the two ν), so the clamp of [`StrainSpaceMaterial::evaluate`]
/// keeps holding. The parameters persist across solves (warm start along incremental loading);
/// [`Self::reset`] returns to the zero-strain material.
#[derive(Clone, Debug)]
pub struct StrainSpaceModel {
    inner: CorotationalModel,
    material: Arc<StrainSpaceMaterial>,
    /// Relaxation ω ∈ (0, 1] of the parameter update.
    pub relaxation: f64,
}

impl StrainSpaceModel {
    /// The model over `mesh` starting from the material at zero strain.
    pub fn new(
        material: Arc<StrainSpaceMaterial>,
        mesh: &TetMesh,
        relaxation: f64,
    ) -> Result<Self, FemError> {
        if material.elements.len() != mesh.tets.len() {
            return Err(FemError::LengthMismatch {
                what: "strain-space elements",
                expected: mesh.tets.len(),
                got: material.elements.len(),
            });
        }
        if !(relaxation > 0.0 && relaxation <= 1.0) {
            return Err(probing_error(format!(
                "relaxation {relaxation} must lie in (0, 1]"
            )));
        }
        let zero = Vector6::zeros();
        let params = (0..mesh.tets.len())
            .map(|e| material.evaluate(e, &zero))
            .collect();
        Ok(Self {
            inner: CorotationalModel::new(mesh, params)?,
            material,
            relaxation,
        })
    }

    /// Current per-element parameters.
    pub fn params(&self) -> &[LinearParams] {
        self.inner.params()
    }

    /// Back to the material at zero strain.
    pub fn reset(&mut self) {
        let zero = Vector6::zeros();
        let params: Vec<LinearParams> = (0..self.material.elements.len())
            .map(|e| self.material.evaluate(e, &zero))
            .collect();
        self.inner
            .set_params(&params)
            .expect("one parameter set per element");
    }

    /// The material.
    pub fn material(&self) -> &Arc<StrainSpaceMaterial> {
        &self.material
    }
}

impl ElasticModel for StrainSpaceModel {
    fn rest_positions(&self) -> &[Vector3<f64>] {
        self.inner.rest_positions()
    }
    fn elements(&self) -> &[softcap_fem::TetGeometry] {
        self.inner.elements()
    }
    fn element_forces(&self, e: usize, x: &[Vector3<f64>]) -> [Vector3<f64>; 4] {
        self.inner.element_forces(e, x)
    }
    fn element_matrix(
        &self,
        e: usize,
        x: &[Vector3<f64>],
        kind: StiffnessKind,
    ) -> softcap_fem::Matrix12 {
        self.inner.element_matrix(e, x, kind)
    }
    fn energy(&self, _x: &[Vector3<f64>]) -> Option<f64> {
        None // Cauchy-elastic (thesis §7.4.3): no potential.
    }
    fn internal_forces(&self, x: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        self.inner.internal_forces(x)
    }
    fn forces_and_energy(&self, x: &[Vector3<f64>]) -> (Vec<Vector3<f64>>, Option<f64>) {
        (self.inner.internal_forces(x), None)
    }
    fn linearize_elements(
        &self,
        first: usize,
        x: &[Vector3<f64>],
        kind: StiffnessKind,
        forces: &mut [[Vector3<f64>; 4]],
        matrices: &mut [softcap_fem::Matrix12],
    ) -> Option<f64> {
        self.inner
            .linearize_elements(first, x, kind, forces, matrices);
        None
    }
    fn update_state(&mut self, x: &[Vector3<f64>]) {
        let strains = self.inner.strains(x);
        let w = self.relaxation;
        let params: Vec<LinearParams> = self
            .inner
            .params()
            .iter()
            .zip(&strains)
            .enumerate()
            .map(|(e, (p, eps))| {
                let target = self.material.evaluate(e, eps);
                LinearParams {
                    lambda: p.lambda + w * (target.lambda - p.lambda),
                    alpha: p.alpha + w * (target.alpha - p.alpha),
                }
            })
            .collect();
        self.inner
            .set_params(&params)
            .expect("one parameter set per element");
    }
}

/// Settings of [`StrainSpaceModel::solve_continued`]: equilibrium of the strain-space material
/// under one load, continued from the previous equilibrium, with incremental loading from rest
/// (bickel2009 §3.4) as the fallback path.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct StrainSpaceSolveSettings {
    /// Relaxation ω ∈ (0, 1] of the parameter update p ← p + ω (p(ε) − p)
    /// ([`StrainSpaceModel`]; 1 = the plain iteration of bickel2009 §3.4).
    pub relaxation: f64,
    /// Load increments of the solve from rest when the continued solve does not converge.
    pub load_steps: usize,
    /// Halvings of ω, each with twice the increments, after a solve from rest that does not
    /// converge (a smaller ω contracts the parameter oscillation more; same fixed points).
    pub relaxation_retries: usize,
    /// Equilibrium iterations per solve (replaces the equilibrium settings' limit). The
    /// displacement iteration is Newton's, but the parameters converge only linearly, at the
    /// rate |1 − ω (1 − μ)| of the relaxed fixed point p ← p + ω (p(ε) − p) (μ the eigenvalues
    /// of ∂p(ε(p))/∂p): measured on the diagnose suite's clean control (648 tets, 1.4 N
    /// presses, ω ½, Newton, displacement tolerance 10⁻⁸ of the bounding-box diagonal), the
    /// deepest frames need 100–110 iterations with the whole load in one solve, so 100 (the
    /// equilibrium default) stopped them just short of the tolerance.
    pub max_iterations: usize,
}

impl Default for StrainSpaceSolveSettings {
    fn default() -> Self {
        Self {
            // ½ halves every parameter jump: it stops the oscillation of the plain iteration on
            // the three-layer block of docs/tissue.md (the tissue stage's default, too).
            relaxation: 0.5,
            load_steps: 4,
            relaxation_retries: 2,
            max_iterations: 400,
        }
    }
}

/// How [`StrainSpaceModel::solve_continued`] reached (or missed) its equilibrium.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StrainSpaceSolve {
    /// The last equilibrium solve (of the last increment when loaded from rest).
    pub report: EquilibriumReport,
    /// `None`: continued from the previous equilibrium; `Some(k)`: from rest by incremental
    /// loading with ω halved k times (the last attempt when not converged).
    pub from_rest_attempt: Option<usize>,
    /// Equilibrium iterations over every attempt.
    pub iterations: usize,
}

impl StrainSpaceSolve {
    /// True if the equilibrium was reached.
    pub fn converged(&self) -> bool {
        self.report.converged()
    }
}

impl StrainSpaceModel {
    /// Equilibrium of the strain-space material (p = p(ε) at every element, bickel2009 §3.4)
    /// under the external nodal `forces` on `setup` (attached nodes fixed at rest), continued
    /// from the equilibrium this model and `x` hold under `previous_forces` — the previous frame
    /// of a recording; the rest shape, the zero-strain parameters and zero forces before the
    /// first solve.
    ///
    /// The path is the incremental loading of §3.4. A Cauchy-elastic material (thesis §7.4.3)
    /// has no memory, but the strain-space fixed point p = p(ε(p)) need not be unique: measured
    /// on the diagnose suite's clean control (648 tets), the full 1.3 N load applied in one step
    /// from rest reaches an equilibrium 0.077 mm (of 0.93 mm) away from the one that 2, 4, 8 or
    /// 16 increments reach (those agree to 10⁻⁸ m). So the load goes from `previous_forces` to
    /// `forces` in ⌈n ‖Δf‖ / max(‖f‖, ‖f_prev‖)⌉ increments (n = `settings.load_steps`, ‖·‖ over
    /// all nodal forces): a recording's next frame is usually one increment; a change of more
    /// than half the load (another location, a jump) is loaded from rest in n increments
    /// instead, the path of the tissue fit's re-simulation, so the equilibrium does not depend
    /// on which frame came before. When that does not converge, the load is applied from rest
    /// again with ω halved and twice the increments, `settings.relaxation_retries` times.
    ///
    /// Non-convergence is the returned status; then `x` and the parameters are left at the
    /// state the call started from, so a later solve continues from the last equilibrium. On
    /// convergence the solver's factor is the consistent tangent at the equilibrium with the
    /// parameters frozen at their final values (p(ε) to the solver tolerance).
    #[allow(clippy::too_many_arguments)]
    pub fn solve_continued(
        &mut self,
        setup: &ProbingSetup,
        solver: &mut StaticSolver,
        x: &mut [Vector3<f64>],
        previous_forces: &[Vector3<f64>],
        forces: &[Vector3<f64>],
        equilibrium: &EquilibriumSettings,
        settings: &StrainSpaceSolveSettings,
    ) -> Result<StrainSpaceSolve, FemError> {
        if !(settings.relaxation > 0.0 && settings.relaxation <= 1.0) {
            return Err(probing_error(format!(
                "relaxation {} must lie in (0, 1]",
                settings.relaxation
            )));
        }
        let n = setup.mesh.vertices.len();
        for (what, len) in [
            ("node positions", x.len()),
            ("previous nodal forces", previous_forces.len()),
            ("nodal forces", forces.len()),
        ] {
            if len != n {
                return Err(FemError::LengthMismatch {
                    what,
                    expected: n,
                    got: len,
                });
            }
        }
        let equilibrium = &EquilibriumSettings {
            max_iterations: settings.max_iterations.max(1),
            ..equilibrium.clone()
        };
        let steps = settings.load_steps.max(1);
        let norm = |f: &[Vector3<f64>]| f.iter().map(|v| v.norm_squared()).sum::<f64>().sqrt();
        let change = previous_forces
            .iter()
            .zip(forces)
            .map(|(a, b)| (b - a).norm_squared())
            .sum::<f64>()
            .sqrt();
        let scale = norm(forces).max(norm(previous_forces));
        let start_x = x.to_vec();
        let start_params = self.params().to_vec();
        let mut iterations = 0;
        let mut last = None;
        let mut path = |m: &mut Self,
                        x: &mut [Vector3<f64>],
                        from: &[Vector3<f64>],
                        increments: usize,
                        iterations: &mut usize| {
            let run = softcap_fem::incremental_loading(
                solver,
                m,
                x,
                |t| softcap_fem::LoadState {
                    external_forces_n: from
                        .iter()
                        .zip(forces)
                        .map(|(a, b)| a + (b - a) * t)
                        .collect(),
                    prescribed: setup.dirichlet(),
                    contact: None,
                },
                &softcap_fem::IncrementalSettings {
                    steps: increments,
                    equilibrium: equilibrium.clone(),
                },
            );
            *iterations += run
                .steps
                .iter()
                .map(|s| s.equilibrium.iterations)
                .sum::<usize>();
            let converged = run.status == SolveStatus::Converged;
            (
                converged,
                run.steps.into_iter().last().map(|s| s.equilibrium),
            )
        };
        self.relaxation = settings.relaxation;
        if change <= 0.5 * scale || scale == 0.0 {
            let increments = if scale > 0.0 {
                ((steps as f64 * change / scale).ceil() as usize).clamp(1, steps)
            } else {
                1
            };
            let (ok, rep) = path(self, x, previous_forces, increments, &mut iterations);
            last = rep;
            if ok && let Some(report) = last.clone() {
                return Ok(StrainSpaceSolve {
                    report,
                    from_rest_attempt: None,
                    iterations,
                });
            }
        }
        let zero = vec![Vector3::zeros(); n];
        let mut increments = steps;
        for attempt in 0..=settings.relaxation_retries {
            self.reset();
            self.relaxation = settings.relaxation * 0.5f64.powi(attempt as i32);
            x.copy_from_slice(&setup.mesh.vertices);
            let (ok, rep) = path(self, x, &zero, increments, &mut iterations);
            if rep.is_some() {
                last = rep;
            }
            if ok && let Some(report) = last.clone() {
                self.relaxation = settings.relaxation;
                return Ok(StrainSpaceSolve {
                    report,
                    from_rest_attempt: Some(attempt),
                    iterations,
                });
            }
            increments *= 2;
        }
        self.relaxation = settings.relaxation;
        self.inner.set_params(&start_params)?;
        x.copy_from_slice(&start_x);
        Ok(StrainSpaceSolve {
            report: last.unwrap_or_else(|| EquilibriumReport::begin(n, n, n)),
            from_rest_attempt: Some(settings.relaxation_retries),
            iterations,
        })
    }
}

/// Settings of [`simulate_probe_contact`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct ContactSynthesisSettings {
    /// Load increments of the first approach (bickel2009 §3.4 incremental loading).
    pub steps: usize,
    /// Secant iterations on the depth.
    pub max_depth_iterations: usize,
    /// Accept when |axial force − target| ≤ this × target.
    pub force_tolerance_rel: f64,
    /// First trial depth beyond the first surface contact, m (the approach stops earlier, at the
    /// first increment whose force reaches the target).
    pub initial_depth_m: f64,
    /// Equilibrium settings per increment.
    pub equilibrium: EquilibriumSettings,
    /// Contact penalty.
    pub contact: ContactSettings,
    /// Halvings of a load increment whose equilibrium does not converge before the synthesis
    /// reports non-convergence (adaptive load stepping).
    pub max_bisections: usize,
}

impl Default for ContactSynthesisSettings {
    fn default() -> Self {
        Self {
            max_depth_iterations: 12,
            force_tolerance_rel: 0.01,
            initial_depth_m: 0.001,
            // The active set is taken from the first iterations of each increment and then
            // frozen: with small increments this is the set of nodes the probe reaches, and it
            // keeps rim nodes from chattering in and out of the penalty field.
            equilibrium: EquilibriumSettings {
                max_iterations: 80,
                displacement_tol_rel: 1e-8,
                residual_tol_rel: 1e-6,
                contact_freeze_after: 1,
                ..EquilibriumSettings::default()
            },
            steps: 8,
            contact: ContactSettings::default(),
            max_bisections: 6,
        }
    }
}

/// Result of [`simulate_probe_contact`].
#[derive(Clone, Debug, PartialEq)]
pub struct ContactSynthesis {
    /// Final node positions, m.
    pub positions_m: Vec<Vector3<f64>>,
    /// Depth of the probe beyond the first contact, m.
    pub depth_m: f64,
    /// Axial contact force reached, N.
    pub axial_force_n: f64,
    /// Positions after each load increment of the final approach.
    pub steps_m: Vec<Vec<Vector3<f64>>>,
    /// Probe depth beyond the first contact at each load increment of the final approach, m.
    pub step_depths_m: Vec<f64>,
    /// Axial contact force at each load increment of the final approach, N.
    pub step_forces_n: Vec<f64>,
    /// The probe pose (world from probe) at first contact (depth 0); increment k is this advanced by
    /// `step_depths_m[k]` along the approach axis.
    pub world_from_probe_at_touch: Isometry3<f64>,
    /// Equilibrium status of the last solve.
    pub status: SolveStatus,
    /// Depth iterations performed.
    pub depth_iterations: usize,
}

/// Synthesis of a novel probe (bickel2009 §3.4): the rigid `tip` approaches along +z of
/// `world_from_probe` (whose origin is placed on the surface, see below); the probe is advanced
/// to depth d in `settings.steps` increments with contact (penalty linear force field per
/// colliding node, [`ContactProblem`]) and the parameters refreshed from the strain at every
/// iteration (strain-space material, [`ElasticModel::update_state`]); d is found by a secant
/// search so that the axial contact force equals `axial_force_n`. Every approach stops at the
/// first increment whose force reaches the target, so the depth is sized from the force (a stiff
/// object is never pushed to `initial_depth_m` when a fraction of it gives the force), and the
/// search is a regula falsi once the target is bracketed; a depth whose approach does not
/// converge bounds the search from above. The status is `Converged` only when the force is
/// within `force_tolerance_rel` of the target. The pose's origin is first
/// moved back along the axis to the first boundary node it would touch, so the given pose may
/// be anywhere on the approach line.
pub fn simulate_probe_contact<M: ElasticModel + Clone>(
    setup: &ProbingSetup,
    model: &mut M,
    tip: TipShape,
    world_from_probe: Isometry3<f64>,
    axial_force_n: f64,
    settings: &ContactSynthesisSettings,
) -> Result<ContactSynthesis, FemError> {
    if !(axial_force_n.is_finite() && axial_force_n >= 0.0) {
        return Err(probing_error(format!(
            "probe force {axial_force_n} N must be finite and non-negative"
        )));
    }
    let probe0 = Probe::new(tip, world_from_probe)?;
    let axis = probe0.axis_world();
    let origin = world_from_probe.translation.vector;
    // Touch point: first boundary node along the approach line within the tip's footprint.
    let footprint = footprint_radius(probe0.tip());
    let first = setup
        .boundary_nodes
        .iter()
        .filter_map(|&n| {
            let d = setup.mesh.vertices[n] - origin;
            let along = d.dot(&axis);
            ((d - axis * along).norm() <= footprint).then_some(along)
        })
        .fold(f64::INFINITY, f64::min);
    if !first.is_finite() {
        return Err(probing_error(
            "the probe's approach line does not meet the mesh surface",
        ));
    }
    let touch = probe0.advanced(first);
    let candidates = setup
        .boundary_nodes
        .iter()
        .copied()
        .filter(|n| setup.attached_nodes.binary_search(n).is_err())
        .collect::<Vec<_>>();
    let mut solver = setup.solver(&*model)?;
    let zero = vec![Vector3::zeros(); setup.mesh.vertices.len()];
    let bc = setup.dirichlet();
    let contact_at = |d: f64| ContactProblem {
        probe: touch.advanced(d),
        candidate_nodes: candidates.clone(),
        settings: settings.contact.clone(),
    };
    // Moves the probe from depth `from` to `to` in `steps` increments (warm-started from `x`);
    // an increment whose equilibrium does not converge is undone (positions and model state)
    // and retried at half the length, up to `max_bisections` halvings in a row; after a
    // converged increment the length grows back (×2, at most the nominal one). With `stop_n`,
    // the approach stops after the first converged increment whose axial force reaches it.
    // Returns the axial force at the last converged depth and the status (not converged when
    // the halvings are used up); `path` / `trace` receive every converged increment.
    let max_bisections = settings.max_bisections;
    let mut advance = |model: &mut M,
                       x: &mut Vec<Vector3<f64>>,
                       from: f64,
                       to: f64,
                       steps: usize,
                       stop_n: Option<f64>,
                       path: &mut Vec<Vec<Vector3<f64>>>,
                       trace: &mut Vec<(f64, f64)>|
     -> (f64, SolveStatus) {
        let nominal = (to - from) / steps.max(1) as f64;
        let mut h = nominal;
        let mut d = from;
        let mut force = 0.0;
        let mut halvings = 0;
        let end = to - 1e-9 * nominal.abs();
        while d < end {
            let next = if d + h >= end { to } else { d + h };
            let saved_x = x.clone();
            let saved_model = model.clone();
            bc.apply(x);
            let rep = solver.solve(
                model,
                x,
                &zero,
                Some(&contact_at(next)),
                &settings.equilibrium,
            );
            if rep.converged() {
                d = next;
                force = rep.contact.axial_force_n;
                path.push(x.clone());
                trace.push((d, force));
                halvings = 0;
                h = (2.0 * h).min(nominal);
                if stop_n.is_some_and(|s| force >= s) {
                    break;
                }
            } else {
                *x = saved_x;
                *model = saved_model;
                if halvings >= max_bisections {
                    return (force, rep.status);
                }
                halvings += 1;
                h *= 0.5;
            }
        }
        (force, SolveStatus::Converged)
    };
    let x = setup.mesh.vertices.clone();
    if axial_force_n == 0.0 {
        return Ok(ContactSynthesis {
            positions_m: x,
            depth_m: 0.0,
            axial_force_n: 0.0,
            steps_m: Vec::new(),
            step_depths_m: Vec::new(),
            step_forces_n: Vec::new(),
            world_from_probe_at_touch: touch.world_from_probe,
            status: SolveStatus::Converged,
            depth_iterations: 0,
        });
    }
    // f(d): axial force after incremental loading from rest to depth d (§3.4). Every evaluation
    // starts from rest with the model's state at entry, so f is a function of d; it stops at
    // the first increment whose force reaches the target (the depth of a stiff object is then
    // sized from the target force, not from `initial_depth_m`: a 0.5 N probe on a block that
    // needs 0.2 mm is never pushed to 1 mm).
    struct Eval {
        force: f64,
        depth: f64,
        status: SolveStatus,
        xs: Vec<Vector3<f64>>,
        path: Vec<Vec<Vector3<f64>>>,
        trace: Vec<(f64, f64)>,
    }
    let model0 = model.clone();
    let target = axial_force_n;
    let tolerance = settings.force_tolerance_rel * target;
    let mut eval = |d: f64, model: &mut M| {
        *model = model0.clone();
        let mut xs = setup.mesh.vertices.clone();
        let mut path = Vec::with_capacity(settings.steps);
        let mut trace = Vec::with_capacity(settings.steps);
        let (force, status) = advance(
            model,
            &mut xs,
            0.0,
            d,
            settings.steps,
            Some(target - tolerance),
            &mut path,
            &mut trace,
        );
        let depth = trace.last().map_or(0.0, |t| t.0);
        Eval {
            force,
            depth,
            status,
            xs,
            path,
            trace,
        }
    };
    // Safeguarded secant (regula falsi once bracketed) on the monotone f(d): `lo` is the deepest
    // converged depth below the target, `hi` the shallowest converged depth above it, `fail` the
    // shallowest depth whose approach did not converge. Every converged increment of every
    // evaluation updates them.
    let mut lo = (0.0f64, 0.0f64);
    let mut prev_lo: Option<(f64, f64)> = None;
    let mut hi: Option<(f64, f64)> = None;
    let mut fail: Option<f64> = None;
    let mut d = settings.initial_depth_m;
    let mut best: Option<Eval> = None;
    let mut model_best = model0.clone();
    let mut iterations = 0;
    let mut failure_status = SolveStatus::Converged;
    while iterations < settings.max_depth_iterations {
        iterations += 1;
        let e = eval(d, model);
        for &(dt, ft) in &e.trace {
            if ft < target - tolerance {
                if dt > lo.0 {
                    prev_lo = Some(lo);
                    lo = (dt, ft);
                }
            } else if ft > target + tolerance && hi.is_none_or(|h| dt < h.0) {
                hi = Some((dt, ft));
            }
        }
        if e.status != SolveStatus::Converged {
            // The approach stopped short of `d`: deeper than its last converged depth there is no
            // equilibrium along this path (within the halvings).
            fail = Some(fail.map_or(d, |f: f64| f.min(d)));
            failure_status = e.status.clone();
        }
        let closer = best
            .as_ref()
            .is_none_or(|b| (e.force - target).abs() < (b.force - target).abs());
        let done = (e.force - target).abs() <= tolerance && !e.trace.is_empty();
        if closer && !e.trace.is_empty() {
            best = Some(e);
            model_best = model.clone();
        }
        if done {
            break;
        }
        // Next depth.
        d = if let Some(h) = hi {
            let w = h.0 - lo.0;
            let t = lo.0 + (target - lo.1) * w / (h.1 - lo.1);
            if t.is_finite() {
                t.clamp(lo.0 + 0.1 * w, h.0 - 0.1 * w)
            } else {
                lo.0 + 0.5 * w
            }
        } else if let Some(f) = fail {
            if f - lo.0 <= 1e-9 + 1e-6 * f {
                break;
            }
            // The target lies beyond `lo`, and the failing depth bounds the search from above.
            let slope = prev_lo.map(|p| (lo.1 - p.1) / (lo.0 - p.0));
            let t = match slope {
                Some(k) if k > 0.0 && k.is_finite() => lo.0 + (target - lo.1) / k,
                _ => 0.5 * (lo.0 + f),
            };
            t.clamp(lo.0 + 0.05 * (f - lo.0), lo.0 + 0.95 * (f - lo.0))
        } else {
            // Not bracketed yet: extrapolate the secant through the last two points below the
            // target, at most doubling the depth.
            let slope = prev_lo.map(|p| (lo.1 - p.1) / (lo.0 - p.0));
            let t = match slope {
                Some(k) if k > 0.0 && k.is_finite() => lo.0 + (target - lo.1) / k,
                _ => 2.0 * d.max(lo.0),
            };
            t.clamp(1.05 * lo.0, 2.0 * lo.0.max(d))
        };
    }
    *model = model_best;
    let Some(best) = best else {
        return Ok(ContactSynthesis {
            positions_m: x,
            depth_m: 0.0,
            axial_force_n: 0.0,
            steps_m: Vec::new(),
            step_depths_m: Vec::new(),
            step_forces_n: Vec::new(),
            world_from_probe_at_touch: touch.world_from_probe,
            status: if failure_status == SolveStatus::Converged {
                SolveStatus::MaxIterations
            } else {
                failure_status
            },
            depth_iterations: iterations,
        });
    };
    // The reported status: converged only when the force is within the tolerance.
    let status = if (best.force - target).abs() <= tolerance {
        SolveStatus::Converged
    } else if best.status != SolveStatus::Converged {
        best.status.clone()
    } else if failure_status != SolveStatus::Converged {
        failure_status
    } else {
        SolveStatus::MaxIterations
    };
    Ok(ContactSynthesis {
        positions_m: best.xs,
        depth_m: best.depth,
        axial_force_n: best.force,
        step_depths_m: best.trace.iter().map(|t| t.0).collect(),
        step_forces_n: best.trace.iter().map(|t| t.1).collect(),
        steps_m: best.path,
        world_from_probe_at_touch: touch.world_from_probe,
        status,
        depth_iterations: iterations,
    })
}

/// Radius of the footprint of a tip (disk / sphere / cylinder radius, mesh extent ⟂ z).
pub fn footprint_radius(tip: &TipShape) -> f64 {
    match tip {
        TipShape::Sphere { radius_m } | TipShape::Disk { radius_m, .. } => *radius_m,
        TipShape::Cylinder {
            radius_m,
            half_length_m,
        } => radius_m.max(*half_length_m),
        TipShape::Mesh { vertices_m, .. } => vertices_m
            .iter()
            .map(|v| v.x.hypot(v.y))
            .fold(0.0, f64::max),
    }
}

/// The world pose of a probe whose leading tip point is `tip_m` and whose approach axis is
/// `axis` (probe +z ↦ axis).
pub fn probe_pose(tip_m: &Vector3<f64>, axis: &Vector3<f64>) -> Isometry3<f64> {
    let rot =
        nalgebra::UnitQuaternion::rotation_between(&Vector3::z(), axis).unwrap_or_else(|| {
            nalgebra::UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI)
        });
    Isometry3::from_parts(nalgebra::Translation3::from(*tip_m), rot)
}

#[cfg(test)]
mod tests {
    use super::{normal_product, normal_product_unblocked};

    /// Deterministic entries of mixed sign and magnitude (a fixed hash of the index, no RNG).
    fn entries(len: usize, salt: u64) -> Vec<f64> {
        (0..len as u64)
            .map(|i| {
                let h = (i.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ salt)
                    .wrapping_mul(0xBF58_476D_1CE4_E5B9);
                let unit = (h >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
                unit * 10f64.powi((h % 7) as i32 - 3)
            })
            .collect()
    }

    /// The blocked J_mᵀ(J_m v) of the LM step is bit for bit the two whole faer products it
    /// replaces (the fit's results depend on the last bit, docs/tissue.md): one block, several
    /// blocks with a partial last one, one row per block, and no rows.
    #[test]
    fn normal_product_is_bitwise_the_two_products() {
        for (n, m) in [(1000, 20), (1000, 75), (40_000, 5), (333, 1), (500, 0)] {
            let flat = entries(n * m, 1);
            let v = entries(n, 2);
            let jt = faer::MatRef::from_column_major_slice(&flat, n, m);
            let mut jv = vec![f64::NAN; m];
            let mut want = vec![f64::NAN; n];
            normal_product_unblocked(jt, &v, &mut jv, &mut want);
            let mut got = vec![f64::NAN; n];
            let mut scratch = vec![0.0; m];
            normal_product(jt, &v, &mut scratch, &mut got);
            for i in 0..n {
                assert_eq!(
                    got[i].to_bits(),
                    want[i].to_bits(),
                    "n {n}, m {m}, entry {i}"
                );
            }
            for r in 0..m {
                assert_eq!(
                    scratch[r].to_bits(),
                    jv[r].to_bits(),
                    "n {n}, m {m}, row {r}"
                );
            }
        }
    }
}
