//! Robot-arm probing (session kind `probe-robot`, bickel2010 thesis §6.3): a 4-DOF arm (base yaw,
//! shoulder, elbow and wrist pitch) carries a 6-axis force/torque sensor and the probe. The rig
//! writes the arm as URDF (`rig/robot.urdf`), the joint log and F/T readings on the DAQ clock
//! (`robot.csv`), following the conventions softcap_capture's `robot` module reads:
//!
//! - the URDF root link (`world`) is the world frame, lengths in metres; a fixed joint places the
//!   arm's base;
//! - link `probe_tip`: origin at the probe tip, +z the pushing direction;
//! - link `ft_sensor`: the sensor frame, mounted on the wrist with an arbitrary fixed rotation;
//! - `robot.csv`: `t_daq_s,yaw,shoulder,elbow,wrist,fx,fy,fz,tx,ty,tz`, joints in rad, force N =
//!   force exerted BY the probe ON the object expressed in `ft_sensor`, torque N·m about the sensor
//!   origin (τ = (tip − sensor origin) × f), both with Gaussian noise.
//!
//! Joint values come from closed-form inverse kinematics of the probe pose (yaw from the wrist
//! position, planar two-link shoulder/elbow with the elbow up, wrist pitch closing the tool angle);
//! forward kinematics uses the URDF joint semantics (origin = translation · Rz(yaw) Ry(pitch)
//! Rx(roll), then the joint motion), so FK(IK(pose)) reproduces the tip and axis to round-off.

use std::fmt::Write as _;

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};

use crate::scenario::Scenario;
use crate::truth::FrameTruth;

const MM: f64 = 1e-3;

/// The arm and its sensors (scenario `[robot]`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RobotSettings {
    /// Base position in the world (beside the block), mm.
    pub base_mm: [f64; 3],
    /// Height of the shoulder (yaw/pitch axes) above the base, mm.
    pub shoulder_height_mm: f64,
    /// Upper arm (shoulder → elbow), mm.
    pub upper_arm_mm: f64,
    /// Forearm (elbow → wrist), mm.
    pub forearm_mm: f64,
    /// Wrist axis → probe tip along the tool axis, mm.
    pub tool_mm: f64,
    /// Wrist axis → F/T sensor origin along the tool axis, mm.
    pub ft_offset_mm: f64,
    /// Fixed mounting rotation of the F/T sensor (URDF rpy, rad) relative to the wrist link.
    pub ft_rpy: [f64; 3],
    /// Sample rate of robot.csv, Hz (DAQ clock).
    pub rate_hz: f64,
    /// F/T force noise, N rms per axis.
    pub force_noise_n: f64,
    /// F/T torque noise, N·m rms per axis.
    pub torque_noise_nm: f64,
    /// Joint encoder noise, rad rms.
    pub joint_noise_rad: f64,
}

impl Default for RobotSettings {
    fn default() -> Self {
        Self {
            base_mm: [-200.0, 20.0, 0.0],
            shoulder_height_mm: 150.0,
            upper_arm_mm: 200.0,
            forearm_mm: 200.0,
            tool_mm: 130.0,
            ft_offset_mm: 30.0,
            ft_rpy: [0.3, 1.2, -0.4],
            rate_hz: 200.0,
            force_noise_n: 0.003,
            torque_noise_nm: 1.0e-4,
            joint_noise_rad: 2.0e-6,
        }
    }
}

impl RobotSettings {
    /// Checks lengths and rates; the message names the field.
    pub fn validate(&self) -> Result<(), String> {
        for (v, f) in [
            (self.shoulder_height_mm, "robot.shoulder_height_mm"),
            (self.upper_arm_mm, "robot.upper_arm_mm"),
            (self.forearm_mm, "robot.forearm_mm"),
            (self.tool_mm, "robot.tool_mm"),
            (self.rate_hz, "robot.rate_hz"),
        ] {
            if !(v > 0.0 && v.is_finite()) {
                return Err(format!("{f} must be positive and finite, got {v}"));
            }
        }
        for (v, f) in [
            (self.force_noise_n, "robot.force_noise_n"),
            (self.torque_noise_nm, "robot.torque_noise_nm"),
            (self.joint_noise_rad, "robot.joint_noise_rad"),
        ] {
            if !(v >= 0.0 && v.is_finite()) {
                return Err(format!("{f} must be ≥ 0 and finite, got {v}"));
            }
        }
        if self
            .base_mm
            .iter()
            .chain(&self.ft_rpy)
            .any(|v| !v.is_finite())
        {
            return Err("robot.base_mm and robot.ft_rpy must be finite".into());
        }
        Ok(())
    }
}

