//! Robot probing rigs (session kind `probe-robot`, thesis §6.3): the tool pose by forward
//! kinematics of the URDF chain (parsed with `urdf-rs`) and the 6-axis force/torque reading
//! rotated from `ft_link` into the world frame.
//!
//! Conventions: the URDF root link's frame is the world frame (a fixed joint places the robot
//! base); URDF lengths are metres (URDF standard); `robot.csv` joint values are radians or
//! `length_unit` (prismatic), forces N and torques N·m, expressed in `ft_link`, with the force
//! being the one the probe exerts on the object. The tool link's origin is the probe tip and its
//! +z axis points along the shaft toward the tip (the pushing direction).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use nalgebra::{Isometry3, Point3, Translation3, Unit, UnitQuaternion, Vector3};

use crate::error::{CaptureError, Result};
use crate::session::CsvTable;
use crate::sync::interpolate;

/// Motion of one joint of a chain.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum JointMotion {
    /// No motion.
    Fixed,
    /// Rotation about the unit axis (joint frame) by q rad (`revolute` and `continuous`).
    Revolute(Unit<Vector3<f64>>),
    /// Translation along the unit axis (joint frame) by q m.
    Prismatic(Unit<Vector3<f64>>),
}

/// One joint of a kinematic chain: `parent_from_child(q) = origin · motion(q)` (URDF joint
/// semantics: `origin` xyz + rpy = Rz(yaw)·Ry(pitch)·Rx(roll), then the motion about/along `axis`).
#[derive(Debug, Clone, PartialEq)]
pub struct ChainJoint {
    /// Joint name.
    pub name: String,
    /// `parent_link_from_joint` at q = 0.
    pub origin: Isometry3<f64>,
    /// Motion.
    pub motion: JointMotion,
}

impl ChainJoint {
    /// `parent_from_child` at joint value `q`.
    pub fn transform(&self, q: f64) -> Isometry3<f64> {
        match self.motion {
            JointMotion::Fixed => self.origin,
            JointMotion::Revolute(axis) => {
                self.origin
                    * Isometry3::from_parts(
                        Translation3::identity(),
                        UnitQuaternion::from_axis_angle(&axis, q),
                    )
            }
            JointMotion::Prismatic(axis) => {
                self.origin
                    * Isometry3::from_parts(
                        Translation3::from(axis.into_inner() * q),
                        UnitQuaternion::identity(),
                    )
            }
        }
    }
}

/// The joints from the root link to one link, in order.
#[derive(Debug, Clone, PartialEq)]
pub struct KinematicChain {
    /// Root link name.
    pub root: String,
    /// Target link name.
    pub link: String,
    /// Joints root → link.
    pub joints: Vec<ChainJoint>,
}

impl KinematicChain {
    /// `root_from_link` with joint values looked up by joint name (fixed joints need none).
    /// `None` when a movable joint's value is missing.
    pub fn forward(&self, q: &BTreeMap<String, f64>) -> Option<Isometry3<f64>> {
        let mut t = Isometry3::identity();
        for j in &self.joints {
            let v = match j.motion {
                JointMotion::Fixed => 0.0,
                _ => *q.get(&j.name)?,
            };
            t *= j.transform(v);
        }
        Some(t)
    }

    /// Names of the movable joints, root → link.
    pub fn movable_joints(&self) -> Vec<&str> {
        self.joints
            .iter()
            .filter(|j| j.motion != JointMotion::Fixed)
            .map(|j| j.name.as_str())
            .collect()
    }
}

/// A robot read from a URDF file: the joint tree.
#[derive(Debug, Clone)]
pub struct RobotModel {
    /// The URDF file.
    pub path: PathBuf,
    /// Root link (the one that is no joint's child).
    pub root: String,
    /// Joint into each child link: `child → (parent, joint)`.
    parent_joint: BTreeMap<String, (String, ChainJoint)>,
}

fn pose(p: &urdf_rs::Pose) -> Isometry3<f64> {
    let [x, y, z] = p.xyz.0;
    let [roll, pitch, yaw] = p.rpy.0;
    Isometry3::from_parts(
        Translation3::new(x, y, z),
        UnitQuaternion::from_euler_angles(roll, pitch, yaw),
    )
}

impl RobotModel {
    /// Parses a URDF file. Floating, planar and spherical joints are rejected (a probing arm's
    /// chain is revolute/prismatic/fixed); so are a missing root or a link with two parents.
    pub fn from_urdf(path: &Path) -> Result<Self> {
        let text = crate::session::read_text(path)?;
        Self::from_urdf_str(path, &text)
    }

