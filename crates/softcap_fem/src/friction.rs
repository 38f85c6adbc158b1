//! Regularized Coulomb friction at the probe contact (extends [`crate::contact`] additively).
//!
//! **Law.** Each contact node n with normal force f_n ≥ 0 (from its penalty spring of
//! [`crate::ContactSpring`]) and unit normal ν carries a stick anchor a (a material point stored in
//! the probe frame, so it moves with the probe). Its tangential slip is δ = (I − ννᵀ)(x − a) and
//! the friction force on the body is
//!
//! f_t = −μ f_n s(‖δ‖/ε) δ/‖δ‖,  s(r) = 2r − r² (r < 1), 1 (r ≥ 1),
//!
//! the C¹ mollifier f₁ of IPC's smoothed Coulomb friction (Li et al. 2020 §5.1, eq. 16) applied to
//! the slip since the anchor. For ‖δ‖ ≥ ε the node slides with |f_t| = μ f_n exactly (Coulomb);
//! below it sticks with tangential stiffness ≈ 2μ f_n/ε (the regularized stick zone, ε =
//! [`FrictionParams::slip_distance_m`]). History (elastic-ideally-plastic tangential spring): after
//! each converged load step [`crate::NodalTerm::commit`] drags every anchor with ‖δ‖ > ε along δ to
//! distance ε, so a sliding node keeps |f_t| = μ f_n at the next step and a reversal re-sticks after
//! slipping 2ε. f_n is lagged (refreshed at every iteration, as IPC lags λ), so the stiffness block
//!
//! −∂f_t/∂x = μ f_n [s′(r)/ε t tᵀ + s(r)/‖δ‖ (P − t tᵀ)] P,  t = δ/‖δ‖, P = I − ννᵀ
//!
//! (→ 2μ f_n/ε P at δ = 0) is symmetric PSD. Parameters: μ (fit target) and ε (numerical).
//! ∂f_t/∂μ = f_t/μ exactly, so a fitter gets the μ derivative for free.

use crate::FemError;
use crate::contact::{ContactProblem, ContactSpring};
use crate::model::ElasticModel;
use crate::nodal::{NodalSolver, NodalTerm};
use crate::statics::{EquilibriumReport, EquilibriumSettings, SolveStatus};
use nalgebra::{Isometry3, Matrix3, Point3, Vector3};
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, BTreeSet};

/// Regularized Coulomb parameters.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrictionParams {
    /// Coulomb coefficient μ ≥ 0.
    pub mu: f64,
    /// Regularization slip ε > 0 \[m\]: slip below which a node sticks elastically.
    pub slip_distance_m: f64,
}

impl Default for FrictionParams {
    fn default() -> Self {
        Self {
            mu: 0.5,
            slip_distance_m: 1e-5,
        }
    }
}

impl FrictionParams {
    /// Checks μ ≥ 0 and ε > 0, both finite.
    pub fn validate(&self) -> Result<(), FemError> {
        if self.mu.is_finite()
            && self.mu >= 0.0
            && self.slip_distance_m.is_finite()
            && self.slip_distance_m > 0.0
        {
            Ok(())
        } else {
            Err(FemError::InvalidFriction {
                mu: self.mu,
                slip_distance_m: self.slip_distance_m,
            })
        }
    }
}

/// s(r) and s′(r) of the C¹ mollifier (IPC f₁).
pub fn mollifier(r: f64) -> (f64, f64) {
    if r < 1.0 {
        (2.0 * r - r * r, 2.0 - 2.0 * r)
    } else {
        (1.0, 0.0)
    }
}

/// Friction force on the body f_t(δ) and −∂f_t/∂δ for tangential slip `delta` (already projected)
/// in the tangent plane with projector `p`, normal force `normal_force_n` ≥ 0.
pub fn regularized_coulomb(
    params: &FrictionParams,
    normal_force_n: f64,
    delta: &Vector3<f64>,
    p: &Matrix3<f64>,
) -> (Vector3<f64>, Matrix3<f64>) {
    let fn_ = normal_force_n.max(0.0);
    let eps = params.slip_distance_m;
    let scale = params.mu * fn_;
    let d = delta.norm();
    if d < 1e-14 * eps {
        return (Vector3::zeros(), p * (2.0 * scale / eps));
    }
    let r = d / eps;
    let (s, ds) = mollifier(r);
    let t = delta / d;
    let ttt = t * t.transpose();
    let f = -t * (scale * s);
    let k = (ttt * (ds / eps) + (p - ttt) * (s / d)) * scale;
    (f, k * p)
}

