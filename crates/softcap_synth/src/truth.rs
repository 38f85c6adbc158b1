//! Ground truth: the stable neo-Hookean block (Smith, de Goes & Kim 2018; `softcap_fem`) on a
//! mesh finer than the template it writes, probed quasi-statically frame by frame with
//! `softcap_fem`'s rigid-probe contact (bickel2009 §3.4), displacement-controlled along the probe
//! axis.
//!
//! The truth element is [`TruthModel`]: the stable neo-Hookean energy per element, optionally plus
//! a second-order Yeoh term (strain stiffening)
//!
//! Ψ(F) = μ/2 (I_C − 3) − μ (J − 1) + λ/2 (J − 1)² + c₂ (I_C − 3)²,
//! P = P_snh + 4 c₂ (I_C − 3) F,  ∂P/∂F = ∂P_snh/∂F + 4 c₂ [(I_C − 3) I₉ + 2 vec F vec Fᵀ],
//!
//! with per-element (λ, μ) (stiff inclusion = a sphere of elements with scaled parameters).
//! Gravity pre-load applies the consistent body force of linear tets, f_a = ρ V_e g / 4 per node.

use nalgebra::{Isometry3, Matrix3, SMatrix, SVector, Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use softcap_app::Progress;
use softcap_fem::element::{Matrix12, StiffnessKind, TetGeometry};
use softcap_fem::{
    AnisotropicModel, ContactDiscretisation, ContactProblem, ContactSettings, DynamicsSettings,
    ElasticModel, ElastoplasticModel, EquilibriumSettings, FrictionParams, FrictionalContact,
    Integrator, J2PlasticityParams, LinearParams, NeoHookeanParams, Probe, PronySeries,
    RayleighDamping, SupportPlane, SupportTangential, TipShape, TransverselyIsotropicParams,
    ViscoelasticModel, neohookean_energy, neohookean_forces, neohookean_tangent, tet_geometries,
};
pub use softcap_mcap::Phase;
use softcap_mesh::{RefineBall, TetEmbedding, TetLocator, TetMesh, box_tet_mesh, refine_near};

use crate::engine::{Engine, StepOutcome};
use crate::error::{Result, SynthError};
use crate::scenario::{Effect, Scenario};

const MM: f64 = 1e-3;

/// Stable neo-Hookean elements with per-element parameters and an optional Yeoh c₂ term.
#[derive(Clone, Debug)]
pub struct TruthModel {
    rest: Vec<Vector3<f64>>,
    geometry: Vec<TetGeometry>,
    /// Per-element (λ, μ).
    pub params: Vec<NeoHookeanParams>,
    /// Per-element Yeoh c₂, Pa (0 = plain stable neo-Hookean).
    pub c2_pa: Vec<f64>,
}

impl TruthModel {
    /// Model over `mesh`; `params` and `c2_pa` hold one entry per tet.
    pub fn new(mesh: &TetMesh, params: Vec<NeoHookeanParams>, c2_pa: Vec<f64>) -> Result<Self> {
        let geometry = tet_geometries(&mesh.vertices, &mesh.tets)?;
        if params.len() != geometry.len() || c2_pa.len() != geometry.len() {
            return Err(softcap_fem::FemError::LengthMismatch {
                what: "per-element truth parameters",
                expected: geometry.len(),
                got: params.len().min(c2_pa.len()),
            }
            .into());
        }
        Ok(Self {
            rest: mesh.vertices.clone(),
            geometry,
            params,
            c2_pa,
        })
    }

    /// Yeoh term: P_s = 4 c₂ (I_C − 3) F.
    fn yeoh_pk1(c2: f64, f: &Matrix3<f64>) -> Matrix3<f64> {
        f * (4.0 * c2 * (f.norm_squared() - 3.0))
    }
}

impl ElasticModel for TruthModel {
    fn rest_positions(&self) -> &[Vector3<f64>] {
        &self.rest
    }
    fn elements(&self) -> &[TetGeometry] {
        &self.geometry
    }
    fn element_forces(&self, e: usize, x: &[Vector3<f64>]) -> [Vector3<f64>; 4] {
        let g = &self.geometry[e];
        let mut f = neohookean_forces(g, &self.params[e], x);
        let c2 = self.c2_pa[e];
        if c2 != 0.0 {
            let p = Self::yeoh_pk1(c2, &g.deformation_gradient(x)) * g.volume_m3;
            for a in 0..4 {
                f[a] += p * g.grads[a];
            }
        }
        f
    }
    fn element_matrix(&self, e: usize, x: &[Vector3<f64>], _kind: StiffnessKind) -> Matrix12 {
        let g = &self.geometry[e];
        let mut k = neohookean_tangent(g, &self.params[e], x);
        let c2 = self.c2_pa[e];
        if c2 != 0.0 {
            let f = g.deformation_gradient(x);
            let vf = SVector::<f64, 9>::from_column_slice(f.as_slice());
            let d = SMatrix::<f64, 9, 9>::identity() * (4.0 * c2 * (f.norm_squared() - 3.0))
                + vf * vf.transpose() * (8.0 * c2);
            let mut dfdx = SMatrix::<f64, 9, 12>::zeros();
            for b in 0..4 {
                for j in 0..3 {
                    for l in 0..3 {
                        dfdx[(j + 3 * l, 3 * b + j)] = g.grads[b][l];
                    }
                }
            }
            k += dfdx.transpose() * d * dfdx * g.volume_m3;
        }
        k
    }
    fn energy(&self, x: &[Vector3<f64>]) -> Option<f64> {
        Some(
            self.geometry
                .iter()
                .enumerate()
                .map(|(e, g)| {
                    let ic = g.deformation_gradient(x).norm_squared() - 3.0;
                    neohookean_energy(g, &self.params[e], x) + g.volume_m3 * self.c2_pa[e] * ic * ic
                })
                .sum(),
        )
    }
}

/// One frame of the protocol (what the probe does), before simulation.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameSpec {
    /// Frame index.
    pub frame: usize,
    /// Exposure mid-time on the camera clock, s.
    pub t_camera_s: f64,
    /// Phase.
    pub phase: Phase,
    /// Location index the probe is at (or moving to).
    pub location: usize,
    /// Probe pose: origin at the tip face centre, +z the approach direction (into the object).
    pub world_from_probe: Isometry3<f64>,
    /// Commanded depth of the tip face centre below the rest surface along the axis, m
    /// (negative while hovering).
    pub depth_m: f64,
}

