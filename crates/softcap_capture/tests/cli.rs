//! The `softcap-capture` binary: exit codes and messages on bad input, and a full run writing
//! capture.mcap that reads back.

use crate::common;

use std::path::{Path, PathBuf};
use std::process::Command;

fn copy_dir(src: &Path, dst: &Path) {
    std::fs::create_dir_all(dst).unwrap();
    for e in std::fs::read_dir(src).unwrap() {
        let e = e.unwrap();
        let to = dst.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            if e.file_name() != "truth" {
                copy_dir(&e.path(), &to);
            }
        } else {
            std::fs::copy(e.path(), &to).unwrap();
        }
    }
}

/// A writable copy of session-min (without truth/).
fn session_copy() -> (tempfile::TempDir, PathBuf) {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("session");
    copy_dir(&common::fixture("session-min"), &dir);
    (tmp, dir)
}

fn edit(path: &Path, f: impl FnOnce(String) -> String) {
    let text = std::fs::read_to_string(path).unwrap();
    std::fs::write(path, f(text)).unwrap();
}

/// Runs the binary on `dir` with detections; returns (exit code, stderr, output path).
fn run(dir: &Path) -> (i32, String, PathBuf) {
    let out = dir.parent().unwrap().join("capture.mcap");
    let o = Command::new(env!("CARGO_BIN_EXE_softcap-capture"))
        .arg(dir)
        .arg("-o")
        .arg(&out)
        .args(["--source", "detections"])
        .output()
        .unwrap();
    (
        o.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&o.stderr).into_owned(),
        out,
    )
}

fn assert_bad_input(dir: &Path, needles: &[&str]) {
    let (code, err, out) = run(dir);
    println!("{err}");
    assert_eq!(code, 2, "exit code; stderr: {err}");
    for n in needles {
        assert!(err.contains(n), "stderr lacks `{n}`: {err}");
    }
    assert!(!out.exists(), "no output on bad input");
    assert!(
        std::fs::read_dir(out.parent().unwrap()).unwrap().all(|e| !e
            .unwrap()
            .file_name()
            .to_string_lossy()
            .ends_with(".tmp")),
        "no temporary left behind"
    );
}

#[test]
fn missing_file_names_the_file() {
    let (_t, dir) = session_copy();
    std::fs::remove_file(dir.join("trigger.csv")).unwrap();
    assert_bad_input(&dir, &["trigger.csv", "cannot read"]);
}

/// session.toml may only name files inside the session folder: an absolute path, a `..` escape
/// and a symlink out of the folder are each exit 2 naming the key and session.toml.
#[test]
fn session_paths_outside_the_folder_are_refused() {
    let (tmp, dir) = session_copy();
    let outside = tmp.path().join("markers.csv");
    std::fs::copy(dir.join("template/markers.csv"), &outside).unwrap();
    let manifest = dir.join("session.toml");
    let original = std::fs::read_to_string(&manifest).unwrap();
    let named = |name: &str| original.replace("\"template/markers.csv\"", &format!("{name:?}"));
    std::fs::write(&manifest, named(&outside.display().to_string())).unwrap();
    assert_bad_input(&dir, &["session.toml", "files.markers", "absolute"]);
    std::fs::write(&manifest, named("template/../../markers.csv")).unwrap();
    assert_bad_input(
        &dir,
        &["session.toml", "files.markers", "leaves the folder"],
    );
    #[cfg(unix)]
    {
        std::os::unix::fs::symlink(tmp.path(), dir.join("up")).unwrap();
        std::fs::write(&manifest, named("up/markers.csv")).unwrap();
        assert_bad_input(&dir, &["session.toml", "files.markers", "symlink"]);
    }
}

