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
use std::collections::BTreeMap;

/// Regularized Coulomb parameters.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrictionParams {
    /// Coulomb coefficient μ ≥ 0.
    pub mu: f64,
    /// Regularization slip ε > 0 [m]: slip below which a node sticks elastically.
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
    /// Σ f_n over the patch [N].
    pub normal_force_n: f64,
    /// Total force of the probe on the body (normal + friction) [N].
    pub contact_force_n: Vector3<f64>,
    /// Total friction force of the probe on the body [N].
    pub friction_force_n: Vector3<f64>,
    /// Tangential force ON THE PROBE = −friction force on the body [N].
    pub probe_tangential_force_n: Vector3<f64>,
    /// Nodes with ‖δ‖ ≥ ε (sliding).
    pub sliding_nodes: usize,
    /// Nodes with ‖δ‖ < ε (sticking).
    pub sticking_nodes: usize,
}

/// Probe contact (normal penalty of [`crate::contact`]) plus regularized Coulomb friction; a
/// [`NodalTerm`] for [`crate::NodalSolver`].
#[derive(Clone, Debug)]
pub struct FrictionalContact {
    /// The probe contact (normal part).
    pub contact: ContactProblem,
    /// Friction parameters.
    pub friction: FrictionParams,
    /// Keep compressed rim nodes in the active set when re-querying (the hysteresis of
    /// [`ContactProblem`]'s active-set update in [`crate::StaticSolver`]); default `false` (plain
    /// re-query, the original behaviour). Switch it on for sharp-rimmed tips that move sideways
    /// (a disk dragged over a coarse mesh): without it a rim node pushed out by the side wall
    /// relaxes back in at the next iteration and the active set cycles until it is frozen, leaving
    /// that node inside the tip.
    pub active_set_hysteresis: bool,
    /// Where the normal forces f_n of the friction law come from (default
    /// [`NormalForceLag::Iteration`], the original behaviour).
    pub normal_force_lag: NormalForceLag,
    lagged_normal_n: BTreeMap<usize, f64>,
    committed: BTreeMap<usize, Vector3<f64>>,
    working: BTreeMap<usize, Vector3<f64>>,
    springs: Vec<ContactSpring>,
    normal_forces_n: Vec<f64>,
}

impl FrictionalContact {
    /// New frictional contact with no stick history.
    pub fn new(contact: ContactProblem, friction: FrictionParams) -> Result<Self, FemError> {
        friction.validate()?;
        Ok(Self {
            contact,
            friction,
            active_set_hysteresis: false,
            normal_force_lag: NormalForceLag::Iteration,
            lagged_normal_n: BTreeMap::new(),
            committed: BTreeMap::new(),
            working: BTreeMap::new(),
            springs: Vec::new(),
            normal_forces_n: Vec::new(),
        })
    }

    /// Moves the probe (anchors move with it: they live in the probe frame).
    pub fn set_pose(&mut self, world_from_probe: Isometry3<f64>) {
        self.contact.probe.world_from_probe = world_from_probe;
    }

    /// Moves the probe to `world_from_probe` and, with friction (μ > 0), carries the nodes that
    /// hold a committed stick anchor rigidly with the probe increment T_new T_old⁻¹: the predictor
    /// of a frictional step, so the iterations start with every stuck node on its anchor and at
    /// its committed penetration.
    ///
    /// Without it, a probe increment of Δ along the axis leaves the patch nodes Δ deep inside the
    /// tip; their penalty springs then carry f_n ≈ k_c Δ (10³ N per node for Δ = 0.6 mm, k_c =
    /// 10⁴ × the node stiffness), the lagged Coulomb law takes that f_n, and a sliding node (zero
    /// tangent stiffness along the slip) is pushed by μ f_n against the elastic stiffness only:
    /// Newton steps of metres and divergence.
    pub fn move_probe(&mut self, x: &mut [Vector3<f64>], world_from_probe: Isometry3<f64>) {
        if self.friction.mu != 0.0 {
            let increment = world_from_probe * self.contact.probe.world_from_probe.inverse();
            for (n, _) in self.anchors_world() {
                x[n] = increment.transform_point(&x[n].into()).coords;
            }
        }
        self.set_pose(world_from_probe);
    }