/// Simulated truth of one frame.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameTruth {
    /// The protocol frame.
    pub spec: FrameSpec,
    /// Object marker positions, m (world).
    pub markers_m: Vec<Vector3<f64>>,
    /// Unit outward normals of the painted marker discs.
    pub marker_normals: Vec<Vector3<f64>>,
    /// Force exerted by the probe on the object, N (world).
    pub force_n: Vector3<f64>,
    /// Force along the probe axis (what the FSR reads), N (≥ 0 when pushing).
    pub axial_force_n: f64,
    /// Friction (tangential) part of `force_n`, N (probe-friction; zero otherwise).
    pub friction_force_n: Vector3<f64>,
    /// Mean tangential slip of the bottom face on its mount, m (support-slip; zero otherwise).
    pub support_slip_m: Vector3<f64>,
    /// Equilibrium iterations used.
    pub iterations: usize,
}

/// Probe geometry shared by simulation, rendering and writing.
#[derive(Clone, Debug, PartialEq)]
pub struct ProbeGeometry {
    /// Contact tip shape (probe frame, +z into the object).
    pub tip: TipShape,
    /// Tip radius, m.
    pub radius_m: f64,
    /// Disk thickness, m (0 for a sphere).
    pub thickness_m: f64,
    /// Shaft radius, m.
    pub shaft_radius_m: f64,
    /// Shaft length from the tip, m.
    pub shaft_length_m: f64,
    /// Shaft marker ids, distances from the tip (m) and colours.
    pub shaft_markers: Vec<(String, f64, String)>,
    /// Shaft marker sphere radius, m.
    pub shaft_marker_radius_m: f64,
}

impl ProbeGeometry {
    /// From the scenario.
    pub fn new(s: &Scenario) -> Self {
        let p = &s.probe;
        let tip = if p.tip == "sphere" {
            TipShape::Sphere {
                radius_m: p.radius_mm * MM,
            }
        } else {
            TipShape::Disk {
                radius_m: p.radius_mm * MM,
                thickness_m: p.thickness_mm * MM,
            }
        };
        Self {
            tip,
            radius_m: p.radius_mm * MM,
            thickness_m: if p.tip == "sphere" {
                0.0
            } else {
                p.thickness_mm * MM
            },
            shaft_radius_m: p.shaft_radius_mm * MM,
            shaft_length_m: p.shaft_length_mm * MM,
            shaft_markers: (0..2)
                .map(|i| {
                    (
                        format!("shaft{i}"),
                        p.shaft_marker_distances_mm[i] * MM,
                        p.shaft_marker_colors[i].clone(),
                    )
                })
                .collect(),
            shaft_marker_radius_m: p.shaft_marker_radius_mm * MM,
        }
    }

    /// World positions of the shaft markers for a probe pose.
    pub fn shaft_marker_positions(&self, world_from_probe: &Isometry3<f64>) -> Vec<Vector3<f64>> {
        self.shaft_markers
            .iter()
            .map(|(_, d, _)| {
                world_from_probe
                    .transform_point(&[0.0, 0.0, -d].into())
                    .coords
            })
            .collect()
    }
}

/// The block, its meshes and markers.
#[derive(Clone, Debug)]
pub struct Block {
    /// Size, m.
    pub size_m: Vector3<f64>,
    /// Template (fit) mesh at rest, m.
    pub fit_mesh: TetMesh,
    /// Ground-truth mesh at rest, m: the structured `truth_cells` mesh; in [`Truth::block`] the
    /// one the simulation ran on ([`refined_truth_mesh`]).
    pub truth_mesh: TetMesh,
    /// Marker ids.
    pub marker_ids: Vec<String>,
    /// Marker rest positions (stress-free shape), m.
    pub markers_rest_m: Vec<Vector3<f64>>,
}

