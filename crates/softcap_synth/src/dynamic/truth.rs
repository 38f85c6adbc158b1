//! The truth of a dynamic scenario: implicit dynamics of a stable neo-Hookean body on a fine mesh
//! (wang2015 eq. 3, M ẍ + D ẋ + f_int(x) = f_ext, lumped mass, Rayleigh D = αM + βK,
//! `softcap_fem::DynamicSolver` with Newmark average acceleration) under gravity, with the
//! scenario's motion: a hand push and release, a drop on a floor (penalty contact), or a shaken
//! clamp. Frame 0 is the observed start: the static sag under gravity for a clamped body, the
//! held (unstressed) block for a drop.

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use softcap_fem::{
    ContactProblem, ContactSettings, DirichletBc, DynamicSolver, DynamicState, DynamicStepStatus,
    DynamicsSettings, EquilibriumSettings, Integrator, NeoHookeanModel, NeoHookeanParams, Probe,
    RayleighDamping, StaticSolver, StiffnessKind, TipShape, gravity_forces, lumped_masses,
};
use softcap_mesh::{TetMesh, box_tet_mesh};

use super::settings::{DynamicSettings, Motion};
use crate::error::{Result, SynthError};
use crate::scenario::Scenario;

const MM: f64 = 1e-3;

/// Rigid motion of the attached region relative to frame 0: p(t) = R p(0) + t.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RigidMotion {
    /// Rotation R.
    pub rotation: UnitQuaternion<f64>,
    /// Translation t, m.
    pub translation_m: Vector3<f64>,
}

impl RigidMotion {
    /// No motion.
    pub fn identity() -> Self {
        Self {
            rotation: UnitQuaternion::identity(),
            translation_m: Vector3::zeros(),
        }
    }

    /// Applies the motion to a frame-0 position.
    pub fn apply(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.rotation * p + self.translation_m
    }
}

/// One camera frame of the truth.
#[derive(Clone, Debug, PartialEq)]
pub struct TruthFrame {
    /// Frame index.
    pub frame: usize,
    /// Exposure time on the camera clock, s.
    pub t_s: f64,
    /// Truth node positions, m.
    pub positions_m: Vec<Vector3<f64>>,
}

/// The support of a clamped body (session.toml `[support]`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SupportPlane {
    /// Unit normal pointing into the object.
    pub normal: Vector3<f64>,
    /// Offset along the normal, m.
    pub offset_m: f64,
    /// Attachment tolerance, m.
    pub tolerance_m: f64,
}

impl SupportPlane {
    /// True if `p` counts as attached.
    pub fn attaches(&self, p: &Vector3<f64>) -> bool {
        self.normal.dot(p) <= self.offset_m + self.tolerance_m
    }
}

/// The simulated material and loads (SI).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TruthMaterial {
    /// Young's modulus of the small-strain linearization, Pa.
    pub young_pa: f64,
    /// Poisson ratio.
    pub poisson: f64,
    /// Density, kg/m³.
    pub density_kg_m3: f64,
    /// Rayleigh α, 1/s.
    pub rayleigh_alpha_per_s: f64,
    /// Rayleigh β, s.
    pub rayleigh_beta_s: f64,
    /// Gravity, m/s².
    pub gravity_m_s2: [f64; 3],
}

