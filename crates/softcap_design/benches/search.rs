//! One goal-based design search at full size (thesis §8.4.2, §8.6): 5 layers × 9 base materials,
//! 5 force–displacement examples, exact branch-and-bound with K = 20 and the margins certified
//! on the exhaustive table (fixtures/design/search-5x9-certified.json), every composite
//! simulated on demand (no precomputed table; a fresh design cache per search). The target is
//! a random design with jittered layer thicknesses (seed 2010, first target of the validation).
//! bickel2010: "under an hour"; issue 11: ≤ 60 s on 2 cores.
//!
//! One search is ≈ 85 CPU-s (≈ 43 s on 2 cores), so the default 10 samples (+ warm-up) take
//! ≈ 8 min on 2 idle cores; `cargo bench -p softcap_design --bench search -- --quick` stops
//! after the warm-up and one sample of each benchmark (criterion's quick mode exits early when
//! one iteration exceeds the 1 s measurement time): two searches, ≈ 1.5 min on 2 idle cores.

use criterion::{Criterion, criterion_group, criterion_main};
use softcap_design::*;
use std::sync::Arc;
use std::time::Duration;

fn target() -> Vec<f64> {
    // First target of `run_experiment` with seed 2010 (design [7, 6, 2, 5, 1], own thicknesses).
    let settings = ExperimentSettings {
        targets: 1,
        ..ExperimentSettings::default()
    };
    random_targets(&Arc::new(reference_library()), &settings).unwrap()[0]
        .response
        .clone()
}

/// The search settings with the margins certified on the 5 × 9 exhaustive table
/// (examples/validation.rs; docs/design.md).
fn certified() -> SearchSettings {
    serde_json::from_str(include_str!(
        "../../../fixtures/design/search-5x9-certified.json"
    ))
    .unwrap()
}

fn bench_search(c: &mut Criterion) {
    let settings = CompositeSettings::default();
    let lib = Arc::new(reference_library());
    let x_bar = target();
    let search = certified();
    let mut g = c.benchmark_group("design_search");
    g.sample_size(10);
    g.warm_up_time(Duration::from_millis(1));
    g.measurement_time(Duration::from_secs(1));
    g.bench_function("exact_b&b_5x9_live_simulation", |b| {
        b.iter(|| {
            let mut ev = ParallelEvaluator::new(lib.clone(), &settings).unwrap();
            let rep = branch_and_bound(5, 9, &x_bar, &mut ev, &search).unwrap();
            assert!(rep.error_m.is_finite());
            rep.evaluations
        })
    });
    g.bench_function("one_composite_simulation_5_examples", |b| {
        let block = Arc::new(LayeredBlock::uniform(&settings).unwrap());
        let mut sim = CompositeSimulator::new(block, lib.clone(), &settings).unwrap();
        b.iter(|| sim.simulate(&[0, 3, 6, 7, 8]).unwrap().iterations)
    });
    g.finish();
}

criterion_group!(benches, bench_search);
criterion_main!(benches);
