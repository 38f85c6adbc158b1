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
//! `cargo bench --workspace --profile test --bench fit_dynamic` (criterion: 10 one-call samples
//! of one evaluation of the objective, every segment simulated once at the truth's parameters
//! over its rest shape). Before criterion starts, the truth and one evaluation are timed (wall
//! and CPU-s, Newton updates and factorizations per step). Environment:
//! `SOFTCAP_FIT_DYNAMIC_BENCH_ONCE=1` runs the whole fit once with the stage defaults instead
//! and prints wall, CPU-s, evaluations (those of the first segments of a fit coarse to fine in
//! time apart), rest-shape solves and where the time went (forward simulation, factorization,
//! rest shape, modal warm start; `DynamicFit::timing`);
//! `SOFTCAP_FIT_DYNAMIC_BENCH_COMPARE=1` also times the evaluation with the system matrix
//! assembled at every Newton iteration (`ForwardSettings::residual_only` off) and with a
//! factorization at every Newton update (`ForwardSettings::refactor_ratio` 0) and prints the
//! largest node distance of each to the default, and times the evaluation with the forward
//! sensitivities of the three log-parameters (`Forward::simulate_with_sensitivities`) and a
//! nearby evaluation (Δ ln p = `SOFTCAP_FIT_DYNAMIC_BENCH_NEAR_DQ`, default 0.01,0.05,-0.05)
//! from the predictor and from that run moved along its sensitivities
//! (`ForwardSettings::start_near`; `…_COMPARE=near` times only those), all with the fit's
//! sensitivity settings (`fit_dynamic::fit::SENSITIVITY`; `…_SENS_TOL=t` sets their tolerance);
//! `SOFTCAP_FIT_DYNAMIC_BENCH_NEAR=0|1` and `…_NEAR_RATIO=ρ` set
//! `ForwardSettings::start_near` and `near_refactor_ratio`;
//! `SOFTCAP_FIT_DYNAMIC_BENCH_EVAL_ONLY=1` stops before criterion;
//! `SOFTCAP_FIT_DYNAMIC_BENCH_FRAMES=N` shortens the sequence;
//! `SOFTCAP_FIT_DYNAMIC_BENCH_JACOBIAN=forward-differences` fits with the forward-difference
//! Jacobian instead of the forward sensitivities (`FitDynamicSettings::jacobian`);
//! `SOFTCAP_FIT_DYNAMIC_BENCH_NEWTON_TOL=t` sets `ForwardSettings::newton_tolerance`.

use std::time::{Duration, Instant};

use criterion::{Criterion, SamplingMode, criterion_group, criterion_main};
use softcap_app::process::cpu_seconds;
use softcap_fem::RayleighDamping;
use softcap_fem::nalgebra::Vector3;
use softcap_tissue::Progress;
use softcap_tissue::fit_dynamic::forward::Perturbed;
use softcap_tissue::fit_dynamic::synthetic::{Synthetic, SyntheticSpec, clamped_box, synthesize};
use softcap_tissue::fit_dynamic::{
    DynamicParams, FitDynamicSettings, Forward, ForwardSettings, JacobianMethod, fit_sequence,
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
        counter_push_nodes: Vec::new(),
        push_s: 0.2,
        frames: frames(),
        frame_rate_hz: 30.0,
        substeps: 4,
        refine: 0,
        elements: softcap_tissue::fit_dynamic::Elements::Linear,
        noise_m: 5.0e-4,
        seed: 11,
    })
    .expect("truth")
}

