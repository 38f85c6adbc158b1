//! `softcap tissue fit-dynamic` / `simulate-dynamic` (wang2015 §6) end to end on a small known-truth
//! sequence, and their bad-input handling. The Table 1 / Table 2 accuracy runs are in
//! `examples/fit_dynamic_table1.rs` (too slow for `make test`); the Table 1 protocol's checks are
//! `table1_one_draw_…` and the ignored `table1_more_draws_…` below.

use std::path::Path;
use std::process::Command;

use nalgebra::Vector3;
use softcap_fem::RayleighDamping;
use softcap_tissue::fit_dynamic::Elements;
use softcap_tissue::fit_dynamic::synthetic::{
    Synthetic, SyntheticSpec, synthesize, write_track_mcap,
};

const E_TRUE: f64 = 5.0e5;

/// A 160 × 30 × 20 mm bar clamped at x = 0, 8 × 2 × 2 cells, pushed for 0.2 s, 30 frames at 30 Hz,
/// 0.3 mm tracking noise.
fn small_bar() -> Synthetic {
    bar(30, 0, 3.0e-4, 3)
}

/// The small bar's truth: `frames` at 30 Hz, simulated on `refine` levels of refinement,
/// observed at the given nodes with `noise_m` of tracking noise.
fn bar(frames: usize, refine: usize, noise_m: f64, seed: u64) -> Synthetic {
    bar_of(frames, refine, Elements::Linear, noise_m, seed)
}

/// [`bar`] with linear or quadratic tets in the truth.
fn bar_of(frames: usize, refine: usize, elements: Elements, noise_m: f64, seed: u64) -> Synthetic {
    let spec = SyntheticSpec::small_clamped_bar();
    synthesize(&SyntheticSpec {
        young_pa: vec![E_TRUE; spec.young_pa.len()],
        frames,
        refine,
        elements,
        noise_m,
        seed,
        ..spec
    })
    .unwrap()
}

/// `s` fitted with `settings`, no progress shown; a fit error fails the test.
fn fit_quietly(
    s: &Synthetic,
    settings: &softcap_tissue::fit_dynamic::FitDynamicSettings,
) -> softcap_tissue::fit_dynamic::DynamicFit {
    softcap_tissue::fit_dynamic::fit_sequence(
        &s.template,
        &s.sequence,
        settings,
        &softcap_tissue::Progress::hidden(),
    )
    .unwrap()
}

/// The small bar's true parameters (E_TRUE everywhere, ν 0.45, α 0.8 1/s, β 1 ms), for the
/// start-state tests.
fn true_params(s: &Synthetic) -> softcap_tissue::fit_dynamic::DynamicParams {
    softcap_tissue::fit_dynamic::DynamicParams {
        young_pa: vec![E_TRUE; s.template.tets.len()],
        poisson: 0.45,
        damping: RayleighDamping {
            alpha_per_s: 0.8,
            beta_s: 1.0e-3,
        },
    }
}

fn write_inputs(dir: &Path, s: &Synthetic) {
    let material = softcap_mcap::proto::DynamicMaterial {
        element: "corotational".into(),
        young_pa: vec![1.0e5],
        poisson: 0.45,
        density_kg_m3: 1100.0,
        rayleigh_alpha_per_s: 1.0,
        rayleigh_beta_s: 2.0e-3,
        rest_positions_m: vec![],
    };
    write_track_mcap(&dir.join("track.mcap"), s, &material).unwrap();
    let msh = softcap_mesh::MshMesh::from_tet_mesh(&s.template, None);
    softcap_mesh::write_msh(dir.join("volume.msh"), &msh).unwrap();
    std::fs::write(
        dir.join("settings.toml"),
        "outer_iterations = 1\nmax_simulations = 40\nsegment_frames = 30\n",
    )
    .unwrap();
}

fn tissue(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_softcap-tissue"))
        .args(args)
        .output()
        .unwrap()
}

/// `softcap-tissue fit-dynamic` on the `tracks` in `d` with `write_inputs`' mesh and settings
/// (plus `extra` arguments), asserted to succeed; the `--json` document it wrote.
fn fit_dynamic_json(d: &Path, tracks: &[&str], extra: &[&str]) -> String {
    let p = |f: &str| d.join(f).display().to_string();
    let mut args = vec!["fit-dynamic".to_string()];
    args.extend(tracks.iter().map(|t| p(t)));
    for (flag, file) in [
        ("--mesh", "volume.msh"),
        ("-o", "dynamic.mcap"),
        ("--json", "fit.json"),
        ("--settings", "settings.toml"),
    ] {
        args.extend([flag.to_string(), p(file)]);
    }
    args.extend(extra.iter().map(|a| a.to_string()));
    args.push("--quiet".into());
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let out = tissue(&args);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    std::fs::read_to_string(d.join("fit.json")).unwrap()
}

