//! The `softcap` binary: parsing, exit codes, exports.

use std::path::Path;
use std::process::Command;

use clap::Parser;
use softcap_cli::{Cli, Command as Cmd, Verb};
use softcap_mcap::proto::{Marker, MarkerFrame, ProbeSample, TriMesh, Vec3};
use softcap_mcap::{Provenance, Writer, topics};

const BIN: &str = env!("CARGO_BIN_EXE_softcap");

fn v(x: f64, y: f64, z: f64) -> Option<Vec3> {
    Some(Vec3 { x, y, z })
}

fn write_capture(path: &Path) {
    let p = Provenance::new("capture", "0.1.0").with_arguments(["softcap-capture", "x"]);
    let mut w = Writer::create(path, &p).unwrap();
    w.write_static(
        &topics::SURFACE_MESH,
        &TriMesh {
            name: "s".into(),
            frame_id: "world".into(),
            positions_m: vec![0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0],
            triangles: vec![0, 1, 2],
        },
    )
    .unwrap();
    for frame in 0..2u64 {
        let t = frame * 33_000_000;
        w.write(
            &topics::MARKERS,
            t,
            &MarkerFrame {
                frame,
                t_camera_s: 0.033 * frame as f64,
                markers: vec![
                    Marker {
                        id: 3,
                        position_m: v(0.5, 0.25, -0.125),
                        visible: true,
                        views: 3,
                        ..Default::default()
                    },
                    Marker {
                        id: 4,
                        position_m: None,
                        ..Default::default()
                    },
                ],
            },
        )
        .unwrap();
        w.write(
            &topics::PROBE,
            t,
            &ProbeSample {
                frame,
                t_camera_s: 0.5 * frame as f64,
                tip_m: v(0.01, 0.02, 0.03),
                axis: v(0.0, 0.0, -1.0),
                force_n: v(0.0, 0.5, -2.0 * frame as f64),
                voltage_v: 1.5,
            },
        )
        .unwrap();
    }
    w.finish().unwrap();
}

fn softcap(args: &[&str]) -> (i32, String, String) {
    let o = Command::new(BIN).args(args).output().unwrap();
    (
        o.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&o.stdout).into(),
        String::from_utf8_lossy(&o.stderr).into(),
    )
}

#[test]
fn parses_inspect_verbs() {
    let cli = Cli::try_parse_from([
        "softcap",
        "inspect",
        "export",
        "capture.mcap",
        "--what",
        "markers",
        "-o",
        "m.csv",
    ])
    .unwrap();
    match cli.command {
        Cmd::Inspect(i) => match i.verb {
            Verb::Export { file, what, output } => {
                assert_eq!(file, Path::new("capture.mcap"));
                assert_eq!(what, "markers");
                assert_eq!(output, Path::new("m.csv"));
            }
            v => panic!("{v:?}"),
        },
        c => panic!("{c:?}"),
    }
    assert!(matches!(
        Cli::try_parse_from(["softcap", "inspect", "digest", "a.mcap"])
            .unwrap()
            .command,
        Cmd::Inspect(_)
    ));
    // Export needs --what and -o.
    assert!(Cli::try_parse_from(["softcap", "inspect", "export", "a.mcap"]).is_err());
    assert!(Cli::try_parse_from(["softcap", "inspect", "frobnicate", "a.mcap"]).is_err());
    // Unknown top-level commands are stages.
    match Cli::try_parse_from(["softcap", "capture", "DIR", "-o", "c.mcap"])
        .unwrap()
        .command
    {
        Cmd::Stage(args) => assert_eq!(args, ["capture", "DIR", "-o", "c.mcap"]),
        c => panic!("{c:?}"),
    }
}

/// `softcap inspect export <file> --what <what> -o <out>`: (exit code, stderr).
fn export(file: &std::path::Path, what: &str, out: &std::path::Path) -> (i32, String) {
    let (code, _, err) = softcap(&[
        "inspect",
        "export",
        file.to_str().unwrap(),
        "--what",
        what,
        "-o",
        out.to_str().unwrap(),
    ]);
    (code, err)
}

