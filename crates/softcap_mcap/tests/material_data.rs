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