/// Where the friction law takes its normal forces f_n from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum NormalForceLag {
    /// The penalty force of each spring at the current iterate, refreshed at every equilibrium
    /// iteration (the original behaviour). A transient deep penetration of one iterate then
    /// becomes a large friction force μ f_n with no tangential stiffness along the slip, which can
    /// throw a sliding node far away.
    #[default]
    Iteration,
    /// Held fixed during a solve at the values set by
    /// [`FrictionalContact::lag_normal_forces`] (0 for nodes without one): each solve is a smooth
    /// problem with a convex friction potential, and an outer loop re-lags f_n until it settles
    /// (IPC's lagged iterations, Li et al. 2020 §5.2).
    Solve,
}

/// Outcome of a frictional contact state.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FrictionReport {
    /// Contact nodes, increasing.
    pub patch_nodes: Vec<usize>,
    /// Σ f_n over the patch \[N\].
    pub normal_force_n: f64,
    /// Total force of the probe on the body (normal + friction) \[N\].
    pub contact_force_n: Vector3<f64>,
    /// Total friction force of the probe on the body \[N\].
    pub friction_force_n: Vector3<f64>,
    /// Tangential force ON THE PROBE = −friction force on the body \[N\].
    pub probe_tangential_force_n: Vector3<f64>,
    /// Nodes with ‖δ‖ ≥ ε (sliding).
    pub sliding_nodes: usize,
    /// Nodes with ‖δ‖ < ε (sticking).
    pub sticking_nodes: usize,
}

/// How the frictional probe contact samples the body's surface.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum ContactDiscretisation {
    /// One contact point per candidate node (node-to-rigid-surface): penalty and friction forces
    /// lumped at the nodes (the original behaviour). A patch of a few nodes in partial slip
    /// switches its drag with the node that sticks or slides: the friction force is a jumping
    /// function of μ and of the tip's position (docs/notes/2026-11-27-frictional-replay-slip.md).
    #[default]
    Nodes,
    /// Quadrature points on the surface triangles (Gauss-point-to-rigid-surface; Wriggers,
    /// *Computational Contact Mechanics*, 2nd ed., §9 — the rigid master is analytic, so each
    /// point is projected onto the tip directly). Every triangle is cut into k² similar
    /// sub-triangles (k = `subdivisions`), each carrying the symmetric 3-point rule of degree 2
    /// (barycentric (2/3, 1/6, 1/6) and permutations, weight ⅓ of the sub-triangle's area;
    /// Strang & Fix 1973, table 4.1). A point q at barycentric N_i(q) of triangle T has position
    /// x_q = Σ_i N_i x_i, its own gap, penalty spring, lagged normal force, stick anchor and
    /// regularized-Coulomb slip (the law of this module), and its force f_q is distributed as
    /// N_i f_q; the stiffness is N_i N_j K_q over all node pairs of T (the off-diagonal pairs
    /// through [`NodalTerm::pair_blocks`]). The penalty stays scale-free: with κ_i = p k_i / A_i
    /// the penalty per unit area at node i (p the contact's `penalty_factor`, k_i the node's mean
    /// diagonal stiffness, A_i its tributary rest area ⅓ Σ_T∋i A_T over the contact triangles),
    /// k_q = w_q A_T Σ_i N_i(q) κ_i, so a fully pressed flat patch gets the nodal springs'
    /// stiffness p k_i at every node. The traction is integrated over the footprint instead of
    /// lumped at the 2–5 nodes a small tip touches, so the stick/slip boundary moves through the
    /// rule's points continuously as k grows.
    Quadrature {
        /// k ≥ 1: each surface triangle is cut into k² sub-triangles of 3 points each.
        subdivisions: usize,
    },
}

/// The points of [`ContactDiscretisation::Quadrature`] on the contact triangles.
#[derive(Clone, Debug)]
struct SurfaceQuadrature {
    /// Contact triangles (every vertex a contact candidate).
    triangles: Vec<[usize; 3]>,
    /// The rule on one triangle: barycentric coordinates and weight (fractions of its area, Σ = 1).
    rule: Vec<([f64; 3], f64)>,
    /// Rest area of each triangle [m²].
    area_m2: Vec<f64>,
    /// Tributary rest area ⅓ Σ_T∋i A_T of every node of the triangles [m²].
    node_area_m2: BTreeMap<usize, f64>,
}