/// NaN or ±Inf anywhere in numeric input is exit 2 naming the file, the line and the field:
/// a TOML `nan` / `-inf` (valid TOML) and a CSV `NaN` / `inf`.
#[test]
fn non_finite_numbers_name_file_line_and_field() {
    let (_tmp, dir) = session_copy();
    edit(&dir.join("rig/cameras.toml"), |t| {
        t.replacen("fx = 711.936538", "fx = nan", 1)
    });
    assert_bad_input(
        &dir,
        &["cameras.toml:5", "camera[0].fx", "not a finite number"],
    );
    let (_tmp, dir) = session_copy();
    edit(&dir.join("rig/fsr.toml"), |t| {
        t.replace("supply_v = 5.0", "supply_v = -inf")
    });
    assert_bad_input(&dir, &["fsr.toml:1", "supply_v", "not a finite number"]);
    let (_tmp, dir) = session_copy();
    edit(&dir.join("detections/cam0.csv"), |t| {
        t.replacen("438.438", "NaN", 1)
    });
    assert_bad_input(&dir, &["cam0.csv", "2", "u", "finite"]);
    let (_tmp, dir) = session_copy();
    edit(&dir.join("fsr.csv"), |t| t.replacen("0.00488", "inf", 1));
    assert_bad_input(&dir, &["fsr.csv", "2", "voltage_v", "finite"]);
}

#[test]
fn malformed_toml_names_file_and_line() {
    let (_t, dir) = session_copy();
    edit(&dir.join("rig/cameras.toml"), |s| {
        s.replacen("fx = 711.936538", "fx = = 711.9", 1)
    });
    assert_bad_input(&dir, &["rig/cameras.toml:5"]);
}

#[test]
fn malformed_csv_line_names_file_line_and_field() {
    let (_t, dir) = session_copy();
    edit(&dir.join("detections/cam1.csv"), |s| {
        let mut lines: Vec<String> = s.lines().map(str::to_string).collect();
        lines[6] = "0,abc,12.0,blue".into();
        lines.join("\n") + "\n"
    });
    assert_bad_input(&dir, &["detections/cam1.csv:7", "field `u`", "abc"]);
}

#[test]
fn singular_camera_names_the_camera() {
    let (_t, dir) = session_copy();
    edit(&dir.join("rig/cameras.toml"), |s| {
        s.replacen("fy = 710.775901", "fy = 0.0", 1)
    });
    assert_bad_input(&dir, &["rig/cameras.toml", "camera `cam1`", "singular"]);
}

#[test]
fn marker_in_fewer_than_two_views_names_the_marker() {
    // Without a template surface nothing can fill m25, which only camera 1 sees.
    let (_t, dir) = session_copy();
    edit(&dir.join("session.toml"), |s| {
        s.replace("surface = \"template/surface.obj\"\n", "")
    });
    assert_bad_input(&dir, &["marker `m25`", "fewer than two views"]);
}

