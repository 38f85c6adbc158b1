//! `dynamic::read_track`: round trip and bad input naming channel and field.

use std::path::Path;

use softcap_mcap::dynamic::read_track;
use softcap_mcap::{Provenance, Writer, proto, topics};

const TET: [f64; 12] = [0.0, 0.0, 0.0, 0.1, 0.0, 0.0, 0.0, 0.1, 0.0, 0.0, 0.0, 0.1];

/// A one-tet track.mcap with `frames` (frame, positions, status) written as given.
fn write(path: &Path, frames: &[(u64, Vec<f64>, &str)], statuses: usize) {
    let mut w = Writer::create(path, &Provenance::new("tissue track", "0")).unwrap();
    w.write_static(
        &topics::VOLUME_MESH,
        &proto::TetMesh {
            positions_m: TET.to_vec(),
            tets: vec![0, 1, 2, 3],
            surface_triangles: vec![0, 2, 1, 0, 1, 3, 1, 2, 3, 0, 3, 2],
            ..Default::default()
        },
    )
    .unwrap();
    w.write_static(
        &topics::DYNAMIC_MATERIAL,
        &proto::DynamicMaterial {
            element: "corotational".into(),
            young_pa: vec![1e5],
            poisson: 0.4,
            density_kg_m3: 1000.0,
            ..Default::default()
        },
    )
    .unwrap();
    for (k, (frame, x, status)) in frames.iter().enumerate() {
        let t = *frame as f64 / 30.0;
        let ns = (t * 1e9) as u64;
        w.write(
            &topics::TRACK_NODES,
            ns,
            &proto::NodeFrame {
                frame: *frame,
                t_camera_s: t,
                positions_m: x.clone(),
            },
        )
        .unwrap();
        if k < statuses {
            w.write(
                &topics::TRACK_STATUS,
                ns,
                &proto::TrackStatus {
                    frame: *frame,
                    t_camera_s: t,
                    status: (*status).into(),
                    residual_m: 1e-4,
                    ..Default::default()
                },
            )
            .unwrap();
        }
    }
    w.finish().unwrap();
}

fn shifted(dz: f64) -> Vec<f64> {
    TET.chunks(3)
        .flat_map(|p| [p[0], p[1], p[2] + dz])
        .collect()
}

#[test]
fn round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("track.mcap");
    write(
        &path,
        &[
            (0, shifted(0.0), "converged"),
            (1, shifted(0.01), "diverged"),
        ],
        2,
    );
    let t = read_track(&path).unwrap();
    assert_eq!(t.mesh.tets, vec![[0, 1, 2, 3]]);
    assert_eq!(t.mesh.surface_triangles.len(), 4);
    assert_eq!(t.material.young_pa, vec![1e5]);
    assert_eq!(t.frames.len(), 2);
    assert_eq!(t.frames[1].positions_m[3], [0.0, 0.0, 0.11]);
    assert!(t.frames[0].is_tracked() && !t.frames[1].is_tracked());
    assert!(t.report.is_none());
}

#[test]
fn bad_track_files_name_channel_and_field() {
    let dir = tempfile::tempdir().unwrap();
    let cases: [(&str, Vec<(u64, Vec<f64>, &str)>, usize, &[&str]); 5] = [
        (
            "short.mcap",
            vec![(0, TET[..9].to_vec(), "converged")],
            1,
            &["/tissue/track/nodes", "frame 0: positions_m", "4 nodes"],
        ),
        (
            "nan.mcap",
            vec![(0, shifted(f64::NAN), "converged")],
            1,
            &["frame 0: positions_m[2]", "not finite"],
        ),
        (
            "order.mcap",
            vec![
                (1, shifted(0.0), "converged"),
                (1, shifted(0.0), "converged"),
            ],
            2,
            &["frame 1: frame", "must increase"],
        ),
        (
            "status.mcap",
            vec![(0, shifted(0.0), "fine")],
            1,
            &["/tissue/track/status", "frame 0: status", "`fine`"],
        ),
        (
            "missing.mcap",
            vec![
                (0, shifted(0.0), "converged"),
                (1, shifted(0.0), "converged"),
            ],
            1,
            &[
                "/tissue/track/status",
                "1 status messages for 2 node frames",
            ],
        ),
    ];
    for (name, frames, statuses, needles) in cases {
        let path = dir.path().join(name);
        write(&path, &frames, statuses);
        let text = read_track(&path).unwrap_err().to_string();
        assert!(text.contains(name), "{text}");
        for n in needles {
            assert!(text.contains(n), "{name}: `{n}` not in: {text}");
        }
    }
}
