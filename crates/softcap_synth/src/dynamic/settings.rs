//! The `[dynamic]` table of a `kind = "dynamic"` scenario: the motion, the truth's time stepping
//! and damping, the depth cameras and their noise. The object's box, meshes, material and density
//! come from the scenario's `[object]` and `[material]` tables (lengths in mm, as everywhere in a
//! scenario file).

use serde::{Deserialize, Serialize};

/// What sets the object in motion.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Motion {
    /// A bar or leaf clamped at its x = 0 end sags under gravity (frame 0), a hand pushes a patch
    /// near its free end (an interaction interval) and lets go: free vibration.
    Release,
    /// A block held above a floor (frame 0, at rest) is let go, falls, lands on an edge and rocks
    /// and jiggles; the floor contact is an interaction (the tracker is not told about the floor).
    Drop,
    /// A cantilever clamped at x = 0 is shaken by its clamp (`support_motion.csv`): a Hann-windowed
    /// sine translation plus a small rotation about the clamp centre, then free ringing.
    Shake,
}

/// A depth camera of the rig: placed on a sphere around the aim point.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DepthCameraSettings {
    /// Azimuth of the camera around the aim point, degrees (0 = on the +x side, 90 = +y).
    pub azimuth_deg: f64,
    /// Elevation above the horizontal plane through the aim point, degrees.
    pub elevation_deg: f64,
    /// Distance from the aim point, mm.
    pub distance_mm: f64,
}

impl Default for DepthCameraSettings {
    fn default() -> Self {
        Self {
            azimuth_deg: -90.0,
            elevation_deg: 35.0,
            distance_mm: 800.0,
        }
    }
}

/// Depth sensor model (a structured-light sensor such as the Kinect v1 that wang2015 used).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DepthSensorSettings {
    /// Image width, px.
    pub width: u32,
    /// Image height, px.
    pub height: u32,
    /// Focal length, px (fx = fy).
    pub focal_px: f64,
    /// Brown–Conrady distortion (k1, k2, p1, p2, k3).
    pub distortion: [f64; 5],
    /// Axial noise σ_z = `sigma_z_per_m` · z² (z in m; Khoshelham & Elberink 2012: 1.425e-3).
    pub sigma_z_per_m: f64,
    /// Disparity quantisation step, px (Kinect v1: 1/8 px).
    pub disparity_step_px: f64,
    /// Projector–camera baseline of the disparity model, mm.
    pub baseline_mm: f64,
    /// Beyond this angle between the viewing ray and the surface normal there is no reading
    /// (grazing holes), degrees.
    pub grazing_deg: f64,
    /// Independent per-pixel dropout probability.
    pub dropout_probability: f64,
    /// Probability that a silhouette pixel reads a "flying pixel" 1–5 cm behind the surface.
    pub edge_outlier_probability: f64,
    /// One count of the 16-bit image, mm.
    pub depth_scale_mm: f64,
    /// Readings outside [min, max] are invalid, mm.
    pub min_depth_mm: f64,
    /// See `min_depth_mm`.
    pub max_depth_mm: f64,
}

impl Default for DepthSensorSettings {
    fn default() -> Self {
        Self {
            width: 640,
            height: 480,
            focal_px: 580.0,
            distortion: [0.02, -0.05, 0.0005, -0.0003, 0.0],
            sigma_z_per_m: 1.425e-3,
            disparity_step_px: 0.125,
            baseline_mm: 75.0,
            grazing_deg: 80.0,
            dropout_probability: 0.01,
            edge_outlier_probability: 0.3,
            depth_scale_mm: 0.1,
            min_depth_mm: 300.0,
            max_depth_mm: 3000.0,
        }
    }
}

