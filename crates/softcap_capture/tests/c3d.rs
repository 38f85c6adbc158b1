//! C3D takes (fixtures/c3d: the ezc3d test files Optotrak, Qualisys and Vicon, the latter two trimmed
//! to 40 frames): marker counts, rates, analog channels, and values checked against a raw decode of
//! the files (C3D float format: 4 × f32 per point; analog f32 with SCALE 1, OFFSET 0 in these files).

use crate::common;

use softcap_capture::read_c3d;

struct Expect {
    file: &'static str,
    markers: usize,
    frames: usize,
    rate_hz: f64,
    first_label: &'static str,
    analog_channels: usize,
    analog_rate_hz: f64,
    first_analog: &'static str,
    /// Frame 0, marker 0, mm (raw decode).
    p0_mm: [f64; 3],
    /// Analog channel 2, sample 0 (raw decode).
    a2_0: Option<f64>,
}

const TAKES: [Expect; 3] = [
    Expect {
        file: "Optotrak.c3d",
        markers: 54,
        frames: 29,
        rate_hz: 30.0,
        first_label: "Marker_1",
        analog_channels: 0,
        analog_rate_hz: 0.0,
        first_analog: "",
        p0_mm: [326.3137512207031, 328.6311340332031, -366.1706237792969],
        a2_0: None,
    },
    Expect {
        file: "Qualisys.c3d",
        markers: 55,
        frames: 40,
        rate_hz: 200.0,
        first_label: "L_IAS",
        analog_channels: 69,
        analog_rate_hz: 2000.0,
        first_analog: "FP1_FX",
        p0_mm: [-220.12261962890625, 306.4248046875, 846.3361206054688],
        a2_0: Some(-0.24925613403320312),
    },
    Expect {
        file: "Vicon.c3d",
        markers: 51,
        frames: 40,
        rate_hz: 100.0,
        first_label: "boite:gauche_ext",
        analog_channels: 38,
        analog_rate_hz: 2000.0,
        first_analog: "Voltage.1",
        p0_mm: [44.16278839111328, -276.8619384765625, 675.6968383789062],
        a2_0: Some(-0.01544412225484848),
    },
];

#[test]
fn three_takes_load_with_marker_counts_rates_and_analog_channels() {
    for e in &TAKES {
        let t = read_c3d(&common::fixture("c3d").join(e.file)).unwrap();
        println!(
            "{}: {} markers × {} frames at {} Hz; {} analog channels at {} Hz",
            e.file,
            t.marker_labels.len(),
            t.frames(),
            t.frame_rate_hz,
            t.analog.labels.len(),
            t.analog.rate_hz
        );
        assert_eq!(t.marker_labels.len(), e.markers, "{}", e.file);
        assert_eq!(t.frames(), e.frames, "{}", e.file);
        assert_eq!(t.frame_rate_hz, e.rate_hz, "{}", e.file);
        assert_eq!(t.marker_labels[0], e.first_label);
        assert_eq!(t.analog.labels.len(), e.analog_channels, "{}", e.file);
        assert!(t.positions_m.iter().all(|f| f.len() == e.markers));
        let p = t.positions_m[0][0].expect("marker 0 valid in frame 0");
        for k in 0..3 {
            assert!((p[k] - e.p0_mm[k] * 1e-3).abs() < 1e-9, "{} {p}", e.file);
        }
        if e.analog_channels > 0 {
            assert_eq!(t.analog.rate_hz, e.analog_rate_hz);
            assert_eq!(t.analog.labels[0], e.first_analog);
            let per_frame = (e.analog_rate_hz / e.rate_hz).round() as usize;
            for s in &t.analog.samples {
                assert_eq!(s.len(), e.frames * per_frame, "{}", e.file);
            }
            let a = t.analog.samples[2][0];
            assert!((a - e.a2_0.unwrap()).abs() < 1e-9, "{} analog {a}", e.file);
        }
    }
}

#[test]
fn qualisys_force_plate_channels_are_labeled() {
    let t = read_c3d(&common::fixture("c3d").join("Qualisys.c3d")).unwrap();
    for (plate, sep, first) in [("FP1", "_", 0), ("PF2", "-", 10)] {
        for (k, axis) in ["FX", "FY", "FZ", "MX", "MY", "MZ"].iter().enumerate() {
            let label = format!("{plate}{sep}{axis}");
            assert_eq!(t.analog_index(&label), Some(first + k), "{label}");
        }
    }
    assert_eq!(t.analog_index("Sync"), Some(56));
    assert!(t.analog.units[..6].iter().all(|u| u == "V"));
}

