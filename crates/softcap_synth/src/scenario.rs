//! Scenario files (`fixtures/scenarios/*.toml`): everything the virtual rig needs to write one
//! session. Every struct has `Default` and `#[serde(default)]`, so a scenario file only lists what
//! differs from the standard 10-location clean session; `docs/synth.md` is the reference.
//!
//! Lengths in scenario files are millimetres (`_mm`), angles degrees (`_deg`), everything else SI.

use serde::{Deserialize, Serialize};
use std::path::Path;

use crate::error::{Result, SynthError};
pub use crate::robot::RobotSettings;

/// One switchable effect: the catalog shared with the diagnosis (its names are the ones
/// `softcap diagnose` reports), plus the two controls.
pub use softcap_mcap::Effect;

/// A whole scenario.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Scenario {
    /// Session name (written to session.toml).
    pub name: String,
    /// Session kind: "probe" (hand-held probe + FSR), "probe-robot" (arm + 6-axis F/T) or
    /// "dynamic" (depth cameras watching a freely moving object, wang2015).
    pub kind: String,
    /// Master seed of every random choice (locations, depths, noise, dropouts, spurious blobs).
    pub seed: u64,
    /// Effects switched on (empty = clean).
    pub effects: Vec<Effect>,
    /// The object.
    pub object: ObjectSettings,
    /// Its material.
    pub material: MaterialSettings,
    /// The probe.
    pub probe: ProbeSettings,
    /// Probing protocol.
    pub protocol: ProtocolSettings,
    /// Cameras.
    pub rig: RigSettings,
    /// Force-sensing resistor and DAQ.
    pub fsr: FsrSettings,
    /// Camera↔DAQ clock relation.
    pub clock: ClockSettings,
    /// What is written and how it is corrupted.
    pub output: OutputSettings,
    /// Parameters of the effects (used only when the effect is switched on).
    pub effect_settings: EffectSettings,
    /// The robot arm and F/T sensor (kind "probe-robot").
    pub robot: RobotSettings,
    /// Motion, damping, depth cameras (kind "dynamic"; the object's box, meshes, material and
    /// density come from `object` and `material`).
    pub dynamic: crate::dynamic::DynamicSettings,
}

impl Default for Scenario {
    fn default() -> Self {
        Self {
            name: "synth-clean".into(),
            kind: "probe".into(),
            seed: 1,
            effects: Vec::new(),
            object: ObjectSettings::default(),
            material: MaterialSettings::default(),
            probe: ProbeSettings::default(),
            protocol: ProtocolSettings::default(),
            rig: RigSettings::default(),
            fsr: FsrSettings::default(),
            clock: ClockSettings::default(),
            output: OutputSettings::default(),
            effect_settings: EffectSettings::default(),
            robot: RobotSettings::default(),
            dynamic: crate::dynamic::DynamicSettings::default(),
        }
    }
}

/// The probed block and its markers.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ObjectSettings {
    /// Block size [x, y, z], mm; it occupies [0, size] in the world, the bottom face on the table.
    pub size_mm: [f64; 3],
    /// Structured cells of the fit mesh written as template/volume.msh (6 tets per cell).
    pub fit_cells: [usize; 3],
    /// Structured cells of the finer ground-truth mesh (6 tets per cell).
    pub truth_cells: [usize; 3],
    /// Local refinement of the truth mesh along the probe's contact paths, mm: every truth tet
    /// within reach of a contact patch is bisected (conforming longest-edge bisection,
    /// `softcap_mesh::refine_near`) until its longest edge is ≤ this; 0 (the default) keeps the
    /// structured `truth_cells` mesh. For contact whose footprint is smaller than the truth's
    /// node spacing (a stuck frictional patch carried by a few nodes;
    /// docs/notes/2026-11-27-probe-friction-truth-resolution.md); the balls are [`crate::truth::contact_refinement_balls`].
    pub truth_refine_edge_mm: f64,
    /// Density, kg/m³ (session.toml `[object]`, gravity pre-load).
    pub density_kg_m3: f64,
    /// Painted markers on the top face: grid columns × rows.
    pub marker_grid: [usize; 2],
    /// Distance of the outer marker rows from the top face's edges, mm.
    pub marker_margin_mm: f64,
    /// Seeded jitter of marker positions around the grid, mm.
    pub marker_jitter_mm: f64,
    /// Painted disc radius, mm.
    pub marker_radius_mm: f64,
    /// Marker colour (session-format colour name).
    pub marker_color: String,
}

