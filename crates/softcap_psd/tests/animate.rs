//! Stage MCAP of `softcap psd animate`: handle trajectory → `/face/mesh` + `/psd/large_scale`
//! round trip against the in-memory run-time synthesis, and bad input (named file / topic /
//! frame / field, exit code 2, no output left behind).

use softcap_mcap::{Provenance, Recording, Topic, proto, topics};
use softcap_psd::*;
use std::path::{Path, PathBuf};
use std::process::Command;

const CM: f64 = 0.01;

fn fixture_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/ict-face")
}

fn provenance() -> Provenance {
    Provenance::new("psd-test", env!("CARGO_PKG_VERSION")).with_seed(1)
}

fn marker_frame(frame: u64, positions: &[[f64; 3]]) -> proto::MarkerFrame {
    proto::MarkerFrame {
        frame,
        t_camera_s: 0.0,
        markers: positions
            .iter()
            .enumerate()
            .map(|(k, p)| proto::Marker {
                id: k as u32,
                position_m: Some(proto::Vec3 {
                    x: p[0],
                    y: p[1],
                    z: p[2],
                }),
                ..Default::default()
            })
            .collect(),
    }
}

fn write_frames(path: &Path, frames: &[proto::MarkerFrame]) {
    let mut w = softcap_mcap::Writer::create(path, &provenance()).unwrap();
    for (i, f) in frames.iter().enumerate() {
        w.write(&topics::MARKERS, i as u64 * 1000, f).unwrap();
    }
    w.finish().unwrap();
}

#[test]
fn animate_mcap_round_trips_the_runtime_frames() {
    let data = IctData::load(fixture_dir()).unwrap();
    let rig = FaceRig::new(&data.mesh, &RigSettings::default()).unwrap();
    let settings = EvaluationSettings {
        training_mixtures: 6,
        heldout_mixtures: 3,
        ..Default::default()
    };
    let (training, heldout) = pose_sets(&data, &settings);
    let poses: Vec<_> = training.iter().map(|r| data.pose(r)).collect();
    let examples = rig.examples(&poses).unwrap();
    let model = fit_wpsd(
        &examples,
        &[0, 4, 9, 14],
        FitMode::Interpolate,
        &rig.edge_weights,
    )
    .unwrap();
    let trajectory = HandleTrajectory {
        frames: heldout
            .iter()
            .enumerate()
            .map(|(i, r)| HandleFrame {
                frame: 10 + i as u64,
                log_time_ns: 33_333_333 * i as u64,
                positions: rig.handle_positions(&data.pose(r)),
            })
            .collect(),
    };
    let dir = tempfile::tempdir().unwrap();
    let markers = dir.path().join("markers.mcap");
    write_handle_trajectory(&markers, &provenance(), &trajectory, CM).unwrap();
    let back = read_handle_trajectory(&markers, rig.handles.len(), CM).unwrap();
    assert_eq!(back.frames.len(), trajectory.frames.len());
    for (a, b) in back.frames.iter().zip(&trajectory.frames) {
        assert_eq!((a.frame, a.log_time_ns), (b.frame, b.log_time_ns));
        for (p, q) in a.positions.iter().zip(&b.positions) {
            assert!((p - q).norm() < 1e-12, "{p} vs {q}");
        }
    }

    let out = dir.path().join("face.mcap");
    let mut anim = Animator::new(&rig, &model).unwrap();
    let summary = animate_to_mcap(
        &mut anim,
        &back,
        &out,
        &provenance(),
        &AnimateSettings::default(),
    )
    .unwrap();
    assert_eq!(summary.frames, 3);

    let rec = Recording::open(&out).unwrap();
    let rest = rec.read_static(&topics::SURFACE_MESH).unwrap();
    assert_eq!(rest.positions_m.len(), 3 * rig.num_vertices());
    assert_eq!(rest.triangles.len(), 3 * rig.topology.triangles.len());
    let faces = rec.read(&topics::FACE_MESH).unwrap();
    let large = rec
        .read(&Topic::<proto::TriMesh>::custom(animate::LARGE_SCALE_TOPIC))
        .unwrap();
    assert_eq!((faces.len(), large.len()), (3, 3));
    let report = rec
        .read_static(&Topic::<proto::Report>::custom(animate::REPORT_TOPIC))
        .unwrap();
    assert!(report.entries.iter().any(|e| e.key == "basis_poses"
        && e.value == Some(proto::key_value::Value::Integer(4))));
    assert!(rec.channel("/viz/face/mesh").is_some());

    // the same frames in memory (a fresh animator, so no state carries over)
    let mut mem = Animator::new(&rig, &model).unwrap();
    let mut max_detail_mm = 0.0f64;
    for ((f, (t_face, face)), (t_large, large)) in back.frames.iter().zip(&faces).zip(&large) {
        assert_eq!((*t_face, *t_large), (f.log_time_ns, f.log_time_ns));
        mem.frame(&f.positions).unwrap();
        for (v, (p, q)) in mem
            .positions
            .iter()
            .zip(mem.large_scale_positions())
            .enumerate()
        {
            for a in 0..3 {
                // exact: the file holds the f32 result widened and scaled to metres
                assert_eq!(face.positions_m[3 * v + a], p[a] as f64 * CM);
                assert_eq!(large.positions_m[3 * v + a], q[a] as f64 * CM);
            }
            let d: f64 = (0..3)
                .map(|a| ((p[a] - q[a]) as f64 * 10.0).powi(2))
                .sum::<f64>()
                .sqrt();
            max_detail_mm = max_detail_mm.max(d);
        }
    }
    // the file carries the WPSD details: final and large-scale surfaces differ
    assert!(max_detail_mm > 0.5, "max detail {max_detail_mm} mm");
}

