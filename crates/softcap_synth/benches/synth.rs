//! Generating the standard session (fixtures/scenarios/standard.toml: 10 locations, truth mesh
//! 5184 tets, template 1536 tets, 3 cameras, images + detections), and its parts.

use criterion::{Criterion, criterion_group, criterion_main};
use softcap_synth::{Scenario, simulate, synthesize, truth::stream};
use std::path::Path;

fn standard() -> Scenario {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/scenarios/standard.toml");
    Scenario::load(&p).expect("standard scenario")
}

fn bench(c: &mut Criterion) {
    let s = standard();
    let mut g = c.benchmark_group("synth");
    g.sample_size(10);
    g.bench_function("standard_truth_simulation", |b| {
        b.iter(|| simulate(&s, &mut stream(s.seed, 1)).expect("simulation"))
    });
    g.bench_function("standard_session_images_and_detections", |b| {
        b.iter(|| {
            let tmp = tempfile::tempdir().expect("tempdir");
            synthesize(&s, &tmp.path().join("s")).expect("session")
        })
    });
    let mut det = s.clone();
    det.output.images = false;
    g.bench_function("standard_session_detections_only", |b| {
        b.iter(|| {
            let tmp = tempfile::tempdir().expect("tempdir");
            synthesize(&det, &tmp.path().join("s")).expect("session")
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