#[test]
fn export_csv_columns_are_exact() {
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("capture.mcap");
    write_capture(&f);
    let m = dir.path().join("m.csv");
    let (code, err) = export(&f, "markers", &m);
    assert_eq!(code, 0, "{err}");
    assert_eq!(
        std::fs::read_to_string(&m).unwrap(),
        "frame,id,x,y,z\n0,3,0.5,0.25,-0.125\n1,3,0.5,0.25,-0.125\n"
    );
    let p = dir.path().join("p.csv");
    let (code, err) = export(&f, "probe", &p);
    assert_eq!(code, 0, "{err}");
    assert_eq!(
        std::fs::read_to_string(&p).unwrap(),
        "frame,t_camera_s,fx,fy,fz,tip_x,tip_y,tip_z\n0,0,0,0.5,0,0.01,0.02,0.03\n1,0.5,0,0.5,-2,0.01,0.02,0.03\n"
    );
    let o = dir.path().join("s.obj");
    let (code, err) = export(&f, "surface", &o);
    assert_eq!(code, 0, "{err}");
    let obj = std::fs::read_to_string(&o).unwrap();
    assert!(
        obj.contains("v 1 0 0\n") && obj.ends_with("f 1 2 3\n"),
        "{obj}"
    );
    // Missing channel: bad input.
    let (code, err) = export(&f, "volume", &o);
    assert_eq!(code, 2);
    assert!(err.contains("/mesh/volume"), "{err}");
}

#[test]
fn summary_channels_dump_digest() {
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("capture.mcap");
    write_capture(&f);
    let fs = f.to_str().unwrap();
    let (code, out, _) = softcap(&["inspect", "summary", fs]);
    assert_eq!(code, 0);
    assert!(
        out.contains("messages:  5") && out.contains("stage:     capture"),
        "{out}"
    );
    let (code, out, _) = softcap(&["inspect", "channels", fs]);
    assert_eq!(code, 0);
    assert!(
        out.contains("/capture/markers\tsoftcap.MarkerFrame\tprotobuf\t2"),
        "{out}"
    );
    let (code, out, err) = softcap(&["inspect", "dump", fs, "--topic", "/capture/probe"]);
    assert_eq!(code, 0, "{err}");
    let lines: Vec<serde_json::Value> = out
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines.len(), 2);
    assert_eq!(lines[1]["log_time_ns"], 33_000_000);
    assert_eq!(lines[1]["message"]["forceN"]["z"], -2.0);
    let (code, d1, _) = softcap(&["inspect", "digest", fs]);
    assert_eq!(code, 0);
    assert_eq!(d1.trim().len(), 64);
}

#[test]
fn corrupt_and_truncated_files_exit_2_naming_file_and_problem() {
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("capture.mcap");
    write_capture(&f);
    let bytes = std::fs::read(&f).unwrap();
    let t = dir.path().join("truncated.mcap");
    std::fs::write(&t, &bytes[..bytes.len() / 2]).unwrap();
    let (code, _, err) = softcap(&["inspect", "summary", t.to_str().unwrap()]);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains(t.to_str().unwrap()) && err.contains("truncated"),
        "{err}"
    );
    let c = dir.path().join("corrupt.mcap");
    std::fs::write(&c, b"this is not an mcap file at all").unwrap();
    let (code, _, err) = softcap(&["inspect", "digest", c.to_str().unwrap()]);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains(c.to_str().unwrap()) && err.contains("magic"),
        "{err}"
    );
    // Bad usage is 2 too.
    let (code, _, _) = softcap(&["inspect", "summary"]);
    assert_eq!(code, 2);
    // Unknown stage: 2 with a clear message.
    let (code, _, err) = softcap(&["no-such-stage-xyz"]);
    assert_eq!(code, 2);
    assert!(err.contains("softcap-no-such-stage-xyz"), "{err}");
}

