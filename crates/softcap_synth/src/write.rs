//! Writing the session folder exactly as `docs/session-format.md` says (length unit mm), plus
//! `truth/`. Files are written into a temporary sibling folder that is renamed into place at the
//! end, so a failed run never leaves a folder that looks like a finished session.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use softcap_core::Camera;
use softcap_mesh::{MshMesh, TetMesh, TriMesh, write_msh, write_tri_mesh_obj};

use crate::error::{Result, SynthError, io_err};
use crate::rig::DetectionRow;
use crate::scenario::{Effect, Scenario};
use crate::sensors::DaqRecord;
use crate::truth::Truth;

const M_TO_MM: f64 = 1e3;

/// A folder being written.
pub struct SessionWriter {
    /// Temporary folder (renamed to `target` by [`SessionWriter::finish`]).
    pub tmp: PathBuf,
    /// Final folder.
    pub target: PathBuf,
}

impl SessionWriter {
    /// Refuses a non-empty existing `target` (checked again by [`Self::begin`]; call it before a
    /// long simulation so a bad output folder fails at once).
    pub fn check_target(target: &Path) -> Result<()> {
        if target.exists() {
            let non_empty = std::fs::read_dir(target)
                .map_err(io_err(target))?
                .next()
                .is_some();
            if non_empty {
                return Err(SynthError::OutputExists {
                    path: target.to_path_buf(),
                });
            }
        }
        Ok(())
    }

    /// Starts writing into `<target>.synth-tmp`; refuses a non-empty existing `target`.
    pub fn begin(target: &Path) -> Result<Self> {
        if target.exists() {
            let non_empty = std::fs::read_dir(target)
                .map_err(io_err(target))?
                .next()
                .is_some();
            if non_empty {
                return Err(SynthError::OutputExists {
                    path: target.to_path_buf(),
                });
            }
        }
        let mut name = target
            .file_name()
            .map(|n| n.to_os_string())
            .unwrap_or_else(|| "session".into());
        name.push(".synth-tmp");
        let tmp = target.with_file_name(name);
        if tmp.exists() {
            std::fs::remove_dir_all(&tmp).map_err(io_err(&tmp))?;
        }
        std::fs::create_dir_all(&tmp).map_err(io_err(&tmp))?;
        Ok(Self {
            tmp,
            target: target.to_path_buf(),
        })
    }

    /// Runs `write` into a fresh temporary folder ([`Self::begin`]) and renames it into place
    /// when it succeeds, or removes it when it fails: a session is written whole or not at all.
    /// Returns `write`'s value and the session folder.
    pub fn atomically<T>(
        target: &Path,
        write: impl FnOnce(&Self) -> Result<T>,
    ) -> Result<(T, PathBuf)> {
        let writer = Self::begin(target)?;
        match write(&writer) {
            Ok(v) => Ok((v, writer.finish()?)),
            Err(e) => {
                writer.abandon();
                Err(e)
            }
        }
    }

    /// Path of a file in the session.
    pub fn path(&self, rel: &str) -> PathBuf {
        self.tmp.join(rel)
    }

    /// Writes a text file (creating folders).
    pub fn text(&self, rel: &str, content: &str) -> Result<()> {
        let p = self.path(rel);
        if let Some(dir) = p.parent() {
            std::fs::create_dir_all(dir).map_err(io_err(dir))?;
        }
        std::fs::write(&p, content).map_err(io_err(&p))
    }

    /// Renames the temporary folder into place.
    pub fn finish(self) -> Result<PathBuf> {
        if self.target.exists() {
            std::fs::remove_dir(&self.target).map_err(io_err(&self.target))?;
        }
        std::fs::rename(&self.tmp, &self.target).map_err(io_err(&self.target))?;
        Ok(self.target)
    }

    /// Removes the temporary folder after a failure.
    pub fn abandon(self) {
        let _ = std::fs::remove_dir_all(&self.tmp);
    }
}

fn mm(v: f64) -> String {
    format!("{:.5}", v * M_TO_MM)
}