fn expect_bad(path: &Path, handles: usize, needles: &[&str]) {
    let e = read_handle_trajectory(path, handles, CM).unwrap_err();
    let msg = e.to_string();
    for n in needles {
        assert!(msg.contains(n), "`{msg}` lacks `{n}`");
    }
    assert!(
        matches!(
            e,
            PsdError::BadMessage { .. } | PsdError::BadRecording { .. }
        ),
        "{e:?}"
    );
}

#[test]
fn bad_handle_trajectories_name_file_topic_frame_and_field() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("m.mcap");
    let good = [[0.0, 0.0, 0.0], [0.01, 0.0, 0.0]];
    // missing handle 1 in frame 7
    write_frames(&p, &[marker_frame(3, &good), marker_frame(7, &good[..1])]);
    expect_bad(
        &p,
        2,
        &[
            "m.mcap",
            "/capture/markers",
            "frame 7",
            "no marker for handle 1",
        ],
    );
    // marker id out of range
    write_frames(&p, &[marker_frame(0, &good)]);
    expect_bad(&p, 1, &["frame 0", "markers.id", "1 ≥ 1 handles"]);
    // non-finite coordinate
    write_frames(&p, &[marker_frame(2, &[[0.0, f64::NAN, 0.0], [0.0; 3]])]);
    expect_bad(&p, 2, &["frame 2", "markers.position_m.y", "not finite"]);
    // position missing
    let mut f = marker_frame(4, &good);
    f.markers[0].position_m = None;
    write_frames(&p, &[f]);
    expect_bad(&p, 2, &["frame 4", "markers.position_m"]);
    // duplicate id
    let mut f = marker_frame(5, &good);
    f.markers[1].id = 0;
    write_frames(&p, &[f]);
    expect_bad(&p, 2, &["frame 5", "appears twice"]);
    // no /capture/markers channel
    let mut w = softcap_mcap::Writer::create(&p, &provenance()).unwrap();
    w.write_static(&topics::CLOCK_SYNC, &proto::ClockSync::default())
        .unwrap();
    w.finish().unwrap();
    expect_bad(&p, 2, &["/capture/markers"]);
    // truncated file
    write_frames(&p, &[marker_frame(0, &good)]);
    let bytes = std::fs::read(&p).unwrap();
    std::fs::write(&p, &bytes[..bytes.len() / 2]).unwrap();
    expect_bad(&p, 2, &["m.mcap"]);
}