/// The `[dynamic]` table.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DynamicSettings {
    /// What sets the object in motion.
    pub motion: Motion,
    /// Camera frames written (frame 0 included).
    pub frames: usize,
    /// Camera frame rate, Hz.
    pub frame_rate_hz: f64,
    /// Implicit time steps of the truth per camera frame.
    pub substeps: usize,
    /// Rayleigh damping D = α M + β K: α, 1/s.
    pub rayleigh_alpha_per_s: f64,
    /// Rayleigh β, s.
    pub rayleigh_beta_s: f64,
    /// Gravity, m/s², world frame.
    pub gravity_m_s2: [f64; 3],
    /// Release: frames at rest before the push.
    pub rest_frames: usize,
    /// Release: frames over which the hand force ramps up (smoothstep); it is let go at once
    /// after them.
    pub push_frames: usize,
    /// Release: total hand force at full push, N (spread over the boundary nodes within
    /// `push_radius_mm` of the push point).
    pub push_force_n: [f64; 3],
    /// Release: push point in the object's rest frame, mm (default: centre of the top edge of the
    /// free end).
    pub push_at_mm: Option<[f64; 3]>,
    /// Release: radius of the pushed patch, mm.
    pub push_radius_mm: f64,
    /// Drop: height of the block's lowest corner above the floor at frame 0, mm.
    pub drop_height_mm: f64,
    /// Drop: tilt of the block about the x axis at frame 0, degrees (it lands on an edge).
    pub drop_tilt_deg: f64,
    /// Drop: floor penalty relative to a node's diagonal stiffness.
    pub floor_penalty_factor: f64,
    /// Shake: amplitude of the clamp translation, mm.
    pub shake_amplitude_mm: [f64; 3],
    /// Shake: amplitude of the clamp rotation vector (about the clamp centre), degrees.
    pub shake_rotation_deg: [f64; 3],
    /// Shake: frequency, Hz.
    pub shake_frequency_hz: f64,
    /// Shake: frames over which the clamp moves (Hann window), starting at frame 1.
    pub shake_frames: usize,
    /// The depth cameras.
    pub cameras: Vec<DepthCameraSettings>,
    /// The depth sensor (the same model for every camera).
    pub sensor: DepthSensorSettings,
    /// Material points on the surface followed in `truth/track_points.csv`.
    pub track_points: usize,
    /// A folder holding a third-party truth (`truth.toml` + `truth.npz`, see
    /// `fixtures/dynamic/README.md`) rendered instead of softcap's own simulation; relative to
    /// the scenario file.
    pub external_truth: Option<String>,
}

impl Default for DynamicSettings {
    fn default() -> Self {
        Self {
            motion: Motion::Release,
            frames: 60,
            frame_rate_hz: 30.0,
            substeps: 8,
            rayleigh_alpha_per_s: 0.8,
            rayleigh_beta_s: 1.0e-3,
            gravity_m_s2: [0.0, 0.0, -9.81],
            rest_frames: 2,
            push_frames: 8,
            push_force_n: [0.0, 0.6, -0.8],
            push_at_mm: None,
            push_radius_mm: 20.0,
            drop_height_mm: 40.0,
            drop_tilt_deg: 12.0,
            floor_penalty_factor: 1.0e3,
            shake_amplitude_mm: [0.0, 10.0, 15.0],
            shake_rotation_deg: [0.0, 3.0, 0.0],
            shake_frequency_hz: 2.5,
            shake_frames: 24,
            cameras: vec![
                DepthCameraSettings {
                    azimuth_deg: -70.0,
                    ..Default::default()
                },
                DepthCameraSettings {
                    azimuth_deg: 110.0,
                    elevation_deg: 30.0,
                    distance_mm: 850.0,
                },
            ],
            sensor: DepthSensorSettings::default(),
            track_points: 400,
            external_truth: None,
        }
    }
}