fn json_number(text: &str, key: &str) -> f64 {
    let at = text.find(&format!("\"{key}\": ")).expect(key) + key.len() + 4;
    let rest = &text[at..];
    let rest = rest.trim_start_matches('[');
    let end = rest.find([',', '\n', ']', '}']).unwrap();
    rest[..end].trim().parse().unwrap()
}

#[test]
fn fit_dynamic_recovers_e_and_writes_material_json_report_rest_and_simulation() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let s = small_bar();
    write_inputs(d, &s);
    let p = |f: &str| d.join(f).display().to_string();
    let json = fit_dynamic_json(d, &["track.mcap"], &["--report", &p("report")]);
    for key in [
        "E_pa",
        "control_points_m",
        "E_pa_tets",
        "nu",
        "alpha",
        "beta",
        "density_kg_m3",
        "trajectory_rmse_m",
        "status",
    ] {
        assert!(
            json.contains(&format!("\"{key}\":")),
            "{key} missing in {json}"
        );
    }
    let e = json_number(&json, "E_pa");
    assert!((e / E_TRUE - 1.0).abs() < 0.05, "E {e}");
    // The relative 1-σ of E, α, β: s²(JᵀJ)⁻¹ and the sandwich ones per frame and per segment;
    // the segment sandwich needs two segments (`null` with one).
    let report = std::fs::read_to_string(d.join("report/report.md")).unwrap();
    assert!(report.contains("sandwich 1-σ per segment"), "{report}");
    let segments: usize = report
        .split_once(" segments,")
        .and_then(|(head, _)| head.rsplit(' ').next())
        .and_then(|n| n.parse().ok())
        .expect("segment count in report.md");
    let object = |key: &str| {
        let at = json.find(&format!("\"{key}\": {{")).expect(key);
        json[at..=at + json[at..].find('}').expect("object ends")].to_string()
    };
    for of in ["E", "alpha", "beta"] {
        let mut finite = vec![
            json_number(&object("relative_sigma"), of),
            json_number(&object("sigma_frame_robust"), of),
        ];
        if segments >= 2 {
            finite.push(json_number(&object("sigma_segment_robust"), of));
        } else {
            assert!(
                object("sigma_segment_robust").contains(&format!("\"{of}\": null"))
                    || object("sigma_segment_robust").contains(&format!("\"{of}\": [null")),
                "{of}: one segment, a segment sandwich in {json}"
            );
        }
        for s in finite {
            assert!(s.is_finite() && s > 0.0, "{of}: 1-sigma {s} in {json}");
        }
    }
    // The trajectory error is at the tracking-noise level (0.3 mm per coordinate).
    let rmse = json_number(&json, "trajectory_rmse_m");
    assert!(rmse < 1.0e-3, "rmse {rmse}");
    assert!(d.join("report/trajectories.png").exists() && d.join("report/report.md").exists());
    // The material (with its rest shape) is readable by the tracker.
    let n = s.template.vertices.len();
    softcap_mcap::dynamic::read_dynamic_material(d.join("dynamic.mcap"), s.template.tets.len(), n)
        .unwrap();
    let m = softcap_mcap::Recording::open(d.join("dynamic.mcap"))
        .unwrap()
        .read_static(&softcap_mcap::topics::DYNAMIC_MATERIAL)
        .unwrap();
    assert_eq!(m.rest_positions_m.len(), 3 * n);
    // simulate-dynamic from frame 8 (after the push) to the end.
    let out = tissue(&[
        "simulate-dynamic",
        &p("dynamic.mcap"),
        "--initial",
        &p("track.mcap"),
        "--frames",
        "8..29",
        "-o",
        &p("sim.mcap"),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let frames = softcap_mcap::Recording::open(d.join("sim.mcap"))
        .unwrap()
        .read(&softcap_mcap::topics::DYNAMIC_SIM_NODES)
        .unwrap();
    assert_eq!(frames.len(), 21);
}

#[test]
fn bad_input_exits_2_naming_the_file_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let s = small_bar();
    write_inputs(d, &s);
    let p = |f: &str| d.join(f).display().to_string();
    // A mesh that is not the tracked one.
    let other = softcap_mesh::box_tet_mesh([0.0; 3], [0.1, 0.02, 0.02], [3, 1, 1]);
    softcap_mesh::write_msh(
        d.join("other.msh"),
        &softcap_mesh::MshMesh::from_tet_mesh(&other, None),
    )
    .unwrap();
    let out = tissue(&[
        "fit-dynamic",
        &p("track.mcap"),
        "--mesh",
        &p("other.msh"),
        "-o",
        &p("d.mcap"),
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("other.msh"));
    // A file that is not a track (a capture-less MCAP: the mesh file itself).
    let out = tissue(&[
        "fit-dynamic",
        &p("volume.msh"),
        "--mesh",
        &p("volume.msh"),
        "-o",
        &p("d.mcap"),
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("volume.msh"));
    // A frame range outside the track.
    let out = tissue(&[
        "simulate-dynamic",
        &p("track.mcap"),
        "--initial",
        &p("track.mcap"),
        "--frames",
        "5..99",
        "-o",
        &p("s.mcap"),
    ]);
    assert_eq!(
        out.status.code(),
        Some(2),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(!d.join("d.mcap").exists() && !d.join("s.mcap").exists());
}

/// Several track.mcaps (recorded motions of one body) are fitted jointly: `fit-dynamic A B`
/// gives what `fit_sequence` gives on the two sequences joined `run::MOTION_GAP_S` apart
/// (the same objective, so the same parameters to 10⁻⁶; only the float text of the JSON
/// differs), and a second track of another body (other gravity) exits 2 naming it.
#[test]
fn several_tracks_are_fitted_jointly() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let first = bar(20, 0, 3.0e-4, 5);
    let second = synthesize(&SyntheticSpec {
        young_pa: vec![E_TRUE; first.template.tets.len()],
        frames: 20,
        push_force_n: Vector3::new(0.0, -0.5, 0.2),
        noise_m: 3.0e-4,
        seed: 6,
        ..SyntheticSpec::small_clamped_bar()
    })
    .unwrap();
    write_inputs(d, &first);
    std::fs::rename(d.join("track.mcap"), d.join("a.mcap")).unwrap();
    write_inputs(d, &second);
    std::fs::rename(d.join("track.mcap"), d.join("b.mcap")).unwrap();
    let json = fit_dynamic_json(d, &["a.mcap", "b.mcap"], &[]);
    let p = |f: &str| d.join(f).display().to_string();
    let joined = first
        .sequence
        .joined(
            &second.sequence,
            softcap_tissue::fit_dynamic::run::MOTION_GAP_S,
        )
        .unwrap();
    let settings: softcap_tissue::fit_dynamic::FitDynamicSettings =
        toml::from_str(&std::fs::read_to_string(d.join("settings.toml")).unwrap()).unwrap();
    let fit = softcap_tissue::fit_dynamic::fit_sequence(
        &second.template,
        &joined,
        &settings,
        &softcap_tissue::Progress::hidden(),
    )
    .unwrap();
    for (key, expected) in [
        ("E_pa", fit.young_pa[0]),
        ("alpha", fit.damping.alpha_per_s),
        ("beta", fit.damping.beta_s),
    ] {
        let got = json_number(&json, key);
        assert!(
            (got / expected - 1.0).abs() < 1e-6,
            "{key}: command line {got}, joined in memory {expected}"
        );
    }
    assert!(
        (fit.young_pa[0] / E_TRUE - 1.0).abs() < 0.05,
        "E {}",
        fit.young_pa[0]
    );
    // Another body: the same mesh under other gravity.
    let mut tilted = second.clone();
    tilted.sequence.gravity_m_s2 = Vector3::new(0.0, -9.80665, 0.0);
    write_inputs(d, &tilted);
    let out = tissue(&[
        "fit-dynamic",
        &p("a.mcap"),
        &p("track.mcap"),
        "--mesh",
        &p("volume.msh"),
        "-o",
        &p("d.mcap"),
        "--quiet",
    ]);
    assert_eq!(
        out.status.code(),
        Some(2),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(String::from_utf8_lossy(&out.stderr).contains("track.mcap"));
    assert!(!d.join("d.mcap").exists());
}

/// Coarse to fine (`refine = 1`): a truth simulated on the once-refined mesh, observed at the
/// given mesh's nodes. Fitted on the given mesh, E comes out low by that mesh's extra bending
/// stiffness; fitted on its refined copy, E is the truth's. The fine polish is short (α and β
/// held, at most 4 simulations of 1,536 tets).
#[test]
fn refine_fits_the_material_not_the_coarse_mesh() {
    let truth = bar(20, 1, 2.0e-4, 5);
    let tets = truth.template.tets.len();
    let settings = softcap_tissue::fit_dynamic::FitDynamicSettings {
        outer_iterations: 1,
        max_simulations: 20,
        fine_max_simulations: 4,
        progress: false,
        refine: 1,
        ..Default::default()
    };
    let fit = fit_quietly(&truth, &settings);
    let coarse = fit.coarse_young_pa.as_ref().unwrap()[0];
    let fine = fit.young_pa[0];
    eprintln!(
        "coarse E {coarse:.4e}, refined E {fine:.4e}, {} simulations",
        fit.simulations
    );
    assert!(
        coarse < 0.8 * E_TRUE,
        "the 192-tet mesh is stiffer in bending: coarse E {coarse:.4e} should be well below {E_TRUE:.1e}"
    );
    assert!(
        (fine / E_TRUE - 1.0).abs() < 0.05,
        "refined fit E {fine:.4e} vs truth {E_TRUE:.1e} (coarse {coarse:.4e})"
    );
    assert_eq!(fit.young_pa_tets.len(), tets);
    assert_eq!(fit.rest_m.len(), truth.template.vertices.len());
    assert_eq!(fit.fit_mesh_size.1, 8 * tets);
}

/// Quadratic elements: a truth converged in bending (quadratic tets on the once-refined mesh),
/// observed at the given mesh's nodes; fitted coarse to fine with quadratic tets on the given
/// 192 tets (α, β fitted again on them), E is the truth's, where the given mesh's linear tets
/// give half of it.
#[test]
fn quadratic_tets_fit_a_converged_truth() {
    let truth = bar_of(16, 1, Elements::Quadratic, 2.0e-4, 7);
    let tets = truth.template.tets.len();
    let settings = softcap_tissue::fit_dynamic::FitDynamicSettings {
        outer_iterations: 1,
        max_simulations: 20,
        fine_max_simulations: 8,
        progress: false,
        elements: Elements::Quadratic,
        ..Default::default()
    };
    let fit = fit_quietly(&truth, &settings);
    let coarse = fit.coarse_young_pa.as_ref().unwrap()[0];
    let fine = fit.young_pa[0];
    eprintln!(
        "coarse linear E {coarse:.4e}, quadratic E {fine:.4e}, alpha {:.3}, beta {:.2e}, {} simulations, status {}",
        fit.damping.alpha_per_s, fit.damping.beta_s, fit.simulations, fit.status
    );
    assert!(coarse < 0.8 * E_TRUE, "coarse linear E {coarse:.4e}");
    assert!(
        (fine / E_TRUE - 1.0).abs() < 0.05,
        "quadratic fit E {fine:.4e} vs truth {E_TRUE:.1e} (coarse {coarse:.4e})"
    );
    assert_eq!(fit.young_pa_tets.len(), tets);
    assert_eq!(fit.fit_mesh_size.1, tets);
}

/// `start_state_modes`: the low-mode share of each segment's initial state is fitted with the
/// parameters (one-segment Jacobian columns); on the small bar E stays within 5 % and the fitted
/// start states lower the trajectory error below the fit from the tracked states.
#[test]
fn start_states_are_fitted_with_the_parameters() {
    let truth = small_bar();
    let fit_with = |modes: usize| {
        let settings = softcap_tissue::fit_dynamic::FitDynamicSettings {
            outer_iterations: 1,
            max_simulations: 40,
            start_state_modes: modes,
            progress: false,
            ..Default::default()
        };
        fit_quietly(&truth, &settings)
    };
    let tracked = fit_with(0);
    let fitted = fit_with(2);
    eprintln!(
        "tracked starts: E {:.4e}, RMS {:.4} mm; fitted starts: E {:.4e}, alpha {:.3}, beta {:.2e}, RMS {:.4} mm, {} + {} one-segment simulations",
        tracked.young_pa[0],
        1e3 * tracked.rms_m,
        fitted.young_pa[0],
        fitted.damping.alpha_per_s,
        fitted.damping.beta_s,
        1e3 * fitted.rms_m,
        fitted.simulations,
        fitted.segment_simulations
    );
    assert_eq!(fitted.start_state_modes, 2);
    assert_eq!(tracked.segment_simulations, 0);
    assert!(fitted.segment_simulations >= 4 * fitted.segments);
    assert!((fitted.young_pa[0] / E_TRUE - 1.0).abs() < 0.05);
    assert!(
        fitted.rms_m < tracked.rms_m,
        "{} vs {}",
        fitted.rms_m,
        tracked.rms_m
    );
    assert_eq!(fitted.covariance.nrows(), 3);
}

/// Model-based start states (`ForwardSettings::start_fit_modes`): fitted in the true body's 24
/// modes to 0.3 mm noisy tracks of the small bar over the whole segment, each segment's start
/// position is closer to the noise-free truth than the tracked (polynomial-smoothed) state; on
/// noise-free tracks it is within 5 % of the motion's amplitude (the linearised modes miss the
/// bent bar's nonlinear share). Its velocity is printed, not asserted: it is not closer (the
/// linear modes ring 0.6 % off the bent bar's frequency over the 0.7 s segment). 1 CPU-s.
#[test]
fn model_based_start_states_denoise_the_tracked_start() {
    use softcap_tissue::fit_dynamic::{Forward, ForwardSettings};
    let clean = bar(30, 0, 0.0, 3);
    let noisy = bar(30, 0, 3.0e-4, 3);
    let segments = clean.sequence.segments(30, 4, 2);
    let n = clean.template.vertices.len();
    let params = true_params(&clean);
    let starts = |truth: &Synthetic, start_fit_modes: usize| {
        let settings = ForwardSettings {
            start_fit_modes,
            ..ForwardSettings::default()
        };
        assert_eq!(settings.start_fit_frames, 30);
        let forward = Forward::new(
            &truth.template,
            &truth.sequence,
            segments.clone(),
            vec![true; n],
            &settings,
        )
        .unwrap();
        let model = forward.model(&params, &clean.rest_m).unwrap();
        forward.start_states(&model, params.damping).unwrap()
    };
    let rms = |a: &[Vector3<f64>], b: &[Vector3<f64>]| {
        (a.iter()
            .zip(b)
            .map(|(p, q)| (p - q).norm_squared())
            .sum::<f64>()
            / n as f64)
            .sqrt()
    };
    // The reference: the noise-free tracked state (the truth's positions; its velocity from the
    // degree-4 polynomial, 1 % low at 30 Hz).
    let reference = starts(&clean, 0);
    let fitted_clean = starts(&clean, 24);
    let tracked = starts(&noisy, 0);
    let fitted = starts(&noisy, 24);
    for (k, seg) in segments.iter().enumerate() {
        let (x, v) = &reference[k];
        let amplitude = x
            .iter()
            .zip(&clean.template.vertices)
            .map(|(p, q)| (p - q).norm())
            .fold(0.0, f64::max);
        let speed = v.iter().map(|p| p.norm()).fold(0.0, f64::max);
        let clean_x = rms(&fitted_clean[k].0, x);
        let (tracked_x, fitted_x) = (rms(&tracked[k].0, x), rms(&fitted[k].0, x));
        let (tracked_v, fitted_v) = (rms(&tracked[k].1, v), rms(&fitted[k].1, v));
        eprintln!(
            "segment {seg:?}: amplitude {:.3} mm, speed {speed:.4} m/s; start position error: noise-free fit {:.4} mm, noisy tracked {:.4} mm, noisy fit {:.4} mm; velocity error: tracked {tracked_v:.4} m/s, fit {fitted_v:.4} m/s",
            1e3 * amplitude,
            1e3 * clean_x,
            1e3 * tracked_x,
            1e3 * fitted_x
        );
        assert!(clean_x < 0.05 * amplitude, "{clean_x} vs {amplitude}");
        assert!(fitted_x < tracked_x, "{fitted_x} vs {tracked_x}");
    }
}

/// Start states against the truth's own state at each segment's start (positions and
/// velocities of the noise-free simulation, `Synthetic::velocities_m_s`), on the small bar:
/// the tracked start (polynomial), the model-based start in the true body's 24 modes
/// (`start_fit_modes`) and the same replacing only those modes' share of the tracked start
/// (`start_fit_keeps_tracked`). On noise-free tracks the kept start is closer to the truth's
/// position than the model-based one (it keeps the bent bar's share outside the linear modes).
/// With `start_fit_choice`, `choose_start_states` picks per segment the start whose simulation
/// fits better, and `start_states` then returns that one. Velocities are printed: on noise-free
/// tracks the polynomial velocity is itself 0.019 m/s RMS off the truth (its peak speed 0.12
/// m/s; the fast modes the 30 Hz frames alias). 2 CPU-s.
#[test]
fn start_states_against_the_truth_and_the_per_segment_choice() {
    use softcap_tissue::fit_dynamic::{Forward, ForwardSettings};
    let clean = bar(30, 0, 0.0, 3);
    let noisy = bar(30, 0, 3.0e-4, 3);
    let segments = clean.sequence.segments(30, 4, 2);
    let n = clean.template.vertices.len();
    let params = true_params(&clean);
    let forward = |truth: &Synthetic, start_fit_modes: usize, keep: bool, choice: bool| {
        let settings = ForwardSettings {
            start_fit_modes,
            start_fit_keeps_tracked: keep,
            start_fit_choice: choice,
            ..ForwardSettings::default()
        };
        Forward::new(
            &truth.template,
            &truth.sequence,
            segments.clone(),
            vec![true; n],
            &settings,
        )
        .unwrap()
    };
    let starts = |f: &Forward| {
        let model = f.model(&params, &clean.rest_m).unwrap();
        f.start_states(&model, params.damping).unwrap()
    };
    let rms = |a: &[Vector3<f64>], b: &[Vector3<f64>]| {
        (a.iter()
            .zip(b)
            .map(|(p, q)| (p - q).norm_squared())
            .sum::<f64>()
            / n as f64)
            .sqrt()
    };
    let variants = [
        (
            "noise-free tracked",
            starts(&forward(&clean, 0, false, false)),
        ),
        ("noise-free kept", starts(&forward(&clean, 24, true, false))),
        (
            "noise-free model",
            starts(&forward(&clean, 24, false, false)),
        ),
        ("noisy tracked", starts(&forward(&noisy, 0, false, false))),
        ("noisy kept", starts(&forward(&noisy, 24, true, false))),
        ("noisy model", starts(&forward(&noisy, 24, false, false))),
    ];
    for (k, seg) in segments.iter().enumerate() {
        let (x, v) = (
            &clean.sequence.positions_m[seg.start],
            &clean.velocities_m_s[seg.start],
        );
        let errors: Vec<(f64, f64)> = variants
            .iter()
            .map(|(_, s)| (rms(&s[k].0, x), rms(&s[k].1, v)))
            .collect();
        for ((name, _), (ex, ev)) in variants.iter().zip(&errors) {
            eprintln!(
                "segment {seg:?} {name}: position {:.4} mm, velocity {ev:.5} m/s",
                1e3 * ex
            );
        }
        assert!(errors[0].0 < 1e-9, "{:?}", errors[0]);
        assert!(errors[1].0 < errors[2].0, "{errors:?}");
    }
    // The per-segment choice, kept for later evaluations.
    let chooser = forward(&noisy, 24, true, true);
    let (choice, sums) = chooser.choose_start_states(&params, &clean.rest_m).unwrap();
    let chosen = starts(&chooser);
    let (tracked, kept) = (&variants[3].1, &variants[4].1);
    for (k, (&c, &(t, m))) in choice.iter().zip(&sums).enumerate() {
        eprintln!(
            "segment {k}: residual sum of squares tracked {t:.3e}, kept {m:.3e} m²; model-based: {c}"
        );
        assert_eq!(c, m < t);
        let expected = if c { &kept[k] } else { &tracked[k] };
        assert!(rms(&chosen[k].0, &expected.0) < 1e-12, "segment {k}");
        assert!(rms(&chosen[k].1, &expected.1) < 1e-12, "segment {k}");
    }
}

/// Coarse to fine in time (`early_segments`): the parameters fitted on the first two of five
/// segments, then polished on all five with a few Levenberg–Marquardt iterations, are those of
/// the fit on all five segments from the warm start (E within 1 %, α and β within 10 %), with
/// fewer simulations of all segments; the truth is recovered as by the plain fit.
#[test]
fn coarse_to_fine_in_time_reaches_the_all_segment_fit() {
    let truth = bar(52, 0, 3.0e-4, 13);
    let fit = |early_segments: usize| {
        let settings = softcap_tissue::fit_dynamic::FitDynamicSettings {
            segment_frames: 9,
            early_segments,
            progress: false,
            ..Default::default()
        };
        fit_quietly(&truth, &settings)
    };
    let (all, staged) = (fit(0), fit(2));
    let show = |name: &str, f: &softcap_tissue::fit_dynamic::DynamicFit| {
        eprintln!(
            "{name}: E {:.4e}, alpha {:.4}, beta {:.4e}, RMS {:.4} mm, {} simulations of all {} segments (+ {:?} of the first), status {}",
            f.young_pa[0],
            f.damping.alpha_per_s,
            f.damping.beta_s,
            1e3 * f.rms_m,
            f.simulations,
            f.segments,
            f.early.as_ref().map(|e| e.simulations),
            f.status
        );
    };
    show("all segments", &all);
    show("coarse to fine in time", &staged);
    assert!(all.segments >= 4, "{} segments", all.segments);
    assert!(all.early.is_none());
    let early = staged.early.as_ref().expect("the early stage ran");
    assert_eq!(early.segments, 2);
    assert!(early.simulations > 0);
    assert!(staged.simulations < all.simulations);
    let rel = |a: f64, b: f64| (a / b - 1.0).abs();
    assert!(rel(staged.young_pa[0], all.young_pa[0]) < 0.01);
    assert!(rel(staged.damping.alpha_per_s, all.damping.alpha_per_s) < 0.10);
    assert!(rel(staged.damping.beta_s, all.damping.beta_s) < 0.10);
    assert!(rel(staged.young_pa[0], E_TRUE) < 0.05);
    assert!(staged.rms_m <= 1.01 * all.rms_m);
}

/// The Table 1 shapes: the clamped bar (bent, twisted by a sideways push on its far top edge)
/// and the leaf blade (bent, twisted by an upward push on its far +y corner).
#[derive(Clone, Copy, Debug)]
enum Table1Shape {
    Bar,
    Leaf,
}

/// wang2015 Table 1 from several motions per noise draw (issue 36; §7 fits each object from a
/// few recorded motions), as `examples/fit_dynamic_table1.rs` `bar1ab` / `leafab --bends 3
/// --twists N --twist-mn 3000 --settle-ms 50 --segment-frames 60 --start-modes 2`: the
/// 200 × 30 × 20 mm bar (E 5·10⁵ Pa) or the 200 × 60 × 6 mm blade (E 2·10⁶ Pa), ν 0.45,
/// ρ 1100 kg/m³, α 0.8 1/s, β 1 ms; three bending pushes (off-axis for 0.2 s, 60 frames at
/// 30 Hz) and `twists` twists (3 N for 0.05 s, 60 frames at 120 Hz), each with its own draw of
/// 0.5 mm spatially correlated noise and its push's interaction extended by 50 ms
/// (`synthesize_motions`). Fitted from the tracked start states, segments of up to 60 frames,
/// the first two modes' share of every start fitted with the parameters (`start_state_modes`: a
/// twist's start velocity from ±2 frames at 120 Hz carries 4× the 30 Hz noise, which rings in
/// the bending modes and biased α up to 15 % without it). Asserts E within 5 %, α within 5 %,
/// β within 20 % (the tolerances). The bar meets them with 4 twists on all of seeds
/// 11–101. The leaf's α error is the noise's own (exact start states leave seed 31 at +4.2 %),
/// along the line that keeps the flap's damping ratio (α and β errors of opposite sign), so it
/// falls as 1/√twists: 4 twists miss seeds 31, 61 (α +5.1 %, −5.8 %), 12 meet seeds 11–111
/// (docs/dynamic-fit.md).
fn table1_protocol_meets_the_tolerances(shape: Table1Shape, seed: u64, twists: u64) {
    use softcap_tissue::fit_dynamic::synthetic::{
        TwistPush, clamped_box, synthesize_motions, table1_motions,
    };
    let (size, cells, young, bend_force) = match shape {
        Table1Shape::Bar => (
            [0.2, 0.03, 0.02],
            [12, 2, 2],
            E_TRUE,
            Vector3::new(0.0, 0.5, -0.4),
        ),
        Table1Shape::Leaf => (
            [0.2, 0.06, 0.006],
            [10, 3, 1],
            2.0e6,
            Vector3::new(0.0, 0.05, -0.08),
        ),
    };
    let (mesh, support, top_edge) = clamped_box(size, cells);
    let off_axis: Vec<usize> = top_edge
        .iter()
        .copied()
        .filter(|&i| mesh.vertices[i].y >= 0.0)
        .collect();
    let (twist_nodes, twist_force) = match shape {
        Table1Shape::Bar => (top_edge, Vector3::new(0.0, 3.0, 0.0)),
        Table1Shape::Leaf => (
            (0..mesh.vertices.len())
                .filter(|&i| {
                    let v = mesh.vertices[i];
                    v.x >= size[0] * (1.0 - 1e-9) && v.y >= 0.5 * size[1] * (1.0 - 1e-9)
                })
                .collect(),
            Vector3::new(0.0, 0.0, 3.0),
        ),
    };
    // Table 1's material, damping and gravity are the small clamped bar's (wang2015 Table 1
    // protocol: ν 0.45, ρ 1100 kg/m³, α 0.8 1/s, β 1e-3 s).
    let bend = SyntheticSpec {
        rest_mesh: mesh.clone(),
        support_nodes: support,
        young_pa: vec![young; mesh.tets.len()],
        push_nodes: off_axis,
        push_force_n: bend_force,
        frames: 60,
        noise_m: 5.0e-4,
        seed: 0,
        ..SyntheticSpec::small_clamped_bar()
    };
    let twist = TwistPush {
        nodes: twist_nodes,
        counter_nodes: Vec::new(),
        force_n: twist_force,
    };
    let specs = table1_motions(&bend, 3, &twist, twists as usize, seed);
    let truth = synthesize_motions(&specs, 0.1, 0.05).unwrap();
    let settings = softcap_tissue::fit_dynamic::FitDynamicSettings {
        segment_frames: 60,
        start_state_modes: 2,
        max_simulations: 200,
        progress: false,
        ..Default::default()
    };
    let fit = fit_quietly(&truth, &settings);
    let e = fit.young_pa[0] / young - 1.0;
    let a = fit.damping.alpha_per_s / 0.8 - 1.0;
    let b = fit.damping.beta_s / 1.0e-3 - 1.0;
    eprintln!(
        "{shape:?} seed {seed}, {twists} twists: E {:+.1} %, alpha {:+.1} %, beta {:+.1} % (1-sigma {:.1} / {:.1} %, segment sandwich {:.1} / {:.1} %), {} frames, status {}",
        100.0 * e,
        100.0 * a,
        100.0 * b,
        100.0 * fit.relative_sigma[1],
        100.0 * fit.relative_sigma[2],
        100.0 * fit.segment_robust_sigma[1],
        100.0 * fit.segment_robust_sigma[2],
        truth.sequence.frames(),
        fit.status
    );
    assert_eq!(truth.sequence.frames() as u64, 60 * (3 + twists));
    assert!(
        e.abs() < 0.05,
        "{shape:?} seed {seed}: E {:+.1} %",
        100.0 * e
    );
    assert!(
        a.abs() < 0.05,
        "{shape:?} seed {seed}: alpha {:+.1} %",
        100.0 * a
    );
    assert!(
        b.abs() < 0.20,
        "{shape:?} seed {seed}: beta {:+.1} %",
        100.0 * b
    );
}

/// [`table1_protocol_meets_the_tolerances`] on one noise draw of each shape with 4 twists, in
/// `make test`.
#[test]
fn table1_one_draw_of_the_bar_and_the_leaf() {
    table1_protocol_meets_the_tolerances(Table1Shape::Bar, 11, 4);
    table1_protocol_meets_the_tolerances(Table1Shape::Leaf, 11, 4);
}

/// [`table1_protocol_meets_the_tolerances`] on more draws: the bar's seed 71, and the leaf's
/// seeds 31 and 61 with 12 twists (with 4, α +5.1 % and −5.8 %).
#[test]
#[ignore = "≈ 180 CPU-s (the bar's seed 71, ≈ 40 CPU-s; the leaf's seeds 31, 61 with 12 twists, 55–80 CPU-s each); cargo test --profile test -p softcap_tissue --test tissue_tests fit_dynamic::table1 -- --ignored"]
fn table1_more_draws_of_the_bar_and_the_leaf() {
    table1_protocol_meets_the_tolerances(Table1Shape::Bar, 71, 4);
    table1_protocol_meets_the_tolerances(Table1Shape::Leaf, 31, 12);
    table1_protocol_meets_the_tolerances(Table1Shape::Leaf, 61, 12);
}