/// Movable joint names, root → tool.
pub const JOINTS: [&str; 4] = ["yaw", "shoulder", "elbow", "wrist"];

/// The 4-DOF arm in metres.
#[derive(Clone, Debug, PartialEq)]
pub struct Arm {
    base_m: Vector3<f64>,
    shoulder_height_m: f64,
    upper_m: f64,
    fore_m: f64,
    tool_m: f64,
    ft_offset_m: f64,
    ft_rpy: [f64; 3],
}

/// URDF joint origin: translation · Rz(yaw) Ry(pitch) Rx(roll).
fn origin(xyz: [f64; 3], rpy: [f64; 3]) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(xyz[0], xyz[1], xyz[2]),
        UnitQuaternion::from_euler_angles(rpy[0], rpy[1], rpy[2]),
    )
}

fn rot(axis: Vector3<f64>, q: f64) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::identity(),
        UnitQuaternion::from_axis_angle(&nalgebra::Unit::new_normalize(axis), q),
    )
}

impl Arm {
    /// From the scenario settings.
    pub fn new(r: &RobotSettings) -> Self {
        Self {
            base_m: Vector3::from(r.base_mm) * MM,
            shoulder_height_m: r.shoulder_height_mm * MM,
            upper_m: r.upper_arm_mm * MM,
            fore_m: r.forearm_mm * MM,
            tool_m: r.tool_mm * MM,
            ft_offset_m: r.ft_offset_mm * MM,
            ft_rpy: r.ft_rpy,
        }
    }

    /// `world_from_wrist` (wrist link frame: +x along the tool axis) for joints q.
    fn wrist(&self, q: &[f64; 4]) -> Isometry3<f64> {
        let y = Vector3::y();
        origin(self.base_m.into(), [0.0; 3])
            * origin([0.0, 0.0, self.shoulder_height_m], [0.0; 3])
            * rot(Vector3::z(), q[0])
            * rot(y, q[1])
            * origin([self.upper_m, 0.0, 0.0], [0.0; 3])
            * rot(y, q[2])
            * origin([self.fore_m, 0.0, 0.0], [0.0; 3])
            * rot(y, q[3])
    }

    /// `world_from_tool` (origin at the tip, +z the pushing direction).
    pub fn tool(&self, q: &[f64; 4]) -> Isometry3<f64> {
        self.wrist(q)
            * origin(
                [self.tool_m, 0.0, 0.0],
                [0.0, std::f64::consts::FRAC_PI_2, 0.0],
            )
    }

    /// `world_from_ft` (the F/T sensor frame).
    pub fn ft(&self, q: &[f64; 4]) -> Isometry3<f64> {
        self.wrist(q) * origin([self.ft_offset_m, 0.0, 0.0], self.ft_rpy)
    }

    /// Joint values putting the tip at `tip_m` with the tool axis along `axis` (which must lie
    /// in the vertical plane through the base's yaw axis and the wrist: a vertical axis always
    /// does). `None` when out of reach.
    pub fn inverse(&self, tip_m: &Vector3<f64>, axis: &Vector3<f64>) -> Option<[f64; 4]> {
        let a = axis.normalize();
        let w = tip_m - a * self.tool_m;
        let o = self.base_m + Vector3::new(0.0, 0.0, self.shoulder_height_m);
        let d = w - o;
        let yaw = d.y.atan2(d.x);
        let (r, down) = (d.xy().norm(), -d.z);
        let (l1, l2) = (self.upper_m, self.fore_m);
        let c = (r * r + down * down - l1 * l1 - l2 * l2) / (2.0 * l1 * l2);
        if !(-1.0..=1.0).contains(&c) {
            return None;
        }
        // Angles grow from the arm's horizontal x toward −z (Ry(q) x = (cos q, 0, −sin q)).
        let elbow = c.acos(); // elbow up: the upper arm rises above the shoulder–wrist line
        let shoulder = down.atan2(r) - (l2 * elbow.sin()).atan2(l1 + l2 * elbow.cos());
        let planar_axis = Vector3::new(yaw.cos(), yaw.sin(), 0.0).dot(&a);
        let tool_angle = (-a.z).atan2(planar_axis);
        Some([yaw, shoulder, elbow, tool_angle - shoulder - elbow])
    }