/// session.toml.
pub fn session_toml(s: &Scenario, images: bool, detections: bool, robot: bool) -> String {
    let mut t = String::new();
    let _ = writeln!(t, "format = \"softcap-session/1\"");
    let _ = writeln!(t, "name = \"{}\"", s.name);
    let _ = writeln!(t, "kind = \"{}\"", s.kind);
    let _ = writeln!(t, "length_unit = \"mm\"\n");
    let _ = writeln!(t, "[files]");
    let _ = writeln!(t, "cameras = \"rig/cameras.toml\"");
    let _ = writeln!(t, "markers = \"template/markers.csv\"");
    if images {
        let _ = writeln!(t, "images = \"frames\"");
    }
    if detections {
        let _ = writeln!(t, "detections = \"detections\"");
    }
    let _ = writeln!(t, "trigger = \"trigger.csv\"");
    if robot {
        let _ = writeln!(t, "robot = \"rig/robot.urdf\"");
        let _ = writeln!(t, "robot_samples = \"robot.csv\"");
    } else {
        let _ = writeln!(t, "fsr = \"rig/fsr.toml\"");
        let _ = writeln!(t, "fsr_samples = \"fsr.csv\"");
    }
    let _ = writeln!(t, "probe = \"rig/probe.toml\"");
    let _ = writeln!(t, "surface = \"template/surface.obj\"");
    let _ = writeln!(t, "volume = \"template/volume.msh\"\n");
    let _ = writeln!(t, "[world]");
    let g = if s.has(Effect::GravityPreload) {
        s.effect_settings.gravity_m_s2
    } else {
        [0.0, 0.0, -9.81]
    };
    let _ = writeln!(t, "gravity = [{:?}, {:?}, {:?}]\n", g[0], g[1], g[2]);
    let _ = writeln!(t, "[support]");
    let _ = writeln!(t, "plane_normal = [0.0, 0.0, 1.0]");
    let _ = writeln!(t, "plane_offset = 0.0");
    let _ = writeln!(t, "tolerance = 0.5\n");
    if robot {
        let _ = writeln!(t, "[robot]");
        let _ = writeln!(t, "tool_link = \"probe_tip\"");
        let _ = writeln!(t, "ft_link = \"ft_sensor\"\n");
    }
    let _ = writeln!(t, "[object]");
    let _ = writeln!(t, "density_kg_m3 = {:?}", s.object.density_kg_m3);
    let _ = writeln!(
        t,
        "notes = \"synthetic block {} x {} x {} mm bonded to the table (softcap synth)\"",
        s.object.size_mm[0], s.object.size_mm[1], s.object.size_mm[2]
    );
    t
}

/// rig/cameras.toml (translations in mm, the session's length unit).
pub fn cameras_toml(cams: &[Camera]) -> String {
    softcap_core::camera::cameras_toml(cams, M_TO_MM)
}

/// rig/probe.toml.
pub fn probe_toml(s: &Scenario) -> String {
    let p = &s.probe;
    let mut t = format!("tip = \"{}\"\nradius = {:.3}\n", p.tip, p.radius_mm);
    for i in 0..2 {
        let _ = write!(
            t,
            "\n[[shaft_marker]]\nid = \"shaft{i}\"\ndistance_from_tip = {:.3}\ncolor = \"{}\"\n",
            p.shaft_marker_distances_mm[i], p.shaft_marker_colors[i]
        );
    }
    t
}

/// rig/fsr.toml.
pub fn fsr_toml(s: &Scenario, calibration: &[[f64; 2]]) -> String {
    let rows: Vec<String> = calibration
        .iter()
        .map(|[f, v]| format!("[{f:.4}, {v:.4}]"))
        .collect();
    format!(
        "supply_v = {:?}\ndivider_ohm = {:?}\n# calibration from known weights: force (N) against measured voltage (V)\ncalibration = [{}]\n",
        s.fsr.supply_v,
        s.fsr.divider_ohm,
        rows.join(", ")
    )
}

/// template/markers.csv.
pub fn markers_csv(truth: &Truth, color: &str) -> String {
    let mut t = String::from("id,x,y,z,color\n");
    for (id, p) in truth.block.marker_ids.iter().zip(&truth.template_markers_m) {
        let _ = writeln!(t, "{id},{},{},{},{color}", mm(p.x), mm(p.y), mm(p.z));
    }
    t
}

/// Writes template/surface.obj and template/volume.msh (the observed template fit mesh, mm).
pub fn write_template_meshes(w: &SessionWriter, mesh_m: &TetMesh) -> Result<()> {
    let mesh_mm = TetMesh {
        vertices: mesh_m.vertices.iter().map(|v| v * M_TO_MM).collect(),
        tets: mesh_m.tets.clone(),
    };
    let faces = mesh_mm.boundary_faces();
    // Compact the surface to its own vertices.
    let mut map = vec![usize::MAX; mesh_mm.vertices.len()];
    let mut surf = TriMesh::default();
    for f in &faces {
        for &v in f {
            if map[v] == usize::MAX {
                map[v] = surf.vertices.len();
                surf.vertices.push(mesh_mm.vertices[v]);
            }
        }
        surf.triangles.push(f.map(|v| map[v]));
    }
    let dir = w.path("template");
    std::fs::create_dir_all(&dir).map_err(io_err(&dir))?;
    write_tri_mesh_obj(w.path("template/surface.obj"), &surf)?;
    write_msh(
        w.path("template/volume.msh"),
        &MshMesh::from_tet_mesh(&mesh_mm, None),
    )?;
    Ok(())
}