#[test]
fn full_run_writes_a_readable_capture_mcap() {
    let (_t, dir) = session_copy();
    let (code, err, out) = run(&dir);
    assert_eq!(code, 0, "{err}");
    let rec = softcap_mcap::Recording::open(&out).unwrap();
    let frames = rec.read(&softcap_mcap::topics::MARKERS).unwrap();
    assert_eq!(frames.len(), 33);
    let probe = rec.read(&softcap_mcap::topics::PROBE).unwrap();
    assert_eq!(probe.len(), 33);
    let f24 = &probe[24].1;
    let force = f24.force_n.as_ref().unwrap();
    assert!((force.z - -1.816).abs() < 0.06, "frame 24 force {force:?}");
    let sync = rec.read_static(&softcap_mcap::topics::CLOCK_SYNC).unwrap();
    // Message convention t_camera = (1 + drift)·t_daq + offset: offset ≈ −2.898 s.
    assert!((sync.offset_s + 2.898387).abs() < 2e-3, "{sync:?}");
    assert!(rec.channel("/viz/capture/markers").is_some());
    assert!(rec.provenance().unwrap().is_some());
    assert!(err.contains("wrote"));

    // /capture/session through the typed reader shared by tissue and diagnose.
    let data = softcap_mcap::CaptureData::read(&out).unwrap();
    let info = &data.session;
    assert_eq!(info.name, "session-min");
    assert_eq!(info.kind, "probe");
    assert_eq!(info.object_markers, 37);
    assert_eq!(info.marker_ids.len(), 39); // 37 object + 2 shaft markers
    assert_eq!(info.marker_ids[0], "m00");
    // template/markers.csv m00 = (3.06336, 4.05583, 20) mm.
    let m00 = info.rest_positions_m[0];
    assert!((m00[0] - 3.06336e-3).abs() < 1e-12 && (m00[2] - 0.02).abs() < 1e-12);
    assert_eq!(info.gravity_m_s2, [0.0, 0.0, -9.81]);
    let support = info.support.unwrap();
    assert_eq!(support.normal, [0.0, 0.0, 1.0]);
    assert!((support.tolerance_m - 0.5e-3).abs() < 1e-15);
    assert_eq!(info.density_kg_m3, Some(1050.0));
    assert_eq!(info.tip_shape, "disk");
    assert!((info.tip_radius_m - 5e-3).abs() < 1e-15);
    assert_eq!(info.shaft_direction, "handle-to-tip");
    assert!(info.trigger_present);
    assert_eq!(data.frames.len(), 33);
    assert!(data.frames.iter().all(|f| f.probe.is_some()));
    // truth/README.md: two probe locations, (19.49, 6.38) and (20.51, 20.08) mm.
    let locations = data.probe_locations(&Default::default());
    assert_eq!(locations.len(), 2, "{locations:?}");
    for (l, (x, y)) in locations
        .iter()
        .zip([(19.49e-3, 6.38e-3), (20.51e-3, 20.08e-3)])
    {
        let tip = l.first_tip_m;
        assert!(((tip[0] - x).hypot(tip[1] - y)) < 1.5e-3, "{tip:?}");
    }
}

/// `--help`/`--version` exit 0; a missing session folder and a malformed session.toml are bad
/// input (2), each named once.
#[test]
fn exit_codes_of_help_version_missing_and_bad_file() {
    use softcap_app::testing::{assert_error_names_once, assert_help_version_usage, run};
    let bin = env!("CARGO_BIN_EXE_softcap-capture");
    assert_help_version_usage(bin);
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("c.mcap");
    let missing = dir.path().join("no-session");
    let r = run(
        bin,
        &[missing.to_str().unwrap(), "-o", out.to_str().unwrap()],
    );
    assert_error_names_once(&r, 2, &missing.join("session.toml"));
    let bad = dir.path().join("bad");
    std::fs::create_dir(&bad).unwrap();
    std::fs::write(bad.join("session.toml"), "format = [\n").unwrap();
    let r = run(bin, &[bad.to_str().unwrap(), "-o", out.to_str().unwrap()]);
    assert_error_names_once(&r, 2, &bad.join("session.toml"));
    assert!(!out.exists());
}

/// Crash safety (docs/reliability.md): capture SIGKILLed at random moments leaves nothing or a
/// complete capture.mcap; two processes writing one output at once leave one complete file.
/// `scripts/kill-test` runs 50 trials (`SOFTCAP_KILL_TRIALS`).
#[test]
fn capture_killed_at_random_moments_leaves_nothing_or_a_complete_file() {
    use softcap_app::testing::{kill_trial_count, kill_trials, race_trials};
    let (_tmp, dir) = session_copy();
    let out = dir.parent().unwrap().join("capture.mcap");
    let capture = || {
        let mut c = Command::new(env!("CARGO_BIN_EXE_softcap-capture"));
        c.arg(&dir)
            .arg("-o")
            .arg(&out)
            .args(["--source", "detections"]);
        c
    };
    let complete = |p: &Path| {
        softcap_mcap::Recording::open(p)
            .map(|_| ())
            .map_err(|e| e.to_string())
    };
    let tally = kill_trials(&capture, &out, kill_trial_count(3), 301, &complete);
    let raced = race_trials(&capture, &out, kill_trial_count(1), &complete);
    eprintln!("capture: {tally:?}, {raced} race trials");
}
