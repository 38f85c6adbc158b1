//! `softcap tissue simulate`: a fitted material synthesizes a sphere probe by incremental
//! loading with contact (bickel2009 §3.4); sim.mcap carries markers, mesh and force per step.

use crate::common;

use common::{SessionSpec, quiet_fit, write_session};
use softcap_mcap::{Recording, topics};
use softcap_tissue::{ProbeShape, ProbeSpec, SimulateConfig, SimulateSettings};

#[test]
fn simulate_reaches_the_force_and_writes_every_load_step() {
    let dir = tempfile::tempdir().unwrap();
    let s = write_session(
        dir.path(),
        &SessionSpec {
            locations: vec![[0.0105, 0.0105], [0.0195, 0.0195]],
            forces_n: vec![0.6, 1.2],
            ..SessionSpec::default()
        },
    );
    let material = dir.path().join("material.mcap");
    quiet_fit(&s.capture, &s.mesh, &material);
    let out = dir.path().join("sim.mcap");
    let settings = SimulateSettings::default();
    let cfg = SimulateConfig {
        material: material.clone(),
        output: out.clone(),
        probe: ProbeSpec {
            shape: ProbeShape::Sphere,
            radius_m: 0.005,
            tip_m: [0.015, 0.015, 0.03],
            axis: [0.0, 0.0, -1.0],
            force_n: 0.8,
            disk_thickness_m: 0.002,
            half_length_m: 0.0,
        },
        settings: settings.clone(),
        arguments: vec![],
    };
    let o = softcap_tissue::simulate::run(&cfg).unwrap();
    eprintln!("{o:?}");
    assert!(o.converged);
    // Force control: within the secant tolerance (1 %) of the request.
    assert!((o.axial_force_n - 0.8).abs() <= 0.01 * 0.8 + 1e-12, "{o:?}");
    // Rest + every increment of the final approach (it stops at the one that reaches the force).
    assert!(o.load_steps >= 3, "{o:?}");
    assert!(o.depth_m > 0.0 && o.max_marker_displacement_m > 1e-4);
    let r = Recording::open(&out).unwrap();
    let markers = r.read(&topics::SIMULATED_MARKERS).unwrap();
    let probe = r.read(&topics::SIMULATED_PROBE).unwrap();
    let meshes = r.read(&topics::DEFORMED_MESH).unwrap();
    assert_eq!(markers.len(), o.load_steps);
    assert_eq!(probe.len(), o.load_steps);
    assert_eq!(meshes.len(), o.load_steps);
    // Probe force per step rises monotonically to the final force (along −z, on the object).
    let fz: Vec<f64> = probe.iter().map(|(_, p)| p.force_n.unwrap().z).collect();
    assert_eq!(fz[0], 0.0);
    assert!(fz.windows(2).all(|w| w[1] <= w[0] + 1e-12), "{fz:?}");
    assert!((fz.last().unwrap() + o.axial_force_n).abs() < 1e-12);
    // Bad probe → exit-2 class error, nothing written.
    let bad = dir.path().join("bad.mcap");
    let mut cfg_bad = cfg.clone();
    cfg_bad.output = bad.clone();
    cfg_bad.probe.radius_m = -1.0;
    let e = softcap_tissue::simulate::run(&cfg_bad).unwrap_err();
    assert!(
        e.is_bad_input() && e.to_string().contains("--radius"),
        "{e}"
    );
    // A probe line that misses the object.
    cfg_bad.probe.radius_m = 0.005;
    cfg_bad.probe.tip_m = [0.2, 0.2, 0.03];
    let e = softcap_tissue::simulate::run(&cfg_bad).unwrap_err();
    assert!(e.is_bad_input(), "{e}");
    assert!(!bad.exists());
}

/// The material's synthesis converged to the force (within the secant tolerance, 1 %), the
/// truth's converged too, and the depths agree within 35 % of the truth's.
fn assert_force_and_depth_match_the_truth(
    o: &softcap_tissue::SimulateOutcome,
    t: &softcap_probing::ContactSynthesis,
    force: f64,
) {
    assert!(o.converged, "{o:?}");
    assert!(
        (o.axial_force_n - force).abs() <= 0.01 * force + 1e-12,
        "{o:?}"
    );
    assert_eq!(t.status, softcap_fem::SolveStatus::Converged);
    assert!(
        (o.depth_m - t.depth_m).abs() <= 0.35 * t.depth_m,
        "{} vs {}",
        o.depth_m,
        t.depth_m
    );
}