impl Default for ObjectSettings {
    fn default() -> Self {
        Self {
            size_mm: [40.0, 40.0, 20.0],
            fit_cells: [8, 8, 4],
            truth_cells: [12, 12, 6],
            truth_refine_edge_mm: 0.0,
            density_kg_m3: 1050.0,
            marker_grid: [6, 6],
            marker_margin_mm: 3.5,
            marker_jitter_mm: 0.6,
            marker_radius_mm: 1.7,
            marker_color: "blue".into(),
        }
    }
}

/// Ground-truth material: stable neo-Hookean (Smith et al. 2018) with optional heterogeneity.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MaterialSettings {
    /// Young's modulus of the small-strain linearization, Pa.
    pub young_pa: f64,
    /// Poisson ratio of the small-strain linearization.
    pub poisson: f64,
    /// Stiff inclusion (effect "stiff-inclusion").
    pub inclusion: InclusionSettings,
    /// Strain stiffening (effect "strain-stiffening").
    pub stiffening: StiffeningSettings,
}

impl Default for MaterialSettings {
    fn default() -> Self {
        Self {
            young_pa: 50_000.0,
            poisson: 0.45,
            inclusion: InclusionSettings::default(),
            stiffening: StiffeningSettings::default(),
        }
    }
}

/// A spherical region whose elements are `stiffness_ratio` times stiffer (both Lamé parameters).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct InclusionSettings {
    /// Centre, mm.
    pub centre_mm: [f64; 3],
    /// Radius, mm.
    pub radius_mm: f64,
    /// Stiffness multiplier.
    pub stiffness_ratio: f64,
}

impl Default for InclusionSettings {
    fn default() -> Self {
        Self {
            centre_mm: [14.0, 26.0, 12.0],
            radius_mm: 7.0,
            stiffness_ratio: 6.0,
        }
    }
}

/// Second-order Yeoh term added to the stable neo-Hookean energy:
/// Ψ_s = c₂ (I_C − 3)², c₂ = `c2_over_mu` · μ.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StiffeningSettings {
    /// c₂ / μ (dimensionless).
    pub c2_over_mu: f64,
}

impl Default for StiffeningSettings {
    fn default() -> Self {
        Self { c2_over_mu: 40.0 }
    }
}

/// The probe: a rigid disk (or sphere) tip on a shaft with two painted shaft markers.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ProbeSettings {
    /// "disk" or "sphere".
    pub tip: String,
    /// Tip radius, mm.
    pub radius_mm: f64,
    /// Disk thickness, mm (rendering and contact geometry).
    pub thickness_mm: f64,
    /// Shaft radius, mm (rendering / occlusion only).
    pub shaft_radius_mm: f64,
    /// Shaft length from the tip, mm (rendering / occlusion only).
    pub shaft_length_mm: f64,
    /// Distances of the two shaft markers from the tip, mm.
    pub shaft_marker_distances_mm: [f64; 2],
    /// Shaft marker colours.
    pub shaft_marker_colors: [String; 2],
    /// Shaft marker sphere radius, mm.
    pub shaft_marker_radius_mm: f64,
    /// Contact penalty factor (softcap_fem `ContactSettings::penalty_factor`).
    pub penalty_factor: f64,
}

impl Default for ProbeSettings {
    fn default() -> Self {
        Self {
            tip: "disk".into(),
            radius_mm: 5.0,
            thickness_mm: 2.0,
            shaft_radius_mm: 1.5,
            shaft_length_mm: 140.0,
            shaft_marker_distances_mm: [60.0, 120.0],
            shaft_marker_colors: ["red".into(), "yellow".into()],
            shaft_marker_radius_mm: 2.2,
            penalty_factor: 1.0e4,
        }
    }
}

