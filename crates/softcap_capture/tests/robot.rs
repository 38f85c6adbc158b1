//! Robot rigs: forward kinematics of a hand-written URDF (fixtures/robot/arm.urdf) against its
//! analytic tool pose, and F/T readings rotated into the world frame.

use crate::common;

use std::collections::BTreeMap;

use softcap_capture::nalgebra::{Point3, Rotation3, Vector3};
use softcap_capture::robot::{RobotModel, RobotRig};

fn analytic(q1: f64, q2: f64, d: f64) -> (Point3<f64>, Vector3<f64>) {
    let rz = Rotation3::from_axis_angle(&Vector3::z_axis(), q1);
    let l = 0.25 + d;
    let tip =
        Point3::new(0.0, 0.0, 0.1) + rz * Vector3::new(0.3 + l * q2.cos(), 0.0, -l * q2.sin());
    (tip, rz * Vector3::new(q2.cos(), 0.0, -q2.sin()))
}

#[test]
fn forward_kinematics_matches_the_analytic_tool_pose() {
    let model = RobotModel::from_urdf(&common::fixture("robot/arm.urdf")).unwrap();
    assert_eq!(model.root, "world");
    let chain = model.chain("probe_tip").unwrap();
    assert_eq!(chain.movable_joints(), ["shoulder", "elbow", "slide"]);
    let mut worst: f64 = 0.0;
    for (i, &(q1, q2, d)) in [
        (0.0, 0.0, 0.0),
        (0.7, 0.4, 0.02),
        (-2.1, 1.3, 0.08),
        (3.0, -0.9, 0.05),
    ]
    .iter()
    .enumerate()
    {
        let q: BTreeMap<String, f64> = [("shoulder", q1), ("elbow", q2), ("slide", d)]
            .iter()
            .map(|(k, v)| (k.to_string(), *v))
            .collect();
        let t = chain.forward(&q).unwrap();
        let (tip, axis) = analytic(q1, q2, d);
        let e_tip = (Point3::from(t.translation.vector) - tip).norm();
        let e_axis = (t.rotation * Vector3::z() - axis).norm();
        println!("pose {i}: tip error {e_tip:.2e} m, axis error {e_axis:.2e}");
        worst = worst.max(e_tip).max(e_axis);
    }
    assert!(worst < 1e-12, "worst {worst}");
    let mut missing = BTreeMap::new();
    missing.insert("shoulder".to_string(), 0.1);
    assert!(
        chain.forward(&missing).is_none(),
        "a missing joint value is reported"
    );
}

#[test]
fn robot_csv_state_interpolates_joints_and_rotates_force_into_the_world() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("robot.csv");
    // Two samples 0.1 s apart; the probe presses along its own axis: in ft_sensor (= tool frame up
    // to the fixed rpy), the tool z is the sensor's +x, so a 2 N push along the tool axis reads
    // fx = 2. Prismatic `slide` in mm (length_unit mm).
    std::fs::write(
        &csv,
        "t_daq_s,shoulder,elbow,slide,fx,fy,fz,tx,ty,tz,extra\n\
         1.0,0.5,0.2,10.0,2.0,0.0,0.0,0.0,0.0,0.1,x\n\
         1.1,0.7,0.4,30.0,4.0,0.0,0.0,0.0,0.0,0.3,y\n",
    )
    .unwrap();
    let rig = RobotRig::load(
        &common::fixture("robot/arm.urdf"),
        &csv,
        "probe_tip",
        "ft_sensor",
        1e-3,
    )
    .unwrap();
    let s = rig.state_at(1.05).unwrap();
    let (tip, axis) = analytic(0.6, 0.3, 0.02);
    assert!((s.tip_m - tip).norm() < 1e-12, "{} vs {tip}", s.tip_m);
    assert!((s.axis - axis).norm() < 1e-12);
    // Interpolated reading (3, 0, 0) N in the sensor frame = 3 N along the tool axis in the world.
    assert!((s.force_n - axis * 3.0).norm() < 1e-12, "{}", s.force_n);
    // Torque (0, 0, 0.2) about the sensor z = the forearm's z, which is Rz(q1)·Ry(q2)·ẑ.
    let sensor_z = Rotation3::from_axis_angle(&Vector3::z_axis(), 0.6)
        * Rotation3::from_axis_angle(&Vector3::y_axis(), 0.3)
        * Vector3::z();
    assert!(
        (s.torque_nm - sensor_z * 0.2).norm() < 1e-12,
        "{}",
        s.torque_nm
    );
}

#[test]
fn bad_urdf_and_unknown_link_are_errors_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("broken.urdf");
    std::fs::write(&p, "<robot name=\"x\"><link name=\"a\"/><joint name=\"j\" type=\"floating\"><parent link=\"a\"/><child link=\"b\"/></joint><link name=\"b\"/></robot>").unwrap();
    let e = RobotModel::from_urdf(&p).unwrap_err().to_string();
    assert!(e.contains("broken.urdf") && e.contains("floating"), "{e}");
    let model = RobotModel::from_urdf(&common::fixture("robot/arm.urdf")).unwrap();
    let e = model.chain("gripper").unwrap_err().to_string();
    assert!(e.contains("arm.urdf") && e.contains("gripper"), "{e}");
}
