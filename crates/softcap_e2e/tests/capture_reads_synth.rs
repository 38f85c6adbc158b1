//! The capture stage reads every diagnose-suite scenario of the virtual rig and recovers the
//! markers, probe tip and force against `truth/` (which only tests read).

use softcap_capture::nalgebra::{Point3, Vector3};
use softcap_capture::{CaptureSettings, MarkerState, Session, capture};
use softcap_synth::{Effect, Scenario, synthesize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

fn scenario_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/scenarios/suite")
}

fn csv_rows(path: &Path) -> Vec<Vec<String>> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| l.split(',').map(str::to_string).collect())
        .collect()
}

#[derive(Debug)]
struct Accuracy {
    marker_rms_mm: f64,
    missing: usize,
    frames_without_probe_pose: Vec<usize>,
    force_rms_n: f64,
    force_max_n: f64,
    /// RMS of the true force's component across the recovered (shaft) force direction, N.
    force_off_axis_rms_n: f64,
    tip_rms_mm: f64,
    clock_offset_error_ms: f64,
}

fn accuracy(dir: &Path, r: &softcap_capture::CaptureResult) -> Accuracy {
    let mut truth: BTreeMap<(usize, String), Point3<f64>> = BTreeMap::new();
    for row in csv_rows(&dir.join("truth/markers.csv")) {
        let p = Point3::new(
            row[2].parse().unwrap(),
            row[3].parse().unwrap(),
            row[4].parse::<f64>().unwrap(),
        ) * 1e-3;
        truth.insert((row[0].parse().unwrap(), row[1].clone()), p);
    }
    let (mut s, mut n, mut missing) = (0.0, 0usize, 0usize);
    for f in &r.frames {
        for (i, m) in f.markers.iter().enumerate() {
            let Some(t) = truth.get(&(f.frame, r.marker_ids[i].clone())) else {
                continue;
            };
            if m.state == MarkerState::Missing {
                missing += 1;
                continue;
            }
            s += (m.position_m - t).norm_squared();
            n += 1;
        }
    }
    let (mut fs, mut fmax, mut ts, mut nt) = (0.0, 0.0f64, 0.0, 0usize);
    let mut fl = 0.0;
    let mut no_pose = Vec::new();
    for row in csv_rows(&dir.join("truth/probe.csv")) {
        let frame: usize = row[0].parse().unwrap();
        let ft = Vector3::new(
            row[2].parse().unwrap(),
            row[3].parse().unwrap(),
            row[4].parse::<f64>().unwrap(),
        );
        let tip = Point3::new(
            row[5].parse().unwrap(),
            row[6].parse().unwrap(),
            row[7].parse::<f64>().unwrap(),
        ) * 1e-3;
        fmax = fmax.max(ft.norm());
        let Some(p) = r.frames[frame].probe.as_ref() else {
            no_pose.push(frame);
            continue;
        };
        let (Some(fe), Some(te)) = (p.force_n, p.tip_m) else {
            no_pose.push(frame);
            continue;
        };
        fs += (fe - ft).norm_squared();
        // the part of the true force across the shaft (capture's force is along it)
        if let Some(e) = fe.try_normalize(1e-12) {
            fl += (ft - e * ft.dot(&e)).norm_squared();
        }
        ts += (te - tip).norm_squared();
        nt += 1;
    }
    let clock = std::fs::read_to_string(dir.join("truth/clock.toml")).unwrap();
    let offset: f64 = clock
        .lines()
        .find(|l| l.starts_with("offset_s"))
        .unwrap()
        .split('=')
        .nth(1)
        .unwrap()
        .trim()
        .parse()
        .unwrap();
    Accuracy {
        marker_rms_mm: (s / n as f64).sqrt() * 1e3,
        missing,
        frames_without_probe_pose: no_pose,
        force_rms_n: (fs / nt as f64).sqrt(),
        force_max_n: fmax,
        force_off_axis_rms_n: (fl / nt as f64).sqrt(),
        tip_rms_mm: (ts / nt as f64).sqrt() * 1e3,
        clock_offset_error_ms: (r.sync.expect("sync").offset_s - offset).abs() * 1e3,
    }
}