    /// Parses URDF text (`path` names the file in errors).
    pub fn from_urdf_str(path: &Path, text: &str) -> Result<Self> {
        let format = |message: String| CaptureError::Format {
            path: path.to_path_buf(),
            message,
        };
        let robot =
            urdf_rs::read_from_string(text).map_err(|e| format(format!("invalid URDF: {e}")))?;
        let mut parent_joint = BTreeMap::new();
        for j in &robot.joints {
            let axis = || {
                Unit::try_new(Vector3::from(j.axis.xyz.0), 1e-12)
                    .ok_or_else(|| format(format!("joint `{}`: zero axis", j.name)))
            };
            let motion = match j.joint_type {
                urdf_rs::JointType::Fixed => JointMotion::Fixed,
                urdf_rs::JointType::Revolute | urdf_rs::JointType::Continuous => {
                    JointMotion::Revolute(axis()?)
                }
                urdf_rs::JointType::Prismatic => JointMotion::Prismatic(axis()?),
                ref other => {
                    return Err(format(format!(
                        "joint `{}`: type {} is not supported (fixed, revolute, continuous, prismatic)",
                        j.name,
                        format!("{other:?}").to_lowercase()
                    )));
                }
            };
            let joint = ChainJoint {
                name: j.name.clone(),
                origin: pose(&j.origin),
                motion,
            };
            if parent_joint
                .insert(j.child.link.clone(), (j.parent.link.clone(), joint))
                .is_some()
            {
                return Err(format(format!(
                    "link `{}` has two parent joints",
                    j.child.link
                )));
            }
        }
        let roots: Vec<&str> = robot
            .links
            .iter()
            .map(|l| l.name.as_str())
            .filter(|l| !parent_joint.contains_key(*l))
            .collect();
        if roots.len() != 1 {
            return Err(format(format!("expected one root link, found {roots:?}")));
        }
        Ok(RobotModel {
            path: path.to_path_buf(),
            root: roots[0].to_string(),
            parent_joint,
        })
    }

    /// The chain root → `link`.
    pub fn chain(&self, link: &str) -> Result<KinematicChain> {
        let mut joints = Vec::new();
        let mut at = link.to_string();
        while at != self.root {
            let (parent, joint) =
                self.parent_joint
                    .get(&at)
                    .ok_or_else(|| CaptureError::Format {
                        path: self.path.clone(),
                        message: format!("no link `{link}` in the URDF"),
                    })?;
            joints.push(joint.clone());
            at = parent.clone();
            if joints.len() > self.parent_joint.len() {
                return Err(CaptureError::Format {
                    path: self.path.clone(),
                    message: "joint loop".into(),
                });
            }
        }
        joints.reverse();
        Ok(KinematicChain {
            root: self.root.clone(),
            link: link.to_string(),
            joints,
        })
    }
}

/// `robot.csv`: joint values and F/T readings on the DAQ clock.
#[derive(Debug, Clone, PartialEq)]
pub struct RobotSamples {
    /// Sample times, DAQ clock, s.
    pub t_daq_s: Vec<f64>,
    /// Joint values per joint name (rad, or m for prismatic joints after unit conversion).
    pub joints: BTreeMap<String, Vec<f64>>,
    /// Force in `ft_link`, N, per sample.
    pub force_n: Vec<Vector3<f64>>,
    /// Torque in `ft_link`, N·m, per sample.
    pub torque_nm: Vec<Vector3<f64>>,
}

