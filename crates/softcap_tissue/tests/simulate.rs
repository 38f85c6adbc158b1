//! `softcap tissue simulate`: a fitted material synthesizes a sphere probe by incremental
//! loading with contact (bickel2009 §3.4); sim.mcap carries markers, mesh and force per step.

mod common;

use common::{SessionSpec, write_session};
use softcap_mcap::{Recording, topics};
use softcap_tissue::{
    FitConfig, FitSettings, ProbeShape, ProbeSpec, SimulateConfig, SimulateSettings,
};

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
    softcap_tissue::fit::run(&FitConfig {
        capture: s.capture.clone(),
        mesh: Some(s.mesh.clone()),
        output: material.clone(),
        report: None,
        settings: FitSettings {
            progress: false,
            ..FitSettings::default()
        },
        arguments: vec![],
    })
    .unwrap();
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
    assert_eq!(o.load_steps, settings.contact.steps + 1);
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