/// Probing protocol: locations and the ramp / hold / release at each.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ProtocolSettings {
    /// Number of probe locations (ignored when `locations_mm` is given).
    pub locations: usize,
    /// Explicit locations [x, y] on the top face, mm.
    pub locations_mm: Vec<[f64; 2]>,
    /// Minimum distance of a seeded location from the top face's edges, mm.
    pub edge_margin_mm: f64,
    /// Indentation depth range [min, max] along the probe axis, mm (seeded per location).
    pub depth_mm: [f64; 2],
    /// Frames of the loading ramp (the last one reaches the full depth).
    pub ramp_frames: usize,
    /// Frames held at full depth.
    pub hold_frames: usize,
    /// Frames of the unloading ramp (the last one is back at the surface).
    pub release_frames: usize,
    /// Frames with the probe lifted, moving to the next location.
    pub move_frames: usize,
    /// Camera frame rate, Hz.
    pub frame_rate_hz: f64,
    /// Camera time of frame 0, s.
    pub start_time_s: f64,
    /// Height of the lifted tip above the surface, mm.
    pub hover_mm: f64,
    /// Probe tilt from the surface normal, degrees (probe-friction uses its own tilt).
    pub tilt_deg: f64,
}

impl Default for ProtocolSettings {
    fn default() -> Self {
        Self {
            locations: 10,
            locations_mm: Vec::new(),
            edge_margin_mm: 9.0,
            depth_mm: [1.6, 2.6],
            ramp_frames: 5,
            hold_frames: 3,
            release_frames: 3,
            move_frames: 3,
            frame_rate_hz: 10.0,
            start_time_s: 0.8845,
            hover_mm: 6.0,
            tilt_deg: 0.0,
        }
    }
}

/// Three cameras in a triangle above the object, looking at its top face.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RigSettings {
    /// Number of cameras (placed evenly on a circle).
    pub cameras: usize,
    /// Image width, px.
    pub width: u32,
    /// Image height, px.
    pub height: u32,
    /// Focal length, px.
    pub focal_px: f64,
    /// Distance of each camera from the aim point, mm.
    pub distance_mm: f64,
    /// Angle of each camera's view direction from the vertical, degrees.
    pub tilt_deg: f64,
    /// Aim point, mm (default: `aim_above_top_mm` above the centre of the top face).
    pub aim_mm: Option<[f64; 3]>,
    /// Height of the default aim point above the top face, mm (keeps the shaft markers in view).
    pub aim_above_top_mm: f64,
    /// Brown–Conrady distortion (k1, k2, p1, p2, k3) of every camera (OpenCV order).
    pub distortion: [f64; 5],
}

impl Default for RigSettings {
    fn default() -> Self {
        Self {
            cameras: 3,
            width: 640,
            height: 480,
            focal_px: 620.0,
            distance_mm: 270.0,
            tilt_deg: 35.0,
            aim_mm: None,
            aim_above_top_mm: 35.0,
            distortion: [-0.045, 0.008, 5.0e-5, -4.0e-5, 0.0],
        }
    }
}

/// FSR in the probe tip: R = k F^(−γ), capped at `r_max_ohm`, read through a divider by the DAQ.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FsrSettings {
    /// k in R = k F^(−γ) (F in N), ohm.
    pub k_ohm: f64,
    /// γ.
    pub exponent: f64,
    /// Resistance at no load, ohm.
    pub r_max_ohm: f64,
    /// Divider supply, V.
    pub supply_v: f64,
    /// Divider resistor, ohm.
    pub divider_ohm: f64,
    /// Calibration forces written to rig/fsr.toml, N (voltages computed with noise).
    pub calibration_forces_n: Vec<f64>,
    /// Relative (multiplicative) noise of the calibration voltages.
    pub calibration_noise: f64,
    /// DAQ sample rate, Hz.
    pub daq_rate_hz: f64,
    /// Voltage noise, V rms.
    pub noise_v: f64,
    /// ADC bits over 0..supply (0 = no quantisation).
    pub adc_bits: u32,
    /// Exposure time (trigger pulse width), s.
    pub exposure_s: f64,
    /// Trigger high level, V.
    pub trigger_high_v: f64,
    /// DAQ recording starts this long before frame 0 and ends this long after the last frame, s.
    pub margin_s: f64,
}