    /// The URDF text (metres, radians).
    pub fn urdf(&self) -> String {
        let mut t = String::from("<?xml version=\"1.0\"?>\n<robot name=\"softcap_synth_arm\">\n");
        for l in [
            "world",
            "base",
            "turret",
            "upper_arm",
            "forearm",
            "wrist_link",
            "ft_sensor",
            "probe_tip",
        ] {
            let _ = writeln!(t, "  <link name=\"{l}\"/>");
        }
        let joint = |t: &mut String,
                     name: &str,
                     kind: &str,
                     parent: &str,
                     child: &str,
                     xyz: [f64; 3],
                     rpy: [f64; 3],
                     axis: Option<[f64; 3]>| {
            let _ = writeln!(t, "  <joint name=\"{name}\" type=\"{kind}\">");
            let _ = writeln!(
                t,
                "    <parent link=\"{parent}\"/>\n    <child link=\"{child}\"/>"
            );
            let _ = writeln!(
                t,
                "    <origin xyz=\"{:.9} {:.9} {:.9}\" rpy=\"{:.12} {:.12} {:.12}\"/>",
                xyz[0], xyz[1], xyz[2], rpy[0], rpy[1], rpy[2]
            );
            if let Some(a) = axis {
                let _ = writeln!(t, "    <axis xyz=\"{} {} {}\"/>", a[0], a[1], a[2]);
                let _ = writeln!(
                    t,
                    "    <limit lower=\"-3.2\" upper=\"3.2\" effort=\"50\" velocity=\"2\"/>"
                );
            }
            let _ = writeln!(t, "  </joint>");
        };
        let b = self.base_m;
        joint(
            &mut t,
            "base_mount",
            "fixed",
            "world",
            "base",
            [b.x, b.y, b.z],
            [0.0; 3],
            None,
        );
        let z = Some([0.0, 0.0, 1.0]);
        let y = Some([0.0, 1.0, 0.0]);
        joint(
            &mut t,
            "yaw",
            "revolute",
            "base",
            "turret",
            [0.0, 0.0, self.shoulder_height_m],
            [0.0; 3],
            z,
        );
        joint(
            &mut t,
            "shoulder",
            "revolute",
            "turret",
            "upper_arm",
            [0.0; 3],
            [0.0; 3],
            y,
        );
        joint(
            &mut t,
            "elbow",
            "revolute",
            "upper_arm",
            "forearm",
            [self.upper_m, 0.0, 0.0],
            [0.0; 3],
            y,
        );
        joint(
            &mut t,
            "wrist",
            "revolute",
            "forearm",
            "wrist_link",
            [self.fore_m, 0.0, 0.0],
            [0.0; 3],
            y,
        );
        joint(
            &mut t,
            "ft_mount",
            "fixed",
            "wrist_link",
            "ft_sensor",
            [self.ft_offset_m, 0.0, 0.0],
            self.ft_rpy,
            None,
        );
        joint(
            &mut t,
            "tool_mount",
            "fixed",
            "wrist_link",
            "probe_tip",
            [self.tool_m, 0.0, 0.0],
            [0.0, std::f64::consts::FRAC_PI_2, 0.0],
            None,
        );
        t.push_str("</robot>\n");
        t
    }
}

/// The robot log on the DAQ clock.
#[derive(Clone, Debug, PartialEq)]
pub struct RobotRecord {
    /// Sample times, DAQ clock, s.
    pub t_daq_s: Vec<f64>,
    /// Joint values (yaw, shoulder, elbow, wrist), rad.
    pub joints_rad: Vec<[f64; 4]>,
    /// Force by the probe on the object in the F/T frame, N.
    pub force_ft_n: Vec<Vector3<f64>>,
    /// Torque about the F/T origin in the F/T frame, N·m.
    pub torque_ft_nm: Vec<Vector3<f64>>,
    /// Clock offset, s (t_daq = offset + (1 + drift) t_camera).
    pub offset_s: f64,
    /// Clock drift.
    pub drift: f64,
}

/// Probe tip, axis and force at camera time `t` (piecewise linear between frames).
fn probe_at(frames: &[FrameTruth], t: f64) -> (Vector3<f64>, Vector3<f64>, Vector3<f64>) {
    let at = |f: &FrameTruth| {
        (
            f.spec.world_from_probe.translation.vector,
            f.spec.world_from_probe.rotation * Vector3::z(),
            f.force_n,
        )
    };
    if t <= frames[0].spec.t_camera_s {
        return at(&frames[0]);
    }
    for w in frames.windows(2) {
        if t <= w[1].spec.t_camera_s {
            let s = (t - w[0].spec.t_camera_s) / (w[1].spec.t_camera_s - w[0].spec.t_camera_s);
            let (a, b) = (at(&w[0]), at(&w[1]));
            return (
                a.0.lerp(&b.0, s),
                a.1.lerp(&b.1, s).normalize(),
                a.2.lerp(&b.2, s),
            );
        }
    }
    at(&frames[frames.len() - 1])
}