impl SurfaceQuadrature {
    /// The rule of `subdivisions` = k on `triangles` whose vertices are all `candidates` (sorted).
    fn new(
        triangles: &[[usize; 3]],
        candidates: &[usize],
        rest_m: &[Vector3<f64>],
        subdivisions: usize,
    ) -> Result<Self, FemError> {
        if subdivisions == 0 {
            return Err(FemError::InvalidSetting {
                what: "contact quadrature subdivisions",
                value: 0.0,
            });
        }
        let k = subdivisions;
        let kf = k as f64;
        // sub-triangles of the reference triangle in grid units (i, j) ↦ (1 − (i+j)/k, i/k, j/k)
        let bary = |i: usize, j: usize| [1.0 - (i + j) as f64 / kf, i as f64 / kf, j as f64 / kf];
        let mut subs = Vec::with_capacity(k * k);
        for i in 0..k {
            for j in 0..k - i {
                subs.push([bary(i, j), bary(i + 1, j), bary(i, j + 1)]);
                if j + 1 < k - i {
                    subs.push([bary(i + 1, j), bary(i + 1, j + 1), bary(i, j + 1)]);
                }
            }
        }
        let mut rule = Vec::with_capacity(3 * subs.len());
        let w = 1.0 / (3.0 * subs.len() as f64);
        for v in &subs {
            for a in 0..3 {
                let l = |b: usize| if a == b { 2.0 / 3.0 } else { 1.0 / 6.0 };
                let n: [f64; 3] =
                    std::array::from_fn(|c| l(0) * v[0][c] + l(1) * v[1][c] + l(2) * v[2][c]);
                rule.push((n, w));
            }
        }
        let is_candidate = |n: usize| candidates.binary_search(&n).is_ok();
        let mut kept = Vec::new();
        let mut area_m2 = Vec::new();
        let mut node_area_m2 = BTreeMap::new();
        for (t, tri) in triangles.iter().enumerate() {
            if let Some(&v) = tri.iter().find(|&&v| v >= rest_m.len()) {
                return Err(FemError::InvalidContactSurface {
                    triangle: t,
                    reason: format!("vertex {v} out of range ({} nodes)", rest_m.len()),
                });
            }
            if !tri.iter().all(|&v| is_candidate(v)) {
                continue;
            }
            let [a, b, c] = tri.map(|v| rest_m[v]);
            let area = 0.5 * (b - a).cross(&(c - a)).norm();
            let scale = (b - a).norm().max((c - a).norm()).max((c - b).norm());
            if !(area > 1e-12 * scale * scale && area.is_finite()) {
                return Err(FemError::InvalidContactSurface {
                    triangle: t,
                    reason: format!("degenerate (rest area {area:e} m²)"),
                });
            }
            for &v in tri {
                *node_area_m2.entry(v).or_insert(0.0) += area / 3.0;
            }
            kept.push(*tri);
            area_m2.push(area);
        }
        Ok(Self {
            triangles: kept,
            rule,
            area_m2,
            node_area_m2,
        })
    }

    /// Nodes and shape-function values of point `key` = triangle × rule length + rule index.
    fn support(&self, key: usize) -> ([usize; 3], [f64; 3]) {
        let nr = self.rule.len();
        (self.triangles[key / nr], self.rule[key % nr].0)
    }

    /// Penalty stiffness k_q = w_q A_T Σ_i N_i p k_i / A_i of point `key` [N/m].
    fn stiffness(&self, key: usize, penalty_factor: f64, node_k: &dyn Fn(usize) -> f64) -> f64 {
        let nr = self.rule.len();
        let (t, (n, w)) = (key / nr, self.rule[key % nr]);
        let kappa: f64 = (0..3)
            .map(|i| {
                let v = self.triangles[t][i];
                n[i] * penalty_factor * node_k(v) / self.node_area_m2[&v]
            })
            .sum();
        w * self.area_m2[t] * kappa
    }

