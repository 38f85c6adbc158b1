//! `fit-base` input: a synthetic capture.mcap of a probed 4 × 5 × 2.5 cm block, written with
//! softcap_mcap, is mapped onto the block mesh (markers → top nodes, probe locations →
//! examples) exactly as the measurements it was made from, and fitted.

use softcap_design::*;
use softcap_mcap::capture::CaptureData;
use softcap_mcap::{Provenance, Writer, proto, topics};
use std::path::Path;

/// Writes `meas` as a capture: frame 0 at rest, then per example one contact frame (markers
/// displaced, probe tip over the patch centre, force on the object) and one release frame.
/// The block is placed at `offset_m` in the world frame.
fn write_capture(path: &Path, meas: &BaseMeasurements, offset_m: [f64; 3]) {
    let markers = &meas.examples[0].marker_nodes;
    let pos = |i: usize| {
        let v = meas.mesh.vertices[i];
        [v.x + offset_m[0], v.y + offset_m[1], v.z + offset_m[2]]
    };
    let v3 = |p: [f64; 3]| {
        Some(proto::Vec3 {
            x: p[0],
            y: p[1],
            z: p[2],
        })
    };
    let mut w = Writer::create(path, &Provenance::new("capture", "test")).unwrap();
    w.write_static(
        &topics::SESSION,
        &proto::SessionInfo {
            name: "block".into(),
            kind: "probe".into(),
            marker_ids: markers.iter().map(|i| format!("m{i}")).collect(),
            object_markers: markers.len() as u32,
            rest_positions_m: markers.iter().map(|&i| v3(pos(i)).unwrap()).collect(),
            tip_shape: "disk".into(),
            tip_radius_m: 0.005,
            ..Default::default()
        },
    )
    .unwrap();
    let mut frame = 0u64;
    let mut put = |frame: u64, disp: Option<&[[f64; 3]]>, probe: Option<([f64; 3], [f64; 3])>| {
        let t = frame * 100_000_000;
        let marker_list = markers
            .iter()
            .enumerate()
            .map(|(k, &i)| {
                let mut p = pos(i);
                if let Some(d) = disp {
                    for c in 0..3 {
                        p[c] += d[k][c];
                    }
                }
                proto::Marker {
                    id: k as u32,
                    position_m: v3(p),
                    visible: true,
                    ..Default::default()
                }
            })
            .collect();
        w.write(
            &topics::MARKERS,
            t,
            &proto::MarkerFrame {
                frame,
                t_camera_s: 0.1 * frame as f64,
                markers: marker_list,
            },
        )
        .unwrap();
        let (tip, force) = probe.unwrap_or(([0.0, 0.0, 0.1], [0.0; 3]));
        w.write(
            &topics::PROBE,
            t,
            &proto::ProbeSample {
                frame,
                t_camera_s: 0.1 * frame as f64,
                tip_m: v3(tip),
                axis: v3([0.0, 0.0, -1.0]),
                force_n: v3(force),
                voltage_v: 0.0,
            },
        )
        .unwrap();
    };
    put(frame, None, None);
    for ex in &meas.examples {
        let n = ex.patch_nodes.len() as f64;
        let mut c = [0.0; 3];
        for &i in &ex.patch_nodes {
            let p = pos(i);
            for k in 0..3 {
                c[k] += p[k] / n;
            }
        }
        frame += 1;
        put(frame, Some(&ex.displacements_m), Some((c, ex.force_n)));
        frame += 1;
        put(frame, None, None);
    }
    w.finish().unwrap();
}

#[test]
fn capture_mcap_maps_onto_the_block_and_fits() {
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [0.04, 0.05, 0.025], [4, 5, 2]);
    let truth = softcap_fem::NeoHookeanParams::from_young_poisson(2.0e5, 0.35).unwrap();
    let examples = [([0.02, 0.02], 6.0), ([0.02, 0.03], 12.0)];
    let meas = synthesize_measurements(&mesh, truth, &examples, 0.011, true).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("capture.mcap");
    let offset = [0.31, -0.12, 0.75];
    write_capture(&path, &meas, offset);

    let capture = CaptureData::read(&path).unwrap();
    let mapped = measurements_from_capture(&capture, &CaptureMappingSettings::default()).unwrap();
    assert_eq!(mapped.mesh.vertices.len(), meas.mesh.vertices.len());
    for (a, b) in mapped.mesh.vertices.iter().zip(&meas.mesh.vertices) {
        let shifted = b + nalgebra::Vector3::from(offset);
        assert!((a - shifted).norm() < 1e-12, "{a} vs {shifted}");
    }
    assert_eq!(mapped.fixed_nodes, meas.fixed_nodes);
    assert_eq!(mapped.examples.len(), meas.examples.len());
    for (a, b) in mapped.examples.iter().zip(&meas.examples) {
        assert_eq!(a.marker_nodes, b.marker_nodes);
        assert_eq!(a.patch_nodes, b.patch_nodes);
        assert_eq!(a.force_n, b.force_n);
        for (da, db) in a.displacements_m.iter().zip(&b.displacements_m) {
            for c in 0..3 {
                assert!((da[c] - db[c]).abs() < 1e-12);
            }
        }
    }
    // A fit from the capture: the linear pre-fit alone is already sub-millimetre; two LM
    // iterations of eq. 8.3 improve on it.
    let settings = BaseFitSettings {
        centres: 1,
        lm: softcap_core::LevenbergMarquardtSettings {
            max_iterations: 2,
            finite_difference: softcap_core::FiniteDifference::Forward,
            ..softcap_core::LevenbergMarquardtSettings::default()
        },
        ..BaseFitSettings::default()
    };
    let rep = fit_isotropic(&mapped, 1.0e5, &settings).unwrap();
    println!(
        "from capture.mcap: linear pre-fit {:.4} mm, fit {:.4} mm",
        rep.linear_rms_m * 1e3,
        rep.rms_m * 1e3
    );
    assert!(rep.rms_m < rep.linear_rms_m);
    assert!(rep.rms_m < 0.15e-3);
}

#[test]
fn capture_with_a_marker_off_the_grid_is_rejected_by_name() {
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [0.04, 0.05, 0.025], [4, 5, 2]);
    let truth = softcap_fem::NeoHookeanParams::from_young_poisson(2.0e5, 0.35).unwrap();
    let meas = synthesize_measurements(&mesh, truth, &[([0.02, 0.02], 6.0)], 0.011, true).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("capture.mcap");
    write_capture(&path, &meas, [0.0; 3]);
    let capture = CaptureData::read(&path).unwrap();
    let coarse = CaptureMappingSettings {
        cells: [3, 3, 2],
        ..CaptureMappingSettings::default()
    };
    let e = measurements_from_capture(&capture, &coarse)
        .unwrap_err()
        .to_string();
    assert!(e.contains("capture.mcap") && e.contains("marker m"), "{e}");
}
