//! Stage output: `face.mcap` round trip (meshes, wrinkle parameters, /viz twins) and the
//! `softcap-face run` command (exit code 2 naming the bad file).

use softcap_face::nalgebra::{Isometry3, Vector3};
use softcap_face::{
    FaceFrame, PinholeCamera, WrinkleCurve, WrinkleSample, project_wrinkle, wrinkles_message,
    write_face_mcap,
};
use softcap_mcap::{Provenance, Recording, topics};
use softcap_mesh::TriMesh;

fn patch() -> TriMesh {
    let n = 11;
    let mut vertices = Vec::new();
    for j in 0..n {
        for i in 0..n {
            vertices.push(Vector3::new(
                i as f64 * 0.1 - 0.5,
                j as f64 * 0.1 - 0.5,
                0.0,
            ));
        }
    }
    let mut triangles = Vec::new();
    for j in 0..n - 1 {
        for i in 0..n - 1 {
            let v = j * n + i;
            triangles.push([v, v + 1, v + n + 1]);
            triangles.push([v, v + n + 1, v + n]);
        }
    }
    TriMesh {
        vertices,
        triangles,
    }
}

#[test]
fn face_mcap_round_trip() {
    let mesh = patch();
    let cam = PinholeCamera {
        world_from_camera: Isometry3::new(
            Vector3::new(0.0, 0.0, 10.0),
            Vector3::new(std::f64::consts::PI, 0.0, 0.0),
        ),
        focal_px: 1000.0,
        principal_px: [500.0, 500.0],
    };
    let curve = WrinkleCurve {
        samples: (0..5)
            .map(|k| WrinkleSample {
                valley_px: [460.0 + 20.0 * k as f64, 500.0],
                depth_px: 3.0,
                width_px: 6.0,
            })
            .collect(),
    };
    let projected = project_wrinkle(&mesh.vertices, &mesh.triangles, &cam, &curve);
    let frames: Vec<FaceFrame> = (0..3)
        .map(|k| FaceFrame {
            frame: 100 + k,
            t_s: k as f64 / 60.0,
            vertices: mesh
                .vertices
                .iter()
                .map(|v| v + Vector3::new(0.0, 0.0, 0.01 * k as f64))
                .collect(),
            wrinkles: if k == 1 {
                vec![(curve.clone(), Some(projected.clone()))]
            } else {
                Vec::new()
            },
        })
        .collect();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("face.mcap");
    let prov = Provenance::new("face", "test");
    write_face_mcap(&path, &prov, &mesh, &frames, 0.01).unwrap();
    let rec = Recording::open(&path).unwrap();
    let rest = rec.read_static(&topics::SURFACE_MESH).unwrap();
    assert_eq!(rest.positions_m.len(), 3 * mesh.vertices.len());
    assert_eq!(rest.triangles.len(), 3 * mesh.triangles.len());
    let meshes = rec.read(&topics::FACE_MESH).unwrap();
    assert_eq!(meshes.len(), 3);
    for (k, (t_ns, m)) in meshes.iter().enumerate() {
        assert_eq!(*t_ns, (k as f64 / 60.0 * 1e9).round() as u64);
        for (v, x) in frames[k].vertices.iter().enumerate() {
            for a in 0..3 {
                assert!((m.positions_m[3 * v + a] - 0.01 * x[a]).abs() < 1e-15);
            }
        }
    }
    let wr = rec.read(&topics::FACE_WRINKLES).unwrap();
    assert_eq!(wr.len(), 1);
    assert_eq!(wr[0].1, wrinkles_message(&frames[1], 0.01));
    let s = &wr[0].1.wrinkles[0].sections[2];
    // 0.01 cm per px at 10 cm, 0.01 m per cm: w = 6 px = 0.06 cm = 6e-4 m
    assert!((s.width_m - 6e-4).abs() < 1e-12 && (s.depth_m - 3e-4).abs() < 1e-12);
    for t in ["/viz/mesh/surface", "/viz/face/mesh", "/viz/face/wrinkles"] {
        assert!(rec.channel(t).is_some(), "{t}");
    }
}

fn fixtures() -> std::path::PathBuf {
    std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../fixtures")
}