fn frames() -> usize {
    std::env::var("SOFTCAP_FIT_DYNAMIC_BENCH_FRAMES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(FRAMES)
}

/// `SOFTCAP_FIT_DYNAMIC_BENCH_NEWTON_TOL`, or the default Newton tolerance.
fn newton_tolerance() -> f64 {
    std::env::var("SOFTCAP_FIT_DYNAMIC_BENCH_NEWTON_TOL")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(ForwardSettings::default().newton_tolerance)
}

/// `SOFTCAP_FIT_DYNAMIC_BENCH_NEAR_RATIO`, or the default `ForwardSettings::near_refactor_ratio`.
fn near_ratio() -> f64 {
    std::env::var("SOFTCAP_FIT_DYNAMIC_BENCH_NEAR_RATIO")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(ForwardSettings::default().near_refactor_ratio)
}

/// The fit's sensitivity settings (`fit_dynamic::fit::SENSITIVITY`), their tolerance set by
/// `SOFTCAP_FIT_DYNAMIC_BENCH_SENS_TOL` if given.
fn sensitivity_settings() -> softcap_fem::SensitivitySettings {
    let fit = softcap_tissue::fit_dynamic::fit::SENSITIVITY;
    softcap_fem::SensitivitySettings {
        tolerance: std::env::var("SOFTCAP_FIT_DYNAMIC_BENCH_SENS_TOL")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(fit.tolerance),
        ..fit
    }
}

/// `ForwardSettings::start_near` (`SOFTCAP_FIT_DYNAMIC_BENCH_NEAR=0|1`; default: the settings'
/// default).
fn start_near() -> bool {
    std::env::var("SOFTCAP_FIT_DYNAMIC_BENCH_NEAR")
        .map_or(ForwardSettings::default().start_near, |v| v != "0")
}

/// Runs `f`, printing its wall time and the process's CPU-s.
fn timed<T>(what: &str, f: impl FnOnce() -> T) -> T {
    let (c0, t0) = (cpu_seconds(), Instant::now());
    let r = f();
    eprintln!(
        "{what}: {:.1} s wall, {:.1} CPU-s",
        t0.elapsed().as_secs_f64(),
        cpu_seconds().zip(c0).map_or(f64::NAN, |(b, a)| b - a)
    );
    r
}

/// The whole fit with the stage defaults: wall, CPU-s, evaluations and where the time went.
fn full_fit(truth: &Synthetic) {
    let jacobian = match std::env::var("SOFTCAP_FIT_DYNAMIC_BENCH_JACOBIAN").as_deref() {
        Ok("forward-differences") => JacobianMethod::ForwardDifferences,
        _ => JacobianMethod::Sensitivities,
    };
    let defaults = FitDynamicSettings::default();
    let settings = FitDynamicSettings {
        progress: false,
        jacobian,
        forward: ForwardSettings {
            newton_tolerance: newton_tolerance(),
            start_near: start_near(),
            near_refactor_ratio: near_ratio(),
            ..defaults.forward.clone()
        },
        ..defaults
    };
    eprintln!(
        "full fit, Jacobian {jacobian:?}, Newton tolerance {:e}",
        settings.forward.newton_tolerance
    );
    let (c0, t0) = (cpu_seconds(), Instant::now());
    let fit = fit_sequence(
        &truth.template,
        &truth.sequence,
        &settings,
        &Progress::hidden(),
    )
    .expect("fit");
    let wall = t0.elapsed().as_secs_f64();
    let cpu = cpu_seconds().zip(c0).map_or(f64::NAN, |(b, a)| b - a);
    let t = &fit.timing;
    eprintln!(
        "full fit: {wall:.1} s wall, {cpu:.1} CPU-s ({} rayon threads, load {})",
        rayon::current_num_threads(),
        std::fs::read_to_string("/proc/loadavg")
            .unwrap_or_default()
            .trim()
    );
    eprintln!(
        "  {} nodes, {} tets, {} frames in {} segments; {} evaluations (simulations of every segment) + {} one-segment; status {}",
        truth.template.vertices.len(),
        truth.template.tets.len(),
        truth.sequence.positions_m.len(),
        fit.segments,
        fit.simulations,
        fit.segment_simulations,
        fit.status
    );
    let other = cpu - t.simulate_cpu_s - t.rest_shape_cpu_s - t.modal_cpu_s;
    eprintln!(
        "  split (CPU-s): forward simulation {:.1} (of which factorization ≈ {:.1}), rest shape {:.1}, modal warm start {:.1}, other {:.1}",
        t.simulate_cpu_s,
        t.factor_cpu_s(),
        t.rest_shape_cpu_s,
        t.modal_cpu_s,
        other
    );
    eprintln!(
        "  {} segment runs, {} time steps, {} Newton iterations ({:.2} per step), {} factorizations ({:.2} per step), {} sensitivity iterations ({:.2} per step)",
        t.segment_runs,
        t.steps,
        t.newton_iterations,
        t.newton_iterations as f64 / t.steps.max(1) as f64,
        t.factorizations,
        t.factorizations as f64 / t.steps.max(1) as f64,
        t.sensitivity_iterations,
        t.sensitivity_iterations as f64 / t.steps.max(1) as f64
    );
    if let Some(e) = &fit.early {
        eprintln!(
            "  coarse to fine in time: {} simulations of the first {} segments first (E {:.4e} Pa, α {:.3} 1/s, β {:.3e} s)",
            e.simulations, e.segments, e.young_pa[0], e.damping.alpha_per_s, e.damping.beta_s
        );
    }
    eprintln!(
        "  {} rest-shape solves, {} Newton iterations; objective history {:?}",
        t.rest_shape_solves, t.rest_shape_iterations, fit.history
    );
    let changes = |h: &[f64]| -> Vec<String> {
        h.windows(2)
            .map(|w| format!("{:.1e}", (w[0] - w[1]) / w[0]))
            .collect()
    };
    if let Some(e) = &fit.early {
        eprintln!(
            "  early p-step: F {:.6e} → {:.6e}, relative decrease per iteration {:?}",
            e.p_step_history.first().unwrap_or(&f64::NAN),
            e.p_step_history.last().unwrap_or(&f64::NAN),
            changes(&e.p_step_history)
        );
    }
    eprintln!(
        "  p-step on all segments: F {:.6e} → {:.6e}, relative decrease per iteration {:?}",
        fit.p_step_history.first().unwrap_or(&f64::NAN),
        fit.p_step_history.last().unwrap_or(&f64::NAN),
        changes(&fit.p_step_history)
    );
    eprintln!(
        "  1-σ (relative): E {:.2e}, α {:.2e}, β {:.2e}",
        fit.relative_sigma[0], fit.relative_sigma[1], fit.relative_sigma[2]
    );
    eprintln!(
        "  E {:.4e} Pa ({:+.1} %), α {:.3} 1/s ({:+.1} %), β {:.3e} s ({:+.1} %); trajectory RMS {:.3} mm (warm start {:.3} mm{})",
        fit.young_pa[0],
        100.0 * (fit.young_pa[0] / YOUNG_PA - 1.0),
        fit.damping.alpha_per_s,
        100.0 * (fit.damping.alpha_per_s / DAMPING.alpha_per_s - 1.0),
        fit.damping.beta_s,
        100.0 * (fit.damping.beta_s / DAMPING.beta_s - 1.0),
        1e3 * fit.rms_m,
        1e3 * fit.rms_warm_m,
        fit.warm_rms_scope()
    );
}

fn bench(c: &mut Criterion) {
    let truth = timed("truth (one simulation of every frame)", sequence);
    if std::env::var_os("SOFTCAP_FIT_DYNAMIC_BENCH_ONCE").is_some() {
        full_fit(&truth);
        return;
    }
    // One evaluation of the objective: every segment simulated once at the truth's parameters
    // over its rest shape, with the default factorization reuse and (for comparison) with a
    // factorization at every Newton update.
    let settings = FitDynamicSettings::default();
    let segments = truth.sequence.segments(
        settings.segment_frames,
        settings.min_segment_frames,
        settings.forward.velocity_half_window,
    );
    let observed = vec![true; truth.template.vertices.len()];
    let forward_with = |refactor_ratio: f64, residual_only: bool| {
        Forward::new(
            &truth.template,
            &truth.sequence,
            segments.clone(),
            observed.clone(),
            &ForwardSettings {
                refactor_ratio,
                residual_only,
                newton_tolerance: newton_tolerance(),
                start_near: start_near(),
                near_refactor_ratio: near_ratio(),
                ..settings.forward.clone()
            },
        )
        .expect("forward")
    };
    let params = DynamicParams {
        young_pa: vec![YOUNG_PA; truth.template.tets.len()],
        poisson: 0.45,
        damping: DAMPING,
    };
    let evaluate = |label: &str, forward: &Forward| {
        let runs = timed(&format!("one evaluation, {label}"), || {
            forward.simulate(&params, &truth.rest_m).expect("simulate")
        });
        let t = forward.timing();
        eprintln!(
            "  {} segments, RMS to the tracked positions {:.4} mm; {} time steps, {:.2} Newton iterations and {:.3} factorizations per step, factorization ≈ {:.0} % of the simulation",
            runs.len(),
            1e3 * forward.rms_m(&runs),
            t.steps,
            t.newton_iterations as f64 / t.steps.max(1) as f64,
            t.factorizations as f64 / t.steps.max(1) as f64,
            100.0 * t.factor_thread_s / t.segment_thread_s.max(1e-12)
        );
        runs
    };
    let forward = forward_with(settings.forward.refactor_ratio, true);
    let runs = evaluate(
        "factorization reuse, residual-only passes (default)",
        &forward,
    );
    let compare = std::env::var("SOFTCAP_FIT_DYNAMIC_BENCH_COMPARE").ok();
    if compare.is_some() {
        let largest = |other: &[softcap_tissue::fit_dynamic::forward::SegmentRun]| {
            runs.iter()
                .zip(other)
                .flat_map(|(a, b)| a.positions_m.iter().zip(&b.positions_m))
                .flat_map(|(a, b)| a.iter().zip(b).map(|(p, q)| (p - q).norm()))
                .fold(0.0f64, f64::max)
        };
        let only_near = compare.as_deref() == Some("near");
        if !only_near {
            let assembled = evaluate(
                "factorization reuse, the matrix assembled at every iteration",
                &forward_with(settings.forward.refactor_ratio, false),
            );
            eprintln!(
                "  largest node distance to the default: {:.3e} m",
                largest(&assembled)
            );
            let newton = evaluate(
                "a factorization per Newton update",
                &forward_with(0.0, true),
            );
            eprintln!(
                "  largest node distance to the default: {:.3e} m",
                largest(&newton)
            );
        }
        // The forward sensitivities of ln E, ln α, ln β (the rest shape held: a timing).
        let eps = 1e-6;
        let perturbed: Vec<Perturbed> = (0..3)
            .map(|k| {
                let mut p = params.clone();
                match k {
                    0 => p.young_pa.iter_mut().for_each(|e| *e *= f64::exp(eps)),
                    1 => p.damping.alpha_per_s *= f64::exp(eps),
                    _ => p.damping.beta_s *= f64::exp(eps),
                }
                Perturbed {
                    params: p,
                    rest_m: truth.rest_m.clone(),
                }
            })
            .collect();
        let sensitive = forward_with(settings.forward.refactor_ratio, true);
        let with = timed(
            "one evaluation with the forward sensitivities of 3 parameters",
            || {
                sensitive
                    .simulate_with_sensitivities(
                        &params,
                        &truth.rest_m,
                        None,
                        &perturbed,
                        &sensitivity_settings(),
                        None,
                    )
                    .expect("simulate")
            },
        );
        let t = sensitive.timing();
        eprintln!(
            "  {:.2} Newton iterations and {:.2} sensitivity iterations per step; largest node distance to the default: {:.3e} m",
            t.newton_iterations as f64 / t.steps.max(1) as f64,
            t.sensitivity_iterations as f64 / t.steps.max(1) as f64,
            largest(&with)
        );
        // A nearby point, as a Levenberg–Marquardt step reaches it: Δ(ln E, ln α, ln β), every
        // step started as usual and from the run above moved along its sensitivities.
        let dq: Vec<f64> = std::env::var("SOFTCAP_FIT_DYNAMIC_BENCH_NEAR_DQ")
            .ok()
            .and_then(|v| v.split(',').map(|x| x.trim().parse().ok()).collect())
            .unwrap_or(vec![0.01, 0.05, -0.05]);
        let shifted = |p: &DynamicParams| {
            let mut p = p.clone();
            p.young_pa.iter_mut().for_each(|e| *e *= f64::exp(dq[0]));
            p.damping.alpha_per_s *= f64::exp(dq[1]);
            p.damping.beta_s *= f64::exp(dq[2]);
            p
        };
        let params2 = shifted(&params);
        let perturbed2: Vec<Perturbed> = perturbed
            .iter()
            .map(|p| Perturbed {
                params: shifted(&p.params),
                rest_m: p.rest_m.clone(),
            })
            .collect();
        let tracks: Vec<_> = with.iter().map(|r| r.steps.clone()).collect();
        let mut near_runs = Vec::new();
        for (label, near) in [
            ("from the predictor", None),
            (
                "from the run above moved by S Δp",
                Some(softcap_tissue::fit_dynamic::Near {
                    tracks: &tracks,
                    dp: &dq[..],
                }),
            ),
        ] {
            let f = forward_with(settings.forward.refactor_ratio, true);
            let runs = timed(
                &format!("a nearby evaluation with sensitivities (Δ ln p = {dq:?}), {label}"),
                || {
                    f.simulate_with_sensitivities(
                        &params2,
                        &truth.rest_m,
                        None,
                        &perturbed2,
                        &sensitivity_settings(),
                        near,
                    )
                    .expect("simulate")
                },
            );
            let t = f.timing();
            eprintln!(
                "  {:.2} Newton iterations, {:.3} factorizations and {:.2} sensitivity iterations per step",
                t.newton_iterations as f64 / t.steps.max(1) as f64,
                t.factorizations as f64 / t.steps.max(1) as f64,
                t.sensitivity_iterations as f64 / t.steps.max(1) as f64,
            );
            near_runs.push(runs);
        }
        let (a, b) = (&near_runs[0], &near_runs[1]);
        let distance = a
            .iter()
            .zip(b)
            .flat_map(|(a, b)| a.positions_m.iter().zip(&b.positions_m))
            .flat_map(|(a, b)| a.iter().zip(b).map(|(p, q)| (p - q).norm()))
            .fold(0.0f64, f64::max);
        let sens_miss = a
            .iter()
            .zip(b)
            .flat_map(|(a, b)| a.sensitivities_m.iter().zip(&b.sensitivities_m))
            .flat_map(|(a, b)| a.iter().zip(b))
            .flat_map(|(a, b)| a.iter().zip(b).map(|(p, q)| (p - q).norm()))
            .fold(0.0f64, f64::max);
        let sens_size = a
            .iter()
            .flat_map(|r| r.sensitivities_m.iter().flatten().flatten())
            .map(|v| v.norm())
            .fold(0.0f64, f64::max);
        eprintln!(
            "  largest node distance between the two: {distance:.3e} m; largest sensitivity difference {sens_miss:.3e} (of {sens_size:.3e})"
        );
    }
    if std::env::var_os("SOFTCAP_FIT_DYNAMIC_BENCH_EVAL_ONLY").is_some() {
        return;
    }
    let mut group = c.benchmark_group("fit_dynamic");
    group
        .sample_size(10)
        .sampling_mode(SamplingMode::Flat)
        .measurement_time(Duration::from_secs(60));
    group.bench_function("objective_2k_nodes_250_frames", |b| {
        b.iter(|| forward.simulate(&params, &truth.rest_m).expect("simulate"))
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