/// Reads `robot.csv` with the columns `t_daq_s`, one per movable joint of `chains` (by name),
/// and `fx,fy,fz,tx,ty,tz`. Prismatic joint values are multiplied by `metres_per_unit`.
pub fn read_robot_csv(
    path: &Path,
    chains: &[&KinematicChain],
    metres_per_unit: f64,
) -> Result<RobotSamples> {
    let t = CsvTable::read(path)?;
    let ct = t.require("t_daq_s")?;
    let mut joint_cols: BTreeMap<String, (usize, f64)> = BTreeMap::new();
    for chain in chains {
        for j in &chain.joints {
            let scale = match j.motion {
                JointMotion::Fixed => continue,
                JointMotion::Revolute(_) => 1.0,
                JointMotion::Prismatic(_) => metres_per_unit,
            };
            joint_cols.insert(j.name.clone(), (t.require(&j.name)?, scale));
        }
    }
    let ft: Vec<usize> = ["fx", "fy", "fz", "tx", "ty", "tz"]
        .iter()
        .map(|c| t.require(c))
        .collect::<Result<_>>()?;
    let mut s = RobotSamples {
        t_daq_s: Vec::with_capacity(t.rows.len()),
        joints: joint_cols.keys().map(|k| (k.clone(), Vec::new())).collect(),
        force_n: Vec::new(),
        torque_nm: Vec::new(),
    };
    for row in &t.rows {
        let time = t.f64_at(row, ct, "t_daq_s")?;
        if s.t_daq_s.last().is_some_and(|&p| time <= p) {
            return Err(CaptureError::field(
                path,
                row.0,
                "t_daq_s",
                "sample times must increase",
            ));
        }
        s.t_daq_s.push(time);
        for (name, &(c, scale)) in &joint_cols {
            let v = t.f64_at(row, c, name)? * scale;
            if let Some(col) = s.joints.get_mut(name) {
                col.push(v);
            }
        }
        let names = ["fx", "fy", "fz", "tx", "ty", "tz"];
        let mut v = [0.0; 6];
        for i in 0..6 {
            v[i] = t.f64_at(row, ft[i], names[i])?;
        }
        s.force_n.push(Vector3::new(v[0], v[1], v[2]));
        s.torque_nm.push(Vector3::new(v[3], v[4], v[5]));
    }
    if s.t_daq_s.len() < 2 {
        return Err(CaptureError::field(
            path,
            2,
            "t_daq_s",
            "need at least two samples",
        ));
    }
    Ok(s)
}

/// The probe of a robot rig at one DAQ time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RobotProbeState {
    /// `world_from_tool`.
    pub world_from_tool: Isometry3<f64>,
    /// Tip (tool origin), world, m.
    pub tip_m: Point3<f64>,
    /// Pushing direction (tool +z), world.
    pub axis: Vector3<f64>,
    /// Force exerted by the probe on the object, world frame, N.
    pub force_n: Vector3<f64>,
    /// Torque about the F/T sensor origin, world frame, N·m.
    pub torque_nm: Vector3<f64>,
}

/// A robot rig: the tool and F/T chains and the samples.
#[derive(Debug, Clone)]
pub struct RobotRig {
    /// Chain root → tool link.
    pub tool: KinematicChain,
    /// Chain root → F/T sensor link.
    pub ft: KinematicChain,
    /// `robot.csv`.
    pub samples: RobotSamples,
}

impl RobotRig {
    /// Loads the URDF, builds both chains and reads `robot.csv`.
    pub fn load(
        urdf: &Path,
        samples: &Path,
        tool_link: &str,
        ft_link: &str,
        metres_per_unit: f64,
    ) -> Result<Self> {
        let model = RobotModel::from_urdf(urdf)?;
        let tool = model.chain(tool_link)?;
        let ft = model.chain(ft_link)?;
        let samples = read_robot_csv(samples, &[&tool, &ft], metres_per_unit)?;
        Ok(RobotRig { tool, ft, samples })
    }

    /// Joint values at a DAQ time (linear interpolation, clamped at the ends).
    pub fn joints_at(&self, t_daq_s: f64) -> BTreeMap<String, f64> {
        self.samples
            .joints
            .iter()
            .map(|(k, v)| (k.clone(), interpolate(&self.samples.t_daq_s, v, t_daq_s)))
            .collect()
    }

    /// Tool pose by forward kinematics and F/T rotated into the world at a DAQ time:
    /// `f_world = R_world_ft · f_ft`, `τ_world = R_world_ft · τ_ft`.
    pub fn state_at(&self, t_daq_s: f64) -> Option<RobotProbeState> {
        let q = self.joints_at(t_daq_s);
        let world_from_tool = self.tool.forward(&q)?;
        let world_from_ft = self.ft.forward(&q)?;
        let s = &self.samples;
        let lerp = |v: &[Vector3<f64>]| {
            let c = |i: usize| v.iter().map(|x| x[i]).collect::<Vec<f64>>();
            Vector3::new(
                interpolate(&s.t_daq_s, &c(0), t_daq_s),
                interpolate(&s.t_daq_s, &c(1), t_daq_s),
                interpolate(&s.t_daq_s, &c(2), t_daq_s),
            )
        };
        Some(RobotProbeState {
            world_from_tool,
            tip_m: Point3::from(world_from_tool.translation.vector),
            axis: world_from_tool.rotation * Vector3::z(),
            force_n: world_from_ft.rotation * lerp(&s.force_n),
            torque_nm: world_from_ft.rotation * lerp(&s.torque_nm),
        })
    }
}
