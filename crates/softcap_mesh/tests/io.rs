//! Readers, writers, round trips and bad-input errors for every mesh format.

use softcap_mesh::io::{msh, obj, ply, tetgen};
use softcap_mesh::nalgebra::Vector3;
use softcap_mesh::*;
use std::io::Cursor;
use std::path::{Path, PathBuf};

fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn example_template() -> PathBuf {
    repo_root().join("fixtures/mesh")
}

/// A small mixed quad/triangle surface with awkward coordinates.
fn sample_obj() -> ObjMesh {
    let vertices = vec![
        Vector3::new(0.1, 0.2, 0.3),
        Vector3::new(1.0 / 3.0, -2.5e-7, 7.0),
        Vector3::new(1e12, 0.0, -0.0),
        Vector3::new(-1.25, 3.5, 2.0_f64.sqrt()),
        Vector3::new(std::f64::consts::PI, 1e-300, 5.0),
    ];
    ObjMesh {
        vertices,
        texcoords: vec![[0.0, 1.0], [0.5, 0.25]],
        normals: vec![Vector3::new(0.0, 0.0, 1.0)],
        polygons: vec![vec![0, 1, 2, 3], vec![1, 4, 2]],
        polygon_texcoords: vec![vec![0, 1, 1, 0], vec![]],
        polygon_normals: vec![vec![], vec![0, 0, 0]],
    }
}

#[test]
fn ict_neutral_face_loads_with_9409_vertices() {
    let path = repo_root().join("fixtures/ict-face/neutral.obj");
    let m = read_obj(&path).expect("ICT neutral face");
    assert_eq!(m.vertices.len(), 9409);
    assert_eq!(m.polygons.len(), 9230);
    let quads = m.polygons.iter().filter(|p| p.len() == 4).count();
    let tris = m.polygons.iter().filter(|p| p.len() == 3).count();
    assert_eq!(quads + tris, m.polygons.len());
    let (tri, origin) = m.triangulate();
    assert_eq!(tri.triangles.len(), 2 * quads + tris);
    assert_eq!(origin.len(), tri.triangles.len());
    // Triangulation preserves each polygon's area vector (planar-ish quads: split sums agree).
    let area = tri.area();
    assert!(area > 0.0 && area.is_finite());
}

#[test]
fn example_session_template_loads() {
    let dir = example_template();
    let surface = read_obj_tri_mesh(dir.join("surface.obj")).expect("surface.obj");
    assert!(!surface.triangles.is_empty());
    let vol = read_msh(dir.join("volume.msh")).expect("volume.msh");
    assert_eq!(vol.vertices.len(), 465);
    assert!(!vol.tets.is_empty());
    let mesh = vol.tet_mesh();
    // 40 x 40 x 20 mm block.
    assert!((mesh.volume().abs() - 40.0 * 40.0 * 20.0).abs() < 1e-6 * 32000.0);
}

#[test]
fn malformed_obj_line_is_rejected_with_its_line_number() {
    let text = "# header\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 abc\nf 1 2 3\n";
    let err = read_obj_from(Cursor::new(text), "bad.obj").unwrap_err();
    assert_eq!(err.line(), Some(5), "{err}");
    let msg = err.to_string();
    assert!(msg.starts_with("bad.obj:5:"), "{msg}");
    assert!(msg.contains("abc"), "{msg}");

    // Out-of-range face index.
    let text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 4\n";
    let err = read_obj_from(Cursor::new(text), "bad.obj").unwrap_err();
    assert_eq!(err.line(), Some(5), "{err}");
    // Index 0 and too-short faces.
    let err =
        read_obj_from(Cursor::new("v 0 0 0\nv 1 0 0\nv 0 1 0\n\nf 0 1 2\n"), "x").unwrap_err();
    assert_eq!(err.line(), Some(5), "{err}");
    let err = read_obj_from(Cursor::new("v 0 0 0\nv 1 0 0\nf 1 2\n"), "x").unwrap_err();
    assert_eq!(err.line(), Some(3), "{err}");
    let err = read_obj_from(Cursor::new("v 0 0 0\nbogus 1 2\n"), "x").unwrap_err();
    assert_eq!(err.line(), Some(2), "{err}");
}

#[test]
fn obj_negative_indices_and_slashes() {
    let text =
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\nf -4/1/1 -3/1/1 -2/1/1 -1/1/1\n";
    let m = read_obj_from(Cursor::new(text), "q.obj").unwrap();
    assert_eq!(m.polygons, vec![vec![0, 1, 2, 3]]);
    assert_eq!(m.polygon_texcoords, vec![vec![0; 4]]);
    assert_eq!(m.to_tri_mesh().triangles.len(), 2);
    assert!((m.to_tri_mesh().area() - 1.0).abs() < 1e-15);
}

