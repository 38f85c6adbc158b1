//! `softcap tissue simulate material.mcap --probe-shape sphere --radius R --tip x,y,z --axis …
//! --force N -o sim.mcap`: synthesis of a novel probe deformation with the captured material
//! (bickel2009 §3.4): the rigid tip approaches the surface along its axis, the probe is advanced
//! in load increments with contact handled as a linear force field, the parameters of every tet
//! refreshed from its strain at every equilibrium iteration (eq. 8), and the depth found by a
//! secant search so that the axial contact force equals the requested force
//! ([`simulate_probe_contact`]).

use std::path::PathBuf;

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use softcap_fem::{SolveStatus, TipShape};
use softcap_mcap::{Provenance, Writer, proto, topics};
use softcap_probing::{
    ContactSynthesis, ContactSynthesisSettings, ProbingSetup, probe_pose, simulate_probe_contact,
    support_nodes,
};

use crate::error::{Result, TissueError};
use crate::output::{LoadedMaterial, read_material, tet_mesh_message};

/// Tip geometry of a simulated probe.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum ProbeShape {
    /// Sphere of the given radius.
    Sphere,
    /// Flat disk of the given radius (thickness `disk_thickness_m`).
    Disk,
    /// Cylinder lying across the approach axis (bickel2009 Fig. 4), length 2 × `half_length_m`.
    Cylinder,
}

/// A novel probe: shape, pose, force.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ProbeSpec {
    /// Tip shape.
    pub shape: ProbeShape,
    /// Radius, m.
    pub radius_m: f64,
    /// A point on the approach line (the tip's leading point is moved back along the axis to
    /// the first surface contact), m, world frame.
    pub tip_m: [f64; 3],
    /// Approach direction (handle → tip), world frame (normalized here).
    pub axis: [f64; 3],
    /// Axial force the probe exerts on the object, N.
    pub force_n: f64,
    /// Disk thickness, m.
    pub disk_thickness_m: f64,
    /// Cylinder half length, m (0 → 2 × radius).
    pub half_length_m: f64,
}

impl ProbeSpec {
    /// The fem tip shape.
    pub fn tip_shape(&self) -> TipShape {
        match self.shape {
            ProbeShape::Sphere => TipShape::Sphere {
                radius_m: self.radius_m,
            },
            ProbeShape::Disk => TipShape::Disk {
                radius_m: self.radius_m,
                thickness_m: self.disk_thickness_m,
            },
            ProbeShape::Cylinder => TipShape::Cylinder {
                radius_m: self.radius_m,
                half_length_m: if self.half_length_m > 0.0 {
                    self.half_length_m
                } else {
                    2.0 * self.radius_m
                },
            },
        }
    }

    fn validate(&self) -> Result<Vector3<f64>> {
        let bad = |field: &str, problem: String| TissueError::BadSettings {
            field: field.into(),
            problem,
        };
        if !(self.radius_m.is_finite() && self.radius_m > 0.0) {
            return Err(bad("--radius", format!("{} must be > 0", self.radius_m)));
        }
        if !(self.force_n.is_finite() && self.force_n >= 0.0) {
            return Err(bad("--force", format!("{} must be ≥ 0", self.force_n)));
        }
        if !self.tip_m.iter().all(|c| c.is_finite()) {
            return Err(bad("--tip", "must be finite".into()));
        }
        let axis = Vector3::from(self.axis);
        if !(axis.iter().all(|c| c.is_finite()) && axis.norm() > 0.0) {
            return Err(bad("--axis", "must be a finite non-zero vector".into()));
        }
        Ok(axis.normalize())
    }
}

/// Settings of a simulation.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SimulateSettings {
    /// Incremental loading, secant on the depth, contact penalty.
    pub contact: ContactSynthesisSettings,
    /// Relaxation ω of the strain-space parameter update ([`softcap_probing::StrainSpaceModel`]).
    pub relaxation: f64,
    /// When the synthesis does not converge (after the load-increment halvings of
    /// `contact.max_bisections`), retry this many times with ω halved and twice the equilibrium
    /// iterations (a smaller ω contracts the parameter oscillation more; same fixed points).
    pub relaxation_retries: usize,
}