impl Block {
    /// Meshes and seeded marker layout of the scenario.
    pub fn new(s: &Scenario, rng: &mut ChaCha8Rng) -> Self {
        let size = s.object.size_mm.map(|v| v * MM);
        let fit_mesh = box_tet_mesh([0.0; 3], size, s.object.fit_cells);
        let truth_mesh = box_tet_mesh([0.0; 3], size, s.object.truth_cells);
        let [gx, gy] = s.object.marker_grid;
        let m = s.object.marker_margin_mm * MM;
        let j = s.object.marker_jitter_mm * MM;
        let mut marker_ids = Vec::new();
        let mut markers_rest_m = Vec::new();
        for r in 0..gy {
            for c in 0..gx {
                let x = m + (size[0] - 2.0 * m) * c as f64 / (gx - 1) as f64;
                let y = m + (size[1] - 2.0 * m) * r as f64 / (gy - 1) as f64;
                let (dx, dy) = (
                    rng.random_range(-1.0..=1.0) * j,
                    rng.random_range(-1.0..=1.0) * j,
                );
                marker_ids.push(format!("m{:02}", marker_ids.len()));
                markers_rest_m.push(Vector3::new(
                    (x + dx).clamp(0.5 * m, size[0] - 0.5 * m),
                    (y + dy).clamp(0.5 * m, size[1] - 0.5 * m),
                    size[2],
                ));
            }
        }
        Self {
            size_m: Vector3::from(size),
            fit_mesh,
            truth_mesh,
            marker_ids,
            markers_rest_m,
        }
    }

    /// Height of the top face, m.
    pub fn top_m(&self) -> f64 {
        self.size_m.z
    }
}

/// Per-element truth parameters of the scenario (heterogeneity and stiffening switched by effects).
pub fn truth_model(s: &Scenario, mesh: &TetMesh) -> Result<TruthModel> {
    let young = if s.has(Effect::GravityPreload) {
        s.effect_settings.gravity_young_pa
    } else {
        s.material.young_pa
    };
    let base = NeoHookeanParams::from_young_poisson(young, s.material.poisson)?;
    let inc = &s.material.inclusion;
    let centre = Vector3::from(inc.centre_mm) * MM;
    let mut params = Vec::with_capacity(mesh.tets.len());
    for t in &mesh.tets {
        let c: Vector3<f64> = t.iter().map(|&i| mesh.vertices[i]).sum::<Vector3<f64>>() / 4.0;
        let inside = s.has(Effect::StiffInclusion) && (c - centre).norm() <= inc.radius_mm * MM;
        let (lame, mu) = base.lame();
        params.push(if inside {
            NeoHookeanParams::from_lame(lame * inc.stiffness_ratio, mu * inc.stiffness_ratio)?
        } else {
            base
        });
    }
    let c2 = if s.has(Effect::StrainStiffening) {
        s.material.stiffening.c2_over_mu * base.mu
    } else {
        0.0
    };
    TruthModel::new(mesh, params, vec![c2; mesh.tets.len()])
}

/// Anisotropy truth: `softcap_fem::AnisotropicModel` (transversely isotropic corotational element,
/// thesis eq. 8.5) with fibres along `effect_settings.anisotropy_fibre`; transverse modulus E and
/// Poisson ratio ν_t = min(ν, 0.4), fibre modulus `anisotropy_fibre_ratio` · E, fibre Poisson
/// ratio 0.1, fibre shear modulus E / (2 (1 + ν_t)).
pub fn anisotropic_model(s: &Scenario, mesh: &TetMesh) -> Result<AnisotropicModel> {
    let e = s.material.young_pa;
    let nt = s.material.poisson.min(0.4);
    let p = TransverselyIsotropicParams::from_engineering(
        e,
        s.effect_settings.anisotropy_fibre_ratio * e,
        nt,
        0.1,
        e / (2.0 * (1.0 + nt)),
    )?;
    let fibre = nalgebra::Unit::new_normalize(Vector3::from(s.effect_settings.anisotropy_fibre));
    Ok(AnisotropicModel::homogeneous(mesh, p, fibre)?)
}

/// Seeded probe locations on the top face (or the scenario's explicit list), m.
pub fn probe_locations(s: &Scenario, block: &Block, rng: &mut ChaCha8Rng) -> Vec<[f64; 2]> {
    if !s.protocol.locations_mm.is_empty() {
        return s
            .protocol
            .locations_mm
            .iter()
            .map(|p| [p[0] * MM, p[1] * MM])
            .collect();
    }
    let m = s.protocol.edge_margin_mm * MM;
    let (lx, ly) = (
        (block.size_m.x - 2.0 * m).max(0.0),
        (block.size_m.y - 2.0 * m).max(0.0),
    );
    let n = s.protocol.locations;
    // Dart throwing with a shrinking minimum spacing: spread out, deterministic for the seed.
    let mut spacing = (lx * ly / n as f64).sqrt() * 0.9;
    let mut out: Vec<[f64; 2]> = Vec::with_capacity(n);
    let mut tries = 0;
    while out.len() < n {
        let p = [m + rng.random::<f64>() * lx, m + rng.random::<f64>() * ly];
        if out
            .iter()
            .all(|q| (q[0] - p[0]).hypot(q[1] - p[1]) >= spacing)
        {
            out.push(p);
        }
        tries += 1;
        if tries % 200 == 0 {
            spacing *= 0.9;
        }
    }
    out
}

