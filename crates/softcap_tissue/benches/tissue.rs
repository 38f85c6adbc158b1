//! Issue 7 benches: the fit of a 1.8k-tet, 48-example session (aim ≤ 60 s on 2 cores) and the
//! synthesis rate of a novel probe with the fitted material.
//!
//! The session is built here, in memory (no other stage): a 40 × 40 × 20 mm block, 10 × 10 × 3
//! cells = 1,800 tets, two stable neo-Hookean layers (E 60 / 20 kPa, ν 0.4), 7 × 7 markers on the
//! top, a 4 mm disk probe (force boundary condition, bickel2009 §4.1) at 12 locations × 4 force
//! levels (0.25 / 0.5 / 0.75 / 1.0 N) = 48 examples, all selected. `fit` runs `fit_session` with
//! the default settings (homogeneous baseline, γ_p by leave-one-location-out, eq. 9 per-example
//! fits, eq. 8 basis, re-simulation). `simulate` synthesizes a 6 mm sphere pressing 0.5 N at an
//! untrained location with the fitted strain-space material (§3.4 incremental loading with
//! contact, force control); its rate in Hz is 1 / median.
//!
//! `scripts/bench softcap_tissue` (= `cargo bench -p softcap_tissue --bench tissue`; criterion,
//! 10 one-call samples of each after one warm-up call). Before criterion starts, one fit and one
//! synthesis are timed and printed with their process CPU time (`single fit: … s wall, … CPU-s`)
//! and figures; `SOFTCAP_TISSUE_BENCH_ONCE=1` stops there (a quick timing, or a `perf record`
//! target).

use std::time::{Duration, Instant};

use criterion::{Criterion, SamplingMode, criterion_group, criterion_main};
use softcap_fem::TipShape;
use softcap_fem::nalgebra::Vector3;
use softcap_probing::StrainSpaceModel;
use softcap_probing::{
    ContactSynthesisSettings, ProbingSetup, StepPreconditioner, probe_pose, simulate_probe_contact,
    support_nodes,
};
use softcap_tissue::{FitSettings, PreparedSession, Progress, fit_session};

#[path = "../tests/common/mod.rs"]
mod common;

const SIZE_M: [f64; 3] = [0.04, 0.04, 0.02];
const CELLS: [usize; 3] = [10, 10, 3];
const FORCES_N: [f64; 4] = [0.25, 0.5, 0.75, 1.0];

fn session() -> PreparedSession {
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], SIZE_M, CELLS);
    let markers = common::marker_grid(SIZE_M, 7);
    let fixed = support_nodes(&mesh, &Vector3::z(), 0.0, 1e-9);
    let setup = ProbingSetup::new(mesh, &markers, fixed).expect("setup");
    let mut truth = common::truth_model_of(&setup.mesh, [6.0e4, 2.0e4], SIZE_M[2], 0.4);
    // 12 locations on a 4 × 3 grid inside the top face (away from the edges); the force levels
    // of one location are solved in turn, each from the previous equilibrium.
    let locations: Vec<[f64; 2]> = (0..4)
        .flat_map(|i| (0..3).map(move |j| [0.008 + 0.008 * i as f64, 0.010 + 0.010 * j as f64]))
        .collect();
    let mut examples = Vec::new();
    for (li, loc) in locations.iter().enumerate() {
        let mut solver = setup.solver(&truth).expect("solver");
        let mut x = setup.mesh.vertices.clone();
        for &f in &FORCES_N {
            let index = examples.len() + 1;
            examples.push(common::in_memory::truth_example(
                &setup,
                &mut truth,
                &mut solver,
                &mut x,
                Vector3::new(loc[0], loc[1], SIZE_M[2]),
                f,
                common::TIP_RADIUS_M,
                li,
                index,
            ));
        }
    }
    common::in_memory::prepared(&setup, examples)
}

/// Process CPU time (user + system, all threads), s; `None` where /proc is not available.
fn cpu_time_s() -> Option<f64> {
    softcap_app::process::cpu_seconds()
}

