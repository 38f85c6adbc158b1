//! The bickel2009 §6 noise experiment on a virtual three-layer block with a known non-linear
//! truth (stable neo-Hookean layers E 60 / 30 / 15 kPa, ν 0.45). Figures are printed and copied
//! into docs/tissue.md.

use crate::common;

use common::in_memory::{prepared, three_layer_setup, three_layer_truth, truth_examples};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use softcap_fem::nalgebra::Vector3;
use softcap_tissue::{FitSettings, Progress, SessionExample, fit_session};

/// Fit settings for relative marker noise `p`: the smoothing γ (and γ_ν) of eq. 9 grows with the
/// noise variance, γ = γ₀ (1 + 10 (p / 0.1)²) — the regularization "required to prevent
/// overfitting due to noise" (bickel2009 §4.1) weighed like a Morozov/Tikhonov parameter
/// (γ ∝ σ²). With γ₀ at 30 % noise the per-example fits follow the noise and one relaxed
/// re-simulation has no equilibrium (session 4, measured).
fn settings_for_noise(p: f64) -> FitSettings {
    let mut s = FitSettings {
        progress: false,
        ..FitSettings::default()
    };
    let k = 1.0 + 10.0 * (p / 0.1).powi(2);
    s.example_fit.gamma_m2 *= k;
    s.example_fit.gamma_nu_m2 *= k;
    s
}

/// bickel2009 §6: "Gaussian noise with a variance of 10 %, 20 % and 30 % to the input
/// displacements … L2 error for all deformations … 0.3 % of the maximum displacement for the
/// case without error, and 2.1 %, 3.1 % and 4.4 %". Here: each observed marker displacement
/// u_i gets noise n_i ~ N(0, (p‖u_i‖)² I), seeded; the strain-space material fitted to the noisy
/// data re-simulates every example from its (exact) force, and the L2 error against the
/// noise-free truth, sqrt(Σ‖x_sim − x_true‖² / n) over all markers of all examples, is reported
/// as a percentage of the largest marker displacement.
/// Runs the experiment at the noise `levels` (fractions); returns the L2 errors in % of the
/// maximum marker displacement.
fn noise_experiment(levels: &[f64]) -> Vec<f64> {
    noise_experiment_with(levels, settings_for_noise)
}

/// The experiment with the fit settings chosen per noise level by `settings`.
fn noise_experiment_with(levels: &[f64], settings: impl Fn(f64) -> FitSettings) -> Vec<f64> {
    let setup = three_layer_setup();
    let mut truth = three_layer_truth(&setup.mesh);
    let locations = [[0.0105, 0.0105], [0.0195, 0.0150], [0.0120, 0.0195]];
    let clean = truth_examples(&setup, &mut truth, &locations, &[0.5, 1.0]);
    let rest = setup.marker_positions(&setup.mesh.vertices);
    let max_disp = clean
        .iter()
        .flat_map(|e| {
            e.example
                .observed
                .iter()
                .map(|o| (o.position_m - rest[o.marker]).norm())
        })
        .fold(0.0, f64::max);
    eprintln!("max marker displacement {:.3} mm", 1e3 * max_disp);
    assert!(max_disp > 1e-3);
    let mut errors = Vec::new();
    for &p in levels {
        let level = (10.0 * p).round() as usize;
        let mut rng = ChaCha8Rng::seed_from_u64(2009 + level as u64);
        let unit = Normal::new(0.0, 1.0).unwrap();
        let noisy: Vec<SessionExample> = clean
            .iter()
            .map(|e| {
                let mut e = e.clone();
                for o in &mut e.example.observed {
                    let u = o.position_m - rest[o.marker];
                    let sigma = p * u.norm();
                    o.position_m += Vector3::from_fn(|_, _| sigma * unit.sample(&mut rng));
                }
                e
            })
            .collect();
        let fit = fit_session(&prepared(&setup, noisy), &settings(p), &Progress::hidden()).unwrap();
        let (mut s2, mut n) = (0.0, 0usize);
        for (k, x) in fit.material_positions_m.iter().enumerate() {
            let x = x.as_ref().expect("strain-space re-simulation converged");
            let sim = setup.marker_positions(x);
            for o in &clean[k].example.observed {
                s2 += (sim[o.marker] - o.position_m).norm_squared();
                n += 1;
            }
        }
        let l2 = (s2 / n as f64).sqrt() / max_disp * 100.0;
        eprintln!(
            "noise {:>2.0} %: L2 error {:.2} % of max displacement (bickel2009: {} %); material RMS vs noisy input {:.4} mm, homogeneous {:.4} mm",
            100.0 * p,
            l2,
            PAPER_PERCENT[level],
            1e3 * fit.outcome.material_rms_m,
            1e3 * fit.outcome.homogeneous_rms_m
        );
        errors.push(l2);
    }
    errors
}