/// Probe orientation: +z of the probe along `axis` (into the object).
fn probe_rotation(tilt_deg: f64, azimuth_rad: f64) -> UnitQuaternion<f64> {
    let down = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI);
    let tilt_axis =
        nalgebra::Unit::new_normalize(Vector3::new(-azimuth_rad.sin(), azimuth_rad.cos(), 0.0));
    UnitQuaternion::from_axis_angle(&tilt_axis, tilt_deg.to_radians()) * down
}

/// The frame schedule: frame 0 at rest with the probe hovering over the first location, then per
/// location a ramp, a hold, a release and moves to the next location.
///
/// probe-friction moves the tip obliquely while it is below the surface: `friction_path_ratio` ×
/// depth sideways (along the location's seeded azimuth) on top of the depth along the axis, and
/// back on the way out. support-slip tilts the probe by `support_tilt_deg` (oblique push).
pub fn schedule(
    s: &Scenario,
    block: &Block,
    rng: &mut ChaCha8Rng,
) -> (Vec<[f64; 2]>, Vec<FrameSpec>) {
    let locations = probe_locations(s, block, rng);
    let p = &s.protocol;
    let tilt = if s.has(Effect::SupportSlip) {
        p.tilt_deg.max(s.effect_settings.support_tilt_deg)
    } else {
        p.tilt_deg
    };
    let drag = if s.has(Effect::ProbeFriction) {
        s.effect_settings.friction_path_ratio
    } else {
        0.0
    };
    let depths: Vec<f64> = locations
        .iter()
        .map(|_| (p.depth_mm[0] + rng.random::<f64>() * (p.depth_mm[1] - p.depth_mm[0])) * MM)
        .collect();
    let azimuths: Vec<f64> = locations
        .iter()
        .map(|_| rng.random::<f64>() * std::f64::consts::TAU)
        .collect();
    let top = block.top_m();
    let pose = |loc: usize, depth_m: f64| {
        let rot = probe_rotation(tilt, azimuths[loc]);
        let axis = rot * Vector3::z();
        let surface = Vector3::new(locations[loc][0], locations[loc][1], top);
        let sideways = Vector3::new(azimuths[loc].cos(), azimuths[loc].sin(), 0.0);
        Isometry3::from_parts(
            Translation3::from(surface + axis * depth_m + sideways * (drag * depth_m.max(0.0))),
            rot,
        )
    };
    let hover = -p.hover_mm * MM;
    let mut frames = Vec::new();
    let mut push = |phase: Phase, location: usize, iso: Isometry3<f64>, depth_m: f64| {
        let frame = frames.len();
        frames.push(FrameSpec {
            frame,
            t_camera_s: p.start_time_s + frame as f64 / p.frame_rate_hz,
            phase,
            location,
            world_from_probe: iso,
            depth_m,
        });
    };
    push(Phase::Rest, 0, pose(0, hover), hover);
    for (l, &d) in depths.iter().enumerate() {
        for k in 1..=p.ramp_frames {
            let z = d * k as f64 / p.ramp_frames as f64;
            push(Phase::Loading, l, pose(l, z), z);
        }
        for _ in 0..p.hold_frames {
            push(Phase::Hold, l, pose(l, d), d);
        }
        for k in 1..=p.release_frames {
            let z = d * (1.0 - k as f64 / p.release_frames as f64);
            push(Phase::Unloading, l, pose(l, z), z);
        }
        let next = (l + 1).min(locations.len() - 1);
        for k in 1..=p.move_frames {
            let a = pose(l, hover);
            let b = pose(next, hover);
            let t = k as f64 / p.move_frames as f64;
            let iso = Isometry3::from_parts(
                Translation3::from(a.translation.vector.lerp(&b.translation.vector, t)),
                a.rotation.slerp(&b.rotation, t),
            );
            push(Phase::Released, next, iso, hover);
        }
    }
    (locations, frames)
}

/// Most tets the truth's local refinement may make (`object.truth_refine_edge_mm`); more is a
/// scenario error (an edge too small for the block), not a silent cap.
pub const MAX_TRUTH_TETS: usize = 400_000;

/// Contact radius of the tip pressed `depth_m` into a flat surface, m: √(R d) for a sphere (Hertz;
/// Johnson, *Contact Mechanics* §4.2), capped at R; the radius of a flat punch for a disk.
fn contact_radius_m(probe: &ProbeGeometry, depth_m: f64) -> f64 {
    match probe.tip {
        TipShape::Sphere { radius_m } => (radius_m * depth_m.max(0.0)).sqrt().min(radius_m),
        _ => probe.radius_m,
    }
}

/// The balls of the truth's local refinement along the probe's contact paths
/// (`object.truth_refine_edge_mm`): one per frame whose tip is below the surface (consecutive
/// equal ones once), centred on the tip apex's projection onto the top face, radius 2 a with a
/// the contact radius at the frame's depth (`contact_radius_m`). Physical reason for 2 a: the
/// patch itself is a; beyond it the surface displacement of its normal and tangential tractions
/// (Boussinesq / Cerruti) decays as 1 / r, so its steepest gradients — and the stick/slip annulus
/// of a dragged patch (Mindlin; Johnson §7.2) at the patch's rim — lie within r ≤ 2 a. The
/// frames sample an oblique stroke every travel / `ramp_frames` (≈ 0.6 mm at the suite's 1.5 mm
/// depths, ≪ a), so the union of the balls covers the swept footprint. Every session gets the
/// same rule from its own schedule.
pub fn contact_refinement_balls(
    probe: &ProbeGeometry,
    top_m: f64,
    frames: &[FrameSpec],
) -> Vec<RefineBall> {
    let mut balls: Vec<RefineBall> = Vec::new();
    for f in frames.iter().filter(|f| f.depth_m > 0.0) {
        let t = f.world_from_probe.translation.vector;
        let ball = RefineBall {
            centre_m: Vector3::new(t.x, t.y, top_m),
            radius_m: 2.0 * contact_radius_m(probe, f.depth_m),
        };
        if balls.last() != Some(&ball) {
            balls.push(ball);
        }
    }
    balls
}

