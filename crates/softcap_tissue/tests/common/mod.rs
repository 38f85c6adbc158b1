//! A virtual probing session written straight to capture.mcap + volume.msh (mm), with a known
//! non-linear heterogeneous truth (stable neo-Hookean, two layers), so tissue tests need no
//! other stage.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

use softcap_fem::nalgebra::Vector3;
use softcap_fem::{EquilibriumSettings, NeoHookeanModel, NeoHookeanParams};
use softcap_mcap::{Provenance, Writer, proto, topics};
use softcap_mesh::TetMesh;
use softcap_probing::PatchSettings;
use softcap_probing::{ObservedMarker, ProbeExample, ProbingSetup, support_nodes};

pub mod in_memory;

/// Block size, m.
pub const SIZE_M: [f64; 3] = [0.03, 0.03, 0.015];
/// Probe tip radius, m.
pub const TIP_RADIUS_M: f64 = 0.004;

/// A virtual session on disk.
pub struct VirtualSession {
    pub capture: PathBuf,
    pub mesh: PathBuf,
    /// The fit mesh in metres.
    pub mesh_m: TetMesh,
    /// Marker rest positions, m.
    pub markers_m: Vec<Vector3<f64>>,
    /// Truth examples (exact marker positions).
    pub examples: Vec<ProbeExample>,
}

pub struct SessionSpec {
    pub cells: [usize; 3],
    /// Probe (x, y) positions, m.
    pub locations: Vec<[f64; 2]>,
    /// Force levels per location (loading ramp, then one hold frame at the last level), N.
    pub forces_n: Vec<f64>,
    /// Young's moduli of the bottom / top layer, Pa.
    pub young_pa: [f64; 2],
    /// Block size, m (markers: a 6 × 6 grid on the top, scaled with it).
    pub size_m: [f64; 3],
    /// Poisson ratio of the truth.
    pub poisson: f64,
}

impl Default for SessionSpec {
    fn default() -> Self {
        Self {
            cells: [6, 6, 3],
            locations: vec![[0.0105, 0.0105], [0.0195, 0.0150], [0.0120, 0.0195]],
            forces_n: vec![0.5, 1.0, 1.5],
            young_pa: [6.0e4, 2.0e4],
            size_m: SIZE_M,
            poisson: 0.4,
        }
    }
}

pub fn markers() -> Vec<Vector3<f64>> {
    markers_on(SIZE_M)
}

/// A 6 × 6 marker grid on the top of a block of `size_m` (cell centres of a 6 × 6 grid).
pub fn markers_on(size_m: [f64; 3]) -> Vec<Vector3<f64>> {
    marker_grid(size_m, 6)
}

/// An n × n marker grid on the top of a block of `size_m` (cell centres of an n × n grid).
pub fn marker_grid(size_m: [f64; 3], n: usize) -> Vec<Vector3<f64>> {
    let mut m = Vec::new();
    for i in 0..n {
        for j in 0..n {
            m.push(Vector3::new(
                size_m[0] * (i as f64 + 0.5) / n as f64,
                size_m[1] * (j as f64 + 0.5) / n as f64,
                size_m[2],
            ));
        }
    }
    m
}

pub fn truth_model(mesh: &TetMesh, young_pa: [f64; 2]) -> NeoHookeanModel {
    truth_model_of(mesh, young_pa, SIZE_M[2], 0.4)
}

/// Two neo-Hookean layers split at half of `height_m`.
pub fn truth_model_of(
    mesh: &TetMesh,
    young_pa: [f64; 2],
    height_m: f64,
    poisson: f64,
) -> NeoHookeanModel {
    let params: Vec<NeoHookeanParams> = mesh
        .tets
        .iter()
        .map(|t| {
            let zc = t.iter().map(|&i| mesh.vertices[i].z).sum::<f64>() / 4.0;
            let e = if zc < 0.5 * height_m {
                young_pa[0]
            } else {
                young_pa[1]
            };
            NeoHookeanParams::from_young_poisson(e, poisson).unwrap()
        })
        .collect();
    NeoHookeanModel::new(mesh, params).unwrap()
}