#[test]
fn obj_round_trip_is_exact() {
    let m = sample_obj();
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("m.obj");
    write_obj(&p, &m).unwrap();
    assert!(
        std::fs::read_dir(dir.path()).unwrap().all(|e| !e
            .unwrap()
            .file_name()
            .to_string_lossy()
            .ends_with(".tmp"))
    );
    assert_eq!(read_obj(&p).unwrap(), m);
    let tri = m.to_tri_mesh();
    write_tri_mesh_obj(&p, &tri).unwrap();
    assert_eq!(read_obj_tri_mesh(&p).unwrap(), tri);
}

#[test]
fn malformed_msh_line_is_rejected_with_its_line_number() {
    let good = std::fs::read_to_string(example_template().join("volume.msh")).unwrap();
    let lines: Vec<&str> = good.lines().collect();
    // Corrupt one coordinate line in the $Nodes section.
    let nodes = lines.iter().position(|l| *l == "$Nodes").unwrap();
    // Header line, entity block line, 465 tags, then coordinates.
    let target = nodes + 3 + 465 + 10; // 0-based index of the 11th coordinate line
    let mut bad: Vec<String> = lines.iter().map(|s| s.to_string()).collect();
    bad[target] = "1.0 oops 2.0".into();
    let text = bad.join("\n") + "\n";
    let err = msh::read_msh_from(Cursor::new(text), "bad.msh").unwrap_err();
    assert_eq!(err.line(), Some(target + 1), "{err}");
    assert!(
        err.to_string()
            .starts_with(&format!("bad.msh:{}:", target + 1)),
        "{err}"
    );

    // A corrupt element line.
    let elems = lines.iter().position(|l| *l == "$Elements").unwrap();
    let target = elems + 3 + 5;
    let mut bad: Vec<String> = lines.iter().map(|s| s.to_string()).collect();
    bad[target] = "17 3 x 9 10".into();
    let text = bad.join("\n") + "\n";
    let err = msh::read_msh_from(Cursor::new(text), "bad.msh").unwrap_err();
    assert_eq!(err.line(), Some(target + 1), "{err}");
}

#[test]
fn msh_round_trip_is_exact() {
    let mut mesh = box_tet_mesh([0.0; 3], [0.3, 0.2, 0.1], [3, 2, 2]);
    mesh.vertices[5].x += 1.0 / 3.0 * 1e-3;
    let boundary = mesh.boundary_faces();
    let m = MshMesh::from_tet_mesh(&mesh, Some(&boundary));
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("m.msh");
    write_msh(&p, &m).unwrap();
    let back = read_msh(&p).unwrap();
    assert_eq!(back, m);
    assert_eq!(back.tet_mesh(), mesh);
}

#[test]
fn ply_round_trips_ascii_and_binary() {
    let m = PlyMesh {
        vertices: sample_obj().vertices,
        polygons: vec![vec![0, 1, 2, 3], vec![1, 4, 2]],
    };
    let dir = tempfile::tempdir().unwrap();
    for fmt in [
        PlyFormat::Ascii,
        PlyFormat::BinaryLittleEndian,
        PlyFormat::BinaryBigEndian,
    ] {
        let p = dir.path().join(format!("m-{fmt:?}.ply"));
        write_ply(&p, &m, fmt).unwrap();
        assert_eq!(read_ply(&p).unwrap(), m, "{fmt:?}");
    }
}

#[test]
fn ply_reads_float_vertices_with_extra_properties_and_rejects_bad_lines() {
    let text = "ply\nformat ascii 1.0\ncomment test\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\nelement face 1\nproperty list uchar uint vertex_index\nend_header\n0 0 0 255\n1 0 0 0\n0 1 0 7\n3 0 1 2\n";
    let m = read_ply_from(Cursor::new(text), "t.ply").unwrap();
    assert_eq!(m.vertices.len(), 3);
    assert_eq!(m.polygons, vec![vec![0, 1, 2]]);
    let bad = text.replace("1 0 0 0\n", "1 zero 0 0\n");
    let err = read_ply_from(Cursor::new(bad), "t.ply").unwrap_err();
    assert_eq!(err.line(), Some(13), "{err}");
    // Binary file cut short.
    let mut bytes = Vec::new();
    ply::write_ply_to(&mut bytes, &m, PlyFormat::BinaryLittleEndian).unwrap();
    bytes.truncate(bytes.len() - 3);
    let err = read_ply_from(Cursor::new(bytes), "t.ply").unwrap_err();
    assert!(err.to_string().contains("truncated"), "{err}");
}

