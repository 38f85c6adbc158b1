//! Criterion bench of the probing layer: the LM step's J_mᵀ(J_m v) of the per-example fits
//! (`lm_normal_product`).

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use softcap_fem::faer;
use softcap_probing::{normal_product, normal_product_unblocked};
use std::hint::black_box;

/// The dense part of the LM step's normal operator, J_mᵀ(J_m v), at every CG iteration of the
/// per-example fits (bickel2009 eq. 9): J_m of the 5,184-tet suite template (2T = 10,368
/// parameters) with 150 observed markers (450 rows, 37 MB), as two whole faer products (session
/// 12) and blocked over rows ([`normal_product`], session 13; the same bits).
fn lm_normal_product(c: &mut Criterion) {
    let mut g = c.benchmark_group("lm_normal_product");
    g.sample_size(20);
    let (n, m) = (10_368, 450);
    let flat: Vec<f64> = (0..n * m)
        .map(|i| ((i % 977) as f64 - 488.0) * 1e-3)
        .collect();
    let v: Vec<f64> = (0..n).map(|i| (i as f64 * 0.37).sin()).collect();
    let jt = faer::MatRef::from_column_major_slice(&flat, n, m);
    let id = format!("{m} x {n}");
    g.bench_function(BenchmarkId::new("two whole products", &id), |b| {
        let mut jv = vec![0.0; m];
        let mut out = vec![0.0; n];
        b.iter(|| {
            normal_product_unblocked(jt, &v, &mut jv, &mut out);
            black_box(out[0])
        })
    });
    g.bench_function(BenchmarkId::new("blocked (normal_product)", &id), |b| {
        let mut jv = vec![0.0; m];
        let mut out = vec![0.0; n];
        b.iter(|| {
            normal_product(jt, &v, &mut jv, &mut out);
            black_box(out[0])
        })
    });
    g.finish();
}

criterion_group!(benches, lm_normal_product);
criterion_main!(benches);