impl DynamicSettings {
    /// Checks ranges; the message names the field.
    pub fn validate(&self) -> Result<(), String> {
        let pos = |v: f64, field: &str| {
            if v > 0.0 && v.is_finite() {
                Ok(())
            } else {
                Err(format!(
                    "dynamic.{field} must be positive and finite, got {v}"
                ))
            }
        };
        let non_negative = |v: f64, field: &str| {
            if v >= 0.0 && v.is_finite() {
                Ok(())
            } else {
                Err(format!("dynamic.{field} must be ≥ 0 and finite, got {v}"))
            }
        };
        let finite = |v: &[f64], field: &str| {
            if v.iter().all(|x| x.is_finite()) {
                Ok(())
            } else {
                Err(format!("dynamic.{field} must be finite"))
            }
        };
        if self.frames < 2 {
            return Err(format!("dynamic.frames must be ≥ 2, got {}", self.frames));
        }
        if self.substeps == 0 {
            return Err("dynamic.substeps must be ≥ 1".into());
        }
        pos(self.frame_rate_hz, "frame_rate_hz")?;
        non_negative(self.rayleigh_alpha_per_s, "rayleigh_alpha_per_s")?;
        non_negative(self.rayleigh_beta_s, "rayleigh_beta_s")?;
        finite(&self.gravity_m_s2, "gravity_m_s2")?;
        finite(&self.push_force_n, "push_force_n")?;
        if let Some(p) = &self.push_at_mm {
            finite(p, "push_at_mm")?;
        }
        pos(self.push_radius_mm, "push_radius_mm")?;
        if self.motion == Motion::Release && self.rest_frames + self.push_frames + 1 >= self.frames
        {
            return Err(format!(
                "dynamic.frames ({}) must exceed rest_frames + push_frames + 1 ({})",
                self.frames,
                self.rest_frames + self.push_frames + 1
            ));
        }
        non_negative(self.drop_height_mm, "drop_height_mm")?;
        if self.drop_tilt_deg.abs() >= 60.0 || self.drop_tilt_deg.is_nan() {
            return Err(format!(
                "dynamic.drop_tilt_deg must be in (−60, 60), got {}",
                self.drop_tilt_deg
            ));
        }
        pos(self.floor_penalty_factor, "floor_penalty_factor")?;
        finite(&self.shake_amplitude_mm, "shake_amplitude_mm")?;
        finite(&self.shake_rotation_deg, "shake_rotation_deg")?;
        pos(self.shake_frequency_hz, "shake_frequency_hz")?;
        if self.cameras.is_empty() {
            return Err("dynamic.cameras: at least one [[dynamic.cameras]] is needed".into());
        }
        for (k, c) in self.cameras.iter().enumerate() {
            pos(c.distance_mm, &format!("cameras[{k}].distance_mm"))?;
            if !(c.elevation_deg.abs() < 89.0 && c.azimuth_deg.is_finite()) {
                return Err(format!(
                    "dynamic.cameras[{k}]: elevation_deg must be in (−89, 89) and azimuth_deg finite"
                ));
            }
        }
        let s = &self.sensor;
        if s.width < 8 || s.height < 8 {
            return Err("dynamic.sensor: width and height must be ≥ 8 px".into());
        }
        pos(s.focal_px, "sensor.focal_px")?;
        finite(&s.distortion, "sensor.distortion")?;
        non_negative(s.sigma_z_per_m, "sensor.sigma_z_per_m")?;
        non_negative(s.disparity_step_px, "sensor.disparity_step_px")?;
        pos(s.baseline_mm, "sensor.baseline_mm")?;
        if !(s.grazing_deg > 0.0 && s.grazing_deg <= 90.0) {
            return Err(format!(
                "dynamic.sensor.grazing_deg must be in (0, 90], got {}",
                s.grazing_deg
            ));
        }
        for (p, field) in [
            (s.dropout_probability, "sensor.dropout_probability"),
            (
                s.edge_outlier_probability,
                "sensor.edge_outlier_probability",
            ),
        ] {
            if !(0.0..=1.0).contains(&p) {
                return Err(format!("dynamic.{field} must be in [0, 1], got {p}"));
            }
        }
        pos(s.depth_scale_mm, "sensor.depth_scale_mm")?;
        pos(s.min_depth_mm, "sensor.min_depth_mm")?;
        if !(s.max_depth_mm > s.min_depth_mm && s.max_depth_mm / s.depth_scale_mm < 65535.0) {
            return Err(format!(
                "dynamic.sensor.max_depth_mm must exceed min_depth_mm and fit 16 bits at depth_scale_mm ({} / {})",
                s.max_depth_mm, s.depth_scale_mm
            ));
        }
        if self.track_points == 0 {
            return Err("dynamic.track_points must be ≥ 1".into());
        }
        Ok(())
    }
}
