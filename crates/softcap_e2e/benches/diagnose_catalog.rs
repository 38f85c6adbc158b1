//! Issue 8 bench: the full diagnose catalog (baseline simulation of every frame, nine hypothesis
//! refits with leave-one-location-out, re-simulation of the winner, JSON) on a 10-location session:
//! `fixtures/scenarios/standard.toml` (10 locations, template 1536 tets) with detections only,
//! captured and fitted once outside the timed loop. Aim: ≤ 5 min on 2 cores.

#[path = "../tests/common/mod.rs"]
mod common;

use criterion::{Criterion, criterion_group, criterion_main};
use softcap_diagnose::{RunConfig, StageSettings};
use softcap_synth::Scenario;
use std::path::Path;
use std::time::Duration;

fn bench(c: &mut Criterion) {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/scenarios/standard.toml");
    let mut s = Scenario::load(&p).expect("standard scenario");
    s.output.images = false;
    s.output.detections = true;
    let inputs = common::prepare_inputs(&s);
    let cfg = RunConfig {
        capture: inputs.capture.clone(),
        material: inputs.material.clone(),
        output: inputs.dir.path().join("diagnosis.mcap"),
        json: Some(inputs.dir.path().join("diagnosis.json")),
        report: None,
        settings: StageSettings::default(),
        arguments: vec![],
        progress: false,
    };
    let mut g = c.benchmark_group("diagnose");
    g.sample_size(10);
    g.warm_up_time(Duration::from_millis(1));
    g.measurement_time(Duration::from_secs(1));
    g.bench_function("full_catalog_10_locations", |b| {
        b.iter(|| softcap_diagnose::run(&cfg).expect("diagnosis"))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
