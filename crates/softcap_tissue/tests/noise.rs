//! The bickel2009 §6 noise experiment on a virtual three-layer block with a known non-linear
//! truth (stable neo-Hookean layers E 60 / 30 / 15 kPa, ν 0.45). Figures are printed and copied
//! into docs/tissue.md.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use softcap_fem::nalgebra::Vector3;
use softcap_fem::probing::{ObservedMarker, ProbeExample, ProbingSetup, support_nodes};
use softcap_fem::{EquilibriumSettings, NeoHookeanModel, NeoHookeanParams, PatchSettings};
use softcap_mcap::capture::{Phase, SupportPlane};
use softcap_tissue::{FitSettings, PreparedSession, Progress, SessionExample, fit_session};

const SIZE_M: [f64; 3] = [0.03, 0.03, 0.015];
const TIP_RADIUS_M: f64 = 0.004;

/// Three layers (bottom → top) of stable neo-Hookean material, E in Pa.
const LAYERS_PA: [f64; 3] = [6.0e4, 3.0e4, 1.5e4];

fn three_layer_truth(mesh: &softcap_mesh::TetMesh) -> NeoHookeanModel {
    let params = mesh
        .tets
        .iter()
        .map(|t| {
            let z = t.iter().map(|&i| mesh.vertices[i].z).sum::<f64>() / 4.0;
            let layer = ((z / SIZE_M[2]) * 3.0).floor().clamp(0.0, 2.0) as usize;
            NeoHookeanParams::from_young_poisson(LAYERS_PA[layer], 0.45).unwrap()
        })
        .collect();
    NeoHookeanModel::new(mesh, params).unwrap()
}

fn setup() -> ProbingSetup {
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], SIZE_M, [6, 6, 3]);
    let mut markers = Vec::new();
    for i in 0..6 {
        for j in 0..6 {
            markers.push(Vector3::new(
                0.0025 + 0.005 * i as f64,
                0.0025 + 0.005 * j as f64,
                SIZE_M[2],
            ));
        }
    }
    let fixed = support_nodes(&mesh, &Vector3::z(), 0.0, 1e-9);
    ProbingSetup::new(mesh, &markers, fixed).unwrap()
}

/// Truth examples under the force boundary condition of a disk probe (bickel2009 §4.1).
fn truth_examples(
    setup: &ProbingSetup,
    truth: &mut NeoHookeanModel,
    locations: &[[f64; 2]],
    forces_n: &[f64],
) -> Vec<SessionExample> {
    let patch = PatchSettings {
        radius_m: TIP_RADIUS_M,
        ..Default::default()
    };
    let mut out = Vec::new();
    for (li, loc) in locations.iter().enumerate() {
        for &f in forces_n {
            let mut ex = ProbeExample {
                frame: out.len() as u64 + 1,
                time_s: 0.1 * (out.len() + 1) as f64,
                tip_m: Vector3::new(loc[0], loc[1], SIZE_M[2]),
                axis: -Vector3::z(),
                force_n: Vector3::new(0.0, 0.0, -f),
                observed: Vec::new(),
            };
            let nodes = setup.patch_nodes(&ex, &patch);
            let forces = setup.nodal_forces(&ex, &nodes);
            let mut solver = setup.solver(&*truth).unwrap();
            let mut x = setup.mesh.vertices.clone();
            let rep = setup.simulate(
                &mut solver,
                truth,
                &mut x,
                &forces,
                &EquilibriumSettings::newton(),
            );
            assert!(rep.converged(), "{rep:?}");
            ex.observed = setup
                .marker_positions(&x)
                .into_iter()
                .enumerate()
                .map(|(marker, position_m)| ObservedMarker { marker, position_m })
                .collect();
            out.push(SessionExample {
                example: ex,
                location: li,
                phase: Phase::Loading,
                frame_index: out.len() + 1,
                log_time_ns: 100_000_000 * (out.len() as u64 + 1),
            });
        }
    }
    out
}

fn prepared(setup: &ProbingSetup, examples: Vec<SessionExample>) -> PreparedSession {
    PreparedSession {
        setup: setup.clone(),
        locations: Vec::new(),
        all_examples: examples.clone(),
        selected: examples,
        tip_radius_m: TIP_RADIUS_M,
        support: SupportPlane {
            normal: [0.0, 0.0, 1.0],
            offset_m: 0.0,
            tolerance_m: 1e-9,
        },
    }
}

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
    let setup = setup();
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
        let fit = fit_session(
            &prepared(&setup, noisy),
            &settings_for_noise(p),
            &Progress::hidden(),
        )
        .unwrap();
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
