//! `MaterialData::read`: round trip and bad input naming the field.

use softcap_mcap::material::MaterialData;
use softcap_mcap::{Provenance, Writer, proto, topics};

fn write(path: &std::path::Path, lambda0: f64) {
    let mut w = Writer::create(path, &Provenance::new("tissue fit", "0")).unwrap();
    let mesh = proto::TetMesh {
        name: "volume".into(),
        frame_id: "world".into(),
        positions_m: vec![
            0.0, 0.0, 0.0, 0.01, 0.0, 0.0, 0.0, 0.01, 0.0, 0.0, 0.0, 0.01,
        ],
        tets: vec![0, 1, 2, 3],
        surface_triangles: vec![],
    };
    w.write_static(&topics::VOLUME_MESH, &mesh).unwrap();
    let m = proto::ElementMaterial {
        example: 0,
        frame: 5,
        lambda_pa: vec![lambda0],
        alpha_pa: vec![0.4 * lambda0],
        strain: vec![0.0; 6],
        residual_m: 1e-4,
    };
    w.write(&topics::ELEMENT_MATERIAL, 500_000_000, &m).unwrap();
    w.finish().unwrap();
}

#[test]
fn round_trip_and_bad_lambda() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("material.mcap");
    write(&path, 1e5);
    let m = MaterialData::read(&path).unwrap();
    assert_eq!(m.tets, vec![[0, 1, 2, 3]]);
    assert_eq!(m.vertices_m[1], [0.01, 0.0, 0.0]);
    assert_eq!(m.element_materials.len(), 1);
    assert_eq!(m.element_materials[0].1.frame, 5);
    assert!(m.basis.is_none() && m.report.is_none());

    let bad = dir.path().join("bad.mcap");
    write(&bad, -1.0);
    let text = MaterialData::read(&bad).unwrap_err().to_string();
    assert!(
        text.contains("bad.mcap") && text.contains("example 0 lambda_pa[0]"),
        "{text}"
    );
}

fn write_basis(path: &std::path::Path, centers_per_tet: Vec<u32>) {
    let mut w = Writer::create(path, &Provenance::new("tissue fit", "0")).unwrap();
    let mesh = proto::TetMesh {
        name: "volume".into(),
        frame_id: "world".into(),
        positions_m: vec![
            0.0, 0.0, 0.0, 0.01, 0.0, 0.0, 0.0, 0.01, 0.0, 0.0, 0.0, 0.01, 0.01, 0.01, 0.01,
        ],
        tets: vec![0, 1, 2, 3, 1, 2, 3, 4],
        surface_triangles: vec![],
    };
    w.write_static(&topics::VOLUME_MESH, &mesh).unwrap();
    // Two tets, M = 2: tet 0 uses two centres, tet 1 one centre plus padding.
    let basis = proto::StrainSpaceBasis {
        elements: 2,
        kernel: "r".into(),
        tail: "none".into(),
        center_examples: vec![0, 1],
        centers_strain: (0..24).map(|i| 1e-3 * i as f64).collect(),
        weights: vec![1e5, 4e4, 2e5, 8e4, 3e5, 1e5, 0.0, 0.0],
        tail_coefficients: vec![],
        centers_per_tet,
        center_samples: vec![0, 2, 0, 0],
        lambda_floor_pa: vec![5e4, 6e4],
        nu_min: 0.0,
        nu_max: 0.49,
        lambda_ceiling_pa: vec![],
    };
    w.write_static(&topics::STRAIN_SPACE_BASIS, &basis).unwrap();
    w.finish().unwrap();
}

#[test]
fn basis_with_per_tet_centre_counts() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("material.mcap");
    write_basis(&path, vec![2, 1]);
    let m = MaterialData::read(&path).unwrap();
    let t0 = m.basis_tet(0).unwrap();
    assert_eq!(t0.weights, &[1e5, 4e4, 2e5, 8e4]);
    assert_eq!(t0.center_samples, &[0, 2]);
    let t1 = m.basis_tet(1).unwrap();
    assert_eq!(t1.centers_strain.len(), 6);
    assert_eq!(t1.weights, &[3e5, 1e5]);
    assert_eq!(t1.lambda_floor_pa, 6e4);
    assert!(m.basis_tet(2).is_none());

    let bad = dir.path().join("bad-counts.mcap");
    write_basis(&bad, vec![2, 3]);
    let text = MaterialData::read(&bad).unwrap_err().to_string();
    assert!(
        text.contains("bad-counts.mcap") && text.contains("centers_per_tet[1]"),
        "{text}"
    );
}