impl Default for FsrSettings {
    fn default() -> Self {
        Self {
            k_ohm: 9168.11,
            exponent: 0.9,
            r_max_ohm: 2.0e7,
            supply_v: 5.0,
            divider_ohm: 10_000.0,
            calibration_forces_n: vec![0.0, 0.05, 0.1, 0.2, 0.4, 0.7, 1.0, 1.5, 2.0, 2.5, 3.0, 4.0],
            calibration_noise: 0.01,
            daq_rate_hz: 200.0,
            noise_v: 0.002,
            adc_bits: 12,
            exposure_s: 0.01,
            trigger_high_v: 5.0,
            margin_s: 0.1,
        }
    }
}

/// t_daq = offset_s + (1 + drift) · t_camera (truth/clock.toml).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ClockSettings {
    /// Offset, s.
    pub offset_s: f64,
    /// Relative drift (e.g. −40e−6).
    pub drift: f64,
}

impl Default for ClockSettings {
    fn default() -> Self {
        Self {
            offset_s: 2.898387,
            drift: -3.9491e-5,
        }
    }
}

/// What the rig writes and how observations are corrupted.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OutputSettings {
    /// Write `frames/<camera>/<frame>.png`.
    pub images: bool,
    /// Write `detections/<camera>.csv`.
    pub detections: bool,
    /// Add a `label` column to detections (correspondence given).
    pub labeled: bool,
    /// Gaussian noise of detected centroids, px rms.
    pub detection_noise_px: f64,
    /// Probability that a visible marker is missing from a camera's detections in a frame.
    pub dropout_probability: f64,
    /// Persistent background specks per camera (spurious blobs present in every frame).
    pub persistent_specks: usize,
    /// Probability per camera and frame of one random spurious blob.
    pub spurious_probability: f64,
    /// Supersampling per pixel axis when rendering markers.
    pub supersample: usize,
    /// Amplitude of the background texture, grey levels.
    pub texture_contrast: f64,
}

impl Default for OutputSettings {
    fn default() -> Self {
        Self {
            images: false,
            detections: true,
            labeled: false,
            detection_noise_px: 0.2,
            dropout_probability: 0.01,
            persistent_specks: 1,
            spurious_probability: 0.05,
            supersample: 8,
            texture_contrast: 14.0,
        }
    }
}

