//! Novel-probe synthesis of bickel2009 §3.4: a rigid tip pressed with rigid-probe contact and
//! incremental loading until the axial force reaches the requested one.

use nalgebra::{Isometry3, Vector3};
use serde::{Deserialize, Serialize};
use softcap_fem::{
    ContactProblem, ContactSettings, ElasticModel, EquilibriumSettings, FemError, Probe,
    SolveStatus, TipShape,
};

use crate::{ProbingSetup, probing_error};

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