    /// (key, position) of every point of the triangles the tip may touch at `x`, sorted by key:
    /// a triangle is skipped when its current centroid lies farther from the tip than its
    /// farthest vertex (then no point of it is inside), unless it is in `keep`.
    fn points(
        &self,
        x: &[Vector3<f64>],
        probe: &crate::contact::Probe,
        keep: &BTreeSet<usize>,
    ) -> Vec<(usize, Vector3<f64>)> {
        let nr = self.rule.len();
        let mut out = Vec::new();
        for (t, tri) in self.triangles.iter().enumerate() {
            let v = tri.map(|i| x[i]);
            let c = (v[0] + v[1] + v[2]) / 3.0;
            let r = v.iter().map(|p| (p - c).norm()).fold(0.0, f64::max);
            let far = probe.closest(&c).is_some_and(|(d, _, _)| d > r);
            if far && !keep.contains(&t) {
                continue;
            }
            for (q, (n, _)) in self.rule.iter().enumerate() {
                out.push((t * nr + q, v[0] * n[0] + v[1] * n[1] + v[2] * n[2]));
            }
        }
        out
    }
}

/// Probe contact (normal penalty of [`crate::contact`]) plus regularized Coulomb friction; a
/// [`NodalTerm`] for [`crate::NodalSolver`]. Its contact points are the candidate nodes
/// ([`ContactDiscretisation::Nodes`], the default) or quadrature points on the surface triangles
/// ([`Self::with_discretisation`]); every point carries the law of this module.
#[derive(Clone, Debug)]
pub struct FrictionalContact {
    /// The probe contact (normal part).
    pub contact: ContactProblem,
    /// Friction parameters.
    pub friction: FrictionParams,
    /// Keep compressed rim points in the active set when re-querying (the hysteresis of
    /// [`ContactProblem`]'s active-set update in [`crate::StaticSolver`]); default `false` (plain
    /// re-query, the original behaviour). Switch it on for sharp-rimmed tips that move sideways
    /// (a disk dragged over a coarse mesh): without it a rim node pushed out by the side wall
    /// relaxes back in at the next iteration and the active set cycles until it is frozen, leaving
    /// that node inside the tip. With μ > 0 a flat punch's kept points stay on its face plane, also
    /// past the rim (`Probe::kept_projection`; frictionless, μ = 0, and in the other solvers they
    /// are kept on the closest feature).
    pub active_set_hysteresis: bool,
    /// Where the normal forces f_n of the friction law come from (default
    /// [`NormalForceLag::Iteration`], the original behaviour).
    pub normal_force_lag: NormalForceLag,
    discretisation: ContactDiscretisation,
    quadrature: Option<SurfaceQuadrature>,
    lagged_normal_n: BTreeMap<usize, f64>,
    committed: BTreeMap<usize, Vector3<f64>>,
    working: BTreeMap<usize, Vector3<f64>>,
    /// Active springs; `ContactSpring::node` is the contact point's key (the node, or triangle ×
    /// rule length + rule index).
    springs: Vec<ContactSpring>,
    normal_forces_n: Vec<f64>,
}

/// Nodes and shape-function values of one contact point (`len` of them used).
struct Support {
    nodes: [usize; 3],
    weights: [f64; 3],
    len: usize,
}

impl FrictionalContact {
    /// New frictional contact with no stick history, contact points at the candidate nodes.
    pub fn new(contact: ContactProblem, friction: FrictionParams) -> Result<Self, FemError> {
        friction.validate()?;
        Ok(Self {
            contact,
            friction,
            active_set_hysteresis: false,
            normal_force_lag: NormalForceLag::Iteration,
            discretisation: ContactDiscretisation::Nodes,
            quadrature: None,
            lagged_normal_n: BTreeMap::new(),
            committed: BTreeMap::new(),
            working: BTreeMap::new(),
            springs: Vec::new(),
            normal_forces_n: Vec::new(),
        })
    }