/// Synthesizes `path`, captures it and measures capture against truth/.
fn synth_and_capture(path: &Path, tmp: &Path) -> (Scenario, Accuracy, usize) {
    let scenario = Scenario::load(path).unwrap();
    let t0 = std::time::Instant::now();
    let out = tmp.join(&scenario.name);
    let report = synthesize(&scenario, &out).unwrap();
    let t_synth = t0.elapsed().as_secs_f64();
    let session = Session::load(&out).unwrap();
    let r = capture(&session, &CaptureSettings::default()).unwrap();
    let a = accuracy(&out, &r);
    println!(
        "{}: {} frames, synth {:.1} s, max force {:.3} N, max marker displacement {:.2} mm; {a:?}",
        scenario.name,
        report.frames,
        t_synth,
        report.max_axial_force_n,
        report.max_marker_displacement_m * 1e3
    );
    assert_eq!(r.frames.len(), report.frames);
    (scenario, a, report.frames)
}

/// Every probe frame has a pose, every marker is visible or filled, and markers (0.3 mm) and the
/// probe tip (0.5 mm) are recovered against truth/.
fn assert_geometry_recovered(name: &str, a: &Accuracy) {
    assert!(
        a.frames_without_probe_pose.is_empty(),
        "{name}: no probe pose in frames {:?}",
        a.frames_without_probe_pose
    );
    assert_eq!(a.missing, 0, "{name}: every marker visible or filled");
    assert!(
        a.marker_rms_mm < 0.3,
        "{name}: marker RMS {:.3} mm",
        a.marker_rms_mm
    );
    assert!(a.tip_rms_mm < 0.5, "{name}: tip RMS {:.3} mm", a.tip_rms_mm);
}

#[test]
fn capture_reads_the_robot_arm_session_and_recovers_tip_and_force() {
    let tmp = tempfile::tempdir().unwrap();
    let path = scenario_dir().join("../robot.toml");
    let (scenario, a, _) = synth_and_capture(&path, tmp.path());
    assert_eq!(scenario.kind, "probe-robot");
    assert!(
        a.frames_without_probe_pose.is_empty(),
        "no probe pose in frames {:?}",
        a.frames_without_probe_pose
    );
    assert_eq!(a.missing, 0);
    assert!(
        a.marker_rms_mm < 0.3,
        "marker RMS {:.3} mm",
        a.marker_rms_mm
    );
    // The tip comes from forward kinematics of the logged joints (URDF), the force from the F/T
    // sensor rotated out of its frame; the clocks are aligned from the data (no trigger line).
    assert!(a.tip_rms_mm < 0.2, "tip RMS {:.3} mm", a.tip_rms_mm);
    assert!(
        a.force_rms_n < 0.03 * a.force_max_n,
        "force RMS {:.4} N vs max {:.3} N",
        a.force_rms_n,
        a.force_max_n
    );
    assert!(
        a.clock_offset_error_ms < 5.0,
        "clock {:.3} ms",
        a.clock_offset_error_ms
    );
}

