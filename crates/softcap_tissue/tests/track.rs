//! `softcap tissue track` on hand-made dynamic captures: a body that does not move stays put, a
//! rigidly translating cloud is followed, the output is deterministic, bad input exits 2 and
//! writes nothing.

use std::path::{Path, PathBuf};
use std::process::Command;

use softcap_mcap::{Provenance, Writer, proto, topics};
use softcap_mesh::nalgebra::Vector3;
use softcap_mesh::{MshMesh, box_tet_mesh, write_msh};
use softcap_tissue::track::{TrackConfig, TrackSettings, run};

/// A free 60 × 30 × 30 mm block (mm mesh) and a capture of its top and side surfaces sampled
/// every 1.5 mm, shifted by `shift(frame)` (m), 6 frames at 30 Hz, gravity off.
fn write_inputs(dir: &Path, shift: impl Fn(usize) -> Vector3<f64>) -> (PathBuf, PathBuf) {
    let mesh_mm = box_tet_mesh([0.0, 0.0, 0.0], [60.0, 30.0, 30.0], [4, 2, 2]);
    let mesh_path = dir.join("volume.msh");
    write_msh(&mesh_path, &MshMesh::from_tet_mesh(&mesh_mm, None)).unwrap();
    let capture = dir.join("capture.mcap");
    let mut w = Writer::create(&capture, &Provenance::new("capture", "0")).unwrap();
    w.write_static(
        &topics::SESSION,
        &proto::SessionInfo {
            name: "block".into(),
            kind: "dynamic".into(),
            gravity_m_s2: Some(proto::Vec3::default()),
            density_kg_m3: Some(1000.0),
            metres_per_unit: 1e-3,
            ..Default::default()
        },
    )
    .unwrap();
    w.write_static(
        &topics::DYNAMIC_SESSION,
        &proto::DynamicSession {
            source: "points".into(),
            frames: 6,
            ..Default::default()
        },
    )
    .unwrap();
    for f in 0..6usize {
        let s = shift(f);
        let mut pos = Vec::new();
        let mut nrm = Vec::new();
        let mut push = |p: Vector3<f64>, n: [f32; 3]| {
            let q = p + s;
            pos.extend([q.x as f32, q.y as f32, q.z as f32]);
            nrm.extend(n);
        };
        for i in 0..=40 {
            for j in 0..=20 {
                let (x, y) = (i as f64 * 0.0015, j as f64 * 0.0015);
                push(Vector3::new(x, y, 0.03), [0.0, 0.0, 1.0]);
                push(Vector3::new(x, 0.0, y), [0.0, -1.0, 0.0]);
            }
        }
        let t = f as f64 / 30.0;
        w.write(
            &topics::POINTS,
            (t * 1e9) as u64,
            &proto::PointCloudFrame {
                frame: f as u64,
                t_camera_s: t,
                positions_m: pos,
                normals: nrm,
                ..Default::default()
            },
        )
        .unwrap();
    }
    w.finish().unwrap();
    (capture, mesh_path)
}

fn config(dir: &Path, capture: PathBuf, mesh: PathBuf, out: &str) -> TrackConfig {
    TrackConfig {
        capture,
        mesh,
        material: None,
        attach: None,
        output: dir.join(out),
        settings: TrackSettings {
            progress: false,
            ..Default::default()
        },
        arguments: vec!["test".into()],
    }
}