/// Writes `dir/capture.mcap` and `dir/volume.msh` (mm).
pub fn write_session(dir: &Path, spec: &SessionSpec) -> VirtualSession {
    let size = spec.size_m;
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], size, spec.cells);
    let markers = markers_on(size);
    let fixed = support_nodes(&mesh, &Vector3::z(), 0.0, 1e-9);
    let setup = ProbingSetup::new(mesh.clone(), &markers, fixed).unwrap();
    let mut truth = truth_model_of(&mesh, spec.young_pa, size[2], spec.poisson);
    // The truth's force boundary condition is the default fit's for this disk tip.
    let patch = PatchSettings {
        radius_m: TIP_RADIUS_M,
        load: softcap_tissue::FitSettings::default().disk_tip_load,
        ..Default::default()
    };
    let newton = EquilibriumSettings::newton();

    // Frames: rest, then per location the ramp, a hold frame, a release frame.
    struct F {
        tip: Vector3<f64>,
        force: f64,
        x: Vec<Vector3<f64>>,
    }
    let rest_tip = Vector3::new(0.5 * size[0], 0.5 * size[1], size[2] + 0.01);
    let mut frames = vec![F {
        tip: rest_tip,
        force: 0.0,
        x: mesh.vertices.clone(),
    }];
    let mut examples = Vec::new();
    for loc in &spec.locations {
        let mut levels = spec.forces_n.clone();
        levels.push(*spec.forces_n.last().unwrap());
        let mut solver = setup.solver(&truth).unwrap();
        let mut x = mesh.vertices.clone();
        for &fz in &levels {
            let surface = Vector3::new(loc[0], loc[1], size[2]);
            let ex = ProbeExample {
                frame: 0,
                time_s: 0.0,
                tip_m: surface,
                axis: -Vector3::z(),
                force_n: Vector3::new(0.0, 0.0, -fz),
                observed: Vec::new(),
            };
            let f = setup.nodal_forces(&ex, &patch);
            let rep = setup.simulate(&mut solver, &mut truth, &mut x, &f, &newton);
            assert!(rep.converged(), "truth: {rep:?}");
            // The tip follows the mean displacement of the patch.
            let nodes = setup.patch_nodes(&ex, &patch);
            let dz = nodes
                .iter()
                .map(|&n| x[n].z - mesh.vertices[n].z)
                .sum::<f64>()
                / nodes.len() as f64;
            frames.push(F {
                tip: surface + Vector3::new(0.0, 0.0, dz),
                force: fz,
                x: x.clone(),
            });
        }
        frames.push(F {
            tip: Vector3::new(loc[0], loc[1], size[2] + 0.01),
            force: 0.0,
            x: mesh.vertices.clone(),
        });
    }

    std::fs::create_dir_all(dir).unwrap();
    let capture = dir.join("capture.mcap");
    let mut w = Writer::create(&capture, &Provenance::new("capture", "test")).unwrap();
    let v = |p: Vector3<f64>| proto::Vec3 {
        x: p.x,
        y: p.y,
        z: p.z,
    };
    w.write_static(
        &topics::SESSION,
        &proto::SessionInfo {
            name: "virtual".into(),
            kind: "probe".into(),
            marker_ids: (0..markers.len()).map(|i| format!("m{i}")).collect(),
            object_markers: markers.len() as u32,
            rest_positions_m: markers.iter().map(|p| v(*p)).collect(),
            gravity_m_s2: Some(proto::Vec3 {
                x: 0.0,
                y: 0.0,
                z: -9.81,
            }),
            support: Some(proto::SupportPlane {
                normal: Some(proto::Vec3 {
                    x: 0.0,
                    y: 0.0,
                    z: 1.0,
                }),
                offset_m: 0.0,
                tolerance_m: 1e-4,
            }),
            tip_shape: "disk".into(),
            tip_radius_m: TIP_RADIUS_M,
            shaft_direction: "handle-to-tip".into(),
            metres_per_unit: 0.001,
            ..Default::default()
        },
    )
    .unwrap();
    for (k, f) in frames.iter().enumerate() {
        let t = 0.05 * k as f64;
        let ns = (t * 1e9).round() as u64;
        let pos = setup.marker_positions(&f.x);
        w.write(
            &topics::MARKERS,
            ns,
            &proto::MarkerFrame {
                frame: k as u64,
                t_camera_s: t,
                markers: pos
                    .iter()
                    .enumerate()
                    .map(|(i, p)| proto::Marker {
                        id: i as u32,
                        position_m: Some(v(*p)),
                        visible: true,
                        ..Default::default()
                    })
                    .collect(),
            },
        )
        .unwrap();
        w.write(
            &topics::PROBE,
            ns,
            &proto::ProbeSample {
                frame: k as u64,
                t_camera_s: t,
                tip_m: Some(v(f.tip)),
                axis: Some(proto::Vec3 {
                    x: 0.0,
                    y: 0.0,
                    z: -1.0,
                }),
                force_n: Some(proto::Vec3 {
                    x: 0.0,
                    y: 0.0,
                    z: -f.force,
                }),
                voltage_v: 0.0,
            },
        )
        .unwrap();
        if f.force > 0.0 {
            examples.push(ProbeExample {
                frame: k as u64,
                time_s: t,
                tip_m: f.tip,
                axis: -Vector3::z(),
                force_n: Vector3::new(0.0, 0.0, -f.force),
                observed: pos
                    .iter()
                    .enumerate()
                    .map(|(marker, p)| ObservedMarker {
                        marker,
                        position_m: *p,
                    })
                    .collect(),
            });
        }
    }
    w.finish().unwrap();

    let mesh_path = dir.join("volume.msh");
    let mut mm = mesh.clone();
    mm.scale(1000.0);
    softcap_mesh::write_msh(&mesh_path, &softcap_mesh::MshMesh::from_tet_mesh(&mm, None)).unwrap();
    VirtualSession {
        capture,
        mesh: mesh_path,
        mesh_m: mesh,
        markers_m: markers,
        examples,
    }
}

/// `softcap_tissue::fit::run` with the default settings and no progress bar or report: the fit
/// every tissue test that is not about fit settings runs.
pub fn quiet_fit(capture: &Path, mesh: &Path, output: &Path) -> softcap_tissue::FitOutcome {
    softcap_tissue::fit::run(&softcap_tissue::FitConfig {
        capture: capture.to_path_buf(),
        mesh: Some(mesh.to_path_buf()),
        output: output.to_path_buf(),
        report: None,
        settings: softcap_tissue::FitSettings {
            progress: false,
            ..softcap_tissue::FitSettings::default()
        },
        arguments: vec![],
    })
    .expect("the fit of a virtual session succeeds")
}
