//! The dynamic replay of the inertia-damping hypothesis (`Extension::Dynamic`: wang2015 eq. 3,
//! M ü + (αM + βK) u̇ + f_int(u) = f_ext, Newmark average acceleration, driven by the force) against
//! its limits on the 648-tet block (40 × 40 × 20 mm, E = 20 kPa, ν = 0.45, fixed base), a force
//! on the top-centre node:
//!
//! - massless, stiffness-proportional damping only (ρ → 0, α = 0, β = τ): β K u̇ + K u = f is a
//!   first-order lag of every mode with the same τ, so after a force ramped on over Δ and held
//!   u(t) = u_qs [1 − (τ/Δ)(e^{Δ/τ} − 1) e^{−(t−t₀)/τ}] (u_qs the quasi-static response);
//! - slow probing (ramps of seconds, the block's lowest period a few ms): the quasi-static model;
//! - released in 1 ms from a static press, undamped: the surface springs back past its rest
//!   shape (the quasi-static model sits at rest).
//!
//! and the rigid-tip dynamic replay (`simulate_sequence_rigid_tip` of `Extension::Dynamic`: the
//! same dynamics with a 5 mm sphere at the commanded poses as penalty contact) against its own:
//! slow probing equals the quasi-static rigid-tip replay, and a tip lifted off at once leaves the
//! surface to spring back past rest.

use nalgebra::Vector3;
use softcap_diagnose::{
    Extension, FemProbeSimulator, FemSimSettings, ProbeLoad, SequenceFrame, SimLoad,
};
use softcap_fem::{CorotationalModel, LinearParams, TipShape};

const CENTRE: [f64; 3] = [0.02, 0.02, 0.02];

fn simulator() -> FemProbeSimulator {
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [0.04, 0.04, 0.02], [6, 6, 3]);
    let model =
        CorotationalModel::homogeneous(&mesh, LinearParams::from_young_poisson(2e4, 0.45).unwrap())
            .unwrap();
    let fixed = FemProbeSimulator::nodes_on_plane(&mesh, &Vector3::z(), 0.0, 1e-9);
    let markers = vec![
        Vector3::from(CENTRE),
        Vector3::new(0.02 + 0.04 / 6.0, 0.02, 0.02),
        Vector3::new(0.005, 0.005, 0.02),
    ];
    FemProbeSimulator::new(&mesh, model, &fixed, &markers, FemSimSettings::default()).unwrap()
}

/// Frames at times `t` with the downward force `f(t)` (N) on the top centre.
fn frames(times: &[f64], f: impl Fn(f64) -> f64) -> Vec<SequenceFrame> {
    times
        .iter()
        .map(|&t| SequenceFrame {
            time_s: t,
            load: SimLoad {
                probe: (f(t) > 0.0).then(|| ProbeLoad {
                    tip_m: Vector3::from(CENTRE),
                    axis: -Vector3::z(),
                    force_n: -Vector3::z() * f(t),
                }),
                body_force_n_m3: Vector3::zeros(),
            },
        })
        .collect()
}

/// Vertical displacement of marker 0 (top centre) per frame, m.
fn uz(x: &[Vec<Vector3<f64>>]) -> Vec<f64> {
    x.iter().map(|row| row[0].z - CENTRE[2]).collect()
}

#[test]
fn stiffness_proportional_damping_without_mass_is_a_first_order_lag() {
    let sim = simulator();
    let (tau, ramp, force) = (0.05, 0.01, 0.02);
    let times: Vec<f64> = (0..=40).map(|k| 0.01 * k as f64).collect();
    let seq = frames(&times, |t| if t > 0.0 { force } else { 0.0 });
    let quasi = uz(&sim.simulate_sequence(&Extension::Elastic, &seq).unwrap());
    let u_qs = quasi[5];
    assert!(u_qs < -5e-5, "the press moves the surface down: {u_qs}");
    let lag = uz(&sim
        .simulate_sequence(
            &Extension::Dynamic {
                density_kg_m3: 1e-3,
                alpha_per_s: 0.0,
                beta_s: tau,
                lame_ratio_factor: 1.0,
            },
            &seq,
        )
        .unwrap());
    for (k, &t) in times.iter().enumerate().skip(1) {
        let want = u_qs * (1.0 - (tau / ramp) * ((ramp / tau).exp() - 1.0) * (-t / tau).exp());
        assert!(
            (lag[k] - want).abs() <= 0.01 * u_qs.abs(),
            "t {t}: {} vs {want} (u_qs {u_qs})",
            lag[k]
        );
    }
}

#[test]
fn slow_probing_is_quasi_static() {
    let sim = simulator();
    let times: Vec<f64> = (0..=12).map(|k| 0.5 * k as f64).collect();
    // ramp on over 2 s, hold 2 s, ramp off over 2 s
    let f = |t: f64| 0.02 * (t / 2.0).min(1.0).min((6.0 - t) / 2.0).max(0.0);
    let seq = frames(&times, f);
    let quasi = sim.simulate_sequence(&Extension::Elastic, &seq).unwrap();
    let dynamic = sim
        .simulate_sequence(
            &Extension::Dynamic {
                density_kg_m3: 1000.0,
                alpha_per_s: 20.0,
                beta_s: 1e-3,
                lame_ratio_factor: 1.0,
            },
            &seq,
        )
        .unwrap();
    let peak = uz(&quasi).into_iter().fold(0.0f64, |a, b| a.max(b.abs()));
    for (q, d) in quasi.iter().zip(&dynamic) {
        for (a, b) in q.iter().zip(d) {
            assert!((a - b).norm() <= 0.01 * peak, "{a} vs {b} (peak {peak})");
        }
    }
}