/// `detections/<camera>.csv`.
pub fn detections_csv(rows: &[DetectionRow], labeled: bool) -> String {
    let mut t = String::from(if labeled {
        "frame,u,v,color,label\n"
    } else {
        "frame,u,v,color\n"
    });
    for r in rows {
        if labeled {
            let Some(l) = &r.label else { continue };
            let _ = writeln!(t, "{},{:.3},{:.3},{},{l}", r.frame, r.uv.x, r.uv.y, r.color);
        } else {
            let _ = writeln!(t, "{},{:.3},{:.3},{}", r.frame, r.uv.x, r.uv.y, r.color);
        }
    }
    t
}

/// trigger.csv.
pub fn trigger_csv(truth: &Truth) -> String {
    let mut t = String::from("frame,t_camera_s\n");
    for f in &truth.frames {
        let _ = writeln!(t, "{},{:.6}", f.spec.frame, f.spec.t_camera_s);
    }
    t
}

/// fsr.csv.
pub fn fsr_csv(daq: &DaqRecord) -> String {
    let mut t = String::from(if daq.trigger_v.is_some() {
        "t_daq_s,voltage_v,trigger_v\n"
    } else {
        "t_daq_s,voltage_v\n"
    });
    for k in 0..daq.t_daq_s.len() {
        match &daq.trigger_v {
            Some(tr) => {
                let _ = writeln!(
                    t,
                    "{:.4},{:.5},{:.4}",
                    daq.t_daq_s[k], daq.voltage_v[k], tr[k]
                );
            }
            None => {
                let _ = writeln!(t, "{:.4},{:.5}", daq.t_daq_s[k], daq.voltage_v[k]);
            }
        }
    }
    t
}

/// truth/markers.csv (object markers then shaft markers, every frame).
pub fn truth_markers_csv(truth: &Truth) -> String {
    let mut t = String::from("frame,id,x,y,z\n");
    for f in &truth.frames {
        for (id, p) in truth.block.marker_ids.iter().zip(&f.markers_m) {
            let _ = writeln!(
                t,
                "{},{id},{},{},{}",
                f.spec.frame,
                mm(p.x),
                mm(p.y),
                mm(p.z)
            );
        }
        for ((id, _, _), p) in truth
            .probe
            .shaft_markers
            .iter()
            .zip(truth.probe.shaft_marker_positions(&f.spec.world_from_probe))
        {
            let _ = writeln!(
                t,
                "{},{id},{},{},{}",
                f.spec.frame,
                mm(p.x),
                mm(p.y),
                mm(p.z)
            );
        }
    }
    t
}

/// truth/probe.csv.
pub fn truth_probe_csv(truth: &Truth) -> String {
    let mut t = String::from("frame,t_camera_s,fx,fy,fz,tip_x,tip_y,tip_z\n");
    for f in &truth.frames {
        let tip = f.spec.world_from_probe.translation.vector;
        let _ = writeln!(
            t,
            "{},{:.6},{:.6},{:.6},{:.6},{},{},{}",
            f.spec.frame,
            f.spec.t_camera_s,
            f.force_n.x,
            f.force_n.y,
            f.force_n.z,
            mm(tip.x),
            mm(tip.y),
            mm(tip.z)
        );
    }
    t
}

/// truth/frames.csv: protocol bookkeeping (location, phase, commanded depth, axial force).
pub fn truth_frames_csv(truth: &Truth) -> String {
    let mut t = String::from("frame,t_camera_s,location,phase,depth_mm,axial_force_n\n");
    for f in &truth.frames {
        let _ = writeln!(
            t,
            "{},{:.6},{},{},{:.5},{:.6}",
            f.spec.frame,
            f.spec.t_camera_s,
            f.spec.location,
            f.spec.phase.name(),
            f.spec.depth_m * M_TO_MM,
            f.axial_force_n
        );
    }
    t
}

/// truth/clock.toml.
pub fn clock_toml(offset_s: f64, drift: f64) -> String {
    format!(
        "# t_daq = offset_s + (1 + drift) * t_camera\noffset_s = {offset_s:.9}\ndrift = {drift:e}\n"
    )
}

