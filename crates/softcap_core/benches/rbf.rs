//! RBF fit (dense saddle-point LU) and batch evaluation at a few thousand centres in 3-D,
//! φ(r) = r³ with quadratic tail (thesis eq. 4.1), plus greedy least-squares selection.
//!
//! Run with `cargo bench -p softcap_core --bench rbf`.

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use softcap_core::{GreedyRbfSettings, Rbf, RbfSettings, ScatteredData, greedy_rbf};
use std::hint::black_box;

fn samples(n: usize, seed: u64) -> (Vec<f64>, Vec<f64>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let pts: Vec<f64> = (0..3 * n).map(|_| rng.random_range(-1.0..1.0)).collect();
    let vals: Vec<f64> = pts
        .chunks(3)
        .flat_map(|x| {
            [
                (2.0 * x[0]).sin() * x[1],
                x[2] * x[2] - x[0],
                (x[1] + x[2]).cos(),
            ]
        })
        .collect();
    (pts, vals)
}

fn bench_rbf(c: &mut Criterion) {
    let settings = RbfSettings::default();
    let mut group = c.benchmark_group("rbf_interpolate_r3_quadratic_3d");
    group.sample_size(10);
    for n in [500, 1000, 2000, 4000] {
        let (pts, vals) = samples(n, 1);
        group.bench_with_input(BenchmarkId::from_parameter(n), &n, |b, _| {
            b.iter(|| {
                let data = ScatteredData::new(&pts, 3, &vals, 3).unwrap();
                black_box(Rbf::interpolate(&data, &settings).unwrap())
            })
        });
    }
    group.finish();

    let mut group = c.benchmark_group("rbf_evaluate_batch_10k_points");
    group.sample_size(10);
    let (query, _) = samples(10_000, 2);
    for n in [1000, 4000] {
        let (pts, vals) = samples(n, 1);
        let data = ScatteredData::new(&pts, 3, &vals, 3).unwrap();
        let rbf = Rbf::interpolate(&data, &settings).unwrap();
        group.bench_with_input(BenchmarkId::new("centres", n), &n, |b, _| {
            b.iter(|| black_box(rbf.evaluate_batch(&query).unwrap()))
        });
    }
    group.finish();

    let mut group = c.benchmark_group("rbf_greedy_2000_samples");
    group.sample_size(10);
    let (pts, vals) = samples(2000, 3);
    let data = ScatteredData::new(&pts, 3, &vals, 3).unwrap();
    let greedy = GreedyRbfSettings {
        tolerance: 1e-2,
        max_centers: 150,
        ..Default::default()
    };
    group.bench_function("tol_1e-2_max_150", |b| {
        b.iter(|| black_box(greedy_rbf(&data, &greedy).unwrap()))
    });
    group.finish();
}

criterion_group!(benches, bench_rbf);
criterion_main!(benches);