#[test]
fn tetgen_round_trip_and_bad_line() {
    let mesh = box_tet_mesh([-1.0; 3], [1.0, 0.5, 1.0 / 3.0], [2, 2, 1]);
    let dir = tempfile::tempdir().unwrap();
    let (n, e) = (dir.path().join("m.node"), dir.path().join("m.ele"));
    write_tetgen(&n, &e, &mesh).unwrap();
    assert_eq!(read_tetgen(&n, &e).unwrap(), mesh);

    // Zero-based numbering, comments, attributes and markers.
    let node = "# comment\n4 3 1 1\n0 0 0 0 9.5 1\n1 1 0 0 9.5 1\n2 0 1 0 9.5 0\n3 0 0 1 9.5 1\n";
    let ele = "1 4 0\n0 0 1 2 3 # tet\n";
    let m = read_tetgen_from(Cursor::new(node), "a.node", Cursor::new(ele), "a.ele").unwrap();
    assert_eq!(m.tets, vec![[0, 1, 2, 3]]);
    assert!((m.volume() - 1.0 / 6.0).abs() < 1e-15);
    let bad = ele.replace("0 0 1 2 3", "0 0 1 2 7");
    let err = read_tetgen_from(Cursor::new(node), "a.node", Cursor::new(bad), "a.ele").unwrap_err();
    assert_eq!(err.line(), Some(2), "{err}");
    assert!(err.to_string().starts_with("a.ele:2:"), "{err}");
    let bad = node.replace("2 0 1 0", "2 0 1.x 0");
    let err = read_tetgen_from(Cursor::new(bad), "a.node", Cursor::new(ele), "a.ele").unwrap_err();
    assert_eq!(err.line(), Some(5), "{err}");
}

#[test]
fn non_finite_coordinates_are_rejected_with_their_line() {
    let err = read_obj_from(Cursor::new("v 0 0 0\nv 1 nan 0\n"), "n.obj").unwrap_err();
    assert_eq!(err.line(), Some(2), "{err}");
    assert!(err.to_string().contains("y is NaN"), "{err}");
    let err = read_obj_from(Cursor::new("v 0 0 0\nvn inf 0 1\n"), "n.obj").unwrap_err();
    assert_eq!(err.line(), Some(2), "{err}");
    let node = "2 3 0 0\n1 0 0 0\n2 0 -inf 0\n";
    let err =
        read_tetgen_from(Cursor::new(node), "n.node", Cursor::new("0 4 0\n"), "n.ele").unwrap_err();
    assert_eq!(err.line(), Some(3), "{err}");
    let ply = "ply\nformat ascii 1.0\nelement vertex 1\nproperty double x\nproperty double y\nproperty double z\nend_header\n0 NaN 0\n";
    let err = read_ply_from(Cursor::new(ply), "n.ply").unwrap_err();
    assert_eq!(err.line(), Some(8), "{err}");
    let good = std::fs::read_to_string(example_template().join("volume.msh")).unwrap();
    let lines: Vec<&str> = good.lines().collect();
    let nodes = lines.iter().position(|l| *l == "$Nodes").unwrap();
    let mut bad: Vec<String> = lines.iter().map(|s| s.to_string()).collect();
    bad[nodes + 3 + 465] = "nan 0 0".into();
    let err = msh::read_msh_from(Cursor::new(bad.join("\n") + "\n"), "n.msh");
    // Either the parser rejects "nan" at its line, or the finite check names node 1.
    let err = err.unwrap_err().to_string();
    assert!(err.starts_with("n.msh"), "{err}");
}

#[test]
fn ict_face_and_example_volume_pass_validation() {
    let face = read_obj_tri_mesh(repo_root().join("fixtures/ict-face/neutral.obj")).unwrap();
    face.validate(&ValidationSettings::default()).unwrap();
    let mut vol = read_msh_tet_mesh(example_template().join("volume.msh")).unwrap();
    let flipped = vol.orient_positive();
    vol.validate(&ValidationSettings::default()).unwrap();
    println!(
        "example volume.msh: {} tets, {flipped} flipped to positive orientation",
        vol.tets.len()
    );
    vol.scale(MM_TO_M);
    assert!((vol.volume() - 0.04 * 0.04 * 0.02).abs() < 1e-12);
}

#[test]
fn missing_file_is_named() {
    let err = read_obj("/nonexistent/dir/face.obj").unwrap_err();
    assert!(
        err.to_string().contains("/nonexistent/dir/face.obj"),
        "{err}"
    );
    let err = tetgen::read_tetgen("/nonexistent/a.node", "/nonexistent/a.ele").unwrap_err();
    assert!(err.to_string().contains("a.node"), "{err}");
    let _ = obj::read_obj_from(Cursor::new(""), "empty.obj").unwrap();
}