    /// The contact points of `discretisation`: for [`ContactDiscretisation::Quadrature`] the
    /// surface `triangles` (e.g. the mesh's boundary faces; each must be a face of an element,
    /// whose node pairs the system pattern holds) whose three vertices are all contact
    /// candidates, with areas at the rest positions `rest_m`; for
    /// [`ContactDiscretisation::Nodes`] the candidate nodes (`triangles` unused). Forgets the
    /// stick history. Errors on k = 0, a vertex out of range or a degenerate triangle.
    pub fn with_discretisation(
        mut self,
        discretisation: ContactDiscretisation,
        triangles: &[[usize; 3]],
        rest_m: &[Vector3<f64>],
    ) -> Result<Self, FemError> {
        self.quadrature = match discretisation {
            ContactDiscretisation::Nodes => None,
            ContactDiscretisation::Quadrature { subdivisions } => {
                let mut candidates = self.contact.candidate_nodes.clone();
                candidates.sort_unstable();
                Some(SurfaceQuadrature::new(
                    triangles,
                    &candidates,
                    rest_m,
                    subdivisions,
                )?)
            }
        };
        self.discretisation = discretisation;
        self.reset_history();
        Ok(self)
    }

    /// The contact discretisation.
    pub fn discretisation(&self) -> ContactDiscretisation {
        self.discretisation
    }

    fn support(&self, key: usize) -> Support {
        match &self.quadrature {
            None => Support {
                nodes: [key; 3],
                weights: [1.0, 0.0, 0.0],
                len: 1,
            },
            Some(q) => {
                let (nodes, weights) = q.support(key);
                Support {
                    nodes,
                    weights,
                    len: 3,
                }
            }
        }
    }

    /// Current position of contact point `key`: x_key (nodes) or Σ_i N_i x_i (quadrature).
    fn position(&self, key: usize, x: &[Vector3<f64>]) -> Vector3<f64> {
        let s = self.support(key);
        if s.len == 1 {
            return x[s.nodes[0]];
        }
        (0..s.len).fold(Vector3::zeros(), |p, a| p + x[s.nodes[a]] * s.weights[a])
    }

    /// Moves the probe (anchors move with it: they live in the probe frame).
    pub fn set_pose(&mut self, world_from_probe: Isometry3<f64>) {
        self.contact.probe.world_from_probe = world_from_probe;
    }

    /// Moves the probe to `world_from_probe` and, with friction (μ > 0), carries the nodes of the
    /// contact points that hold a committed stick anchor rigidly with the probe increment
    /// T_new T_old⁻¹: the predictor of a frictional step, so the iterations start with every
    /// stuck point on its anchor and at its committed penetration.
    ///
    /// Without it, a probe increment of Δ along the axis leaves the patch nodes Δ deep inside the
    /// tip; their penalty springs then carry f_n ≈ k_c Δ (10³ N per node for Δ = 0.6 mm, k_c =
    /// 10⁴ × the node stiffness), the lagged Coulomb law takes that f_n, and a sliding node (zero
    /// tangent stiffness along the slip) is pushed by μ f_n against the elastic stiffness only:
    /// Newton steps of metres and divergence.
    pub fn move_probe(&mut self, x: &mut [Vector3<f64>], world_from_probe: Isometry3<f64>) {
        if self.friction.mu != 0.0 {
            let increment = world_from_probe * self.contact.probe.world_from_probe.inverse();
            let mut nodes = BTreeSet::new();
            for &key in self.committed.keys() {
                let s = self.support(key);
                nodes.extend((0..s.len).map(|a| s.nodes[a]));
            }
            for n in nodes {
                x[n] = increment.transform_point(&x[n].into()).coords;
            }
        }
        self.set_pose(world_from_probe);
    }

    /// Moves the lagged normal forces of [`NormalForceLag::Solve`] towards the penalty forces f of
    /// the current springs at `x`, f_lag ← f_lag + ω (f − f_lag) (ω = `relaxation` ∈ (0, 1];
    /// points no longer in contact have f = 0). Call after a converged solve, then solve again
    /// (IPC's lagged iterations, Li et al. 2020 §5.2); ω < 1 damps the two-cycles of a rim point
    /// that leaves and re-enters the patch between solves. Returns max_q |f − f_lag| / max(Σ f,
    /// tiny) before the update, so a caller iterates until it is small.
    pub fn lag_normal_forces(&mut self, x: &[Vector3<f64>], relaxation: f64) -> f64 {
        let w = relaxation.clamp(f64::MIN_POSITIVE, 1.0);
        let fresh: BTreeMap<usize, f64> = self
            .springs
            .iter()
            .map(|s| {
                let p = self.position(s.node, x);
                (s.node, s.force(&p).dot(&s.normal).max(0.0))
            })
            .collect();
        let total: f64 = fresh.values().sum();
        let mut change: f64 = 0.0;
        for (n, f) in &fresh {
            change = change.max((f - self.lagged_normal_n.get(n).copied().unwrap_or(0.0)).abs());
        }
        for (n, f) in &self.lagged_normal_n {
            if !fresh.contains_key(n) {
                change = change.max(*f);
            }
        }
        let mut next = BTreeMap::new();
        for (n, old) in &self.lagged_normal_n {
            let f = fresh.get(n).copied().unwrap_or(0.0);
            let v = old + w * (f - old);
            if v > 0.0 {
                next.insert(*n, v);
            }
        }
        for (n, f) in &fresh {
            next.entry(*n).or_insert(w * f);
        }
        self.lagged_normal_n = next;
        change / total.max(f64::MIN_POSITIVE)
    }