/// Parameters of the switchable effects.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EffectSettings {
    /// sensor-lag: FSR first-order lag time constant, s.
    pub sensor_lag_tau_s: f64,
    /// sensor-lag: half-width of the FSR hysteresis (play operator), as a fraction of the
    /// session's largest axial force.
    pub sensor_hysteresis_fraction: f64,
    /// clock-offset: extra DAQ offset on top of `clock.offset_s`, s (the DAQ starts recording
    /// at an arbitrary time; without a trigger line nothing ties the clocks together).
    pub clock_extra_offset_s: f64,
    /// clock-offset: constant latency of the FSR channel behind the trigger channel of the same
    /// DAQ, s (e.g. the group delay of a delta-sigma ADC's decimation filter, which the digital
    /// trigger input does not have). When > 0 the trigger line is kept (capture syncs the clocks
    /// exactly from it) and the DAQ reads at time t the force of t − latency: a pure time shift
    /// of force against geometry that the trigger cannot reveal. 0 (default): the no-trigger
    /// variant with `clock_extra_offset_s`.
    pub clock_force_latency_s: f64,
    /// gravity-preload: gravity, m/s² (world frame).
    pub gravity_m_s2: [f64; 3],
    /// anisotropy: fibre direction (world).
    pub anisotropy_fibre: [f64; 3],
    /// anisotropy: fibre / transverse Young's modulus ratio.
    pub anisotropy_fibre_ratio: f64,
    /// gravity-preload: Young's modulus used instead of `material.young_pa` (a softer object
    /// sags visibly), Pa.
    pub gravity_young_pa: f64,
    /// viscoelasticity: Prony branch g (fraction of the long-term stiffness that relaxes).
    pub viscoelastic_g: f64,
    /// viscoelasticity: Prony branch relaxation time τ, s.
    pub viscoelastic_tau_s: f64,
    /// plasticity: J2 uniaxial yield stress σ_y, Pa.
    pub plastic_yield_pa: f64,
    /// plasticity: uniaxial hardening modulus H, Pa.
    pub plastic_hardening_pa: f64,
    /// probe-friction: Coulomb coefficient μ under the tip.
    pub friction_mu: f64,
    /// probe-friction: regularization slip ε of the Coulomb law, mm.
    pub friction_slip_distance_mm: f64,
    /// probe-friction: tangential travel of the tip per unit of indentation depth while in
    /// contact (the path is oblique; the probe axis keeps `protocol.tilt_deg`).
    pub friction_path_ratio: f64,
    /// probe-friction: how the truth's frictional contact samples the surface: 0 = at the top
    /// nodes (node-to-rigid-surface, the original truth); k ≥ 1 = quadrature points on the top
    /// triangles, each cut into k² sub-triangles of 3 points
    /// (`softcap_fem::ContactDiscretisation::Quadrature`).
    pub friction_contact_subdivisions: usize,
    /// support-slip: total tangential stiffness of the mount under the bottom face, N/m
    /// (spread evenly over the support nodes).
    pub support_stiffness_n_per_m: f64,
    /// support-slip: probe tilt from the surface normal (oblique probing), degrees.
    pub support_tilt_deg: f64,
    /// inertia-damping: Rayleigh mass-proportional damping α, 1/s.
    pub rayleigh_alpha_per_s: f64,
    /// inertia-damping: Rayleigh stiffness-proportional damping β, s.
    pub rayleigh_beta_s: f64,
    /// inertia-damping: implicit time steps per camera frame.
    pub dynamics_substeps: usize,
}

impl Default for EffectSettings {
    fn default() -> Self {
        Self {
            sensor_lag_tau_s: 0.25,
            sensor_hysteresis_fraction: 0.08,
            clock_extra_offset_s: 0.137,
            clock_force_latency_s: 0.0,
            gravity_m_s2: [0.0, 0.0, -9.81],
            gravity_young_pa: 2_200.0,
            anisotropy_fibre: [1.0, 0.0, 0.0],
            anisotropy_fibre_ratio: 5.0,
            viscoelastic_g: 0.5,
            viscoelastic_tau_s: 0.1,
            plastic_yield_pa: 4_000.0,
            plastic_hardening_pa: 2_000.0,
            friction_mu: 0.6,
            friction_slip_distance_mm: 0.01,
            friction_path_ratio: 0.6,
            friction_contact_subdivisions: 0,
            support_stiffness_n_per_m: 800.0,
            support_tilt_deg: 20.0,
            rayleigh_alpha_per_s: 6.0,
            rayleigh_beta_s: 1.0e-4,
            dynamics_substeps: 4,
        }
    }
}