#[test]
fn run_writes_mcap_and_bad_input_exits_2_naming_the_file() {
    let exe = env!("CARGO_BIN_EXE_softcap-face");
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("face.mcap");
    let mocap = fixtures().join("animface-mocap/jaw_subset.csv");
    let face = fixtures().join("ict-face/neutral.obj");
    let landmarks = fixtures().join("animface-mocap/ict_landmarks.csv");
    let args = |extra: &[&std::ffi::OsStr]| {
        let mut c = std::process::Command::new(exe);
        c.arg("run")
            .arg("--mocap")
            .arg(&mocap)
            .arg("--face")
            .arg(&face)
            .arg("--landmarks")
            .arg(&landmarks)
            .arg("-o")
            .arg(&out)
            .args(extra);
        c
    };
    // bad wrinkle file: exit 2, message names it, nothing written
    let bad = dir.path().join("bad_wrinkles.json");
    std::fs::write(&bad, "{ \"camera\": 3 ").unwrap();
    let o = args(&["--wrinkles".as_ref(), bad.as_os_str()])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("bad_wrinkles.json"));
    assert!(!out.exists());
    // a wrinkle sample with a negative width: exit 2 naming the file and the sample
    let neg = dir.path().join("neg_width.json");
    std::fs::write(
        &neg,
        r#"{ "camera": { "world_from_camera": { "rotation": [0.0, 0.0, 0.0, 1.0], "translation": [0.0, 0.0, 60.0] },
             "focal_px": 1000.0, "principal_px": [500.0, 500.0] },
           "frames": [ { "frame": 390, "wrinkles": [ { "samples": [
               { "valley_px": [500.0, 400.0], "depth_px": 2.0, "width_px": 5.0 },
               { "valley_px": [510.0, 400.0], "depth_px": 2.0, "width_px": -5.0 } ] } ] } ] }"#,
    )
    .unwrap();
    let o = args(&["--wrinkles".as_ref(), neg.as_os_str()])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("neg_width.json") && err.contains("sample 1"),
        "{err}"
    );
    assert!(!out.exists());
    // two markers on one vertex in the landmark table: exit 2 naming the table
    let dup = dir.path().join("dup_landmarks.csv");
    let table = std::fs::read_to_string(&landmarks).unwrap();
    let mut lines: Vec<String> = table.lines().map(String::from).collect();
    let first_vertex = lines[1].split(',').nth(1).unwrap().to_string();
    let mut cols: Vec<String> = lines[2].split(',').map(String::from).collect();
    cols[1] = first_vertex;
    lines[2] = cols.join(",");
    std::fs::write(&dup, lines.join("\n")).unwrap();
    let o = std::process::Command::new(exe)
        .arg("run")
        .arg("--mocap")
        .arg(&mocap)
        .arg("--face")
        .arg(&face)
        .arg("--landmarks")
        .arg(&dup)
        .arg("-o")
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("dup_landmarks.csv"), "{err}");
    assert!(!out.exists());
    // missing frame: exit 2 naming the take
    let o = args(&["--frames".as_ref(), "999999".as_ref()])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("jaw_subset.csv"));
    // a real run: frames 0 and 390 of the jaw take
    let o = args(&["--frames".as_ref(), "0,390".as_ref()])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let rec = Recording::open(&out).unwrap();
    let meshes = rec.read(&topics::FACE_MESH).unwrap();
    assert_eq!(meshes.len(), 2);
    let rest = rec.read_static(&topics::SURFACE_MESH).unwrap();
    // frame 0 is the neutral pose (correspondence → zero displacement); frame 390 opens the jaw
    let max_move = |m: &softcap_mcap::proto::TriMesh| {
        m.positions_m
            .iter()
            .zip(&rest.positions_m)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max)
    };
    assert!(max_move(&meshes[0].1) < 1e-9);
    assert!(max_move(&meshes[1].1) > 0.01, "jaw opens by more than 1 cm");
}

/// `--help`/`--version` exit 0; a missing and a malformed mocap take are bad input (2), each
/// named once.
#[test]
fn exit_codes_of_help_version_missing_and_bad_file() {
    use softcap_app::testing::{assert_error_names_once, assert_help_version_usage, run};
    let bin = env!("CARGO_BIN_EXE_softcap-face");
    assert_help_version_usage(bin);
    let dir = tempfile::tempdir().unwrap();
    let face = dir.path().join("face.obj");
    let out = dir.path().join("table.csv");
    for (name, content) in [("missing.csv", None), ("bad.csv", Some("no,header\nx,y\n"))] {
        let take = dir.path().join(name);
        if let Some(c) = content {
            std::fs::write(&take, c).unwrap();
        }
        let r = run(
            bin,
            &[
                "landmarks",
                "--mocap",
                take.to_str().unwrap(),
                "--face",
                face.to_str().unwrap(),
                "-o",
                out.to_str().unwrap(),
            ],
        );
        assert_error_names_once(&r, 2, &take);
    }
    assert!(!out.exists());
}
