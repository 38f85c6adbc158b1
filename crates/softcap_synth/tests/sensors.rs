//! The FSR effect "sensor-lag": first-order lag and play hysteresis of the sensed force, checked
//! on a triangular force ramp against their closed forms.

use softcap_synth::nalgebra::{Isometry3, Vector3};
use softcap_synth::sensors::record;
use softcap_synth::truth::stream;
use softcap_synth::{Effect, FrameSpec, FrameTruth, Phase, Scenario};

/// 0 → 2 N → 0 over 2 s in 0.05 s frames, then 2 s at rest.
fn triangle() -> Vec<FrameTruth> {
    (0..=80)
        .map(|k| {
            let t = k as f64 * 0.05;
            let f = if t <= 1.0 {
                2.0 * t
            } else if t <= 2.0 {
                2.0 * (2.0 - t)
            } else {
                0.0
            };
            FrameTruth {
                spec: FrameSpec {
                    frame: k,
                    t_camera_s: t,
                    phase: Phase::Loading,
                    location: 0,
                    world_from_probe: Isometry3::identity(),
                    depth_m: 0.0,
                },
                markers_m: Vec::new(),
                marker_normals: Vec::new(),
                force_n: Vector3::new(0.0, 0.0, -f),
                axial_force_n: f,
                friction_force_n: Vector3::zeros(),
                support_slip_m: Vector3::zeros(),
                iterations: 0,
            }
        })
        .collect()
}

/// Sensed force at camera time t (nearest DAQ sample; noise-free clock relation of the record).
fn sensed_at(s: &Scenario, frames: &[FrameTruth], t_cam: f64) -> f64 {
    let d = record(s, frames, &mut stream(1, 3));
    let t_daq = d.offset_s + (1.0 + d.drift) * t_cam;
    let k = d
        .t_daq_s
        .iter()
        .enumerate()
        .min_by(|a, b| (a.1 - t_daq).abs().total_cmp(&(b.1 - t_daq).abs()))
        .unwrap()
        .0;
    d.sensed_force_n[k]
}

#[test]
fn hysteresis_reads_low_while_loading_and_high_while_unloading() {
    let frames = triangle();
    let mut s = Scenario {
        effects: vec![Effect::SensorLag],
        ..Default::default()
    };
    s.effect_settings.sensor_lag_tau_s = 1e-4; // isolate the play operator
    s.effect_settings.sensor_hysteresis_fraction = 0.08;
    let up = sensed_at(&s, &frames, 0.5); // true 1 N, loading
    let down = sensed_at(&s, &frames, 1.5); // true 1 N, unloading
    println!("at 1 N: loading {up:.4} N, unloading {down:.4} N");
    assert!((up - 0.92).abs() < 0.01, "{up}");
    assert!((down - 1.08).abs() < 0.01, "{down}");
    assert!(sensed_at(&s, &frames, 3.9).abs() < 1e-9);
    // Without the effect the FSR element sees the true force.
    s.effects.clear();
    assert!((sensed_at(&s, &frames, 0.5) - 1.0).abs() < 0.01);
}

#[test]
fn first_order_lag_delays_the_ramp_by_tau() {
    let frames = triangle();
    let mut s = Scenario {
        effects: vec![Effect::SensorLag],
        ..Default::default()
    };
    s.effect_settings.sensor_lag_tau_s = 0.2;
    s.effect_settings.sensor_hysteresis_fraction = 0.0;
    // On a ramp F = 2t the lagged response is 2(t − τ(1 − e^{−t/τ})): behind by ≈ 2τ = 0.4 N.
    let t: f64 = 0.9;
    let expect = 2.0 * (t - 0.2 * (1.0 - (-t / 0.2).exp()));
    let got = sensed_at(&s, &frames, t);
    println!(
        "lagged at {t} s: {got:.4} N (closed form {expect:.4} N, true {:.1} N)",
        2.0 * t
    );
    assert!((got - expect).abs() < 0.02, "{got} vs {expect}");
}