/// What was simulated (or read from a third-party solver).
#[derive(Clone, Debug)]
pub struct DynamicTruth {
    /// Material, damping and gravity of the truth.
    pub material: TruthMaterial,
    /// Truth mesh at rest (stress-free), world frame, m.
    pub mesh: TetMesh,
    /// The template's tet mesh at rest, same box and placement, coarser (`object.fit_cells`).
    pub template_rest: TetMesh,
    /// Support plane of a clamped body (`None`: free).
    pub support: Option<SupportPlane>,
    /// Truth nodes held by the support.
    pub attached: Vec<usize>,
    /// One entry per camera frame.
    pub frames: Vec<TruthFrame>,
    /// Support motion per frame (identity without shaking).
    pub support_motion: Vec<RigidMotion>,
    /// Intervals in which unknown external forces act (hand, floor), s.
    pub interactions: Vec<(f64, f64)>,
    /// Solver statistics: steps that needed sub-stepping.
    pub retried_steps: usize,
    /// Largest Newton iteration count of any step.
    pub max_iterations: usize,
    /// One line naming the solver that produced the truth.
    pub solver: String,
    /// One line describing the motion (from the third-party truth), if not the scenario's.
    pub motion_note: Option<String>,
}

/// The body's rest box and its placement in the world.
pub fn placement(s: &Scenario) -> ([f64; 3], [f64; 3], Isometry3<f64>) {
    let [l, w, h] = s.object.size_mm.map(|v| v * MM);
    let d = &s.dynamic;
    match d.motion {
        Motion::Release | Motion::Shake => (
            [0.0, -0.5 * w, -0.5 * h],
            [l, 0.5 * w, 0.5 * h],
            Isometry3::identity(),
        ),
        Motion::Drop => {
            let rot =
                UnitQuaternion::from_axis_angle(&Vector3::x_axis(), d.drop_tilt_deg.to_radians());
            // lowest corner of the rotated box at drop height
            let half = Vector3::new(0.5 * l, 0.5 * w, 0.5 * h);
            let mut lowest = f64::INFINITY;
            for b in 0..8 {
                let c = Vector3::new(
                    if b & 1 == 0 { -half.x } else { half.x },
                    if b & 2 == 0 { -half.y } else { half.y },
                    if b & 4 == 0 { -half.z } else { half.z },
                );
                lowest = lowest.min((rot * c).z);
            }
            let lift = d.drop_height_mm * MM - lowest;
            (
                [-half.x, -half.y, -half.z],
                [half.x, half.y, half.z],
                Isometry3::from_parts(Translation3::new(0.0, 0.0, lift), rot),
            )
        }
    }
}

fn placed_box(min: [f64; 3], max: [f64; 3], cells: [usize; 3], iso: &Isometry3<f64>) -> TetMesh {
    let mut m = box_tet_mesh(min, max, cells);
    for v in &mut m.vertices {
        *v = iso.transform_vector(v) + iso.translation.vector;
    }
    m
}

/// The clamp of a release / shake scenario: the x = 0 face.
fn clamp_plane(motion: Motion, length_m: f64) -> Option<SupportPlane> {
    match motion {
        Motion::Release | Motion::Shake => Some(SupportPlane {
            normal: Vector3::x(),
            offset_m: 0.0,
            tolerance_m: 1e-6 * length_m.max(1e-3),
        }),
        Motion::Drop => None,
    }
}