#[test]
fn trimmed_fixtures_equal_the_first_frames_of_the_full_takes() {
    // The full takes live in shared/data/c3d beside the repository; the check is skipped where
    // they are absent (the fixture tests above stand on their own).
    let manifest = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let Some(shared) = manifest
        .ancestors()
        .map(|a| a.join("shared/data/c3d"))
        .find(|p| p.is_dir())
    else {
        println!("shared/data/c3d absent; skipped");
        return;
    };
    for name in ["Qualisys.c3d", "Vicon.c3d"] {
        let full_path = shared.join(name);
        let full = read_c3d(&full_path).unwrap();
        let trimmed = read_c3d(&common::fixture("c3d").join(name)).unwrap();
        assert!(full.frames() > trimmed.frames());
        assert_eq!(
            full.positions_m[..trimmed.frames()],
            trimmed.positions_m[..]
        );
        let n = trimmed.analog.samples[0].len();
        for (a, b) in full.analog.samples.iter().zip(&trimmed.analog.samples) {
            assert_eq!(&a[..n], &b[..]);
        }
    }
}

#[test]
fn truncated_c3d_is_bad_input_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("cut.c3d");
    let bytes = std::fs::read(common::fixture("c3d").join("Optotrak.c3d")).unwrap();
    std::fs::write(&p, &bytes[..1000]).unwrap();
    let e = read_c3d(&p).unwrap_err();
    assert!(e.to_string().contains("cut.c3d"), "{e}");
}

/// A `mocap` session (fixtures/c3d/qualisys-session: `files.c3d` + a 4-marker template) through the
/// capture stage and the binary: 40 frames at 200 Hz, markers equal the take's, analog carried.
#[test]
fn mocap_session_captures_the_template_markers_from_the_take() {
    use softcap_capture::{CaptureSettings, MarkerState, Session, SessionKind, capture};
    let dir = common::fixture("c3d/qualisys-session");
    let session = Session::load(&dir).unwrap();
    assert_eq!(session.kind, SessionKind::Mocap);
    let r = capture(&session, &CaptureSettings::default()).unwrap();
    let take = read_c3d(&common::fixture("c3d/Qualisys.c3d")).unwrap();
    assert_eq!(r.frames.len(), 40);
    assert_eq!(r.marker_ids, ["L_IAS", "L_IPS", "R_IPS", "R_IAS"]);
    assert!((r.frames[39].t_camera_s - 39.0 / 200.0).abs() < 1e-12);
    for f in &r.frames {
        for (m, s) in f.markers.iter().enumerate() {
            let c = take.marker_index(&r.marker_ids[m]).unwrap();
            match take.positions_m[f.frame][c] {
                Some(p) => {
                    assert_eq!(s.state, MarkerState::Visible);
                    assert_eq!(s.position_m, p);
                }
                None => assert_eq!(s.state, MarkerState::Missing),
            }
        }
    }
    assert_eq!(r.analog.as_ref().unwrap().labels.len(), 69);

    let out_dir = tempfile::tempdir().unwrap();
    let out = out_dir.path().join("capture.mcap");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_softcap-capture"))
        .arg(&dir)
        .arg("-o")
        .arg(&out)
        .output()
        .unwrap();
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let rec = softcap_mcap::Recording::open(&out).unwrap();
    assert_eq!(rec.read(&softcap_mcap::topics::MARKERS).unwrap().len(), 40);
}

#[test]
fn mocap_template_marker_missing_from_the_take_is_bad_input_naming_it() {
    let (_tmp, dir) = common::session_copy("c3d/qualisys-session");
    std::fs::copy(common::fixture("c3d/Qualisys.c3d"), dir.join("take.c3d")).unwrap();
    let toml = std::fs::read_to_string(dir.join("session.toml")).unwrap();
    std::fs::write(
        dir.join("session.toml"),
        toml.replace("\"Qualisys.c3d\"", "\"take.c3d\""),
    )
    .unwrap();
    let csv = dir.join("template/markers.csv");
    let text = std::fs::read_to_string(&csv).unwrap();
    std::fs::write(&csv, text + "NOSE,0,0,0,white\n").unwrap();
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_softcap-capture"))
        .arg(&dir)
        .arg("-o")
        .arg(dir.join("out.mcap"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("marker `NOSE`") && err.contains("take.c3d"),
        "{err}"
    );
    assert!(!dir.join("out.mcap").exists());
}
