//! Issue 30 benches: one Gauss–Newton step of `softcap tissue reshape` solved by the Woodbury
//! identity with the singular lemma vs by conjugate gradients on the same normal equations
//! (saito-barbic Table 1: 238k unknowns, 1,143 constraints — CG 897 s, Woodbury 9.5 s).
//!
//! The step is the first one of the ICP stage of the known-truth box
//! ([`softcap_tissue::reshape::known_truth`]: 12 landmarks, 150 ICP markers, the x = 0 face
//! attached) on templates of 720 and 5,760 tets; CG runs without preconditioner to
//! ‖M Δs + g‖ ≤ 1e-6 ‖g‖ (capped at 20,000 iterations). Before criterion starts, each size is
//! timed once and printed with the CG iteration count, its residual and the relative difference
//! of the two steps, and so is the inexact step (CG preconditioned by the Woodbury solve over the
//! soft rows, [`pcg_step`]) at the relative residuals [`PCG_TOLERANCES`];
//! `SOFTCAP_RESHAPE_BENCH_ONCE=1` stops there, `SOFTCAP_RESHAPE_BENCH_NO_CG=1` skips the
//! unpreconditioned CG runs, `SOFTCAP_RESHAPE_BENCH_NO_WOODBURY=1` the exact step (PCG alone, no
//! step difference; with it `SOFTCAP_RESHAPE_BENCH_DENSE_Z=1` also times forming every row's
//! column of Z and the step with M's products with Z dense, not through the equilibrium
//! factor), and `SOFTCAP_RESHAPE_BENCH_CELLS` (e.g. `22,20,15`: 39,600
//! tets) adds one larger size to the single runs.
//!
//! `cargo bench --workspace --profile test --bench reshape` (criterion: `scripts/bench
//! softcap_tissue -- reshape`).

use std::time::{Duration, Instant};

use criterion::{Criterion, SamplingMode, criterion_group, criterion_main};
use softcap_tissue::reshape::step::{cg_step, field_norm, pcg_step, woodbury_step};
use softcap_tissue::reshape::{FirstStep, ReshapeSettings, known_truth};

const CG_TOLERANCE: f64 = 1e-6;
const CG_MAX_ITERATIONS: usize = 20_000;
/// Relative residuals of the inexact (preconditioned CG) step timed by the single runs.
const PCG_TOLERANCES: [f64; 4] = [1e-1, 1e-3, 1e-4, 1e-6];
const PCG_MAX_ITERATIONS: usize = 2_000;

fn first_step(cells: [usize; 3]) -> FirstStep {
    let (problem, _) = known_truth::problem_with_cells(false, cells);
    FirstStep::new(&problem, &ReshapeSettings::default()).expect("first Gauss-Newton step")
}

/// CPU seconds of this process so far (all threads; Linux `/proc/self/stat` utime + stime at
/// 100 ticks per second), NaN elsewhere.
fn cpu_seconds() -> f64 {
    softcap_app::process::cpu_seconds().unwrap_or(f64::NAN)
}

/// CPU seconds of the calling thread so far (`/proc/thread-self/stat`), NaN elsewhere. The work
/// outside the rayon pool (the pool's threads run the parallel parts while this one waits
/// asleep): the serial part of a timed call.
fn thread_cpu_seconds() -> f64 {
    softcap_app::process::thread_cpu_seconds().unwrap_or(f64::NAN)
}

/// How the inexact step's preconditioner treats the six constant modes.
fn shift(pcg: &softcap_tissue::reshape::step::CgOutcome) -> &'static str {
    if pcg.singular_lemma {
        "singular lemma"
    } else {
        "shifted base"
    }
}

/// The inexact step of `sys` to each of [`PCG_TOLERANCES`], timed and printed.
fn pcg_once(label: &str, sys: &softcap_tissue::reshape::step::NormalSystem<'_>) {
    for tolerance in PCG_TOLERANCES {
        let (t0, c0, s0) = (Instant::now(), cpu_seconds(), thread_cpu_seconds());
        let pcg = pcg_step(sys, tolerance, PCG_MAX_ITERATIONS);
        let (cpu, serial) = (cpu_seconds() - c0, thread_cpu_seconds() - s0);
        eprintln!(
            "{label}: PCG to {tolerance:.0e}: {:.3} s wall, {cpu:.2} CPU-s ({serial:.2} on the \
             calling thread, {:.2} in the pool of {} threads: {:.2} s on idle cores), {} \
             iterations, {} rows in its Woodbury part ({}), residual {:.1e}",
            t0.elapsed().as_secs_f64(),
            cpu - serial,
            rayon::current_num_threads(),
            serial + (cpu - serial) / rayon::current_num_threads() as f64,
            pcg.iterations,
            pcg.woodbury_rows,
            shift(&pcg),
            pcg.relative_residual
        );
    }
}

