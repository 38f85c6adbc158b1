//! Shared by the diagnose suite (tests/diagnose_suite.rs) and the catalog bench
//! (benches/diagnose_catalog.rs): the stage chain synth → capture → tissue fit on a scenario,
//! in-process through each stage's library API.
#![allow(dead_code)]

use softcap_capture::{CaptureSettings, Session, capture, write_capture_mcap};
use softcap_synth::{Scenario, synthesize};
use softcap_tissue::fit::{FitConfig, FitSettings};
use std::path::{Path, PathBuf};
use std::time::Instant;

pub fn suite_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/scenarios/suite")
}

/// The inputs of `softcap diagnose` for one scenario, in a temporary folder.
pub struct Inputs {
    pub dir: tempfile::TempDir,
    pub capture: PathBuf,
    pub material: PathBuf,
    /// Seconds spent in synth, capture, tissue fit.
    pub seconds: [f64; 3],
}

/// synth → capture (capture.mcap) → `softcap_tissue::fit::run` (material.mcap), each through the
/// stage's library API exactly as the binaries call it.
///
/// Developer aid: with `SOFTCAP_SUITE_CACHE=DIR`, the capture.mcap / material.mcap of a scenario
/// are kept in `DIR/<name>-<hash of the resolved scenario>/` and reused by later runs (for
/// iterating on the diagnose stage only; stale when synth, capture or tissue code changes —
/// delete DIR then). Unset (CI), every run makes fresh inputs.
pub fn prepare_inputs(scenario: &Scenario) -> Inputs {
    let dir = tempfile::tempdir().unwrap();
    let cache = std::env::var_os("SOFTCAP_SUITE_CACHE").map(|d| {
        use std::hash::{Hash, Hasher};
        let mut h = std::collections::hash_map::DefaultHasher::new();
        format!("{scenario:?}").hash(&mut h);
        PathBuf::from(d).join(format!("{}-{:016x}", scenario.name, h.finish()))
    });
    if let Some(c) = &cache
        && c.join("capture.mcap").is_file()
        && c.join("material.mcap").is_file()
    {
        return Inputs {
            capture: c.join("capture.mcap"),
            material: c.join("material.mcap"),
            dir,
            seconds: [0.0; 3],
        };
    }
    let inputs = prepare_fresh(scenario, dir);
    if let Some(c) = &cache {
        std::fs::create_dir_all(c).unwrap();
        std::fs::copy(&inputs.capture, c.join("capture.mcap")).unwrap();
        std::fs::copy(&inputs.material, c.join("material.mcap")).unwrap();
    }
    inputs
}

fn prepare_fresh(scenario: &Scenario, dir: tempfile::TempDir) -> Inputs {
    let session_dir = dir.path().join("session");
    let t0 = Instant::now();
    synthesize(scenario, &session_dir).unwrap();
    let t_synth = t0.elapsed().as_secs_f64();

    let t0 = Instant::now();
    let session = Session::load(&session_dir).unwrap();
    let settings = CaptureSettings::default();
    let result = capture(&session, &settings).unwrap();
    let capture_path = dir.path().join("capture.mcap");
    write_capture_mcap(&capture_path, &session, &result, &settings, &[]).unwrap();
    let t_capture = t0.elapsed().as_secs_f64();

    let t0 = Instant::now();
    let material_path = dir.path().join("material.mcap");
    let volume = session.volume.clone().expect("template/volume.msh");
    let settings = FitSettings {
        progress: false,
        ..Default::default()
    };
    softcap_tissue::fit::run(&FitConfig {
        capture: capture_path.clone(),
        mesh: Some(volume),
        output: material_path.clone(),
        report: None,
        settings,
        arguments: vec![],
    })
    .expect("softcap_tissue::fit::run");
    let t_tissue = t0.elapsed().as_secs_f64();
    Inputs {
        dir,
        capture: capture_path,
        material: material_path,
        seconds: [t_synth, t_capture, t_tissue],
    }
}