/// bickel2009 §6: L2 error at 0 / 10 / 20 / 30 % noise, % of the maximum displacement.
const PAPER_PERCENT: [f64; 4] = [0.3, 2.1, 3.1, 4.4];

/// Noise-free and 30 % noise (the light variant; the full table is the ignored test below).
/// Measured (docs/tissue.md, trust-region LM, γ grown with the noise variance): 1.45 % and
/// 4.58 % (paper 0.3 % and 4.4 %; session 4 without the trust region: 3.09 % and 6.20 %).
/// Tolerances: the noise-free model error within 2.5 % of the maximum displacement, 30 % noise
/// within 6 %, and noise makes it worse.
#[test]
fn noise_experiment_zero_and_thirty_percent() {
    let e = noise_experiment(&[0.0, 0.3]);
    assert!(e[0] < 2.5, "{e:?}");
    assert!(e[1] < 6.0, "{e:?}");
    assert!(e[1] > e[0], "{e:?}");
}

/// The full table of bickel2009 §6 (0 / 10 / 20 / 30 %), ≈ 90 s in the test profile.
/// Measured (session 7, default fit): 1.84 / 2.18 / 4.40 / 4.37 % (paper 0.3 / 2.1 / 3.1 / 4.4 %).
#[test]
#[ignore = "heavy (four fits, ≈ 2 min); the 0 % / 30 % variant runs by default"]
fn noise_experiment_full_table() {
    let e = noise_experiment(&[0.0, 0.1, 0.2, 0.3]);
    for v in &e {
        assert!(*v < 6.0, "{e:?}");
    }
    assert!(e[3] > e[0], "{e:?}");
}

/// Fit settings that minimize the *training* error, as the paper's noise-free figure measures it
/// (docs/notes/2026-11-26-tissue-fit-defaults.md): no shrinkage toward the homogeneous field
/// (γ_p = 0, no leave-one-location-out choice), converged per-example fits (40 LM iterations,
/// relative cost tolerance 1e-6) and an exactly interpolating strain-space basis (greedy
/// tolerance 0, up to 64 centres). The defaults trade this training error for held-out prediction.
fn paper_training_settings() -> FitSettings {
    let mut s = settings_for_noise(0.0);
    s.gamma_prior_candidates = vec![];
    s.example_fit.gamma_prior = 0.0;
    s.example_fit.max_iterations = 40;
    s.example_fit.relative_cost_tolerance = 1e-6;
    s.basis.relative_tolerance = 0.0;
    s.basis.max_centers = 64;
    s
}

/// bickel2009 §6's noise-free row with training-error settings: the linear corotational material
/// with strain-dependent per-tet (λ, α) reproduces the three-layer neo-Hookean block to the
/// paper's 0.3 % of the maximum displacement. Measured (session 8): 0.29 %. Tolerance 0.5 %
/// (the default settings give 1.84 %, so the test separates the two).
#[test]
fn noise_free_row_with_training_settings_matches_the_paper() {
    let e = noise_experiment_with(&[0.0], |_| paper_training_settings());
    assert!(e[0] < 0.5, "{e:?}");
}