/// Fits the session of `spec`, then synthesizes a 6 mm sphere pressing `force` down at `tip_m`
/// with the fitted material (`softcap tissue simulate`) and with the truth (its neo-Hookean
/// layers, the same probe): (the material's outcome, the truth's synthesis).
fn sphere_with_material_and_truth(
    spec: &SessionSpec,
    tip_m: [f64; 3],
    force: f64,
) -> (
    softcap_tissue::SimulateOutcome,
    softcap_probing::ContactSynthesis,
    tempfile::TempDir,
) {
    let dir = tempfile::tempdir().unwrap();
    let s = write_session(dir.path(), spec);
    let material = dir.path().join("material.mcap");
    quiet_fit(&s.capture, &s.mesh, &material);
    let probe = ProbeSpec {
        shape: ProbeShape::Sphere,
        radius_m: 0.006,
        tip_m,
        axis: [0.0, 0.0, -1.0],
        force_n: force,
        disk_thickness_m: 0.002,
        half_length_m: 0.0,
    };
    let o = softcap_tissue::simulate::run(&SimulateConfig {
        material,
        output: dir.path().join("sim.mcap"),
        probe: probe.clone(),
        settings: SimulateSettings::default(),
        arguments: vec![],
    })
    .unwrap();
    let fixed =
        softcap_probing::support_nodes(&s.mesh_m, &softcap_fem::nalgebra::Vector3::z(), 0.0, 1e-9);
    let setup = softcap_probing::ProbingSetup::new(s.mesh_m.clone(), &s.markers_m, fixed).unwrap();
    let mut truth = common::truth_model_of(&s.mesh_m, spec.young_pa, spec.size_m[2], spec.poisson);
    let pose = softcap_probing::probe_pose(
        &softcap_fem::nalgebra::Vector3::from(probe.tip_m),
        &-softcap_fem::nalgebra::Vector3::z(),
    );
    let t = softcap_probing::simulate_probe_contact(
        &setup,
        &mut truth,
        probe.tip_shape(),
        pose,
        force,
        &softcap_probing::ContactSynthesisSettings::default(),
    )
    .unwrap();
    (o, t, dir)
}

/// Regression test for the soft demo block (issue 7: `softcap tissue simulate` on the 2.2 kPa
/// demo material stopped at the first 1 mm depth increment with MaxIterations). A soft
/// (2.2 kPa top / 3 kPa bottom neo-Hookean) block probed with a 4 mm disk at 0.02 / 0.04 N is
/// fitted, then a novel probe — a 6 mm sphere at an untrained location, 0.04 N — is synthesized
/// (adaptive load increments with bisection, relaxation retries) and compared with the truth's
/// own synthesis of the same probe.
#[test]
fn simulate_converges_on_a_soft_block_with_a_novel_probe() {
    let spec = SessionSpec {
        locations: vec![[0.0105, 0.0105], [0.0195, 0.0195], [0.0105, 0.0195]],
        forces_n: vec![0.02, 0.04],
        young_pa: [3.0e3, 2.2e3],
        ..SessionSpec::default()
    };
    let force = 0.04;
    let (o, t, dir) = sphere_with_material_and_truth(&spec, [0.0175, 0.0125, 0.03], force);
    let out = dir.path().join("sim.mcap");
    eprintln!(
        "soft block, novel 6 mm sphere at 0.04 N: material depth {:.3} mm ({} load steps, {:.4} N), truth depth {:.3} mm ({:?})",
        1e3 * o.depth_m,
        o.load_steps,
        o.axial_force_n,
        1e3 * t.depth_m,
        t.status
    );
    assert_force_and_depth_match_the_truth(&o, &t, force);
    assert!(Recording::open(&out).is_ok());
}

/// Regression test for the suite block (issue 7: on the 40 × 40 × 20 mm suite block the
/// pipelines' default novel probe — a 6 mm sphere pressing 0.5 N at the top centre — overshot to
/// 2.40 N inside the first 1 mm depth trial and stopped with MaxIterations). A suite-like block
/// (40 × 40 × 20 mm, 648 tets, neo-Hookean E = 50 kPa, ν = 0.45 as synth's default material),
/// trained with a 4 mm disk at 0.5 / 1.0 N at three locations, synthesizes that probe: every
/// approach now stops at the first increment that reaches the force, so the depth is sized from
/// the target. Compared with the truth's own synthesis of the same probe (within 35 %).
#[test]
fn simulate_sizes_the_depth_from_the_force_on_a_suite_like_block() {
    let spec = SessionSpec {
        locations: vec![[0.013, 0.013], [0.027, 0.02], [0.015, 0.028]],
        forces_n: vec![0.5, 1.0],
        young_pa: [5.0e4, 5.0e4],
        size_m: [0.04, 0.04, 0.02],
        poisson: 0.45,
        ..SessionSpec::default()
    };
    let force = 0.5;
    let (o, t, _dir) = sphere_with_material_and_truth(&spec, [0.02, 0.02, 0.03], force);
    eprintln!(
        "suite-like block, 6 mm sphere at 0.5 N: material depth {:.3} mm ({} load steps, {:.4} N), truth depth {:.3} mm ({:?}, {} depth iterations)",
        1e3 * o.depth_m,
        o.load_steps,
        o.axial_force_n,
        1e3 * t.depth_m,
        t.status,
        t.depth_iterations
    );
    assert_force_and_depth_match_the_truth(&o, &t, force);
}