impl Default for SimulateSettings {
    fn default() -> Self {
        Self {
            contact: ContactSynthesisSettings::default(),
            relaxation: crate::fit::DEFAULT_RELAXATION,
            relaxation_retries: 2,
        }
    }
}

/// What to run: the library form of `softcap tissue simulate`.
#[derive(Clone, Debug)]
pub struct SimulateConfig {
    /// material.mcap.
    pub material: PathBuf,
    /// sim.mcap to write.
    pub output: PathBuf,
    /// The probe.
    pub probe: ProbeSpec,
    /// Settings.
    pub settings: SimulateSettings,
    /// Full argument list (provenance).
    pub arguments: Vec<String>,
}

/// Result of a simulation.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SimulateOutcome {
    /// Probe depth beyond first contact, m.
    pub depth_m: f64,
    /// Axial force reached, N.
    pub axial_force_n: f64,
    /// Load steps written.
    pub load_steps: usize,
    /// Converged?
    pub converged: bool,
    /// Largest marker displacement from rest, m.
    pub max_marker_displacement_m: f64,
}

/// The probing setup of a loaded material: its mesh, markers, attached region.
pub fn setup_of(loaded: &LoadedMaterial) -> Result<ProbingSetup> {
    let path = &loaded.data.path;
    let support = loaded.support.ok_or_else(|| {
        TissueError::bad_input(
            path,
            "/tissue/report support.*",
            "no support plane recorded: cannot attach the object",
        )
    })?;
    let attached = support_nodes(
        &loaded.mesh,
        &Vector3::from(support.normal),
        support.offset_m,
        support.tolerance_m.max(1e-9),
    );
    if attached.is_empty() {
        return Err(TissueError::bad_input(
            path,
            "/tissue/report support.*",
            "no mesh node lies on the support plane",
        ));
    }
    Ok(ProbingSetup::new(
        loaded.mesh.clone(),
        &loaded.markers_rest_m,
        attached,
    )?)
}

/// Synthesizes the probe with the loaded material (bickel2009 §3.4).
pub fn simulate(
    loaded: &LoadedMaterial,
    setup: &ProbingSetup,
    probe: &ProbeSpec,
    settings: &SimulateSettings,
) -> Result<ContactSynthesis> {
    let axis = probe.validate()?;
    let pose = probe_pose(&Vector3::from(probe.tip_m), &axis);
    let mut relaxation = settings.relaxation;
    let mut contact = settings.contact.clone();
    let mut attempt = 0;
    loop {
        let mut model = softcap_probing::StrainSpaceModel::new(
            loaded.material.clone(),
            &setup.mesh,
            relaxation,
        )
        .map_err(|e| TissueError::BadSettings {
            field: "relaxation".into(),
            problem: e.to_string(),
        })?;
        let syn = simulate_probe_contact(
            setup,
            &mut model,
            probe.tip_shape(),
            pose,
            probe.force_n,
            &contact,
        )
        .map_err(|e| match e {
            softcap_fem::FemError::Probing { what } => TissueError::BadSettings {
                field: "probe".into(),
                problem: what,
            },
            e => e.into(),
        })?;
        if syn.status == SolveStatus::Converged || attempt >= settings.relaxation_retries {
            return Ok(syn);
        }
        attempt += 1;
        relaxation *= 0.5;
        contact.equilibrium.max_iterations *= 2;
    }
}

/// Nominal time between load steps in sim.mcap, ns (0.1 s).
pub const LOAD_STEP_NS: u64 = 100_000_000;