impl Scenario {
    /// Reads a scenario TOML file; errors name the file and the field.
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|source| SynthError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::parse(path, &text)
    }

    /// Parses scenario TOML text (`path` is used in errors only). `name` is the one required
    /// key; errors name the line and the field (`protocol.locations`).
    pub fn parse(path: &Path, text: &str) -> Result<Self> {
        let err = |message: String| SynthError::Scenario {
            path: path.to_path_buf(),
            message,
        };
        let table: toml::Table = text
            .parse()
            .map_err(|e: toml::de::Error| err(describe_toml_error(text, &e)))?;
        if !table.contains_key("name") {
            return Err(err(
                "field `name` is missing (required: it names the session)".into(),
            ));
        }
        if let Some(bad) = softcap_app::non_finite(text) {
            return Err(err(bad.to_string()));
        }
        let mut s: Scenario =
            toml::from_str(text).map_err(|e| err(describe_toml_error(text, &e)))?;
        if let Some(dir) = &s.dynamic.external_truth {
            let resolved = crate::dynamic::external::resolve(path, dir);
            s.dynamic.external_truth = Some(resolved.to_string_lossy().into_owned());
        }
        s.validate().map_err(|message| SynthError::Scenario {
            path: path.to_path_buf(),
            message,
        })?;
        Ok(s)
    }

    /// True if `effect` is switched on.
    pub fn has(&self, effect: Effect) -> bool {
        self.effects.contains(&effect)
    }

    /// Checks ranges; the message names the field.
    pub fn validate(&self) -> std::result::Result<(), String> {
        let pos = |v: f64, field: &str| {
            if v > 0.0 && v.is_finite() {
                Ok(())
            } else {
                Err(format!("{field} must be positive and finite, got {v}"))
            }
        };
        if self.name.is_empty() || self.name.contains(['/', '\\', '"']) {
            return Err(format!(
                "name {:?} must be non-empty without / \\ \"",
                self.name
            ));
        }
        if self.kind == "dynamic" {
            return self.validate_dynamic();
        }
        if self.kind != "probe" && self.kind != "probe-robot" {
            return Err(format!(
                "kind must be \"probe\", \"probe-robot\" or \"dynamic\", got {:?}",
                self.kind
            ));
        }
        for (i, v) in self.object.size_mm.iter().enumerate() {
            pos(*v, &format!("object.size_mm[{i}]"))?;
        }
        for (name, c) in [
            ("object.fit_cells", self.object.fit_cells),
            ("object.truth_cells", self.object.truth_cells),
        ] {
            if c.contains(&0) {
                return Err(format!("{name} must be ≥ 1 in every direction"));
            }
        }
        let h = self.object.truth_refine_edge_mm;
        if !(h.is_finite() && h >= 0.0) {
            return Err(format!(
                "object.truth_refine_edge_mm must be ≥ 0 and finite (0 = off), got {h}"
            ));
        }
        pos(self.object.marker_radius_mm, "object.marker_radius_mm")?;
        if self.object.marker_grid.iter().any(|&n| n < 2) {
            return Err("object.marker_grid must be at least 2 × 2".into());
        }
        pos(self.material.young_pa, "material.young_pa")?;
        if !(self.material.poisson > -1.0 && self.material.poisson < 0.5) {
            return Err(format!(
                "material.poisson must be in (−1, 0.5), got {}",
                self.material.poisson
            ));
        }
        pos(
            self.material.inclusion.stiffness_ratio,
            "material.inclusion.stiffness_ratio",
        )?;
        if self.probe.tip != "disk" && self.probe.tip != "sphere" {
            return Err(format!(
                "probe.tip must be \"disk\" or \"sphere\", got {:?}",
                self.probe.tip
            ));
        }
        pos(self.probe.radius_mm, "probe.radius_mm")?;
        pos(self.probe.thickness_mm, "probe.thickness_mm")?;
        pos(self.protocol.frame_rate_hz, "protocol.frame_rate_hz")?;
        if self.protocol.ramp_frames == 0 || self.protocol.release_frames == 0 {
            return Err("protocol.ramp_frames and protocol.release_frames must be ≥ 1".into());
        }
        if self.protocol.locations_mm.is_empty() && self.protocol.locations == 0 {
            return Err("protocol.locations must be ≥ 1".into());
        }
        let [d0, d1] = self.protocol.depth_mm;
        if !(d0 > 0.0 && d1 >= d0 && d1 < self.object.size_mm[2]) {
            return Err(format!(
                "protocol.depth_mm must satisfy 0 < min ≤ max < block height, got [{d0}, {d1}]"
            ));
        }
        if self.rig.cameras < 2 {
            return Err("rig.cameras must be ≥ 2".into());
        }
        pos(self.rig.focal_px, "rig.focal_px")?;
        pos(self.fsr.daq_rate_hz, "fsr.daq_rate_hz")?;
        pos(self.fsr.k_ohm, "fsr.k_ohm")?;
        if self.fsr.calibration_forces_n.len() < 2 {
            return Err("fsr.calibration_forces_n needs at least two forces".into());
        }
        self.validate_effects()?;
        if self.kind == "probe-robot" {
            self.robot.validate()?;
            if self.protocol.tilt_deg != 0.0 || self.has(Effect::SupportSlip) {
                return Err(
                    "kind \"probe-robot\": the 4-DOF arm probes vertically (protocol.tilt_deg = 0, no support-slip)"
                        .into(),
                );
            }
            if self.has(Effect::SensorLag) || self.has(Effect::ClockOffset) {
                return Err(
                    "kind \"probe-robot\": sensor-lag and clock-offset are FSR / trigger effects (robot sessions have neither)"
                        .into(),
                );
            }
        }
        if !(self.output.images || self.output.detections) {
            return Err("output: at least one of images / detections must be on".into());
        }
        if self.output.supersample == 0 {
            return Err("output.supersample must be ≥ 1".into());
        }
        for p in [
            self.output.dropout_probability,
            self.output.spurious_probability,
        ] {
            if !(0.0..=1.0).contains(&p) {
                return Err(format!("output probabilities must be in [0, 1], got {p}"));
            }
        }
        Ok(())
    }

    /// A dynamic scenario: the object, its material and the `[dynamic]` table (probe, protocol,
    /// FSR and effects do not apply).
    fn validate_dynamic(&self) -> std::result::Result<(), String> {
        if !self.effects.is_empty() {
            return Err("effects: a dynamic scenario takes no probing effects".into());
        }
        for (i, v) in self.object.size_mm.iter().enumerate() {
            if !(*v > 0.0 && v.is_finite()) {
                return Err(format!(
                    "object.size_mm[{i}] must be positive and finite, got {v}"
                ));
            }
        }
        for (name, c) in [
            ("object.fit_cells", self.object.fit_cells),
            ("object.truth_cells", self.object.truth_cells),
        ] {
            if c.contains(&0) {
                return Err(format!("{name} must be ≥ 1 in every direction"));
            }
        }
        if !(self.object.density_kg_m3 > 0.0 && self.object.density_kg_m3.is_finite()) {
            return Err("object.density_kg_m3 must be positive and finite".into());
        }
        if !(self.material.young_pa > 0.0 && self.material.young_pa.is_finite()) {
            return Err("material.young_pa must be positive and finite".into());
        }
        if !(self.material.poisson > -1.0 && self.material.poisson < 0.5) {
            return Err(format!(
                "material.poisson must be in (−1, 0.5), got {}",
                self.material.poisson
            ));
        }
        self.dynamic.validate()
    }

    /// Effect parameters and combinations the truth simulation can produce.
    fn validate_effects(&self) -> std::result::Result<(), String> {
        let es = &self.effect_settings;
        let non_negative = |v: f64, field: &str| {
            if v >= 0.0 && v.is_finite() {
                Ok(())
            } else {
                Err(format!(
                    "effect_settings.{field} must be ≥ 0 and finite, got {v}"
                ))
            }
        };
        let positive = |v: f64, field: &str| {
            if v > 0.0 && v.is_finite() {
                Ok(())
            } else {
                Err(format!(
                    "effect_settings.{field} must be positive and finite, got {v}"
                ))
            }
        };
        positive(es.sensor_lag_tau_s, "sensor_lag_tau_s")?;
        non_negative(es.sensor_hysteresis_fraction, "sensor_hysteresis_fraction")?;
        non_negative(es.clock_force_latency_s, "clock_force_latency_s")?;
        positive(es.gravity_young_pa, "gravity_young_pa")?;
        positive(es.anisotropy_fibre_ratio, "anisotropy_fibre_ratio")?;
        if es.anisotropy_fibre.iter().all(|v| *v == 0.0)
            || es.anisotropy_fibre.iter().any(|v| !v.is_finite())
        {
            return Err("effect_settings.anisotropy_fibre must be a finite non-zero vector".into());
        }
        non_negative(es.viscoelastic_g, "viscoelastic_g")?;
        positive(es.viscoelastic_tau_s, "viscoelastic_tau_s")?;
        positive(es.plastic_yield_pa, "plastic_yield_pa")?;
        non_negative(es.plastic_hardening_pa, "plastic_hardening_pa")?;
        non_negative(es.friction_mu, "friction_mu")?;
        positive(es.friction_slip_distance_mm, "friction_slip_distance_mm")?;
        non_negative(es.friction_path_ratio, "friction_path_ratio")?;
        positive(es.support_stiffness_n_per_m, "support_stiffness_n_per_m")?;
        if !(0.0..60.0).contains(&es.support_tilt_deg) {
            return Err(format!(
                "effect_settings.support_tilt_deg must be in [0, 60), got {}",
                es.support_tilt_deg
            ));
        }
        non_negative(es.rayleigh_alpha_per_s, "rayleigh_alpha_per_s")?;
        non_negative(es.rayleigh_beta_s, "rayleigh_beta_s")?;
        if es.dynamics_substeps == 0 {
            return Err("effect_settings.dynamics_substeps must be ≥ 1".into());
        }
        // One simulation engine per session: each of these groups changes how the truth is
        // time-stepped (history, nodal terms, inertia, body force) and they are not combined.
        let groups: [(&str, bool); 5] = [
            ("viscoelasticity", self.has(Effect::Viscoelasticity)),
            ("plasticity", self.has(Effect::Plasticity)),
            ("inertia-damping", self.has(Effect::InertiaDamping)),
            (
                "probe-friction / support-slip",
                self.has(Effect::ProbeFriction) || self.has(Effect::SupportSlip),
            ),
            ("gravity-preload", self.has(Effect::GravityPreload)),
        ];
        let on: Vec<&str> = groups.iter().filter(|g| g.1).map(|g| g.0).collect();
        if on.len() > 1 {
            return Err(format!(
                "effects: {} cannot be combined in one session (one of them per scenario)",
                on.join(" + ")
            ));
        }
        let material: Vec<&str> = [
            Effect::Anisotropy,
            Effect::StiffInclusion,
            Effect::StrainStiffening,
        ]
        .into_iter()
        .filter(|e| self.has(*e))
        .map(Effect::name)
        .collect();
        if self.has(Effect::Plasticity) && !material.is_empty() {
            return Err(format!(
                "effects: plasticity (J2 corotational truth) cannot be combined with {}",
                material.join(", ")
            ));
        }
        if self.has(Effect::Anisotropy)
            && (self.has(Effect::Viscoelasticity)
                || self.has(Effect::StiffInclusion)
                || self.has(Effect::StrainStiffening))
        {
            return Err(
                "effects: anisotropy replaces the neo-Hookean truth and cannot be combined with viscoelasticity, stiff-inclusion or strain-stiffening"
                    .into(),
            );
        }
        Ok(())
    }
}