#[test]
fn plot_extracts_fields_and_writes_png() {
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("capture.mcap");
    write_capture(&f);
    // The extracted series are exactly the written values (frame 0 has force z = 0, a proto3
    // default that the JSON mapping would omit; it must still be read as 0).
    let r = softcap_mcap::Recording::open(&f).unwrap();
    let s = softcap_cli::plot::extract(
        &r,
        "/capture/probe",
        &["force_n.z".into(), "voltage_v".into()],
        None,
    )
    .unwrap();
    assert_eq!(s[0].points, vec![(0.0, 0.0), (0.033, -2.0)]);
    assert_eq!(s[1].points, vec![(0.0, 1.5), (0.033, 1.5)]);
    let m = softcap_cli::plot::extract(
        &r,
        "/capture/markers",
        &["markers[id=3].position_m.z".into()],
        Some("frame"),
    )
    .unwrap();
    assert_eq!(m[0].points, vec![(0.0, -0.125), (1.0, -0.125)]);

    let png = dir.path().join("force.png");
    let (code, out, err) = softcap(&[
        "inspect",
        "plot",
        f.to_str().unwrap(),
        "--topic",
        "/capture/probe",
        "--field",
        "force_n.z",
        "--field",
        "tip_m.x",
        "-o",
        png.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("2 series, 4 points"), "{out}");
    let img = std::fs::read(&png).unwrap();
    assert_eq!(&img[1..4], b"PNG");

    let (code, _, err) = softcap(&[
        "inspect",
        "plot",
        f.to_str().unwrap(),
        "--topic",
        "/capture/probe",
        "--field",
        "force_n.w",
        "-o",
        png.to_str().unwrap(),
    ]);
    assert_eq!(code, 2);
    assert!(err.contains("force_n.w"), "{err}");
}

/// `--help`/`--version` exit 0; a missing or corrupt MCAP is bad input (2) named once.
#[test]
fn exit_codes_of_help_version_missing_and_bad_file() {
    use softcap_app::testing::{assert_error_names_once, assert_help_version_usage, run};
    assert_help_version_usage(BIN);
    let r = run(BIN, &["inspect", "--help"]);
    assert_eq!(r.code, 0, "{r:?}");
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing.mcap");
    let r = run(BIN, &["inspect", "summary", missing.to_str().unwrap()]);
    assert_error_names_once(&r, 2, &missing);
    let bad = dir.path().join("bad.mcap");
    std::fs::write(&bad, b"not an mcap file at all").unwrap();
    let r = run(BIN, &["inspect", "digest", bad.to_str().unwrap()]);
    assert_error_names_once(&r, 2, &bad);
}

/// `--what volume -o X.msh`: a tet mesh channel as Gmsh 4.1 that reads back with the same nodes
/// and tets (the `softcap tissue reshape` output becomes a template again).
#[test]
fn export_volume_as_msh_reads_back() {
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("volume.mcap");
    let p = Provenance::new("tissue reshape", "0.1.0").with_arguments(["softcap-tissue", "x"]);
    let mut w = Writer::create(&f, &p).unwrap();
    let positions_m = vec![
        0.0, 0.0, 0.0, 0.01, 0.0, 0.0, 0.0, 0.02, 0.0, 0.0, 0.0, 0.03, 0.01, 0.02, 0.03,
    ];
    w.write_static(
        &topics::VOLUME_MESH,
        &softcap_mcap::proto::TetMesh {
            name: "v".into(),
            frame_id: "world".into(),
            positions_m: positions_m.clone(),
            tets: vec![0, 1, 2, 3, 1, 2, 3, 4],
            surface_triangles: vec![0, 2, 1],
        },
    )
    .unwrap();
    w.finish().unwrap();
    let o = dir.path().join("v.msh");
    let (code, err) = export(&f, "volume", &o);
    assert_eq!(code, 0, "{err}");
    let m = softcap_mesh::read_msh_tet_mesh(&o).unwrap();
    assert_eq!(m.tets, vec![[0, 1, 2, 3], [1, 2, 3, 4]]);
    let flat: Vec<f64> = m.vertices.iter().flat_map(|v| [v.x, v.y, v.z]).collect();
    assert_eq!(flat, positions_m);
}

/// `--what nodes`: a track.mcap's `/tissue/track/nodes` as `frame,node,x,y,z` (m); a file
/// without that channel exits 2 naming it and writes nothing.
#[test]
fn export_tracked_nodes_as_csv() {
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("track.mcap");
    let p = Provenance::new("tissue track", "0.1.0").with_arguments(["softcap-tissue", "x"]);
    let mut w = Writer::create(&f, &p).unwrap();
    for frame in 0..2u64 {
        let dz = 0.001 * frame as f64;
        w.write(
            &topics::TRACK_NODES,
            frame * 33_333_333,
            &softcap_mcap::proto::NodeFrame {
                frame,
                t_camera_s: frame as f64 / 30.0,
                positions_m: vec![0.0, 0.0, dz, 0.25, -0.5, 0.125 + dz],
            },
        )
        .unwrap();
    }
    w.finish().unwrap();
    let o = dir.path().join("n.csv");
    let (code, err) = export(&f, "nodes", &o);
    assert_eq!(code, 0, "{err}");
    assert_eq!(
        std::fs::read_to_string(&o).unwrap(),
        "frame,node,x,y,z\n0,0,0,0,0\n0,1,0.25,-0.5,0.125\n1,0,0,0,0.001\n1,1,0.25,-0.5,0.126\n"
    );
    let capture = dir.path().join("capture.mcap");
    write_capture(&capture);
    let o2 = dir.path().join("none.csv");
    let (code, err) = export(&capture, "nodes", &o2);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains("capture.mcap") && err.contains("/tissue/track/nodes"),
        "{err}"
    );
    assert!(!o2.exists());
}