#[test]
fn a_fast_release_rebounds_past_the_rest_shape() {
    let sim = simulator();
    // pressed and at rest at t = 0, the force off within 1 ms, then 60 ms of free motion
    let times: Vec<f64> = (0..=60).map(|k| 0.001 * k as f64).collect();
    let seq = frames(&times, |t| if t < 0.0005 { 0.02 } else { 0.0 });
    let quasi = uz(&sim.simulate_sequence(&Extension::Elastic, &seq).unwrap());
    let dynamic = uz(&sim
        .simulate_sequence(
            &Extension::Dynamic {
                density_kg_m3: 1000.0,
                alpha_per_s: 0.0,
                beta_s: 0.0,
                lame_ratio_factor: 1.0,
            },
            &seq,
        )
        .unwrap());
    let u0 = dynamic[0];
    assert!(u0 < -5e-5 && (u0 - quasi[0]).abs() < 1e-9 * u0.abs().max(1.0));
    assert!(
        quasi[1..].iter().all(|u| u.abs() < 1e-12),
        "quasi-static: at rest"
    );
    let rebound = dynamic.iter().fold(f64::NEG_INFINITY, |a, &b| a.max(b));
    assert!(
        rebound > 0.3 * u0.abs(),
        "rebound {rebound} past rest for a press of {u0}"
    );
}

/// Frames at times `t` with the 5 mm sphere's tip `depth(t)` (m, ≤ 0: above the surface) below
/// the top centre, straight down.
fn pose_frames(times: &[f64], depth: impl Fn(f64) -> f64) -> Vec<SequenceFrame> {
    times
        .iter()
        .map(|&t| SequenceFrame {
            time_s: t,
            load: SimLoad {
                probe: Some(ProbeLoad {
                    tip_m: Vector3::from(CENTRE) - Vector3::z() * depth(t),
                    axis: -Vector3::z(),
                    force_n: Vector3::zeros(),
                }),
                body_force_n_m3: Vector3::zeros(),
            },
        })
        .collect()
}

#[test]
fn slow_rigid_tip_probing_is_the_quasi_static_rigid_replay() {
    let sim = simulator().with_rigid_tip(TipShape::Sphere { radius_m: 0.005 });
    // 2 mm deep over 2 s, held 2 s, up over 2 s, frames 0.1 s apart (steps of 25 ms resolve the
    // block's lowest modes, ≈ 30 Hz); the tip starts and ends 0.05 mm above the surface, so the
    // release (the frame after the last one in contact lifts it off at once) leaves 0.05 mm to
    // spring back
    let times: Vec<f64> = (0..=65).map(|k| 0.1 * k as f64).collect();
    let seq = pose_frames(&times, |t| {
        2e-3 * (t / 2.0).min(1.0).min((6.0 - t) / 2.0).max(0.0) - 5e-5
    });
    let quasi = sim
        .simulate_sequence_rigid_tip(&Extension::Elastic, &seq)
        .unwrap()
        .expect("the simulator has a rigid tip");
    let dynamic = sim
        .simulate_sequence_rigid_tip(
            &Extension::Dynamic {
                density_kg_m3: 1000.0,
                alpha_per_s: 20.0,
                beta_s: 1e-3,
                lame_ratio_factor: 1.0,
            },
            &seq,
        )
        .unwrap()
        .expect("the rigid tip replays the dynamic model");
    let peak = uz(&quasi).into_iter().fold(0.0f64, |a, b| a.max(b.abs()));
    assert!(peak > 1e-3, "the tip presses the surface down: {peak}");
    let worst = quasi
        .iter()
        .zip(&dynamic)
        .flat_map(|(q, d)| q.iter().zip(d).map(|(a, b)| (a - b).norm()))
        .fold(0.0f64, f64::max);
    // measured 0.19 % of the peak
    assert!(
        worst <= 0.01 * peak,
        "{worst} m off the quasi-static replay (peak {peak})"
    );
}

#[test]
fn a_rigid_tip_lifted_at_once_leaves_the_surface_ringing() {
    let sim = simulator().with_rigid_tip(TipShape::Sphere { radius_m: 0.005 });
    // 2 mm deep at t = 0 (solved quasi-statically), 5 mm above the surface 1 ms later, then 60 ms
    let times: Vec<f64> = (0..=60).map(|k| 0.001 * k as f64).collect();
    let seq = pose_frames(&times, |t| if t < 0.0005 { 2e-3 } else { -5e-3 });
    let quasi = uz(&sim
        .simulate_sequence_rigid_tip(&Extension::Elastic, &seq)
        .unwrap()
        .unwrap());
    let dynamic = uz(&sim
        .simulate_sequence_rigid_tip(
            &Extension::Dynamic {
                density_kg_m3: 1000.0,
                alpha_per_s: 0.0,
                beta_s: 0.0,
                lame_ratio_factor: 1.0,
            },
            &seq,
        )
        .unwrap()
        .unwrap());
    let u0 = dynamic[0];
    assert!(
        u0 < -1e-3 && (u0 - quasi[0]).abs() < 1e-9,
        "pressed: {u0} vs {}",
        quasi[0]
    );
    assert!(
        quasi[1..].iter().all(|u| u.abs() < 1e-9),
        "quasi-static: at rest"
    );
    let rebound = dynamic.iter().fold(f64::NEG_INFINITY, |a, &b| a.max(b));
    assert!(
        rebound > 0.3 * u0.abs(),
        "rebound {rebound} past rest for a press of {u0}"
    );
}