/// Samples the arm's joints and the F/T sensor on the DAQ clock over the session.
pub fn record(
    s: &Scenario,
    arm: &Arm,
    frames: &[FrameTruth],
    rng: &mut ChaCha8Rng,
) -> Result<RobotRecord, String> {
    let r = &s.robot;
    let (offset_s, drift) = (s.clock.offset_s, s.clock.drift);
    let to_daq = |t_cam: f64| offset_s + (1.0 + drift) * t_cam;
    let to_cam = |t_daq: f64| (t_daq - offset_s) / (1.0 + drift);
    let dt = 1.0 / r.rate_hz;
    let margin = s.fsr.margin_s;
    let t0 = (to_daq(frames[0].spec.t_camera_s - margin) / dt).floor() * dt;
    let t1 = to_daq(frames[frames.len() - 1].spec.t_camera_s + margin);
    let n = ((t1 - t0) / dt).ceil() as usize + 1;
    let normal = |sigma: f64| Normal::new(0.0, sigma).expect("finite σ ≥ 0");
    let (nf, nt, nq) = (
        normal(r.force_noise_n),
        normal(r.torque_noise_nm),
        normal(r.joint_noise_rad),
    );
    let mut out = RobotRecord {
        t_daq_s: Vec::with_capacity(n),
        joints_rad: Vec::with_capacity(n),
        force_ft_n: Vec::with_capacity(n),
        torque_ft_nm: Vec::with_capacity(n),
        offset_s,
        drift,
    };
    for k in 0..n {
        let t_daq = t0 + k as f64 * dt;
        let (tip, axis, force) = probe_at(frames, to_cam(t_daq));
        let q = arm.inverse(&tip, &axis).ok_or_else(|| {
            format!(
                "robot: probe tip ({:.1}, {:.1}, {:.1}) mm is out of the arm's reach",
                tip.x / MM,
                tip.y / MM,
                tip.z / MM
            )
        })?;
        let ft = arm.ft(&q);
        let torque = (tip - ft.translation.vector).cross(&force);
        let rinv = ft.rotation.inverse();
        let noise3 = |d: &Normal<f64>, rng: &mut ChaCha8Rng| {
            Vector3::new(d.sample(rng), d.sample(rng), d.sample(rng))
        };
        out.t_daq_s.push(t_daq);
        out.joints_rad.push(q.map(|v| v + nq.sample(rng)));
        out.force_ft_n.push(rinv * force + noise3(&nf, rng));
        out.torque_ft_nm.push(rinv * torque + noise3(&nt, rng));
    }
    Ok(out)
}

/// robot.csv.
pub fn robot_csv(rec: &RobotRecord) -> String {
    let mut t = format!("t_daq_s,{},fx,fy,fz,tx,ty,tz\n", JOINTS.join(","));
    for k in 0..rec.t_daq_s.len() {
        let q = rec.joints_rad[k];
        let (f, m) = (rec.force_ft_n[k], rec.torque_ft_nm[k]);
        let _ = writeln!(
            t,
            "{:.5},{:.8},{:.8},{:.8},{:.8},{:.6},{:.6},{:.6},{:.7},{:.7},{:.7}",
            rec.t_daq_s[k], q[0], q[1], q[2], q[3], f.x, f.y, f.z, m.x, m.y, m.z
        );
    }
    t
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inverse_kinematics_reproduces_tip_and_axis() {
        let arm = Arm::new(&RobotSettings::default());
        let mut worst: f64 = 0.0;
        for (tip, axis) in [
            (Vector3::new(0.02, 0.02, 0.02), -Vector3::z()),
            (Vector3::new(0.031, 0.009, 0.014), -Vector3::z()),
            (Vector3::new(0.01, 0.035, 0.026), -Vector3::z()),
            (Vector3::new(0.03, 0.02, 0.02), Vector3::new(0.3, 0.0, -1.0)),
        ] {
            let q = arm.inverse(&tip, &axis).unwrap();
            let t = arm.tool(&q);
            let e_tip = (t.translation.vector - tip).norm();
            let e_axis = (t.rotation * Vector3::z() - axis.normalize()).norm();
            worst = worst.max(e_tip).max(e_axis);
        }
        assert!(worst < 1e-12, "{worst:e}");
        assert!(
            arm.inverse(&Vector3::new(2.0, 0.0, 0.0), &-Vector3::z())
                .is_none()
        );
    }
}