fn timed<T>(what: &str, f: impl FnOnce() -> T) -> T {
    let (t0, c0) = (Instant::now(), cpu_time_s());
    let r = f();
    let cpu = match (c0, cpu_time_s()) {
        (Some(a), Some(b)) => format!("{:.1} CPU-s", b - a),
        _ => "CPU n/a".into(),
    };
    eprintln!("{what}: {:.2} s wall, {cpu}", t0.elapsed().as_secs_f64());
    r
}

fn bench(c: &mut Criterion) {
    let prepared = session();
    let mut settings = FitSettings {
        progress: false,
        ..FitSettings::default()
    };
    // A/B of the LM step's CG preconditioner (default: the fit's own).
    match std::env::var("SOFTCAP_TISSUE_BENCH_PRECONDITIONER").as_deref() {
        Ok("jacobi") => settings.example_fit.preconditioner = StepPreconditioner::Jacobi,
        Ok("woodbury") => settings.example_fit.preconditioner = StepPreconditioner::Woodbury,
        _ => {}
    }
    eprintln!(
        "step preconditioner: {:?}",
        settings.example_fit.preconditioner
    );
    let fit = timed("single fit", || {
        fit_session(&prepared, &settings, &Progress::hidden()).expect("fit")
    });
    eprintln!(
        "  {} tets, {} examples; γ_p = {} (LOLO {}); marker RMS homogeneous {:.4} mm, per-example {:.4} mm, material {:.4} mm, {} re-simulations not converged",
        fit.outcome.tets,
        fit.outcome.examples.len(),
        fit.outcome.gamma_prior,
        fit.outcome
            .gamma_prior_scores
            .iter()
            .map(|s| format!("{}: {:.4} mm", s.gamma_prior, 1e3 * s.heldout_rms_m))
            .collect::<Vec<_>>()
            .join(", "),
        1e3 * fit.outcome.homogeneous_rms_m,
        1e3 * fit.outcome.example_rms_m,
        1e3 * fit.outcome.material_rms_m,
        fit.outcome.material_failures
    );
    eprintln!(
        "  chosen γ_p's per-example fits: {} LM iterations, {} CG iterations in all",
        fit.fits.iter().map(|f| f.iterations).sum::<usize>(),
        fit.fits.iter().map(|f| f.cg_iterations).sum::<usize>()
    );
    let setup = &prepared.setup;
    let model = StrainSpaceModel::new(fit.material.clone().expect("material"), &setup.mesh, 0.5)
        .expect("model");
    let pose = probe_pose(&Vector3::new(0.02, 0.015, 0.025), &-Vector3::z());
    let tip = TipShape::Sphere { radius_m: 0.006 };
    let cs = ContactSynthesisSettings::default();
    let synth = || {
        let mut m = model.clone();
        let r =
            simulate_probe_contact(setup, &mut m, tip.clone(), pose, 0.5, &cs).expect("synthesis");
        assert_eq!(r.status, softcap_fem::SolveStatus::Converged);
        r
    };
    let r = timed("single synthesis", synth);
    eprintln!(
        "  6 mm sphere at 0.5 N: depth {:.3} mm, {} load steps, {} depth iterations",
        1e3 * r.depth_m,
        r.step_depths_m.len(),
        r.depth_iterations
    );
    if std::env::var_os("SOFTCAP_TISSUE_BENCH_ONCE").is_some() {
        eprintln!("SOFTCAP_TISSUE_BENCH_ONCE set: single runs only, no criterion samples");
        return;
    }

    // Each sample is one call (flat sampling): the fit is tens of seconds, so criterion's
    // minimum of 10 samples (+ one warm-up call) is ≈ 11 fits.
    let mut g = c.benchmark_group("tissue");
    g.sample_size(10);
    g.sampling_mode(SamplingMode::Flat);
    g.warm_up_time(Duration::from_millis(1));
    g.measurement_time(Duration::from_secs(1));
    g.bench_function("simulate_sphere_0.5N_1800_tets", |b| b.iter(synth));
    g.bench_function("fit_1800_tets_48_examples", |b| {
        b.iter(|| fit_session(&prepared, &settings, &Progress::hidden()).expect("fit"))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