    /// Forgets the stick history (all anchors), e.g. when the probe is lifted off between
    /// locations.
    pub fn reset_history(&mut self) {
        self.lagged_normal_n.clear();
        self.committed.clear();
        self.working.clear();
        self.springs.clear();
        self.normal_forces_n.clear();
    }

    /// Committed stick anchors of the contact points (key: the node, or the quadrature point's
    /// index), world frame.
    pub fn anchors_world(&self) -> Vec<(usize, Vector3<f64>)> {
        self.committed
            .iter()
            .map(|(&n, a)| (n, self.to_world(a)))
            .collect()
    }

    fn to_world(&self, a_probe: &Vector3<f64>) -> Vector3<f64> {
        self.contact
            .probe
            .world_from_probe
            .transform_point(&Point3::from(*a_probe))
            .coords
    }

    fn to_probe(&self, x: &Vector3<f64>) -> Vector3<f64> {
        self.contact
            .probe
            .world_from_probe
            .inverse_transform_point(&Point3::from(*x))
            .coords
    }

    fn slip(&self, i: usize, x: &[Vector3<f64>]) -> (Vector3<f64>, Matrix3<f64>) {
        let s = &self.springs[i];
        let p = Matrix3::identity() - s.normal * s.normal.transpose();
        let xq = self.position(s.node, x);
        let a = self.working.get(&s.node).map_or(xq, |a| self.to_world(a));
        (p * (xq - a), p)
    }

    fn friction_at(&self, i: usize, x: &[Vector3<f64>]) -> (Vector3<f64>, Matrix3<f64>) {
        let (delta, p) = self.slip(i, x);
        regularized_coulomb(&self.friction, self.normal_forces_n[i], &delta, &p)
    }

    /// Report at positions `x` (after a solve). `patch_nodes` are the nodes that carry contact
    /// force (for quadrature: the vertices of the triangles with an active point);
    /// `sliding_nodes` / `sticking_nodes` count contact points.
    pub fn report(&self, x: &[Vector3<f64>]) -> FrictionReport {
        let mut r = FrictionReport::default();
        let mut patch = BTreeSet::new();
        for (i, s) in self.springs.iter().enumerate() {
            let fnv = s.force(&self.position(s.node, x));
            let (ft, _) = self.friction_at(i, x);
            let sup = self.support(s.node);
            patch.extend((0..sup.len).map(|a| sup.nodes[a]));
            r.normal_force_n += fnv.dot(&s.normal).max(0.0);
            r.contact_force_n += fnv + ft;
            r.friction_force_n += ft;
            let (delta, _) = self.slip(i, x);
            if delta.norm() >= self.friction.slip_distance_m * (1.0 - 1e-9) {
                r.sliding_nodes += 1;
            } else {
                r.sticking_nodes += 1;
            }
        }
        r.patch_nodes = patch.into_iter().collect();
        r.probe_tangential_force_n = -r.friction_force_n;
        r
    }

    /// Each active point's stiffness −∂f_q/∂x_q (penalty + friction).
    fn point_matrices(&self, x: &[Vector3<f64>]) -> Vec<Matrix3<f64>> {
        (0..self.springs.len())
            .map(|i| self.springs[i].matrix() + self.friction_at(i, x).1)
            .collect()
    }
}

