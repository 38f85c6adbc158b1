//! Shared by the diagnose suite (tests/diagnose_suite.rs) and the catalog bench
//! (benches/diagnose_catalog.rs): the stage chain synth → capture → tissue fit on a scenario,
//! in-process through each stage's library API.
#![allow(dead_code)]

use softcap_capture::{CaptureSettings, Session, capture, write_capture_mcap};
use softcap_synth::{Scenario, synthesize};
use std::path::{Path, PathBuf};
use std::time::Instant;

pub fn suite_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/scenarios/suite")
}

/// The inputs of `softcap diagnose` for one scenario, in a temporary folder.
pub struct Inputs {
    pub dir: tempfile::TempDir,
    pub capture: PathBuf,
    pub material: PathBuf,
    /// Seconds spent in synth, capture, tissue fit.
    pub seconds: [f64; 3],
}

/// synth → capture (capture.mcap) → tissue fit (material.mcap).
pub fn prepare_inputs(scenario: &Scenario) -> Inputs {
    let dir = tempfile::tempdir().unwrap();
    let session_dir = dir.path().join("session");
    let t0 = Instant::now();
    synthesize(scenario, &session_dir).unwrap();
    let t_synth = t0.elapsed().as_secs_f64();

    let t0 = Instant::now();
    let session = Session::load(&session_dir).unwrap();
    let settings = CaptureSettings::default();
    let result = capture(&session, &settings).unwrap();
    let capture_path = dir.path().join("capture.mcap");
    write_capture_mcap(&capture_path, &session, &result, &settings, &[]).unwrap();
    let t_capture = t0.elapsed().as_secs_f64();

    let t0 = Instant::now();
    let material_path = dir.path().join("material.mcap");
    let volume = session.volume.clone().expect("template/volume.msh");
    material::fit_homogeneous_material(
        &capture_path,
        &volume,
        session.metres_per_unit,
        &material_path,
    );
    let t_tissue = t0.elapsed().as_secs_f64();
    Inputs {
        dir,
        capture: capture_path,
        material: material_path,
        seconds: [t_synth, t_capture, t_tissue],
    }
}

pub mod material {
    //! The tissue stage's material.mcap for the suite.
    use softcap_fem::LinearParams;
    use softcap_fem::nalgebra::Vector3;
    use softcap_fem::probing::{
        HomogeneousFitSettings, ObservedMarker, PatchSettings, ProbeExample, ProbingSetup,
        fit_homogeneous, support_nodes,
    };
    use softcap_mcap::capture::CaptureData;
    use softcap_mcap::{Provenance, Writer, proto, topics};
    use std::path::Path;

    fn v3(a: [f64; 3]) -> Vector3<f64> {
        Vector3::new(a[0], a[1], a[2])
    }

    /// Homogeneous average fit (bickel2009 Fig. 8 baseline, `softcap_fem::probing::fit_homogeneous`)
    /// over the contact frames, written as `/mesh/volume` + one `/tissue/element_material`.
    pub fn fit_homogeneous_material(
        capture: &Path,
        volume_msh: &Path,
        metres_per_unit: f64,
        out: &Path,
    ) -> LinearParams {
        let cap = CaptureData::read(capture).unwrap();
        let mut mesh = softcap_mesh::read_msh_tet_mesh(volume_msh).unwrap();
        for v in &mut mesh.vertices {
            *v *= metres_per_unit;
        }
        let s = &cap.session;
        let support = s.support.as_ref().expect("support plane");
        let attached = support_nodes(
            &mesh,
            &v3(support.normal),
            support.offset_m,
            support.tolerance_m.max(1e-9),
        );
        let rest: Vec<Vector3<f64>> = s.rest_positions_m.iter().map(|p| v3(*p)).collect();
        let setup = ProbingSetup::new(mesh, &rest, attached).unwrap();
        let peak = cap
            .frames
            .iter()
            .filter_map(|f| f.probe.as_ref().map(|p| p.force_magnitude_n()))
            .fold(0.0, f64::max);
        let examples: Vec<ProbeExample> = cap
            .frames
            .iter()
            .filter_map(|f| {
                let p = f.probe.as_ref()?;
                let force = v3(p.force_n?);
                if force.norm() < 0.3 * peak {
                    return None;
                }
                Some(ProbeExample {
                    frame: f.frame,
                    time_s: f.t_camera_s,
                    tip_m: v3(p.tip_m?),
                    axis: v3(p.axis?),
                    force_n: force,
                    observed: f
                        .markers
                        .iter()
                        .filter(|m| (m.id as usize) < s.object_markers && m.visible && !m.filled)
                        .map(|m| ObservedMarker {
                            marker: m.id as usize,
                            position_m: v3(m.position_m),
                        })
                        .collect(),
                })
            })
            .collect();
        let fit = fit_homogeneous(
            &setup,
            &examples,
            &HomogeneousFitSettings {
                patch: PatchSettings {
                    radius_m: s.tip_radius_m,
                    ..Default::default()
                },
                ..Default::default()
            },
        )
        .unwrap();
        let nt = setup.mesh.tets.len();
        let mut w =
            Writer::create(out, &Provenance::new("tissue fit (suite helper)", "test")).unwrap();
        w.write_static(
            &topics::VOLUME_MESH,
            &proto::TetMesh {
                name: "volume".into(),
                positions_m: setup
                    .mesh
                    .vertices
                    .iter()
                    .flat_map(|v| [v.x, v.y, v.z])
                    .collect(),
                tets: setup
                    .mesh
                    .tets
                    .iter()
                    .flat_map(|t| t.map(|i| i as u32))
                    .collect(),
                ..Default::default()
            },
        )
        .unwrap();
        w.write(
            &topics::ELEMENT_MATERIAL,
            0,
            &proto::ElementMaterial {
                lambda_pa: vec![fit.params.lambda; nt],
                alpha_pa: vec![fit.params.alpha; nt],
                residual_m: fit.rms_m,
                ..Default::default()
            },
        )
        .unwrap();
        w.finish().unwrap();
        fit.params
    }
}
