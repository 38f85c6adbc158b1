//! Novel-probe synthesis of bickel2009 §3.4: a rigid tip pressed with rigid-probe contact and
//! incremental loading until the axial force reaches the requested one.

use nalgebra::{Isometry3, Vector3};
use serde::{Deserialize, Serialize};
use softcap_fem::{
    ContactProblem, ContactSettings, DirichletBc, ElasticModel, EquilibriumSettings, FemError,
    Probe, SolveStatus, StaticSolver, TipShape,
};

use crate::{ProbingSetup, probing_error};

/// Settings of [`simulate_probe_contact`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
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

impl ContactSynthesis {
    /// The probe at first contact, no load applied: the rest positions `x`.
    fn at_touch(
        x: Vec<Vector3<f64>>,
        world_from_probe_at_touch: Isometry3<f64>,
        status: SolveStatus,
        depth_iterations: usize,
    ) -> Self {
        Self {
            positions_m: x,
            depth_m: 0.0,
            axial_force_n: 0.0,
            steps_m: Vec::new(),
            step_depths_m: Vec::new(),
            step_forces_n: Vec::new(),
            world_from_probe_at_touch,
            status,
            depth_iterations,
        }
    }
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
    let touch = probe_at_touch(setup, tip, world_from_probe)?;
    let mut approach = Approach::new(setup, &*model, touch, settings)?;
    let at_touch = approach.touch.world_from_probe;
    let rest = setup.mesh.vertices.clone();
    if axial_force_n == 0.0 {
        return Ok(ContactSynthesis::at_touch(
            rest,
            at_touch,
            SolveStatus::Converged,
            0,
        ));
    }
    let model0 = model.clone();
    let target = axial_force_n;
    let tolerance = settings.force_tolerance_rel * target;
    let mut bracket = DepthBracket::default();
    let mut d = settings.initial_depth_m;
    let mut best: Option<DepthEvaluation> = None;
    let mut model_best = model0.clone();
    let mut iterations = 0;
    let mut failure_status = SolveStatus::Converged;
    while iterations < settings.max_depth_iterations {
        iterations += 1;
        let e = approach.press_from_rest(d, model, &model0, target - tolerance);
        bracket.record(&e.trace, target, tolerance);
        if e.status != SolveStatus::Converged {
            // The approach stopped short of `d`: deeper than its last converged depth there is no
            // equilibrium along this path (within the halvings).
            bracket.fail = Some(bracket.fail.map_or(d, |f: f64| f.min(d)));
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
        match bracket.next_depth(d, target) {
            Some(next) => d = next,
            None => break,
        }
    }
    *model = model_best;
    let Some(best) = best else {
        let status = if failure_status == SolveStatus::Converged {
            SolveStatus::MaxIterations
        } else {
            failure_status
        };
        return Ok(ContactSynthesis::at_touch(
            rest, at_touch, status, iterations,
        ));
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
        positions_m: best.positions_m,
        depth_m: best.depth_m,
        axial_force_n: best.force,
        step_depths_m: best.trace.iter().map(|t| t.0).collect(),
        step_forces_n: best.trace.iter().map(|t| t.1).collect(),
        steps_m: best.path,
        world_from_probe_at_touch: at_touch,
        status,
        depth_iterations: iterations,
    })
}

/// The probe moved back along its approach line to first contact: to the first boundary node
/// within the tip's footprint of the line.
fn probe_at_touch(
    setup: &ProbingSetup,
    tip: TipShape,
    world_from_probe: Isometry3<f64>,
) -> Result<Probe, FemError> {
    let probe = Probe::new(tip, world_from_probe)?;
    let axis = probe.axis_world();
    let origin = world_from_probe.translation.vector;
    let footprint = footprint_radius(probe.tip());
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
    Ok(probe.advanced(first))
}

/// The axial force of one approach from rest to a depth: f(d) of the depth search.
struct DepthEvaluation {
    /// Axial force at the last converged depth, N.
    force: f64,
    /// The last converged depth beyond first contact, m.
    depth_m: f64,
    /// `Converged`, or the status of the increment whose halvings were used up.
    status: SolveStatus,
    /// Node positions at the last converged depth, m.
    positions_m: Vec<Vector3<f64>>,
    /// Node positions after each converged increment, m.
    path: Vec<Vec<Vector3<f64>>>,
    /// (depth, axial force) after each converged increment.
    trace: Vec<(f64, f64)>,
}

/// The rigid probe pressing the object from first contact: solver, supports and contact
/// candidates shared by every approach of the depth search.
struct Approach<'a> {
    setup: &'a ProbingSetup,
    settings: &'a ContactSynthesisSettings,
    /// The probe at first contact (depth 0).
    touch: Probe,
    /// Unattached boundary nodes, the ones the probe may push.
    candidates: Vec<usize>,
    solver: StaticSolver,
    bc: DirichletBc,
    /// No external forces: the probe loads the object through contact only.
    zero: Vec<Vector3<f64>>,
}

impl<'a> Approach<'a> {
    fn new<M: ElasticModel>(
        setup: &'a ProbingSetup,
        model: &M,
        touch: Probe,
        settings: &'a ContactSynthesisSettings,
    ) -> Result<Self, FemError> {
        let candidates = setup.free_boundary_nodes();
        Ok(Self {
            setup,
            settings,
            touch,
            candidates,
            solver: setup.solver(model)?,
            bc: setup.dirichlet(),
            zero: vec![Vector3::zeros(); setup.mesh.vertices.len()],
        })
    }