/// `softcap tissue simulate`: reads material.mcap, synthesizes, writes sim.mcap atomically.
pub fn run(cfg: &SimulateConfig) -> Result<SimulateOutcome> {
    let loaded = read_material(&cfg.material)?;
    let setup = setup_of(&loaded)?;
    let syn = simulate(&loaded, &setup, &cfg.probe, &cfg.settings)?;
    if syn.status != SolveStatus::Converged {
        return Err(TissueError::NotConverged {
            what: format!(
                "probe synthesis at depth {:.4} mm ({:.4} N of {:.4} N)",
                1e3 * syn.depth_m,
                syn.axial_force_n,
                cfg.probe.force_n
            ),
            status: format!("{:?}", syn.status),
        });
    }
    let err = |e: softcap_mcap::Error| TissueError::Output {
        path: cfg.output.clone(),
        reason: e.to_string(),
    };
    let settings_toml = toml::to_string(&cfg.settings).unwrap_or_default();
    let probe_toml = toml::to_string(&cfg.probe).unwrap_or_default();
    let provenance = Provenance::new("tissue simulate", env!("CARGO_PKG_VERSION"))
        .with_arguments(cfg.arguments.iter())
        .with_settings(format!("{settings_toml}\n[probe]\n{probe_toml}"))
        .with_input(&cfg.material)
        .map_err(|e| TissueError::ReadMcap {
            path: cfg.material.clone(),
            source: Box::new(e),
        })?;
    let mut w = Writer::create(&cfg.output, &provenance).map_err(err)?;
    w.write_static(&topics::VOLUME_MESH, &tet_mesh_message(&setup.mesh))
        .map_err(err)?;
    let v = |p: &Vector3<f64>| proto::Vec3 {
        x: p.x,
        y: p.y,
        z: p.z,
    };
    let axis = syn.world_from_probe_at_touch.rotation * Vector3::z();
    let touch = syn.world_from_probe_at_touch.translation.vector;
    let rest = setup.marker_positions(&setup.mesh.vertices);
    let mut max_disp: f64 = 0.0;
    // Step 0 = rest, then every load increment of the final approach.
    let states = std::iter::once((0.0, 0.0, &setup.mesh.vertices)).chain(
        syn.step_depths_m
            .iter()
            .zip(&syn.step_forces_n)
            .zip(&syn.steps_m)
            .map(|((d, f), x)| (*d, *f, x)),
    );
    let mut steps = 0;
    for (k, (depth, force, x)) in states.enumerate() {
        let t = k as u64 * LOAD_STEP_NS;
        let markers = setup.marker_positions(x);
        for (m, r) in markers.iter().zip(&rest) {
            max_disp = max_disp.max((m - r).norm());
        }
        w.write(
            &topics::SIMULATED_MARKERS,
            t,
            &proto::SimulatedMarkers {
                frame: k as u64,
                example: 0,
                load_step: k as u32,
                ids: (0..markers.len() as u32).collect(),
                positions_m: markers.iter().map(v).collect(),
                measured_m: Vec::new(),
            },
        )
        .map_err(err)?;
        w.write(
            &topics::SIMULATED_PROBE,
            t,
            &proto::ProbeSample {
                frame: k as u64,
                t_camera_s: t as f64 * 1e-9,
                tip_m: Some(v(&(touch + axis * depth))),
                axis: Some(v(&axis)),
                force_n: Some(v(&(axis * force))),
                voltage_v: 0.0,
            },
        )
        .map_err(err)?;
        w.write(
            &topics::DEFORMED_MESH,
            t,
            &proto::TetMesh {
                name: format!("load step {k}"),
                frame_id: "world".into(),
                positions_m: x.iter().flat_map(|p| [p.x, p.y, p.z]).collect(),
                tets: Vec::new(),
                surface_triangles: Vec::new(),
            },
        )
        .map_err(err)?;
        steps += 1;
    }
    let converged = syn.status == SolveStatus::Converged;
    let number = |key: &str, v: f64, unit: &str| proto::KeyValue {
        key: key.into(),
        value: Some(proto::key_value::Value::Number(v)),
        unit: unit.into(),
    };
    w.write_static(
        &topics::TISSUE_REPORT,
        &proto::Report {
            title: "softcap tissue simulate (bickel2009 §3.4)".into(),
            entries: vec![
                number("depth", syn.depth_m, "m"),
                number("axial_force", syn.axial_force_n, "N"),
                number("requested_force", cfg.probe.force_n, "N"),
                number("max_marker_displacement", max_disp, "m"),
                proto::KeyValue {
                    key: "status".into(),
                    value: Some(proto::key_value::Value::Text(format!("{:?}", syn.status))),
                    unit: String::new(),
                },
            ],
        },
    )
    .map_err(err)?;
    w.finish().map_err(err)?;
    Ok(SimulateOutcome {
        depth_m: syn.depth_m,
        axial_force_n: syn.axial_force_n,
        load_steps: steps,
        converged,
        max_marker_displacement_m: max_disp,
    })
}