impl NodalTerm for FrictionalContact {
    fn refresh(
        &mut self,
        x: &[Vector3<f64>],
        node_stiffness: &dyn Fn(usize) -> f64,
        requery: bool,
    ) {
        if requery || self.springs.is_empty() {
            let previous: &[ContactSpring] = if self.active_set_hysteresis {
                &self.springs
            } else {
                &[]
            };
            // a stuck patch carried past a punch's rim stays on its face (μ > 0 only:
            // `Probe::kept_projection`)
            let on_face = self.friction.mu > 0.0;
            let springs = match &self.quadrature {
                None if previous.is_empty() => self.contact.springs(x, node_stiffness),
                None => self
                    .contact
                    .springs_with_hysteresis(x, node_stiffness, previous, on_face),
                Some(q) => {
                    let nr = q.rule.len();
                    let keep: BTreeSet<usize> = previous.iter().map(|s| s.node / nr).collect();
                    let points = q.points(x, &self.contact.probe, &keep);
                    let pf = self.contact.settings.penalty_factor;
                    self.contact.point_springs(
                        &points,
                        |key| q.stiffness(key, pf, node_stiffness),
                        previous,
                        on_face,
                    )
                }
            };
            self.springs = springs;
            let mut working = BTreeMap::new();
            for s in &self.springs {
                let a = self
                    .working
                    .get(&s.node)
                    .or_else(|| self.committed.get(&s.node))
                    .copied()
                    .unwrap_or_else(|| self.to_probe(&self.position(s.node, x)));
                working.insert(s.node, a);
            }
            self.working = working;
        }
        self.normal_forces_n = match self.normal_force_lag {
            NormalForceLag::Iteration => self
                .springs
                .iter()
                .map(|s| s.force(&self.position(s.node, x)).dot(&s.normal).max(0.0))
                .collect(),
            NormalForceLag::Solve => self
                .springs
                .iter()
                .map(|s| self.lagged_normal_n.get(&s.node).copied().unwrap_or(0.0))
                .collect(),
        };
    }

    fn add_forces(&self, x: &[Vector3<f64>], out: &mut [Vector3<f64>]) {
        for (i, s) in self.springs.iter().enumerate() {
            let (ft, _) = self.friction_at(i, x);
            let f = s.force(&self.position(s.node, x)) + ft;
            let sup = self.support(s.node);
            if sup.len == 1 {
                out[sup.nodes[0]] += f;
            } else {
                for a in 0..sup.len {
                    out[sup.nodes[a]] += f * sup.weights[a];
                }
            }
        }
    }

    fn blocks(&self, x: &[Vector3<f64>]) -> Vec<(usize, Matrix3<f64>)> {
        let mut out = Vec::with_capacity(self.springs.len());
        for (s, k) in self.springs.iter().zip(self.point_matrices(x)) {
            let sup = self.support(s.node);
            if sup.len == 1 {
                out.push((sup.nodes[0], k));
            } else {
                for a in 0..sup.len {
                    out.push((sup.nodes[a], k * (sup.weights[a] * sup.weights[a])));
                }
            }
        }
        out
    }

    fn pair_blocks(&self, x: &[Vector3<f64>]) -> Vec<(usize, usize, Matrix3<f64>)> {
        if self.quadrature.is_none() {
            return Vec::new();
        }
        let mut out = Vec::with_capacity(3 * self.springs.len());
        for (s, k) in self.springs.iter().zip(self.point_matrices(x)) {
            let sup = self.support(s.node);
            for a in 0..sup.len {
                for b in a + 1..sup.len {
                    out.push((
                        sup.nodes[a],
                        sup.nodes[b],
                        k * (sup.weights[a] * sup.weights[b]),
                    ));
                }
            }
        }
        out
    }

    fn commit(&mut self, x: &[Vector3<f64>]) {
        let eps = self.friction.slip_distance_m;
        let mut committed = BTreeMap::new();
        for i in 0..self.springs.len() {
            let key = self.springs[i].node;
            let (delta, _) = self.slip(i, x);
            let d = delta.norm();
            let xq = self.position(key, x);
            let a_world = self.working.get(&key).map_or(xq, |a| self.to_world(a));
            let a_world = if d > eps {
                a_world + delta * (1.0 - eps / d)
            } else {
                a_world
            };
            committed.insert(key, self.to_probe(&a_world));
        }
        self.committed = committed.clone();
        self.working = committed;
    }
}

