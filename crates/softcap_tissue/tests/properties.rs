//! Property test of the wang2015 §5 tracker (docs/reliability.md): random block sizes, materials
//! and motions of an observed surface cloud. Every frame ends with a reported status
//! (converged / max-iterations / diverged …), never a panic, and every reported position is
//! finite. Few cases keep it CI-cheap (`PROPTEST_CASES` raises them).

use proptest::prelude::*;
use softcap_mcap::{Provenance, Writer, proto, topics};
use softcap_mesh::nalgebra::Vector3;
use softcap_mesh::{MshMesh, box_tet_mesh, write_msh};
use softcap_tissue::track::{TrackConfig, TrackSettings, run};

/// A block `size` (m; mesh in mm) and 4 frames at 30 Hz of its top face sampled on a 12 × 12
/// grid, moved by `velocity` (m per frame) plus a per-point noise of `noise` m.
fn write_inputs(
    dir: &std::path::Path,
    size: [f64; 3],
    velocity: Vector3<f64>,
    noise: f64,
) -> (std::path::PathBuf, std::path::PathBuf) {
    let mesh_mm = box_tet_mesh([0.0; 3], size.map(|s| 1e3 * s), [3, 2, 2]);
    let mesh = dir.join("volume.msh");
    write_msh(&mesh, &MshMesh::from_tet_mesh(&mesh_mm, None)).unwrap();
    let capture = dir.join("capture.mcap");
    let mut w = Writer::create(&capture, &Provenance::new("capture", "0")).unwrap();
    let session = proto::SessionInfo {
        name: "block".into(),
        kind: "dynamic".into(),
        gravity_m_s2: Some(proto::Vec3::default()),
        density_kg_m3: Some(1000.0),
        metres_per_unit: 1e-3,
        ..Default::default()
    };
    w.write_static(&topics::SESSION, &session).unwrap();
    let dynamic = proto::DynamicSession {
        source: "points".into(),
        frames: 4,
        ..Default::default()
    };
    w.write_static(&topics::DYNAMIC_SESSION, &dynamic).unwrap();
    for f in 0..4u64 {
        let mut positions_m = Vec::new();
        let mut normals = Vec::new();
        for k in 0..144u64 {
            let (i, j) = ((k % 12) as f64, (k / 12) as f64);
            // A deterministic pseudo-random jitter per point and frame.
            let h = ((k * 7919 + f * 104729) % 1000) as f64 / 500.0 - 1.0;
            let p = Vector3::new(
                size[0] * (i + 0.5) / 12.0,
                size[1] * (j + 0.5) / 12.0,
                size[2],
            ) + velocity * f as f64
                + Vector3::new(0.0, 0.0, noise * h);
            positions_m.extend([p.x as f32, p.y as f32, p.z as f32]);
            normals.extend([0.0f32, 0.0, 1.0]);
        }
        let t = f as f64 / 30.0;
        let frame = proto::PointCloudFrame {
            frame: f,
            t_camera_s: t,
            positions_m,
            normals,
            ..Default::default()
        };
        w.write(&topics::POINTS, (t * 1e9) as u64, &frame).unwrap();
    }
    w.finish().unwrap();
    (capture, mesh)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 4, ..ProptestConfig::default() })]

    #[test]
    fn every_tracked_frame_has_a_status_and_finite_positions(
        size in [0.02f64..0.1, 0.02f64..0.1, 0.01f64..0.05],
        velocity in [-0.003f64..0.003, -0.003f64..0.003, -0.003f64..0.003],
        noise in 0.0f64..0.002,
        young_pa in 1.0e4f64..1.0e7,
        poisson in 0.0f64..0.48,
    ) {
        let dir = tempfile::tempdir().unwrap();
        let (capture, mesh) = write_inputs(dir.path(), size, Vector3::from(velocity), noise);
        let cfg = TrackConfig {
            capture,
            mesh,
            material: None,
            attach: None,
            output: dir.path().join("track.mcap"),
            settings: TrackSettings { progress: false, young_pa, poisson, ..Default::default() },
            arguments: vec![],
        };
        let o = run(&cfg).unwrap();
        prop_assert_eq!(o.frames.len(), 4);
        for fr in &o.frames {
            prop_assert!(
                ["converged", "max-iterations", "diverged"].contains(&fr.status),
                "status {}", fr.status
            );
            prop_assert!(fr.positions_m.iter().all(|p| p.iter().all(|c| c.is_finite())),
                "frame {}: non-finite position ({})", fr.frame, fr.status);
        }
    }
}
