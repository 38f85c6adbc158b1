//! Sessions written by the virtual rig: layout, determinism, physical sanity of the truth.

use sha2::{Digest, Sha256};
use softcap_synth::{Effect, Scenario, SynthError, synthesize};
use std::collections::BTreeMap;
use std::path::Path;

fn small(name: &str, seed: u64) -> Scenario {
    let mut s = Scenario {
        name: name.into(),
        seed,
        ..Default::default()
    };
    s.object.fit_cells = [4, 4, 2];
    s.object.truth_cells = [6, 6, 3];
    s.protocol.locations = 2;
    s.protocol.ramp_frames = 3;
    s.protocol.hold_frames = 1;
    s.protocol.release_frames = 2;
    s.protocol.move_frames = 1;
    s
}

fn hashes(dir: &Path) -> BTreeMap<String, String> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                let rel = p.strip_prefix(dir).unwrap().to_string_lossy().to_string();
                out.insert(rel, hex::encode(Sha256::digest(std::fs::read(&p).unwrap())));
            }
        }
    }
    out
}

#[test]
fn same_seed_gives_identical_files_and_another_seed_does_not() {
    let tmp = tempfile::tempdir().unwrap();
    let mut s = small("det", 7);
    s.output.images = true;
    s.rig.width = 320;
    s.rig.height = 240;
    s.rig.focal_px = 310.0;
    let a = synthesize(&s, &tmp.path().join("a")).unwrap();
    let b = synthesize(&s, &tmp.path().join("b")).unwrap();
    assert_eq!(a.frames, b.frames);
    let (ha, hb) = (hashes(&a.path), hashes(&b.path));
    assert!(ha.len() > 20, "{} files", ha.len());
    assert_eq!(ha, hb, "same seed ⇒ byte-identical files");
    s.seed = 8;
    let c = synthesize(&s, &tmp.path().join("c")).unwrap();
    let hc = hashes(&c.path);
    assert_ne!(ha["detections/cam0.csv"], hc["detections/cam0.csv"]);
    assert_ne!(ha["truth/markers.csv"], hc["truth/markers.csv"]);
}

#[test]
fn session_layout_and_truth_are_consistent() {
    let tmp = tempfile::tempdir().unwrap();
    let s = small("layout", 3);
    let r = synthesize(&s, &tmp.path().join("s")).unwrap();
    // 1 rest frame + 2 locations × (3 + 1 + 2 + 1).
    assert_eq!(r.frames, 1 + 2 * 7);
    assert_eq!(r.truth_tets, 6 * 6 * 6 * 3);
    assert_eq!(r.fit_tets, 6 * 4 * 4 * 2);
    for f in [
        "session.toml",
        "rig/cameras.toml",
        "rig/fsr.toml",
        "rig/probe.toml",
        "template/markers.csv",
        "template/surface.obj",
        "template/volume.msh",
        "detections/cam0.csv",
        "detections/cam2.csv",
        "trigger.csv",
        "fsr.csv",
        "truth/markers.csv",
        "truth/probe.csv",
        "truth/clock.toml",
        "truth/README.md",
    ] {
        assert!(r.path.join(f).is_file(), "{f} missing");
    }
    let readme = std::fs::read_to_string(r.path.join("truth/README.md")).unwrap();
    assert!(readme.contains("none (CLEAN)"), "{readme}");
    let fsr = std::fs::read_to_string(r.path.join("fsr.csv")).unwrap();
    assert!(fsr.starts_with("t_daq_s,voltage_v,trigger_v\n"));
    // The rest frame has no force; loading frames push down (fz < 0) with |f| growing.
    let probe = std::fs::read_to_string(r.path.join("truth/probe.csv")).unwrap();
    let rows: Vec<Vec<f64>> = probe
        .lines()
        .skip(1)
        .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
        .collect();
    assert_eq!(rows[0][4], 0.0);
    assert!(rows[1][4] < 0.0 && rows[2][4] < rows[1][4] && rows[3][4] < rows[2][4]);
    // Frictionless flat disk pushed straight down: the force is vertical.
    assert!(rows[3][2].abs() < 1e-3 * rows[3][4].abs(), "{:?}", rows[3]);
    // Truth markers of frame 0 equal the template.
    let tmpl = std::fs::read_to_string(r.path.join("template/markers.csv")).unwrap();
    let truth = std::fs::read_to_string(r.path.join("truth/markers.csv")).unwrap();
    for (a, b) in tmpl.lines().skip(1).zip(truth.lines().skip(1)) {
        let a: Vec<&str> = a.split(',').collect();
        let b: Vec<&str> = b.split(',').collect();
        assert_eq!(b[0], "0");
        assert_eq!(&a[0..4], &b[1..5]);
    }
    assert!(r.max_marker_displacement_m > 0.5e-3 && r.max_marker_displacement_m < 5e-3);
}

#[test]
fn clock_offset_removes_the_trigger_line_and_moves_the_daq_clock() {
    let tmp = tempfile::tempdir().unwrap();
    let mut s = small("clock", 5);
    s.effects = vec![Effect::ClockOffset];
    let r = synthesize(&s, &tmp.path().join("c")).unwrap();
    let fsr = std::fs::read_to_string(r.path.join("fsr.csv")).unwrap();
    assert!(fsr.starts_with("t_daq_s,voltage_v\n"));
    let clock = std::fs::read_to_string(r.path.join("truth/clock.toml")).unwrap();
    let expect = s.clock.offset_s + s.effect_settings.clock_extra_offset_s;
    assert!(
        clock.contains(&format!("offset_s = {expect:.9}")),
        "{clock}"
    );
    let readme = std::fs::read_to_string(r.path.join("truth/README.md")).unwrap();
    assert!(readme.contains("clock-offset"));
}

#[test]
fn bad_scenarios_name_the_field_and_write_nothing() {
    let e = Scenario::parse(
        Path::new("x.toml"),
        "name = \"x\"\n[object]\nsize_mm = [40, 40, -1]\n",
    )
    .unwrap_err();
    assert!(e.to_string().contains("object.size_mm[2]"), "{e}");
    let e = Scenario::parse(
        Path::new("x.toml"),
        "name = \"x\"\neffects = [\"telepathy\"]\n",
    )
    .unwrap_err();
    assert!(e.to_string().contains("x.toml"), "{e}");
    let e = Scenario::parse(
        Path::new("x.toml"),
        "name = \"x\"\n[protocol]\nloctions = 3\n",
    )
    .unwrap_err();
    assert!(e.to_string().contains("loctions"), "{e}");
    let tmp = tempfile::tempdir().unwrap();
    std::fs::write(tmp.path().join("keep.txt"), "x").unwrap();
    let e = synthesize(&small("x", 1), tmp.path()).unwrap_err();
    assert!(matches!(e, SynthError::OutputExists { .. }), "{e}");
}

#[test]
fn every_committed_scenario_parses() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/scenarios");
    let mut n = 0;
    for d in [dir.clone(), dir.join("suite")] {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.extension().is_some_and(|x| x == "toml") {
                Scenario::load(&p).unwrap_or_else(|e| panic!("{e}"));
                n += 1;
            }
        }
    }
    assert!(n >= 7, "{n} scenarios");
}