    /// Moves the lagged normal forces of [`NormalForceLag::Solve`] towards the penalty forces f of
    /// the current springs at `x`, f_lag ← f_lag + ω (f − f_lag) (ω = `relaxation` ∈ (0, 1];
    /// nodes no longer in contact have f = 0). Call after a converged solve, then solve again
    /// (IPC's lagged iterations, Li et al. 2020 §5.2); ω < 1 damps the two-cycles of a rim node
    /// that leaves and re-enters the patch between solves. Returns max_n |f − f_lag| / max(Σ f,
    /// tiny) before the update, so a caller iterates until it is small.
    pub fn lag_normal_forces(&mut self, x: &[Vector3<f64>], relaxation: f64) -> f64 {
        let w = relaxation.clamp(f64::MIN_POSITIVE, 1.0);
        let fresh: BTreeMap<usize, f64> = self
            .springs
            .iter()
            .map(|s| (s.node, s.force(&x[s.node]).dot(&s.normal).max(0.0)))
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

    /// Committed stick anchors of the contact nodes, world frame.
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
        let a = self
            .working
            .get(&s.node)
            .map_or(x[s.node], |a| self.to_world(a));
        (p * (x[s.node] - a), p)
    }

    fn friction_at(&self, i: usize, x: &[Vector3<f64>]) -> (Vector3<f64>, Matrix3<f64>) {
        let (delta, p) = self.slip(i, x);
        regularized_coulomb(&self.friction, self.normal_forces_n[i], &delta, &p)
    }

    /// Report at positions `x` (after a solve).
    pub fn report(&self, x: &[Vector3<f64>]) -> FrictionReport {
        let mut r = FrictionReport::default();
        for (i, s) in self.springs.iter().enumerate() {
            let fnv = s.force(&x[s.node]);
            let (ft, _) = self.friction_at(i, x);
            r.patch_nodes.push(s.node);
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
        r.probe_tangential_force_n = -r.friction_force_n;
        r
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
            self.springs = if self.active_set_hysteresis && !self.springs.is_empty() {
                self.contact
                    .springs_with_hysteresis(x, node_stiffness, &self.springs)
            } else {
                self.contact.springs(x, node_stiffness)
            };
            let mut working = BTreeMap::new();
            for s in &self.springs {
                let a = self
                    .working
                    .get(&s.node)
                    .or_else(|| self.committed.get(&s.node))
                    .copied()
                    .unwrap_or_else(|| self.to_probe(&x[s.node]));
                working.insert(s.node, a);
            }
            self.working = working;
        }
        self.normal_forces_n = match self.normal_force_lag {
            NormalForceLag::Iteration => self
                .springs
                .iter()
                .map(|s| s.force(&x[s.node]).dot(&s.normal).max(0.0))
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
            out[s.node] += s.force(&x[s.node]) + ft;
        }
    }

    fn blocks(&self, x: &[Vector3<f64>]) -> Vec<(usize, Matrix3<f64>)> {
        self.springs
            .iter()
            .enumerate()
            .map(|(i, s)| (s.node, s.matrix() + self.friction_at(i, x).1))
            .collect()
    }

    fn commit(&mut self, x: &[Vector3<f64>]) {
        let eps = self.friction.slip_distance_m;
        let mut committed = BTreeMap::new();
        for i in 0..self.springs.len() {
            let node = self.springs[i].node;
            let (delta, _) = self.slip(i, x);
            let d = delta.norm();
            let a_world = self
                .working
                .get(&node)
                .map_or(x[node], |a| self.to_world(a));
            let a_world = if d > eps {
                a_world + delta * (1.0 - eps / d)
            } else {
                a_world
            };
            committed.insert(node, self.to_probe(&a_world));
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
        let Some(c) = contact.as_deref_mut().filter(|_| lagged && rep.converged()) else {
            return LaggedSolve {
                equilibrium: rep,
                lag_mismatch,
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
            };
        }
    }
}
