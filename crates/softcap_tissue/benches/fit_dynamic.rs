//! Issue 36 speed bench: a full `fit-dynamic` fit of a 2k-node, 250-frame sequence (aim ≤ 5 min
//! on 2 cores; wang2015 reports 0.2–3 hours on 8 cores for its fits).
//!
//! The sequence is built here, in memory, with softcap's own dynamics
//! (`fit_dynamic::synthetic`): a 200 × 30 × 30 mm bar of 40 × 6 × 6 cells (2,009 nodes, 8,640
//! tets, the size of `fixtures/scenarios/dynamic/bench-2k`), clamped at x = 0, sagging under
//! gravity, pushed off-axis at its tip for 0.2 s and ringing down, 250 frames at 30 Hz with
//! 0.5 mm of tracking-level noise; E = 5·10⁵ Pa, α = 0.8 1/s, β = 10⁻³ s. The fit runs with the
//! default settings from E = 10⁵ Pa.
//!
//! `cargo bench --profile test -p softcap_tissue --bench fit_dynamic` (criterion: 10 one-call
//! samples of one evaluation of the objective, i.e. every segment simulated once at the fitted
//! parameters). Before criterion starts, the truth and one whole fit are timed and printed
//! (`full fit: … s wall`, the fitted parameters and their errors); `SOFTCAP_FIT_DYNAMIC_BENCH_ONCE=1`
//! stops there. Run it under `/usr/bin/time -v` for the CPU-seconds.

use std::time::{Duration, Instant};

use criterion::{Criterion, SamplingMode, criterion_group, criterion_main};
use softcap_fem::RayleighDamping;
use softcap_fem::nalgebra::Vector3;
use softcap_tissue::Progress;
use softcap_tissue::fit_dynamic::synthetic::{Synthetic, SyntheticSpec, clamped_box, synthesize};
use softcap_tissue::fit_dynamic::{
    DynamicParams, FitDynamicSettings, Forward, ForwardSettings, fit_sequence,
};

const SIZE_M: [f64; 3] = [0.2, 0.03, 0.03];
const CELLS: [usize; 3] = [40, 6, 6];
const FRAMES: usize = 250;
const YOUNG_PA: f64 = 5.0e5;
const DAMPING: RayleighDamping = RayleighDamping {
    alpha_per_s: 0.8,
    beta_s: 1.0e-3,
};

fn sequence() -> Synthetic {
    let (mesh, support, push) = clamped_box(SIZE_M, CELLS);
    let push: Vec<usize> = push
        .into_iter()
        .filter(|&i| mesh.vertices[i].y >= 0.0)
        .collect();
    synthesize(&SyntheticSpec {
        young_pa: vec![YOUNG_PA; mesh.tets.len()],
        rest_mesh: mesh,
        support_nodes: support,
        poisson: 0.45,
        density_kg_m3: 1100.0,
        damping: DAMPING,
        gravity_m_s2: Vector3::new(0.0, 0.0, -9.80665),
        push_nodes: push,
        push_force_n: Vector3::new(0.0, 0.5, -0.4),
        push_s: 0.2,
        frames: FRAMES,
        frame_rate_hz: 30.0,
        substeps: 4,
        refine: 0,
        elements: softcap_tissue::fit_dynamic::Elements::Linear,
        noise_m: 5.0e-4,
        seed: 11,
    })
    .expect("truth")
}

fn timed<T>(what: &str, f: impl FnOnce() -> T) -> T {
    let t0 = Instant::now();
    let r = f();
    eprintln!("{what}: {:.1} s wall", t0.elapsed().as_secs_f64());
    r
}

fn bench(c: &mut Criterion) {
    let truth = timed("truth (one simulation of every frame)", sequence);
    let settings = FitDynamicSettings {
        progress: false,
        ..FitDynamicSettings::default()
    };
    let fit = timed("full fit", || {
        fit_sequence(
            &truth.template,
            &truth.sequence,
            &settings,
            &Progress::hidden(),
        )
        .expect("fit")
    });
    eprintln!(
        "  {} nodes, {} tets, {} frames in {} segments; {} simulations + {} one-segment; status {}",
        truth.template.vertices.len(),
        truth.template.tets.len(),
        FRAMES,
        fit.segments,
        fit.simulations,
        fit.segment_simulations,
        fit.status
    );
    eprintln!(
        "  E {:.4e} Pa ({:+.1} %), α {:.3} 1/s ({:+.1} %), β {:.3e} s ({:+.1} %); trajectory RMS {:.3} mm (warm start {:.3} mm)",
        fit.young_pa[0],
        100.0 * (fit.young_pa[0] / YOUNG_PA - 1.0),
        fit.damping.alpha_per_s,
        100.0 * (fit.damping.alpha_per_s / DAMPING.alpha_per_s - 1.0),
        fit.damping.beta_s,
        100.0 * (fit.damping.beta_s / DAMPING.beta_s - 1.0),
        1e3 * fit.rms_m,
        1e3 * fit.rms_warm_m
    );
    if std::env::var_os("SOFTCAP_FIT_DYNAMIC_BENCH_ONCE").is_some() {
        return;
    }
    let segments = truth.sequence.segments(
        settings.segment_frames,
        settings.min_segment_frames,
        settings.forward.velocity_half_window,
    );
    let observed = vec![true; truth.template.vertices.len()];
    let forward = Forward::new(
        &truth.template,
        &truth.sequence,
        segments,
        observed,
        &ForwardSettings::default(),
    )
    .expect("forward");
    let params = DynamicParams {
        young_pa: fit.young_pa_tets.clone(),
        poisson: fit.poisson,
        damping: fit.damping,
    };
    let mut group = c.benchmark_group("fit_dynamic");
    group
        .sample_size(10)
        .sampling_mode(SamplingMode::Flat)
        .measurement_time(Duration::from_secs(60));
    group.bench_function("objective_2k_nodes_250_frames", |b| {
        b.iter(|| forward.simulate(&params, &fit.rest_m).expect("simulate"))
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