/// Outer iterations of the lagged normal forces ([`NormalForceLag::Solve`], IPC's lagged
/// iterations, Li et al. 2020 §5.2) of [`solve_lagged`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LaggedIterations {
    /// Outer iterations (solve, re-lag f_n) per step.
    pub max_outer: usize,
    /// f_n has settled when no node's f_n changes by more than this fraction of Σ f_n.
    pub tolerance: f64,
    /// Under-relaxation ω of the lagged f_n from the third outer iteration on.
    pub relaxation: f64,
    /// After `max_outer` iterations the step is accepted when the last change is within this
    /// fraction of Σ f_n: during unloading a rim node can leave and re-enter the patch between
    /// outer iterations (a two-cycle of the discrete active set); its share is the reported
    /// [`LaggedSolve::lag_mismatch`]. Above it the step reports `MaxIterations`.
    pub accept: f64,
}

impl Default for LaggedIterations {
    fn default() -> Self {
        Self {
            max_outer: 6,
            tolerance: 1e-2,
            relaxation: 0.5,
            accept: 0.2,
        }
    }
}

/// Outcome of [`solve_lagged`].
#[derive(Clone, Debug, PartialEq)]
pub struct LaggedSolve {
    /// The last equilibrium solve (status `MaxIterations` when f_n did not settle within
    /// [`LaggedIterations::accept`]).
    pub equilibrium: EquilibriumReport,
    /// The last outer iteration's max_n |Δf_n| / Σ f_n (0 without lagged friction).
    pub lag_mismatch: f64,
    /// Equilibrium solves run (outer iterations; 1 without lagged friction).
    pub outer: usize,
    /// Equilibrium iterations over every solve (`equilibrium.iterations` counts the last one's).
    pub iterations: usize,
}

/// One quasi-static step with node-level terms and frictional probe contact whose normal forces
/// are lagged: solve with f_n held ([`NormalForceLag::Solve`]), re-lag f_n from the converged
/// springs ([`FrictionalContact::lag_normal_forces`], ω = 1 for the first two re-lags, then
/// [`LaggedIterations::relaxation`]), repeat until f_n settles (IPC's lagged iterations, Li et
/// al. 2020 §5.2). With [`NormalForceLag::Iteration`] (or without `contact`) it is one
/// [`NodalSolver::solve`]. Place the probe first ([`FrictionalContact::move_probe`]); nothing is
/// committed (call [`NodalTerm::commit`] on every term after a converged step). Never panics.
#[allow(clippy::too_many_arguments)]
pub fn solve_lagged<M: ElasticModel + ?Sized>(
    solver: &mut NodalSolver,
    model: &mut M,
    x: &mut [Vector3<f64>],
    f_ext: &[Vector3<f64>],
    mut contact: Option<&mut FrictionalContact>,
    others: &mut [&mut dyn NodalTerm],
    settings: &EquilibriumSettings,
    lag: &LaggedIterations,
) -> LaggedSolve {
    let lagged = contact
        .as_ref()
        .is_some_and(|c| c.normal_force_lag == NormalForceLag::Solve);
    let mut lag_mismatch = 0.0;
    let mut outer = 0;
    let mut iterations = 0;
    loop {
        let mut rep = {
            let mut terms: Vec<&mut dyn NodalTerm> = Vec::with_capacity(1 + others.len());
            if let Some(c) = contact.as_deref_mut() {
                terms.push(c);
            }
            for t in others.iter_mut() {
                terms.push(&mut **t);
            }
            solver.solve(model, x, f_ext, &mut terms, settings)
        };
        iterations += rep.iterations;
        let Some(c) = contact.as_deref_mut().filter(|_| lagged && rep.converged()) else {
            return LaggedSolve {
                equilibrium: rep,
                lag_mismatch,
                outer: outer + 1,
                iterations,
            };
        };
        let relaxation = if outer < 2 { 1.0 } else { lag.relaxation };
        lag_mismatch = c.lag_normal_forces(x, relaxation);
        outer += 1;
        let last = outer >= lag.max_outer.max(1);
        if last && lag_mismatch > lag.accept {
            rep.status = SolveStatus::MaxIterations;
        }
        if last || lag_mismatch <= lag.tolerance {
            return LaggedSolve {
                equilibrium: rep,
                lag_mismatch,
                outer,
                iterations,
            };
        }
    }
}