#[test]
fn capture_reads_every_suite_scenario_and_recovers_the_truth() {
    let tmp = tempfile::tempdir().unwrap();
    let mut paths: Vec<PathBuf> = std::fs::read_dir(scenario_dir())
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "toml"))
        .collect();
    paths.sort();
    assert!(paths.len() >= 6, "{} suite scenarios", paths.len());
    // Developer aid: SOFTCAP_SUITE_ONLY=a,b checks only those scenarios (unset in CI: all).
    if let Ok(only) = std::env::var("SOFTCAP_SUITE_ONLY") {
        let names: Vec<&str> = only.split(',').map(str::trim).collect();
        paths.retain(|p| {
            p.file_stem()
                .and_then(|s| s.to_str())
                .is_some_and(|s| names.contains(&s))
        });
    }
    for path in paths {
        let (scenario, a, _) = synth_and_capture(&path, tmp.path());
        assert_geometry_recovered(&scenario.name, &a);
        let force_latency = scenario.has(Effect::ClockOffset)
            && scenario.effect_settings.clock_force_latency_s > 0.0;
        if scenario.has(Effect::SensorLag) || force_latency {
            // The concealed effect: the FSR reading lags and hysteresis bends it (sensor-lag), or
            // the FSR channel lags the trigger by a constant latency (clock-offset), so the
            // recovered force is clearly off the truth.
            assert!(
                a.force_rms_n > 0.05 * a.force_max_n,
                "{}: sensor lag should show, force RMS {:.4} N of max {:.3} N",
                scenario.name,
                a.force_rms_n,
                a.force_max_n
            );
        } else {
            // Capture's force is the FSR magnitude along the shaft; under the anisotropic block the
            // disk's rim also takes a lateral reaction, which that model cannot see.
            // The tilted disk of support-slip likewise. The FSR (calibration noise, ADC) has an
            // absolute floor of ≈ 0.03 N RMS (clean: 0.029 N), which dominates on soft sessions.
            // probe-friction: the FSR reads only the force along the shaft; the friction
            // traction under the dragged tip (up to ≈ 0.3 of the axial force in the truth) is
            // the concealed part of the force vector.
            // viscoelasticity (session 7 TOML: g 2, τ 0.3 s, the force relaxes by a third within
            // every hold): measured 3.04 % RMS of the peak (0.114 of 3.75 N); the elastic sessions
            // read ≤ 2.7 % (strain-stiffening 0.117 of 4.28 N).
            // plasticity (session 8 TOML: a 14 mm flat punch into a yielding block): the rim takes
            // a lateral reaction the shaft FSR cannot see — measured 0.0550 N RMS of 1.584 N
            // (3.5 %), of which 0.0533 N across the shaft (`force_off_axis_rms_n`).
            let bound = if scenario.has(Effect::ProbeFriction) {
                0.4
            } else if scenario.has(Effect::Viscoelasticity) || scenario.has(Effect::Plasticity) {
                0.04
            } else if scenario.has(Effect::Anisotropy) || scenario.has(Effect::SupportSlip) {
                0.08
            } else {
                0.03
            };
            assert!(
                a.force_rms_n < (bound * a.force_max_n).max(0.045),
                "{}: force RMS {:.4} N vs max {:.3} N",
                scenario.name,
                a.force_rms_n,
                a.force_max_n
            );
            if scenario.has(Effect::Plasticity) {
                // what capture can see, the force along the shaft, within the elastic sessions'
                // 3 % (measured 0.0136 N of 1.584 N)
                let along = (a.force_rms_n.powi(2) - a.force_off_axis_rms_n.powi(2))
                    .max(0.0)
                    .sqrt();
                assert!(
                    along < 0.03 * a.force_max_n,
                    "{}: force RMS along the shaft {along:.4} N vs max {:.3} N",
                    scenario.name,
                    a.force_max_n
                );
            }
        }
        // clock-offset without a trigger line: capture's data-driven sync; with the force-channel
        // latency the trigger is present and the clocks themselves are exact.
        if !scenario.has(Effect::ClockOffset) || force_latency {
            assert!(
                a.clock_offset_error_ms < 2.0,
                "{}: clock {:.3} ms",
                scenario.name,
                a.clock_offset_error_ms
            );
        }
    }
}

/// The two top-level scenarios besides the robot: `standard.toml` (the generation bench's session:
/// 10 locations, rendered PNG frames + detections) and `demo.toml` (`make demo`'s embedded default,
/// concealed gravity pre-load). Capture reads both and recovers markers, tip and force.
#[test]
fn capture_reads_the_standard_and_demo_scenarios() {
    let tmp = tempfile::tempdir().unwrap();
    for name in ["standard", "demo"] {
        let path = scenario_dir().join(format!("../{name}.toml"));
        let (scenario, a, frames) = synth_and_capture(&path, tmp.path());
        assert!(frames > 1, "{}: {frames} frames", scenario.name);
        assert_geometry_recovered(&scenario.name, &a);
        // The FSR's calibration error grows at the top of its range: the standard session probes
        // to 1.77 N (measured 0.063 N RMS = 3.6 %, default detection noise), the suite to ≈ 1.3 N.
        assert!(
            a.force_rms_n < (0.05 * a.force_max_n).max(0.045),
            "{}: force RMS {:.4} N vs max {:.3} N",
            scenario.name,
            a.force_rms_n,
            a.force_max_n
        );
        assert!(
            a.clock_offset_error_ms < 2.0,
            "{}: clock {:.3} ms",
            scenario.name,
            a.clock_offset_error_ms
        );
    }
}