/// The truth mesh the simulation runs on: `block.truth_mesh` (structured `truth_cells`), refined
/// along the contact paths of `frames` to longest edges ≤ `object.truth_refine_edge_mm` when that
/// is set ([`contact_refinement_balls`]; `softcap_mesh::refine_near`, conforming, so every
/// vertex of the structured mesh keeps its index and the new ones are edge midpoints — the
/// bottom and top faces stay planes at z = 0 and z = top).
pub fn refined_truth_mesh(s: &Scenario, block: &Block, frames: &[FrameSpec]) -> Result<TetMesh> {
    let h = s.object.truth_refine_edge_mm;
    if h <= 0.0 {
        return Ok(block.truth_mesh.clone());
    }
    let balls = contact_refinement_balls(&ProbeGeometry::new(s), block.top_m(), frames);
    Ok(refine_near(&block.truth_mesh, &balls, h * MM, MAX_TRUTH_TETS)?.mesh)
}

/// Consistent body force of linear tets under gravity: f_a = Σ_e ρ V_e g / 4.
pub fn gravity_forces(mesh: &TetMesh, density_kg_m3: f64, g: Vector3<f64>) -> Vec<Vector3<f64>> {
    let mut f = vec![Vector3::zeros(); mesh.vertices.len()];
    for t in 0..mesh.tets.len() {
        let w = g * (density_kg_m3 * mesh.tet_volume(t) / 4.0);
        for &a in &mesh.tets[t] {
            f[a] += w;
        }
    }
    f
}

/// Everything the simulation produced.
#[derive(Clone, Debug)]
pub struct Truth {
    /// The block.
    pub block: Block,
    /// Probe geometry.
    pub probe: ProbeGeometry,
    /// Per-frame truth.
    pub frames: Vec<FrameTruth>,
    /// The template written to `template/`: markers, m. This is the frame-0 (observed) state,
    /// except under gravity pre-load, where it is the UNLOADED (stress-free) shape and every
    /// frame, frame 0 included, sees the block sagged (docs/synth.md).
    pub template_markers_m: Vec<Vector3<f64>>,
    /// The template fit mesh (same convention as `template_markers_m`), m.
    pub template_fit_mesh: TetMesh,
    /// Probe locations on the top face, m.
    pub locations_m: Vec<[f64; 2]>,
    /// Elements of the truth mesh inside the stiff inclusion (0 when off).
    pub inclusion_elements: usize,
    /// Largest equilibrium iteration count of any frame.
    pub max_iterations: usize,
    /// Elements that ever yielded (plasticity; 0 otherwise).
    pub yielded_elements: usize,
    /// Largest element von Mises stress √(3/2 s:s) (s = dev σ) of any frame, Pa (plasticity; 0
    /// otherwise). With the yield stress raised out of reach this is the elastic peak that
    /// `plastic_yield_pa` is compared with (docs/synth.md).
    pub peak_von_mises_pa: f64,
    /// probe-friction: largest mismatch of the lagged normal forces of the friction law at an
    /// accepted step, max_n |Δf_n| / Σ f_n (0 otherwise; see `crate::engine`).
    pub friction_lag_mismatch: f64,
}

