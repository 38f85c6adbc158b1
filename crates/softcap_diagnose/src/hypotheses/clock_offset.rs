//! `clock-offset`: the camera and force clocks disagree by a constant offset.
//!
//! Screen: the force trace shifted in time, f_eff(t) = f(t + δ), δ on a grid of a quarter of the
//! median frame interval over ±0.3 s (a fixed offset field through the tangent response).
//! Signature: equal force delays at 10 % and 50 % of the ramp (a pure time shift; a lag's delay
//! grows). Confirmation: the default model under the shifted force, δ around the screen's
//! estimate, with the material refitted to the shifted forces (`force_channel`).

use super::Effect;
use super::contract::{Context, Hypothesis, param};
use super::force_channel;
use crate::Result;
use crate::confirm::Confirmed;
use crate::screen::{Refit, Variant};
use crate::signal::{median_dt, sample};
use crate::signatures::Signatures;
use crate::sim::ProbeSimulator;
use nalgebra::Vector3;

/// The clock-offset hypothesis.
pub struct ClockOffset;

/// Force trace shifted in time, f_eff(t_k) = f(t_k + δ) (linear interpolation, held at the ends).
pub fn shifted_forces(t: &[f64], f: &[Vector3<f64>], offset_s: f64) -> Vec<Vector3<f64>> {
    t.iter().map(|&tk| sample(t, f, tk + offset_s)).collect()
}

impl Hypothesis for ClockOffset {
    fn effect(&self) -> Effect {
        Effect::ClockOffset
    }

    fn term(&self) -> &'static str {
        "force time base shifted: f_eff(t) = f(t + offset_s)"
    }

    fn variants(&self, cx: &Context<'_>) -> Vec<Variant> {
        let p = cx.prepared;
        let (f, t) = (&p.force_n, &p.times_s);
        let nt = t.len();
        let dt_med = {
            let mut d: Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).collect();
            d.sort_by(f64::total_cmp);
            d.get(d.len() / 2).copied().unwrap_or(0.03)
        };
        let step = (dt_med / 4.0).clamp(1e-3, 0.01);
        let nsteps = (0.3 / step).round() as i64;
        (-nsteps..=nsteps)
            .filter(|&i| i != 0)
            .map(|i| i as f64 * step)
            .map(|delta| {
                let df: Vec<_> = (0..nt).map(|k| sample(t, f, t[k] + delta) - f[k]).collect();
                Variant {
                    fixed: vec![("offset_s", delta)],
                    offset: Some(p.load_field(&df)),
                    bases: vec![],
                }
            })
            .collect()
    }

    fn signature_support(&self, s: &Signatures) -> f64 {
        if s.delays_like_a_time_shift() {
            1.0
        } else {
            0.0
        }
    }

    fn confirm(
        &self,
        cx: &Context<'_>,
        refit: &Refit,
        scored: &dyn Fn(usize, usize) -> bool,
        sim: &mut dyn ProbeSimulator,
    ) -> Result<Option<Confirmed>> {
        let (rec, seg, p) = (cx.rec, cx.seg, cx.prepared);
        let t = &p.times_s;
        let dt = median_dt(t);
        let thr = 1e-3 * seg.peak_force_n().max(1e-9);
        let d0 = param(&refit.params, "offset_s").unwrap_or(0.0);
        let step = (dt / 8.0).clamp(1e-3, 0.01);
        let grid = (-4..=4)
            .map(|i| {
                let offset_s = d0 + i as f64 * step;
                let f = shifted_forces(t, &p.force_n, offset_s);
                (
                    vec![("offset_s".into(), offset_s)],
                    force_channel::frames_with_forces(rec, &f, thr),
                )
            })
            .collect();
        force_channel::confirm(
            grid,
            rec,
            seg,
            p,
            sim,
            cx.settings.refit_compliance_scale,
            scored,
            "time-shifted force f(t + offset)",
            "default model under the time-shifted force f(t + offset)",
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shifting_recovers_a_delayed_ramp() {
        let t: Vec<f64> = (0..50).map(|k| 0.02 * k as f64).collect();
        let f: Vec<_> = t
            .iter()
            .map(|&x| Vector3::new((x - 0.3).max(0.0), 0.0, 0.0))
            .collect();
        let delayed: Vec<_> = t
            .iter()
            .map(|&x| Vector3::new((x - 0.3 - 0.1).max(0.0), 0.0, 0.0))
            .collect();
        let s = shifted_forces(&t, &delayed, 0.1);
        for k in 0..45 {
            assert!((s[k].x - f[k].x).abs() < 1e-12, "{k}");
        }
    }
}