    /// Contact with the probe at depth `d` beyond first contact.
    fn contact_at(&self, d: f64) -> ContactProblem {
        ContactProblem {
            probe: self.touch.advanced(d),
            candidate_nodes: self.candidates.clone(),
            settings: self.settings.contact.clone(),
        }
    }

    /// f(d): incremental loading from rest to depth `d` (§3.4) in `settings.steps` increments,
    /// the model reset to `model0` first, so f is a function of d. Stops at the first increment
    /// whose force reaches `stop_n` (the depth of a stiff object is then sized from the target
    /// force, not from `initial_depth_m`: a 0.5 N probe on a block that needs 0.2 mm is never
    /// pushed to 1 mm).
    fn press_from_rest<M: ElasticModel + Clone>(
        &mut self,
        d: f64,
        model: &mut M,
        model0: &M,
        stop_n: f64,
    ) -> DepthEvaluation {
        *model = model0.clone();
        let steps = self.settings.steps;
        let mut positions_m = self.setup.mesh.vertices.clone();
        let mut path = Vec::with_capacity(steps);
        let mut trace = Vec::with_capacity(steps);
        let (force, status) = self.advance(
            model,
            &mut positions_m,
            (0.0, d),
            steps,
            Some(stop_n),
            &mut path,
            &mut trace,
        );
        DepthEvaluation {
            force,
            depth_m: trace.last().map_or(0.0, |t| t.0),
            status,
            positions_m,
            path,
            trace,
        }
    }

    /// Moves the probe from depth `from` to `to` in `steps` increments (warm-started from `x`);
    /// an increment whose equilibrium does not converge is undone (positions and model state)
    /// and retried at half the length, up to `max_bisections` halvings in a row; after a
    /// converged increment the length grows back (×2, at most the nominal one). With `stop_n`,
    /// the approach stops after the first converged increment whose axial force reaches it.
    /// Returns the axial force at the last converged depth and the status (not converged when
    /// the halvings are used up); `path` / `trace` receive every converged increment.
    #[allow(clippy::too_many_arguments)]
    fn advance<M: ElasticModel + Clone>(
        &mut self,
        model: &mut M,
        x: &mut Vec<Vector3<f64>>,
        (from, to): (f64, f64),
        steps: usize,
        stop_n: Option<f64>,
        path: &mut Vec<Vec<Vector3<f64>>>,
        trace: &mut Vec<(f64, f64)>,
    ) -> (f64, SolveStatus) {
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
            self.bc.apply(x);
            let contact = self.contact_at(next);
            let rep = self.solver.solve(
                model,
                x,
                &self.zero,
                Some(&contact),
                &self.settings.equilibrium,
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
                if halvings >= self.settings.max_bisections {
                    return (force, rep.status);
                }
                halvings += 1;
                h *= 0.5;
            }
        }
        (force, SolveStatus::Converged)
    }
}

/// The state of the safeguarded secant (regula falsi once bracketed) on the monotone f(d):
/// `lo` is the deepest converged (depth, force) below the target, `prev_lo` the one before it,
/// `hi` the shallowest converged one above it, `fail` the shallowest depth whose approach did not
/// converge. Every converged increment of every evaluation updates them.
struct DepthBracket {
    lo: (f64, f64),
    prev_lo: Option<(f64, f64)>,
    hi: Option<(f64, f64)>,
    fail: Option<f64>,
}

impl Default for DepthBracket {
    fn default() -> Self {
        Self {
            lo: (0.0, 0.0),
            prev_lo: None,
            hi: None,
            fail: None,
        }
    }
}

impl DepthBracket {
    /// Takes in the converged increments (depth, force) of one evaluation.
    fn record(&mut self, trace: &[(f64, f64)], target: f64, tolerance: f64) {
        for &(dt, ft) in trace {
            if ft < target - tolerance {
                if dt > self.lo.0 {
                    self.prev_lo = Some(self.lo);
                    self.lo = (dt, ft);
                }
            } else if ft > target + tolerance && self.hi.is_none_or(|h| dt < h.0) {
                self.hi = Some((dt, ft));
            }
        }
    }

    /// The next trial depth after depth `d`; `None` when a failing depth leaves no room above
    /// `lo`.
    fn next_depth(&self, d: f64, target: f64) -> Option<f64> {
        let lo = self.lo;
        let slope = self.prev_lo.map(|p| (lo.1 - p.1) / (lo.0 - p.0));
        let secant = |fallback: f64| match slope {
            Some(k) if k > 0.0 && k.is_finite() => lo.0 + (target - lo.1) / k,
            _ => fallback,
        };
        Some(if let Some(h) = self.hi {
            let w = h.0 - lo.0;
            let t = lo.0 + (target - lo.1) * w / (h.1 - lo.1);
            if t.is_finite() {
                t.clamp(lo.0 + 0.1 * w, h.0 - 0.1 * w)
            } else {
                lo.0 + 0.5 * w
            }
        } else if let Some(f) = self.fail {
            if f - lo.0 <= 1e-9 + 1e-6 * f {
                return None;
            }
            // The target lies beyond `lo`, and the failing depth bounds the search from above.
            secant(0.5 * (lo.0 + f)).clamp(lo.0 + 0.05 * (f - lo.0), lo.0 + 0.95 * (f - lo.0))
        } else {
            // Not bracketed yet: extrapolate the secant through the last two points below the
            // target, at most doubling the depth.
            secant(2.0 * d.max(lo.0)).clamp(1.05 * lo.0, 2.0 * lo.0.max(d))
        })
    }
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