/// The simulation engine of the scenario's effects (see [`crate::engine`]).
fn build_engine(
    s: &Scenario,
    mesh: &TetMesh,
    bc: &softcap_fem::DirichletBc,
    unloaded: &[Vector3<f64>],
    contact: &ContactProblem,
) -> Result<Engine> {
    let es = &s.effect_settings;
    let elastic = |s: &Scenario| -> Result<Box<dyn ElasticModel>> {
        Ok(if s.has(Effect::Anisotropy) {
            Box::new(anisotropic_model(s, mesh)?)
        } else {
            Box::new(truth_model(s, mesh)?)
        })
    };
    if s.has(Effect::Viscoelasticity) {
        let prony = PronySeries::standard_linear_solid(es.viscoelastic_g, es.viscoelastic_tau_s)?;
        return Engine::viscoelastic(ViscoelasticModel::new(truth_model(s, mesh)?, prony)?, bc);
    }
    if s.has(Effect::Plasticity) {
        let model = ElastoplasticModel::homogeneous(
            mesh,
            LinearParams::from_young_poisson(s.material.young_pa, s.material.poisson)?,
            J2PlasticityParams {
                yield_stress_pa: es.plastic_yield_pa,
                hardening_modulus_pa: es.plastic_hardening_pa,
            },
        )?;
        return Engine::plastic(model, bc);
    }
    if s.has(Effect::ProbeFriction) || s.has(Effect::SupportSlip) {
        let friction = FrictionParams {
            mu: if s.has(Effect::ProbeFriction) {
                es.friction_mu
            } else {
                0.0
            },
            slip_distance_m: es.friction_slip_distance_mm * MM,
        };
        let support = if s.has(Effect::SupportSlip) {
            let nodes: Vec<usize> = (0..mesh.vertices.len())
                .filter(|&i| mesh.vertices[i].z <= 1e-12)
                .collect();
            Some(SupportPlane::new(
                nalgebra::Unit::new_normalize(Vector3::z()),
                0.0,
                nodes,
                unloaded,
                &mesh.boundary_faces(),
                SupportTangential::Springs {
                    stiffness_n_per_m: es.support_stiffness_n_per_m,
                },
            )?)
        } else {
            None
        };
        let discretisation = match es.friction_contact_subdivisions {
            0 => ContactDiscretisation::Nodes,
            k => ContactDiscretisation::Quadrature { subdivisions: k },
        };
        let mut fc = FrictionalContact::new(contact.clone(), friction)?.with_discretisation(
            discretisation,
            &mesh.boundary_faces(),
            &mesh.vertices,
        )?;
        fc.active_set_hysteresis = s.has(Effect::ProbeFriction);
        if s.has(Effect::ProbeFriction) {
            fc.normal_force_lag = softcap_fem::NormalForceLag::Solve;
        }
        return Engine::nodal(elastic(s)?, bc, fc, support);
    }
    if s.has(Effect::InertiaDamping) {
        let model = elastic(s)?;
        let masses = softcap_fem::lumped_masses(&*model, s.object.density_kg_m3);
        let settings = DynamicsSettings {
            integrator: Integrator::NewmarkAverageAcceleration,
            time_step_s: 1.0 / s.protocol.frame_rate_hz / es.dynamics_substeps as f64,
            damping: RayleighDamping {
                alpha_per_s: es.rayleigh_alpha_per_s,
                beta_s: es.rayleigh_beta_s,
            },
            stiffness: StiffnessKind::Consistent,
            max_iterations: 40,
            displacement_tol_rel: 1e-9,
            residual_tol_rel: 1e-7,
            contact_freeze_after: 8,
        };
        return Engine::dynamic(model, masses, bc, unloaded.to_vec(), settings);
    }
    Engine::elastic(elastic(s)?, bc)
}

/// The truth's rigid probe at `world_from_probe`. A disk tip is a flat-ended indenter: it resolves
/// every penetration through its leading face ([`Probe::with_punch_face`]), so a frictionless
/// punch pushes the material under it along its axis only, as a rigid flat punch does. Resolved by
/// the closest feature (parry's projection) instead, a node the face carries down within `depth`
/// of the rim was pushed out sideways through the rim: measured on the suite sessions
/// (docs/notes/2026-11-27-flat-punch-footprint-load.md) a lateral force of 4–28 % of the axial one at some locations that no
/// recorded channel sees (the probe's force sensor reads along its shaft), which capped every
/// diagnosis of those sessions at the rim artefact rather than the physics. Spheres and meshes
/// are unchanged.
fn truth_probe(geom: &ProbeGeometry, world_from_probe: Isometry3<f64>) -> Result<Probe> {
    Ok(Probe::new(geom.tip.clone(), world_from_probe)?.with_punch_face())
}

/// Runs the ground-truth simulation of a scenario.
pub fn simulate(s: &Scenario, rng: &mut ChaCha8Rng) -> Result<Truth> {
    simulate_with_progress(s, rng, &Progress::hidden())
}