/// 3t² − 2t³ clamped to [0, 1].
fn smoothstep(t: f64) -> f64 {
    let t = t.clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// The clamp motion of a shake scenario at time `t_s`: amplitude × sin(2π f τ) · sin²(π τ / T)
/// for τ = t − t₀ in [0, T] (a Hann window, so the clamp starts and stops smoothly), t₀ half a
/// frame after frame 0.
pub(crate) fn shake_motion(d: &DynamicSettings, t_s: f64) -> RigidMotion {
    if d.motion != Motion::Shake {
        return RigidMotion::identity();
    }
    let t0 = 0.5 / d.frame_rate_hz;
    let span = d.shake_frames as f64 / d.frame_rate_hz;
    let tau = t_s - t0;
    let s = if tau <= 0.0 || tau >= span {
        0.0
    } else {
        (std::f64::consts::TAU * d.shake_frequency_hz * tau).sin()
            * (std::f64::consts::PI * tau / span).sin().powi(2)
    };
    let rot = Vector3::from(d.shake_rotation_deg.map(f64::to_radians)) * s;
    RigidMotion {
        rotation: UnitQuaternion::from_scaled_axis(rot),
        translation_m: Vector3::from(d.shake_amplitude_mm) * (s * MM),
    }
}

/// The hand of a release scenario: total force F(t) = F · smoothstep((t − t_a)/(t_b − t_a)) for
/// t < t_b, released at t_b; (t_a, t_b) is the interaction interval.
pub(crate) fn push_interval(d: &DynamicSettings) -> (f64, f64) {
    let t_a = (d.rest_frames as f64 - 0.5) / d.frame_rate_hz;
    (t_a, t_a + d.push_frames as f64 / d.frame_rate_hz)
}

fn hand_force(d: &DynamicSettings, t_s: f64) -> Vector3<f64> {
    if d.motion != Motion::Release {
        return Vector3::zeros();
    }
    let (t_a, t_b) = push_interval(d);
    if t_s >= t_b {
        return Vector3::zeros();
    }
    Vector3::from(d.push_force_n) * smoothstep((t_s - t_a) / (t_b - t_a))
}

/// Simulates the scenario's truth (or reads its third-party truth, see [`super::external`]).
pub fn simulate(s: &Scenario) -> Result<DynamicTruth> {
    let d = &s.dynamic;
    let (min, max, iso) = placement(s);
    let mesh = placed_box(min, max, s.object.truth_cells, &iso);
    let template_rest = placed_box(min, max, s.object.fit_cells, &iso);
    let support = clamp_plane(d.motion, max[0] - min[0]);
    let attached: Vec<usize> = match &support {
        Some(p) => (0..mesh.vertices.len())
            .filter(|&i| p.attaches(&mesh.vertices[i]))
            .collect(),
        None => Vec::new(),
    };
    let params = NeoHookeanParams::from_young_poisson(s.material.young_pa, s.material.poisson)?;
    let mut model = NeoHookeanModel::homogeneous(&mesh, params)?;
    let masses = lumped_masses(&model, s.object.density_kg_m3);
    let gravity = gravity_forces(&masses, Vector3::from(d.gravity_m_s2));
    let mut bc = DirichletBc::new();
    for &i in &attached {
        bc.fix_node(i, mesh.vertices[i]);
    }
    let x0 = initial_positions(&mut model, &mesh, &bc, &gravity)?;

    let h = 1.0 / (d.frame_rate_hz * d.substeps as f64);
    let settings = DynamicsSettings {
        integrator: Integrator::NewmarkAverageAcceleration,
        time_step_s: h,
        damping: RayleighDamping {
            alpha_per_s: d.rayleigh_alpha_per_s,
            beta_s: d.rayleigh_beta_s,
        },
        stiffness: StiffnessKind::Consistent,
        max_iterations: 25,
        ..DynamicsSettings::default()
    };
    let mut solver = DynamicSolver::with_bc(&model, masses, &bc)?;
    let mut state = DynamicState::at_rest(x0.clone());
    let floor = floor_contact(d, &mesh)?;
    let hand_nodes = hand_patch(s, &mesh, &iso);
    let forces_at = |t: f64| -> Vec<Vector3<f64>> {
        let mut f = gravity.clone();
        let total = hand_force(d, t);
        if total != Vector3::zeros() && !hand_nodes.is_empty() {
            let each = total / hand_nodes.len() as f64;
            for &i in &hand_nodes {
                f[i] += each;
            }
        }
        f
    };
    solver.initialize_acceleration(&model, &mut state, &forces_at(0.0), &settings);

    let mut truth = DynamicTruth {
        material: TruthMaterial {
            young_pa: s.material.young_pa,
            poisson: s.material.poisson,
            density_kg_m3: s.object.density_kg_m3,
            rayleigh_alpha_per_s: d.rayleigh_alpha_per_s,
            rayleigh_beta_s: d.rayleigh_beta_s,
            gravity_m_s2: d.gravity_m_s2,
        },
        mesh: mesh.clone(),
        template_rest,
        support,
        attached: attached.clone(),
        frames: vec![TruthFrame {
            frame: 0,
            t_s: 0.0,
            positions_m: x0.clone(),
        }],
        support_motion: vec![RigidMotion::identity()],
        interactions: Vec::new(),
        retried_steps: 0,
        max_iterations: 0,
        solver: format!(
            "softcap_fem stable neo-Hookean (Smith, de Goes & Kim 2018), implicit Newmark average acceleration, {} steps per frame",
            d.substeps
        ),
        motion_note: None,
    };
    if d.motion == Motion::Release {
        truth.interactions.push(push_interval(d));
    }
    let mut contact_times: Vec<f64> = Vec::new();
    for frame in 1..d.frames {
        for _ in 0..d.substeps {
            let t_next = state.time_s + h;
            let motion = shake_motion(d, t_next);
            let targets: Vec<(usize, Vector3<f64>)> = attached
                .iter()
                .map(|&i| (i, motion.apply(&x0[i])))
                .collect();
            let f = forces_at(t_next);
            let (iters, in_contact) = advance(
                &mut solver,
                &mut model,
                &mut state,
                &f,
                &targets,
                floor.as_ref(),
                &settings,
                &mut truth.retried_steps,
            )
            .map_err(|message| SynthError::Simulation { frame, message })?;
            truth.max_iterations = truth.max_iterations.max(iters);
            if in_contact {
                contact_times.push(state.time_s);
            }
        }
        let t = frame as f64 / d.frame_rate_hz;
        truth.frames.push(TruthFrame {
            frame,
            t_s: t,
            positions_m: state.positions_m.clone(),
        });
        truth.support_motion.push(shake_motion(d, t));
    }
    truth.interactions.extend(merge_times(&contact_times, h));
    Ok(truth)
}

/// Frame-0 positions: the static equilibrium under gravity of a clamped body (Newton with line
/// search), the rest shape of a free one (held, then let go at t = 0).
fn initial_positions(
    model: &mut NeoHookeanModel,
    mesh: &TetMesh,
    bc: &DirichletBc,
    gravity: &[Vector3<f64>],
) -> Result<Vec<Vector3<f64>>> {
    let mut x = mesh.vertices.clone();
    if bc.dofs().is_empty() {
        return Ok(x);
    }
    let mut solver = StaticSolver::with_bc(&*model, bc)?;
    let report = solver.solve(model, &mut x, gravity, None, &EquilibriumSettings::newton());
    if !report.converged() {
        return Err(SynthError::Simulation {
            frame: 0,
            message: format!("static sag under gravity: {:?}", report.status),
        });
    }
    Ok(x)
}

/// The floor of a drop scenario: a wide flat punch whose leading face is the plane z = 0,
/// pushing up (penalty contact on every boundary node).
fn floor_contact(d: &DynamicSettings, mesh: &TetMesh) -> Result<Option<ContactProblem>> {
    if d.motion != Motion::Drop {
        return Ok(None);
    }
    let probe = Probe::new(
        TipShape::Disk {
            radius_m: 10.0,
            thickness_m: 1.0,
        },
        Isometry3::identity(),
    )?
    .with_punch_face();
    let mut candidate_nodes: Vec<usize> = mesh.boundary_faces().into_iter().flatten().collect();
    candidate_nodes.sort_unstable();
    candidate_nodes.dedup();
    Ok(Some(ContactProblem {
        probe,
        candidate_nodes,
        settings: ContactSettings {
            penalty_factor: d.floor_penalty_factor,
        },
    }))
}

/// Boundary nodes within the push radius of the push point (release scenarios).
fn hand_patch(s: &Scenario, mesh: &TetMesh, iso: &Isometry3<f64>) -> Vec<usize> {
    let d = &s.dynamic;
    if d.motion != Motion::Release {
        return Vec::new();
    }
    let [l, _, h] = s.object.size_mm;
    let at = d.push_at_mm.unwrap_or([l - d.push_radius_mm, 0.0, 0.5 * h]);
    let centre = iso * nalgebra::Point3::from(Vector3::from(at) * MM);
    let mut nodes: Vec<usize> = mesh.boundary_faces().into_iter().flatten().collect();
    nodes.sort_unstable();
    nodes.dedup();
    nodes.retain(|&i| (mesh.vertices[i] - centre.coords).norm() <= d.push_radius_mm * MM);
    nodes
}

/// One truth step to the attached nodes' `targets`; a step whose Newton iterations fail is redone
/// from the same state in 4, then 16 sub-steps (targets interpolated linearly). Returns (largest
/// iteration count, contact active at the end).
#[allow(clippy::too_many_arguments)]
fn advance(
    solver: &mut DynamicSolver,
    model: &mut NeoHookeanModel,
    state: &mut DynamicState,
    forces: &[Vector3<f64>],
    targets: &[(usize, Vector3<f64>)],
    floor: Option<&ContactProblem>,
    settings: &DynamicsSettings,
    retried: &mut usize,
) -> std::result::Result<(usize, bool), String> {
    let start = state.clone();
    let mut last = String::new();
    for split in [1usize, 4, 16] {
        *state = start.clone();
        let sub = DynamicsSettings {
            time_step_s: settings.time_step_s / split as f64,
            ..settings.clone()
        };
        let mut iters = 0;
        let mut ok = true;
        let mut contact = false;
        for k in 0..split {
            // prescribed positions interpolated linearly within the step
            let frac = (k + 1) as f64 / split as f64;
            let mut sub_bc = DirichletBc::new();
            for (node, target) in targets {
                let from = start.positions_m[*node];
                sub_bc.fix_node(*node, from + (target - from) * frac);
            }
            let r = solver.step(model, state, forces, Some(&sub_bc), floor, &sub);
            iters = iters.max(r.iterations);
            contact = !r.contact.patch_nodes.is_empty();
            if r.status != DynamicStepStatus::Converged {
                last = format!("{:?} after {} iterations", r.status, r.iterations);
                ok = false;
                break;
            }
        }
        if ok {
            if split > 1 {
                *retried += 1;
            }
            return Ok((iters, contact));
        }
    }
    Err(format!(
        "dynamic step at t = {:.4} s did not converge with 1, 4 or 16 sub-steps: {last}",
        start.time_s + settings.time_step_s
    ))
}

/// Merges contact instants (step ends) into intervals, bridging gaps of up to two steps.
fn merge_times(times: &[f64], h: f64) -> Vec<(f64, f64)> {
    let mut out: Vec<(f64, f64)> = Vec::new();
    for &t in times {
        match out.last_mut() {
            Some(last) if t - last.1 <= 2.5 * h => last.1 = t,
            _ => out.push((t - h, t)),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shake_window_starts_and_stops_at_rest() {
        let d = DynamicSettings {
            motion: Motion::Shake,
            ..DynamicSettings::default()
        };
        assert_eq!(shake_motion(&d, 0.0), RigidMotion::identity());
        let end = (d.shake_frames as f64 + 1.0) / d.frame_rate_hz;
        assert!(shake_motion(&d, end).translation_m.norm() < 1e-15);
        let mid = shake_motion(&d, 0.5 / d.frame_rate_hz + 0.1);
        assert!(mid.translation_m.norm() > 1e-3);
    }

    #[test]
    fn contact_instants_merge_into_intervals() {
        let h = 0.01;
        let m = merge_times(&[0.1, 0.11, 0.12, 0.3, 0.31], h);
        assert_eq!(m.len(), 2);
        assert!((m[0].0 - 0.09).abs() < 1e-12 && (m[0].1 - 0.12).abs() < 1e-12);
    }
}