/// "line L, field `table.key`: message" for a TOML (syntax or schema) error.
fn describe_toml_error(text: &str, e: &toml::de::Error) -> String {
    let message = e.message().trim().replace('\n', " ");
    let Some(span) = e.span() else {
        return message;
    };
    let start = span.start.min(text.len());
    let line_no = text[..start].matches('\n').count() + 1;
    let lines: Vec<&str> = text.lines().collect();
    let mut table = String::new();
    let mut key = None;
    for (i, l) in lines.iter().enumerate().take(line_no).rev() {
        let l = l.trim();
        if key.is_none() && l.contains('=') && !l.starts_with('[') && !l.starts_with('#') {
            key = l
                .split('=')
                .next()
                .map(|k| k.trim().trim_matches('"').to_string());
        }
        if l.starts_with('[') {
            table = l.trim_matches(|c| c == '[' || c == ']').trim().to_string();
            break;
        }
        if i == 0 {
            break;
        }
    }
    let field = match key {
        Some(k) if table.is_empty() => Some(k),
        Some(k) => Some(format!("{table}.{k}")),
        None if table.is_empty() => None,
        None => Some(table),
    };
    match field {
        Some(f) => format!("line {line_no}, field `{f}`: {message}"),
        None => format!("line {line_no}: {message}"),
    }
}