/// [`simulate`], with a bar over the frames on `progress`.
pub fn simulate_with_progress(
    s: &Scenario,
    rng: &mut ChaCha8Rng,
    progress: &Progress,
) -> Result<Truth> {
    s.validate().map_err(|message| SynthError::Scenario {
        path: format!("<scenario {}>", s.name).into(),
        message,
    })?;
    let mut block = Block::new(s, rng);
    let (locations_m, frames_spec) = schedule(s, &block, rng);
    block.truth_mesh = refined_truth_mesh(s, &block, &frames_spec)?;
    let probe_geom = ProbeGeometry::new(s);
    let mesh = &block.truth_mesh;
    let inclusion_elements = if s.has(Effect::StiffInclusion) {
        let nh = truth_model(s, mesh)?;
        let base = nh.params.iter().map(|p| p.mu).fold(f64::INFINITY, f64::min);
        nh.params.iter().filter(|p| p.mu > base * 1.0001).count()
    } else {
        0
    };

    // Support: the bottom face bonded to the table (support-slip replaces it by a compliant mount).
    let mut bc = softcap_fem::DirichletBc::new();
    for (i, v) in mesh.vertices.iter().enumerate() {
        if v.z <= 1e-12 {
            bc.fix_node(i, *v);
        }
    }
    let top = block.top_m();
    let candidates: Vec<usize> = (0..mesh.vertices.len())
        .filter(|&i| mesh.vertices[i].z >= top - 1e-12)
        .collect();
    let f_ext = if s.has(Effect::GravityPreload) {
        gravity_forces(
            mesh,
            s.object.density_kg_m3,
            Vector3::from(s.effect_settings.gravity_m_s2),
        )
    } else {
        vec![Vector3::zeros(); mesh.vertices.len()]
    };
    let settings = EquilibriumSettings {
        max_iterations: 60,
        displacement_tol_rel: 1e-9,
        residual_tol_rel: 1e-7,
        ..EquilibriumSettings::newton()
    };
    let contact_settings = ContactSettings {
        penalty_factor: s.probe.penalty_factor,
    };
    let first_contact = ContactProblem {
        probe: truth_probe(&probe_geom, frames_spec[0].world_from_probe)?,
        candidate_nodes: candidates.clone(),
        settings: contact_settings.clone(),
    };
    let mut engine = build_engine(s, mesh, &bc, &mesh.vertices, &first_contact)?;

    // Unloaded state: rest, or sagged under gravity.
    let mut unloaded = mesh.vertices.clone();
    let mut max_iterations = 0;
    if s.has(Effect::GravityPreload) {
        let mut x = mesh.vertices.clone();
        let steps = 2;
        for k in 1..=steps {
            let f: Vec<_> = f_ext
                .iter()
                .map(|f| f * (k as f64 / steps as f64))
                .collect();
            let out = engine.step(
                &mut x,
                &f,
                None,
                &candidates,
                &contact_settings,
                0.0,
                &settings,
            )?;
            if !out.converged {
                return Err(SynthError::Simulation {
                    frame: 0,
                    message: format!("gravity pre-load step {k}: {}", out.status),
                });
            }
            max_iterations = max_iterations.max(out.iterations);
        }
        unloaded = x;
    }
    let locator = TetLocator::new(mesh);
    let embed = |p: &Vector3<f64>| -> TetEmbedding {
        locator
            .locate(p)
            .expect("a point of the block lies in or near its mesh")
    };
    let marker_embeddings: Vec<TetEmbedding> = block.markers_rest_m.iter().map(embed).collect();
    let geometry = engine.model().elements().to_vec();
    let base_substeps = if s.has(Effect::InertiaDamping) {
        s.effect_settings.dynamics_substeps
    } else {
        1
    };

    let mut x = unloaded.clone();
    let mut peak_von_mises_pa: f64 = 0.0;
    let mut friction_lag_mismatch: f64 = 0.0;
    let mut last_outcome = StepOutcome {
        converged: true,
        status: String::new(),
        iterations: 0,
        force_n: Vector3::zeros(),
        friction_force_n: Vector3::zeros(),
        support_slip_m: Vector3::zeros(),
        friction_lag_mismatch: 0.0,
    };
    let mut prev_spec: Option<FrameSpec> = None;
    let mut frames = Vec::with_capacity(frames_spec.len());
    let bar = progress.bar("ground truth: frames", frames_spec.len() as u64);
    for spec in &frames_spec {
        bar.inc(1);
        let probe = truth_probe(&probe_geom, spec.world_from_probe)?;
        // A dynamic body can leave the held tip (inertia carries the surface below it): the tip
        // stays an obstacle while it is below the rest surface. Tested on the nodes alone, a disk
        // thinner than its depth (2 mm at 2.27 mm) held over a surface that had moved away below it
        // was dropped, and the surface sprang back up through it (measured on the suite's
        // inertia-damping session: 1.98 mm inside the tip at two hold frames).
        let held_below_surface = matches!(engine, Engine::Dynamic { .. }) && spec.depth_m > 0.0;
        let touches = held_below_surface
            || candidates.iter().any(|&i| {
                probe.penetration(&unloaded[i]).is_some() || probe.penetration(&x[i]).is_some()
            });
        if !touches {
            engine.lift_off();
        }
        let zero = StepOutcome {
            converged: true,
            status: String::new(),
            iterations: 0,
            force_n: Vector3::zeros(),
            friction_force_n: Vector3::zeros(),
            support_slip_m: Vector3::zeros(),
            friction_lag_mismatch: 0.0,
        };
        let outcome = match prev_spec.as_ref() {
            None => {
                x.clone_from(&unloaded);
                zero
            }
            Some(_) if !touches && engine.memoryless() => {
                x.clone_from(&unloaded);
                zero
            }
            // Rate-independent history (frictional stick anchors): the probe held still keeps the
            // last equilibrium, which is a fixed point of the step (anchors already committed).
            Some(prev)
                if touches
                    && matches!(engine, Engine::Nodal { .. })
                    && prev.world_from_probe == spec.world_from_probe =>
            {
                last_outcome.clone()
            }
            Some(prev) => {
                let from = prev.world_from_probe;
                let dt = spec.t_camera_s - prev.t_camera_s;
                let previous = x.clone();
                // Unloading: warm-start from the previous displacement scaled by the depth ratio,
                // so the contact patch starts close to its final shape instead of inside the probe.
                if touches
                    && !matches!(engine, Engine::Dynamic { .. })
                    && prev.location == spec.location
                    && spec.depth_m < prev.depth_m
                    && prev.depth_m > 0.0
                {
                    let ratio = (spec.depth_m / prev.depth_m).clamp(0.0, 1.0);
                    for (xi, ui) in x.iter_mut().zip(&unloaded) {
                        *xi = ui + (*xi - ui) * ratio;
                    }
                }
                engine.save();
                let start = x.clone();
                let mut result = None;
                // 1, 4, 16 sub-steps from the warm start; then (reached only when those failed,
                // which was an error before) 16 and 64 from the previous equilibrium itself: the
                // depth-ratio warm start is the frame's END state, while a sub-step's tip is still
                // near the previous pose — on a frictional patch finer than the 4 mm meshes (the
                // locally refined truth, `object.truth_refine_edge_mm`) that mismatch made every
                // sub-step count diverge at the first unloading frame (measured:
                // docs/notes/2026-11-27-probe-friction-truth-resolution.md).
                let attempts = [
                    (1usize, true),
                    (4, true),
                    (16, true),
                    (16, false),
                    (64, false),
                ];
                for (attempt, &(factor, warm)) in attempts.iter().enumerate() {
                    let substeps = base_substeps * factor;
                    engine.restore();
                    x.clone_from(if warm { &start } else { &previous });
                    let mut last: Option<StepOutcome> = None;
                    for k in 1..=substeps {
                        let t = k as f64 / substeps as f64;
                        let iso = Isometry3::from_parts(
                            Translation3::from(
                                from.translation
                                    .vector
                                    .lerp(&spec.world_from_probe.translation.vector, t),
                            ),
                            from.rotation.slerp(&spec.world_from_probe.rotation, t),
                        );
                        let p = touches.then(|| truth_probe(&probe_geom, iso)).transpose()?;
                        let out = engine.step(
                            &mut x,
                            &f_ext,
                            p.as_ref(),
                            &candidates,
                            &contact_settings,
                            dt / substeps as f64,
                            &settings,
                        )?;
                        let ok = out.converged;
                        last = Some(out);
                        if !ok {
                            break;
                        }
                    }
                    let out = last.expect("at least one substep ran");
                    if out.converged {
                        result = Some(out);
                        break;
                    } else if attempt + 1 == attempts.len() {
                        return Err(SynthError::Simulation {
                            frame: spec.frame,
                            message: format!("{} after {substeps} substeps", out.status),
                        });
                    }
                }
                result.expect("converged or returned")
            }
        };
        max_iterations = max_iterations.max(outcome.iterations);
        last_outcome = outcome.clone();
        friction_lag_mismatch = friction_lag_mismatch.max(outcome.friction_lag_mismatch);
        if let Engine::Plastic { model, .. } = &engine {
            peak_von_mises_pa = peak_von_mises_pa.max(max_von_mises_pa(model, &x));
        }
        prev_spec = Some(spec.clone());
        let markers_m = marker_embeddings
            .iter()
            .map(|e| e.position(&mesh.tets, &x))
            .collect();
        let marker_normals = marker_embeddings
            .iter()
            .map(|e| {
                let f = geometry[e.tet].deformation_gradient(&x);
                let n = f
                    .try_inverse()
                    .map(|fi| fi.transpose() * Vector3::z())
                    .unwrap_or(Vector3::z());
                n.normalize()
            })
            .collect();
        let axis = spec.world_from_probe.rotation * Vector3::z();
        frames.push(FrameTruth {
            spec: spec.clone(),
            markers_m,
            marker_normals,
            force_n: outcome.force_n,
            axial_force_n: outcome.force_n.dot(&axis),
            friction_force_n: outcome.friction_force_n,
            support_slip_m: outcome.support_slip_m,
            iterations: outcome.iterations,
        });
    }
    let yielded_elements = match &engine {
        Engine::Plastic { model, .. } => model
            .plastic_states()
            .iter()
            .filter(|p| p.equivalent_plastic_strain > 0.0)
            .count(),
        _ => 0,
    };

    // The template: the frame-0 state, carried to the fit mesh by embedding its vertices in the
    // truth mesh — except under gravity pre-load, where it is the unloaded (stress-free) box
    // (lead decision 2026-11-21 20:30: a template equal to the sagged frame 0 would make the
    // effect unidentifiable by superposition).
    let template_state = if s.has(Effect::GravityPreload) {
        &mesh.vertices
    } else {
        &unloaded
    };
    let template_markers_m = marker_embeddings
        .iter()
        .map(|e| e.position(&mesh.tets, template_state))
        .collect();
    let mut template_fit_mesh = block.fit_mesh.clone();
    for v in template_fit_mesh.vertices.iter_mut() {
        *v = embed(v).position(&mesh.tets, template_state);
    }
    bar.finish_and_clear();
    Ok(Truth {
        block,
        probe: probe_geom,
        frames,
        template_markers_m,
        template_fit_mesh,
        locations_m,
        inclusion_elements,
        max_iterations,
        yielded_elements,
        peak_von_mises_pa,
        friction_lag_mismatch,
    })
}

/// Largest element von Mises stress σ_vm = √(3/2 s:s), s = σ − tr(σ)/3 I, of the return-mapped
/// (committed) stress at `x`, Pa.
fn max_von_mises_pa(model: &ElastoplasticModel, x: &[Vector3<f64>]) -> f64 {
    (0..model.elements().len())
        .map(|e| {
            let sigma = model.element_return(e, x).0.stress_pa;
            let dev = sigma - Matrix3::identity() * (sigma.trace() / 3.0);
            (1.5 * dev.norm_squared()).sqrt()
        })
        .fold(0.0, f64::max)
}

/// Seeded RNG of one purpose: every consumer gets its own stream so that switching one output on
/// or off does not change the others.
pub fn stream(seed: u64, purpose: u64) -> ChaCha8Rng {
    let mut r = ChaCha8Rng::seed_from_u64(seed);
    r.set_stream(purpose);
    r
}