/// truth/README.md naming every effect switched on.
pub fn truth_readme(s: &Scenario, truth: &Truth, daq: Option<&DaqRecord>) -> String {
    let mut t = format!(
        "# Ground truth of {} (synthetic, softcap synth)\n\n",
        s.name
    );
    if s.effects.is_empty() {
        t.push_str("Effects switched on: none (CLEAN).\n\n");
    } else {
        let names: Vec<&str> = s.effects.iter().map(|e| e.name()).collect();
        let _ = writeln!(t, "Effects switched on: {}.\n", names.join(", "));
    }
    for e in &s.effects {
        let es = &s.effect_settings;
        let line = match e {
            Effect::ClockOffset if es.clock_force_latency_s > 0.0 => format!(
                "- clock-offset: trigger line present, but the FSR channel lags it by {:.3} s (the force read at camera time t is the force of t - {:.3} s); DAQ offset {:.6} s.",
                es.clock_force_latency_s,
                es.clock_force_latency_s,
                daq.map_or(0.0, |d| d.offset_s)
            ),
            Effect::ClockOffset => format!(
                "- clock-offset: no trigger line (fsr.csv has no trigger_v); DAQ offset {:.6} s (extra {:.3} s).",
                daq.map_or(0.0, |d| d.offset_s),
                es.clock_extra_offset_s
            ),
            Effect::SensorLag => format!(
                "- sensor-lag: FSR first-order lag tau = {} s, play hysteresis half-width {} x force.",
                es.sensor_lag_tau_s, es.sensor_hysteresis_fraction
            ),
            Effect::GravityPreload => format!(
                "- gravity-preload: gravity {:?} m/s^2, density {} kg/m^3, E = {} Pa; template/ holds the UNLOADED (stress-free) box, every frame (frame 0 included) sees the block sagged under gravity.",
                es.gravity_m_s2, s.object.density_kg_m3, es.gravity_young_pa
            ),
            Effect::Viscoelasticity => format!(
                "- viscoelasticity: Prony series on the neo-Hookean truth (softcap_fem::ViscoelasticModel, quasi-static), one branch g = {}, tau = {} s; the probe is position controlled, so the force relaxes during each hold.",
                es.viscoelastic_g, es.viscoelastic_tau_s
            ),
            Effect::Plasticity => format!(
                "- plasticity: J2 plasticity on the corotational element (softcap_fem::ElastoplasticModel), E = {} Pa, nu = {}, yield stress {} Pa, hardening {} Pa; {} truth elements yielded, the surface keeps a permanent set after each release.",
                s.material.young_pa,
                s.material.poisson,
                es.plastic_yield_pa,
                es.plastic_hardening_pa,
                truth.yielded_elements
            ),
            Effect::ProbeFriction => format!(
                "- probe-friction: regularized Coulomb friction under the tip (softcap_fem::FrictionalContact), mu = {}, slip distance {} mm; while in contact the tip also moves {} x depth sideways (oblique path), dragging the surface.",
                es.friction_mu, es.friction_slip_distance_mm, es.friction_path_ratio
            ),
            Effect::SupportSlip => format!(
                "- support-slip: the bottom face sits on a compliant mount (softcap_fem::SupportPlane, tangential springs, {} N/m in total) instead of being bonded; the probe is tilted {} deg (oblique push), so the block slides on its support.",
                es.support_stiffness_n_per_m, es.support_tilt_deg
            ),
            Effect::InertiaDamping => format!(
                "- inertia-damping: implicit dynamics (softcap_fem::DynamicSolver, Newmark average acceleration, {} steps per frame), density {} kg/m^3, Rayleigh damping alpha = {} 1/s, beta = {} s.",
                es.dynamics_substeps,
                s.object.density_kg_m3,
                es.rayleigh_alpha_per_s,
                es.rayleigh_beta_s
            ),
            Effect::StiffInclusion => format!(
                "- stiff-inclusion: sphere centre {:?} mm, radius {} mm, {}x stiffer ({} truth elements).",
                s.material.inclusion.centre_mm,
                s.material.inclusion.radius_mm,
                s.material.inclusion.stiffness_ratio,
                truth.inclusion_elements
            ),
            Effect::Anisotropy => format!(
                "- anisotropy: transversely isotropic corotational truth (softcap_fem::AnisotropicModel, thesis eq. 8.5), fibres along {:?}, fibre/transverse modulus ratio {}.",
                es.anisotropy_fibre, es.anisotropy_fibre_ratio
            ),
            Effect::StrainStiffening => format!(
                "- strain-stiffening: Yeoh term c2 (I_C - 3)^2 with c2 = {} mu.",
                s.material.stiffening.c2_over_mu
            ),
        };
        let _ = writeln!(t, "{line}");
    }
    let m = &s.material;
    let _ = write!(
        t,
        "\nObject and material\n- Block {} x {} x {} mm occupying [0, size] in the world; bottom face (z = 0) bonded to the table.\n\
         - Stable neo-Hookean (Smith, de Goes & Kim 2018) E = {} Pa, nu = {} on a {} x {} x {}-cell structured mesh{} ({} tets); \
         the template volume.msh has {} x {} x {} cells ({} tets).\n",
        s.object.size_mm[0],
        s.object.size_mm[1],
        s.object.size_mm[2],
        if s.has(Effect::GravityPreload) {
            s.effect_settings.gravity_young_pa
        } else {
            m.young_pa
        },
        m.poisson,
        s.object.truth_cells[0],
        s.object.truth_cells[1],
        s.object.truth_cells[2],
        if s.object.truth_refine_edge_mm > 0.0 {
            format!(
                " refined to edges <= {} mm within twice the contact radius of every loaded tip pose",
                s.object.truth_refine_edge_mm
            )
        } else {
            String::new()
        },
        truth.block.truth_mesh.tets.len(),
        s.object.fit_cells[0],
        s.object.fit_cells[1],
        s.object.fit_cells[2],
        truth.block.fit_mesh.tets.len()
    );
    let locs: Vec<String> = truth
        .locations_m
        .iter()
        .map(|p| format!("({:.2}, {:.2})", p[0] * M_TO_MM, p[1] * M_TO_MM))
        .collect();
    let _ = write!(
        t,
        "\nProbe\n- Rigid {} radius {} mm, {} penalty contact (softcap_fem), displacement controlled.\n\
         - {} locations (x, y mm): {}.\n\
         - Per location: {} ramp frames, {} hold frames, {} release frames, {} move frames at {} Hz; frame 0 is the rest state.\n\
         - truth/frames.csv: location, phase, commanded depth and axial force per frame.\n",
        s.probe.tip,
        s.probe.radius_mm,
        if s.has(Effect::ProbeFriction) {
            "frictional"
        } else {
            "frictionless"
        },
        truth.locations_m.len(),
        locs.join(", "),
        s.protocol.ramp_frames,
        s.protocol.hold_frames,
        s.protocol.release_frames,
        s.protocol.move_frames,
        s.protocol.frame_rate_hz
    );
    let f = &s.fsr;
    let o = &s.output;
    if s.kind == "probe-robot" {
        let r = &s.robot;
        let _ = write!(
            t,
            "\nRobot (kind probe-robot)\n- 4-DOF arm (rig/robot.urdf: yaw, shoulder, elbow, wrist), base at {:?} mm; tool link probe_tip (+z pushing), F/T link ft_sensor mounted with rpy {:?} rad.\n\
             - robot.csv at {} Hz on the DAQ clock (no trigger line): joints from closed-form IK of the true probe pose + {} rad noise; force by the probe on the object and torque about the sensor origin in ft_sensor, + {} N / {} N m noise.\n\
             - The FSR lines below do not apply (no fsr files).\n",
            r.base_mm, r.ft_rpy, r.rate_hz, r.joint_noise_rad, r.force_noise_n, r.torque_noise_nm
        );
    }
    let _ = write!(
        t,
        "\nSensors and noise\n- FSR: R = {} F^-{} ohm capped at {:e} ohm; divider {} ohm, supply {} V; calibration voltages carry {}% noise.\n\
         - DAQ {} Hz, {} V rms noise, {}-bit quantisation; trigger high {} V during each {} s exposure.\n\
         - Detections: projections + {} px noise, {} dropout probability, hidden by the probe or facing away removed, {} persistent speck(s) per camera, random spurious blobs with probability {} per frame.\n\
         - Images: anti-aliased discs ({}x{} supersampling) on a textured neutral background.\n\
         - Seed {}.\n",
        f.k_ohm,
        f.exponent,
        f.r_max_ohm,
        f.divider_ohm,
        f.supply_v,
        f.calibration_noise * 100.0,
        f.daq_rate_hz,
        f.noise_v,
        f.adc_bits,
        f.trigger_high_v,
        f.exposure_s,
        o.detection_noise_px,
        o.dropout_probability,
        o.persistent_specks,
        o.spurious_probability,
        o.supersample,
        o.supersample,
        s.seed
    );
    t
}