#[test]
fn cli_exits_2_on_bad_input_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let markers = dir.path().join("bad.mcap");
    // 89 handles expected; frame 1 lacks handle 88
    let all = vec![[0.0; 3]; 89];
    write_frames(
        &markers,
        &[marker_frame(0, &all), marker_frame(1, &all[..88])],
    );
    let out = dir.path().join("face.mcap");
    let o = Command::new(env!("CARGO_BIN_EXE_softcap-psd"))
        .args(["animate", "--fixtures"])
        .arg(fixture_dir())
        .arg("--markers")
        .arg(&markers)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("bad.mcap") && err.contains("frame 1") && err.contains("handle 88"),
        "{err}"
    );
    let left: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(left, vec![std::ffi::OsString::from("bad.mcap")], "{left:?}");
}

/// `--help`/`--version` exit 0; a missing and a malformed marker trajectory are bad input (2),
/// each named once, before any work.
#[test]
fn exit_codes_of_help_version_missing_and_bad_file() {
    use softcap_app::testing::{assert_error_names_once, assert_help_version_usage, run};
    let bin = env!("CARGO_BIN_EXE_softcap-psd");
    assert_help_version_usage(bin);
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.mcap");
    for (name, content) in [
        ("missing.csv", None),
        ("bad.csv", Some("frame,handle,x_cm,y_cm,z_cm\n0,0,1,zz,3\n")),
    ] {
        let markers = dir.path().join(name);
        if let Some(c) = content {
            std::fs::write(&markers, c).unwrap();
        }
        let r = run(
            bin,
            &[
                "animate",
                "--markers",
                markers.to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
            ],
        );
        assert_error_names_once(&r, 2, &markers);
    }
    assert!(!out.exists());
}

/// Crash safety (docs/reliability.md): `psd animate` SIGKILLed at random moments leaves nothing
/// or a complete face.mcap; two processes writing one output at once leave one complete file.
/// `scripts/kill-test` runs 50 trials (`SOFTCAP_KILL_TRIALS`).
#[test]
fn animate_killed_at_random_moments_leaves_nothing_or_a_complete_file() {
    use softcap_app::testing::{kill_trial_count, kill_trials, race_trials};
    let data = IctData::load(fixture_dir()).unwrap();
    let rig = FaceRig::new(&data.mesh, &RigSettings::default()).unwrap();
    let pose = data.pose(&pose_sets(&data, &EvaluationSettings::default()).1[0]);
    let trajectory = HandleTrajectory {
        frames: (0..3)
            .map(|i| HandleFrame {
                frame: i,
                log_time_ns: 33_333_333 * i,
                positions: rig.handle_positions(&pose),
            })
            .collect(),
    };
    let dir = tempfile::tempdir().unwrap();
    let markers = dir.path().join("markers.mcap");
    write_handle_trajectory(&markers, &provenance(), &trajectory, CM).unwrap();
    let out = dir.path().join("face.mcap");
    let animate = || {
        let mut c = Command::new(env!("CARGO_BIN_EXE_softcap-psd"));
        c.args(["animate", "--fixtures"]).arg(fixture_dir());
        c.arg("--markers").arg(&markers).arg("--out").arg(&out);
        c
    };
    let complete = |p: &Path| Recording::open(p).map(|_| ()).map_err(|e| e.to_string());
    // One kill in `make test` (a run is ≈ 10 s in the test profile); scripts/kill-test runs 50.
    let tally = kill_trials(&animate, &out, kill_trial_count(1), 321, &complete);
    let raced = race_trials(&animate, &out, kill_trial_count(0), &complete);
    eprintln!("psd animate: {tally:?}, {raced} race trials");
}
