//! The force-sensing resistor, the DAQ and its clock, the trigger line, and the sensor-lag effect.
//!
//! FSR (bickel2009 §5): R(F) = min(k F^(−γ), R_max), read through a divider,
//! v = V_s · R_d / (R_d + R(F)). The DAQ samples v on its own clock,
//! t_daq = offset + (1 + drift) · t_camera (docs/session-format.md truth/clock.toml), adds Gaussian noise and
//! quantises to `adc_bits` over 0..V_s. The trigger line is high during each frame's exposure.
//!
//! sensor-lag: the force the FSR element reports follows the true axial force F through a
//! first-order lag, τ dF_l/dt = F − F_l (exact discretisation per DAQ step), then a play-type
//! hysteresis whose half-width is proportional to the force: y ← clamp(y, F_l(1 − h), F_l(1 + h)),
//! so it reads low while loading, high while unloading and returns to 0 at no load.
//!
//! clock-offset with `clock_force_latency_s` = δ > 0: the trigger line is recorded as usual, but the
//! FSR channel reads at DAQ time t the force of camera time t − δ (a constant channel latency such
//! as a delta-sigma ADC's filter group delay): a pure time shift of force against geometry.

use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use crate::scenario::{Effect, FsrSettings, Scenario};
use crate::truth::FrameTruth;

/// Divider voltage of the FSR under axial force `force_n` (noise-free), V.
pub fn fsr_voltage(fsr: &FsrSettings, force_n: f64) -> f64 {
    let r = if force_n > 0.0 {
        (fsr.k_ohm * force_n.powf(-fsr.exponent)).min(fsr.r_max_ohm)
    } else {
        fsr.r_max_ohm
    };
    fsr.supply_v * fsr.divider_ohm / (fsr.divider_ohm + r)
}

/// Calibration table [[force_n, voltage_v]] with multiplicative voltage noise, strictly
/// increasing in both columns.
pub fn calibration(fsr: &FsrSettings, rng: &mut ChaCha8Rng) -> Vec<[f64; 2]> {
    let noise = Normal::new(0.0, fsr.calibration_noise.max(0.0)).expect("finite σ");
    let mut forces = fsr.calibration_forces_n.clone();
    forces.sort_by(f64::total_cmp);
    forces.dedup();
    let mut out: Vec<[f64; 2]> = Vec::with_capacity(forces.len());
    for f in forces {
        let mut v = fsr_voltage(fsr, f) * (1.0 + noise.sample(rng));
        if let Some(last) = out.last() {
            v = v.max(last[1] + 1e-4);
        }
        out.push([f, v]);
    }
    out
}

/// Piecewise-linear axial force of the frames at camera time `t`, N (held constant outside).
pub fn axial_force_at(frames: &[FrameTruth], t_camera_s: f64) -> f64 {
    let first = &frames[0];
    if t_camera_s <= first.spec.t_camera_s {
        return first.axial_force_n;
    }
    for w in frames.windows(2) {
        let (a, b) = (&w[0], &w[1]);
        if t_camera_s <= b.spec.t_camera_s {
            let s = (t_camera_s - a.spec.t_camera_s) / (b.spec.t_camera_s - a.spec.t_camera_s);
            return a.axial_force_n + s * (b.axial_force_n - a.axial_force_n);
        }
    }
    frames[frames.len() - 1].axial_force_n
}

/// The DAQ recording.
#[derive(Clone, Debug, PartialEq)]
pub struct DaqRecord {
    /// Sample times on the DAQ clock, s.
    pub t_daq_s: Vec<f64>,
    /// FSR divider voltage, V.
    pub voltage_v: Vec<f64>,
    /// Trigger line, V (None without a trigger line).
    pub trigger_v: Option<Vec<f64>>,
    /// The force the FSR element responded to (after lag / hysteresis), N.
    pub sensed_force_n: Vec<f64>,
    /// Clock offset actually used, s.
    pub offset_s: f64,
    /// Clock drift actually used.
    pub drift: f64,
}

/// Samples the FSR and the trigger line on the DAQ clock.
pub fn record(s: &Scenario, frames: &[FrameTruth], rng: &mut ChaCha8Rng) -> DaqRecord {
    let fsr = &s.fsr;
    // clock-offset with a latency: trigger kept, force channel delayed; otherwise no trigger line
    // and an extra DAQ offset.
    let latency_s = if s.has(Effect::ClockOffset) {
        s.effect_settings.clock_force_latency_s
    } else {
        0.0
    };
    let clock_offset = s.has(Effect::ClockOffset) && latency_s <= 0.0;
    let offset_s = s.clock.offset_s
        + if clock_offset {
            s.effect_settings.clock_extra_offset_s
        } else {
            0.0
        };
    let drift = s.clock.drift;
    let to_daq = |t_cam: f64| offset_s + (1.0 + drift) * t_cam;
    let to_cam = |t_daq: f64| (t_daq - offset_s) / (1.0 + drift);
    let dt = 1.0 / fsr.daq_rate_hz;
    let t0 = (to_daq(frames[0].spec.t_camera_s - fsr.margin_s) / dt).floor() * dt;
    let t1 = to_daq(frames[frames.len() - 1].spec.t_camera_s + fsr.margin_s);
    let n = ((t1 - t0) / dt).ceil() as usize + 1;
    let noise = Normal::new(0.0, fsr.noise_v.max(0.0)).expect("finite σ");
    let lsb = if fsr.adc_bits > 0 {
        fsr.supply_v / ((1u64 << fsr.adc_bits) - 1) as f64
    } else {
        0.0
    };
    let quantise = |v: f64| {
        if lsb > 0.0 {
            (v / lsb).round() * lsb
        } else {
            v
        }
    };
    let lag = s.has(Effect::SensorLag);
    let tau = s.effect_settings.sensor_lag_tau_s.max(1e-9);
    let h = s.effect_settings.sensor_hysteresis_fraction;
    let (mut lagged, mut play) = (0.0f64, 0.0f64);
    let mut out = DaqRecord {
        t_daq_s: Vec::with_capacity(n),
        voltage_v: Vec::with_capacity(n),
        trigger_v: (!clock_offset).then(|| Vec::with_capacity(n)),
        sensed_force_n: Vec::with_capacity(n),
        offset_s,
        drift,
    };
    for k in 0..n {
        let t_daq = t0 + k as f64 * dt;
        let t_cam = to_cam(t_daq);
        let f_true = axial_force_at(frames, t_cam - latency_s).max(0.0);
        let f_sensed = if lag {
            if k == 0 {
                lagged = f_true;
                play = f_true;
            } else {
                lagged += (1.0 - (-dt / tau).exp()) * (f_true - lagged);
            }
            play = play.clamp(lagged * (1.0 - h), lagged * (1.0 + h));
            play
        } else {
            f_true
        };
        let v = quantise(fsr_voltage(fsr, f_sensed) + noise.sample(rng));
        out.t_daq_s.push(t_daq);
        out.voltage_v.push(v);
        out.sensed_force_n.push(f_sensed);
        if let Some(tr) = out.trigger_v.as_mut() {
            let high = frames
                .iter()
                .any(|f| (t_cam - f.spec.t_camera_s).abs() <= 0.5 * fsr.exposure_s);
            let level = if high { fsr.trigger_high_v } else { 0.0 };
            tr.push(level + 2.0 * noise.sample(rng));
        }
    }
    out
}