#[test]
fn a_rigidly_moving_cloud_is_followed_and_the_output_is_deterministic() {
    let dir = tempfile::tempdir().unwrap();
    // a free body at rest in frame 0, then moving at (0, −0.7, 1) mm per frame: normal to both
    // observed faces (a shift along a face is seen only at its edges, like any
    // point-to-surface fit)
    let step = Vector3::new(0.0, -0.0007, 0.001);
    let (capture, mesh) = write_inputs(dir.path(), |f| step * f as f64);
    let o = run(&config(dir.path(), capture.clone(), mesh.clone(), "a.mcap")).unwrap();
    assert_eq!(o.frames.len(), 6);
    let rest = box_tet_mesh([0.0, 0.0, 0.0], [0.06, 0.03, 0.03], [4, 2, 2]);
    let rows: Vec<String> = o
        .frames
        .iter()
        .enumerate()
        .map(|(f, fr)| {
            let want = step * f as f64;
            let mean: Vector3<f64> = fr
                .positions_m
                .iter()
                .zip(&rest.vertices)
                .map(|(p, r)| p - r)
                .sum::<Vector3<f64>>()
                / rest.vertices.len() as f64;
            let e = 1e3 * (mean - want);
            format!(
                "frame {f} {}: error ({:.3}, {:.3}, {:.3}) mm, residual {:.3} mm, {} EM",
                fr.status,
                e.x,
                e.y,
                e.z,
                1e3 * fr.residual_m,
                fr.em_iterations
            )
        })
        .collect();
    // frame 0 stays put; then the body starts from rest (one frame of lag) and keeps up
    for (f, fr) in o.frames.iter().enumerate() {
        assert_ne!(fr.status, "diverged", "{}", rows.join("\n"));
        let mean: Vector3<f64> = fr
            .positions_m
            .iter()
            .zip(&rest.vertices)
            .map(|(p, r)| p - r)
            .sum::<Vector3<f64>>()
            / rest.vertices.len() as f64;
        let tolerance = if f == 0 { 5e-5 } else { 3e-4 };
        assert!(
            (mean - step * f as f64).norm() < tolerance,
            "{}",
            rows.join("\n")
        );
        assert!(fr.residual_m < tolerance, "{}", rows.join("\n"));
    }
    // the typed reader gives back what the tracker wrote
    let track = softcap_mcap::dynamic::read_track(dir.path().join("a.mcap")).unwrap();
    assert_eq!(track.frames.len(), o.frames.len());
    assert_eq!(track.mesh.vertices_m.len(), rest.vertices.len());
    for (read, fr) in track.frames.iter().zip(&o.frames) {
        assert_eq!(read.status.status, fr.status);
        for (a, b) in read.positions_m.iter().zip(&fr.positions_m) {
            assert_eq!(*a, [b.x, b.y, b.z]);
        }
    }
    run(&config(dir.path(), capture, mesh, "b.mcap")).unwrap();
    let digest = |p: &str| {
        softcap_mcap::Recording::open(dir.path().join(p))
            .unwrap()
            .digest()
            .unwrap()
    };
    assert_eq!(digest("a.mcap"), digest("b.mcap"));
}

fn run_cli(args: &[&std::ffi::OsStr]) -> (i32, String) {
    let st = Command::new(env!("CARGO_BIN_EXE_softcap-tissue"))
        .args(args)
        .output()
        .unwrap();
    (
        st.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&st.stderr).into_owned(),
    )
}

#[test]
fn bad_track_input_exits_2_naming_the_file_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let (capture, mesh) = write_inputs(dir.path(), |_| Vector3::zeros());
    let out = dir.path().join("track.mcap");
    // a mesh that does not match the capture (another object, 1 m away)
    let far = box_tet_mesh([1000.0, 0.0, 0.0], [1060.0, 30.0, 30.0], [2, 1, 1]);
    let far_path = dir.path().join("far.msh");
    write_msh(&far_path, &MshMesh::from_tet_mesh(&far, None)).unwrap();
    let (code, err) = run_cli(&[
        "track".as_ref(),
        capture.as_os_str(),
        "--mesh".as_ref(),
        far_path.as_os_str(),
        "-o".as_ref(),
        out.as_os_str(),
    ]);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains("far.msh") && err.contains("does not match"),
        "{err}"
    );
    assert!(!out.exists());
    // a capture that is not dynamic
    let probe = dir.path().join("probe.mcap");
    let mut w = Writer::create(&probe, &Provenance::new("capture", "0")).unwrap();
    w.write_static(
        &topics::SESSION,
        &proto::SessionInfo {
            name: "p".into(),
            kind: "probe".into(),
            ..Default::default()
        },
    )
    .unwrap();
    w.finish().unwrap();
    let (code, err) = run_cli(&[
        "track".as_ref(),
        probe.as_os_str(),
        "--mesh".as_ref(),
        mesh.as_os_str(),
        "-o".as_ref(),
        out.as_os_str(),
    ]);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains("probe.mcap") && err.contains("not a dynamic capture"),
        "{err}"
    );
    assert!(!out.exists());
    // attachment nodes past the mesh
    let attach = dir.path().join("attach.csv");
    std::fs::write(&attach, "node\n3\n999\n").unwrap();
    let (code, err) = run_cli(&[
        "track".as_ref(),
        capture.as_os_str(),
        "--mesh".as_ref(),
        mesh.as_os_str(),
        "--attach".as_ref(),
        attach.as_os_str(),
        "-o".as_ref(),
        out.as_os_str(),
    ]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("attach.csv") && err.contains("999"), "{err}");
    assert!(!out.exists());
    // a mesh with a broken line
    let broken = dir.path().join("broken.msh");
    std::fs::write(
        &broken,
        "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\nxx\n",
    )
    .unwrap();
    let (code, err) = run_cli(&[
        "track".as_ref(),
        capture.as_os_str(),
        "--mesh".as_ref(),
        broken.as_os_str(),
        "-o".as_ref(),
        out.as_os_str(),
    ]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("broken.msh"), "{err}");
    assert!(!out.exists());
}
