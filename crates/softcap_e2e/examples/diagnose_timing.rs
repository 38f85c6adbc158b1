//! Issue 8 timing: "the full catalog on a 10-location session takes ≤ 5 minutes on 2 cores".
//! The catalog bench (benches/diagnose_catalog.rs) runs on the clean `standard` session, where no
//! re-simulation grid runs; the expensive sessions are the effect sessions that trigger the
//! refined rigid-tip replays. This test times `softcap_diagnose::run` on the suite's
//! probe-friction scenario (`fixtures/scenarios/suite/probe-friction.toml`) with
//! `protocol.locations` raised from 5 to 10 in code, and prints the diagnose wall time, the
//! process CPU time it used, the verdict and every ranked hypothesis at full precision (so two
//! builds can be compared bit for bit). Synth, capture and tissue fit run once outside the
//! timed call (`SOFTCAP_SUITE_CACHE` reuses them, tests/common); with `SOFTCAP_TIMING_JSON=FILE`
//! the diagnosis JSON is copied to FILE.
//!
//! `cargo run --release -p softcap_e2e --example diagnose_timing`

#[path = "../tests/common/mod.rs"]
mod common;

use softcap_diagnose::{RunConfig, StageSettings};
use softcap_synth::Scenario;
use std::time::Instant;

fn main() {
    let mut scenario =
        Scenario::load(&common::suite_dir().join("probe-friction.toml")).expect("suite scenario");
    scenario.protocol.locations = 10;
    let inputs = common::prepare_inputs(&scenario);
    let json = inputs.dir.path().join("diagnosis.json");
    let cpu0 = softcap_app::process::cpu_seconds();
    let t0 = Instant::now();
    let d = softcap_diagnose::run(&RunConfig {
        capture: inputs.capture.clone(),
        material: inputs.material.clone(),
        output: inputs.dir.path().join("diagnosis.mcap"),
        json: Some(json.clone()),
        report: None,
        settings: StageSettings::default(),
        arguments: vec![],
        progress: false,
    })
    .expect("diagnosis");
    let wall = t0.elapsed().as_secs_f64();
    let cpu = cpu0
        .zip(softcap_app::process::cpu_seconds())
        .map(|(a, b)| b - a);
    if let Some(out) = std::env::var_os("SOFTCAP_TIMING_JSON") {
        std::fs::copy(&json, out).expect("copy diagnosis.json");
    }
    let s = inputs.seconds;
    println!(
        "TIMING | probe-friction, 10 locations | diagnose {wall:.1} s wall, {} CPU | synth {:.1} s, capture {:.1} s, tissue {:.1} s (0 = cached)",
        cpu.map_or("n/a".to_string(), |c| format!("{c:.1} s")),
        s[0],
        s[1],
        s[2]
    );
    println!("verdict {}", d.verdict);
    for r in &d.ranked {
        println!(
            "{} before {:?} after {:?} params {:?}",
            r.hypothesis, r.heldout_rmse_before_m, r.heldout_rmse_after_m, r.params
        );
    }
    assert!(
        d.ranked.iter().any(|r| r.hypothesis == d.verdict) || d.verdict == "none",
        "verdict {} is not among the ranked hypotheses",
        d.verdict
    );
}