/// One timed Woodbury and CG solve of `step`, printed.
fn once(label: &str, step: &FirstStep) {
    let sys = step.system();
    if std::env::var_os("SOFTCAP_RESHAPE_BENCH_NO_WOODBURY").is_some() {
        pcg_once(label, &sys);
        if std::env::var_os("SOFTCAP_RESHAPE_BENCH_DENSE_Z").is_some() {
            // The same step with every row's column of Z formed (as the exact step does), M's
            // products with Z dense instead of through the factor.
            let (c0, s0) = (cpu_seconds(), thread_cpu_seconds());
            let z = sys.dense_z();
            eprintln!(
                "{label}: every row's column of Z ({}; {} kept) formed in {:.2} CPU-s ({:.2} on \
                 the calling thread)",
                z.ncols(),
                sys.z.ncols(),
                cpu_seconds() - c0,
                thread_cpu_seconds() - s0
            );
            let dense = softcap_tissue::reshape::step::NormalSystem {
                z: &z,
                implicit: None,
                ..sys
            };
            pcg_once(&format!("{label}, Z dense"), &dense);
        }
        return;
    }
    let (t0, c0) = (Instant::now(), cpu_seconds());
    let w = woodbury_step(&sys).expect("Woodbury step");
    let tw = t0.elapsed().as_secs_f64();
    let cw = cpu_seconds() - c0;
    eprintln!(
        "{label}: {} unknowns, {} constraint rows, Laplacian factor {} values: Woodbury \
         {tw:.3} s wall, {cw:.2} CPU-s",
        6 * sys.jacobians.len(),
        step.rows(),
        sys.laplacian.factor_len()
    );
    let size = field_norm(&w);
    let difference = |s: &[nalgebra::Vector6<f64>]| {
        let d: Vec<_> = w.iter().zip(s).map(|(a, b)| a - b).collect();
        field_norm(&d) / size
    };
    for tolerance in PCG_TOLERANCES {
        let (t0, c0) = (Instant::now(), cpu_seconds());
        let pcg = pcg_step(&sys, tolerance, PCG_MAX_ITERATIONS);
        let tp = t0.elapsed().as_secs_f64();
        let cp = cpu_seconds() - c0;
        eprintln!(
            "{label}: PCG to {tolerance:.0e}: {tp:.3} s wall, {cp:.2} CPU-s, {} iterations, \
             {} rows in its Woodbury part ({}), residual {:.1e}, step difference {:.1e}; \
             Woodbury / PCG {:.1} CPU-s, {:.1} wall",
            pcg.iterations,
            pcg.woodbury_rows,
            shift(&pcg),
            pcg.relative_residual,
            difference(&pcg.step),
            cw / cp,
            tw / tp
        );
    }
    if std::env::var_os("SOFTCAP_RESHAPE_BENCH_NO_CG").is_some() {
        return;
    }
    let t0 = Instant::now();
    let cg = cg_step(&sys, CG_TOLERANCE, CG_MAX_ITERATIONS);
    let tc = t0.elapsed().as_secs_f64();
    let diff = difference(&cg.step) * size;
    eprintln!(
        "{label}: {} unknowns, {} constraint rows: Woodbury {tw:.3} s ({cw:.2} CPU-s), CG {tc:.3} s \
         ({} iterations, residual {:.1e}, step difference {:.1e}); CG / Woodbury {:.1}",
        6 * sys.jacobians.len(),
        step.rows(),
        cg.iterations,
        cg.relative_residual,
        diff / size,
        tc / tw
    );
}

fn bench(c: &mut Criterion) {
    let sizes = [("720_tets", [8, 5, 3]), ("5760_tets", [16, 10, 6])];
    let steps: Vec<(&str, FirstStep)> = sizes.iter().map(|(l, c)| (*l, first_step(*c))).collect();
    for (label, step) in &steps {
        once(label, step);
    }
    if let Ok(cells) = std::env::var("SOFTCAP_RESHAPE_BENCH_CELLS") {
        let c: Vec<usize> = cells.split(',').filter_map(|v| v.parse().ok()).collect();
        if let [x, y, z] = c[..] {
            let t0 = Instant::now();
            let step = first_step([x, y, z]);
            eprintln!("system built in {:.1} s", t0.elapsed().as_secs_f64());
            once(&format!("{} tets", 6 * x * y * z), &step);
        }
    }
    if std::env::var_os("SOFTCAP_RESHAPE_BENCH_ONCE").is_some() {
        eprintln!("SOFTCAP_RESHAPE_BENCH_ONCE set: single runs only, no criterion samples");
        return;
    }
    let mut g = c.benchmark_group("reshape");
    g.sample_size(10);
    g.sampling_mode(SamplingMode::Flat);
    g.warm_up_time(Duration::from_millis(1));
    g.measurement_time(Duration::from_secs(1));
    for (label, step) in &steps {
        let sys = step.system();
        g.bench_function(format!("woodbury_step_{label}"), |b| {
            b.iter(|| woodbury_step(&sys).expect("Woodbury step"))
        });
        g.bench_function(format!("cg_step_{label}"), |b| {
            b.iter(|| cg_step(&sys, CG_TOLERANCE, CG_MAX_ITERATIONS))
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
