//! `sensor-lag`: the force sensor's reading lags and loops behind the force on the object.
//!
//! Screen: the FSR chain of [`crate::sensor`] to first order in (τ, h): the reading r lags the
//! force by τ ṙ and its play reads low by h r while the force rises, high while it falls, so
//! f_true ≈ f + τ ḟ + h sgn(ḟ) f (ḟ along the force), τ, h ≥ 0 through the tangent response.
//! Signature: the force still rising in the holds, a delay that grows along the ramp (a pure time
//! shift's is constant: clock-offset). Confirmation: the default model under the true force behind
//! the reading (the chain inverted by a regularised forward fit, [`crate::sensor::true_forces`]) —
//! lag τ around the screen's estimate × play h ∈ {0, 2.5, 5, 10 %, the estimate} — with the
//! material refitted to the corrected forces (`force_channel`).

use super::Effect;
use super::contract::{Context, Hypothesis, param};
use super::force_channel;
use crate::Result;
use crate::confirm::Confirmed;
use crate::indentation::{Column, ForceCandidate, ForceObservations, heldout_fit};
use crate::screen::{Basis, Refit, Variant};
use crate::signal::{derivative, median_dt};
use crate::signatures::Signatures;
use crate::sim::ProbeSimulator;
use nalgebra::Vector3;

/// The sensor-lag hypothesis.
pub struct SensorLag;

impl Hypothesis for SensorLag {
    fn effect(&self) -> Effect {
        Effect::SensorLag
    }

    fn term(&self) -> &'static str {
        "FSR chain: first-order lag tau_s then play hysteresis of half-width hysteresis * f (f_true = f + tau_s df/dt + hysteresis sgn(df/dt) f to first order)"
    }

    fn variants(&self, cx: &Context<'_>) -> Vec<Variant> {
        let p = cx.prepared;
        let (f, t) = (&p.force_n, &p.times_s);
        let d = derivative(t, f);
        let play: Vec<Vector3<f64>> = f
            .iter()
            .zip(&d)
            .map(|(f, d)| f * d.dot(f).signum())
            .collect();
        vec![Variant {
            fixed: vec![],
            offset: None,
            bases: vec![
                Basis {
                    name: "tau_s",
                    nonneg: true,
                    field: p.load_field(&d),
                },
                Basis {
                    name: "hysteresis",
                    nonneg: true,
                    field: p.load_field(&play),
                },
            ],
        }]
    }

    fn signature_support(&self, s: &Signatures) -> f64 {
        let mut v = 0.0;
        if s.hold_force_drift > super::clock_offset::RISING_HOLD_DRIFT {
            v += 1.0;
        } else if s.hold_force_drift < -0.01 {
            v -= 1.0;
        }
        if s.delays_like_a_time_shift() {
            v -= 0.5;
        } else if s.delays_like_a_lag() {
            v += 0.5;
        }
        v
    }

    /// The true force behind the reading through the inverse FSR chain
    /// ([`crate::sensor::true_forces`]) at the fitted τ and play: the lag's exponential approach
    /// after a ramp's corner, which its first-order screen term τ ḟ (a time shift's) leaves out.
    fn planning_variant(&self, cx: &Context<'_>, refit: &Refit) -> Option<Variant> {
        let p = cx.prepared;
        let tau_s = param(&refit.params, "tau_s")?;
        let h = param(&refit.params, "hysteresis").unwrap_or(0.0);
        let axes: Vec<Vector3<f64>> = cx.rec.frames.iter().map(|f| f.axis).collect();
        let f = crate::sensor::true_forces(&p.times_s, &p.force_n, &axes, tau_s, h);
        let df: Vec<Vector3<f64>> = f.iter().zip(&p.force_n).map(|(a, b)| a - b).collect();
        Some(Variant {
            fixed: vec![],
            offset: Some(p.load_field(&df)),
            bases: vec![],
        })
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
        // The FSR chain (crate::sensor): lag τ around the screen's estimate × play fraction h
        // from none to 10 % — the hysteresis FSR data sheets quote (Interlink FSR 400
        // series: ±10 % average, (R_F+ − R_F−)/R_F+) — and the screen's own estimate.
        let tau0 = param(&refit.params, "tau_s").unwrap_or(dt).max(0.25 * dt);
        let h0 = param(&refit.params, "hysteresis").unwrap_or(0.0);
        let axes: Vec<Vector3<f64>> = rec.frames.iter().map(|f| f.axis).collect();
        let mut hs = vec![0.0, 0.025, 0.05, 0.1];
        if h0 > 0.0 && h0 < 0.5 && !hs.contains(&h0) {
            hs.push(h0);
        }
        let obs = ForceObservations::new(rec, seg, p);
        // the force channel's candidates: the reading itself (no lag), then every grid point's
        // true force, each with the nuisance's scale and tip offset
        let force_column = |params, f: &[Vector3<f64>]| {
            force_channel::corrected_force_candidate(&obs, params, f, rec)
        };
        let mut force_grid = vec![force_column(
            vec![("tau_s".into(), 0.0), ("hysteresis".into(), 0.0)],
            &p.force_n,
        )];
        let mut grid = Vec::new();
        for m in [0.8, 0.9, 1.0, 1.1, 1.25] {
            for &h in &hs {
                let tau_s = tau0 * m;
                let f = crate::sensor::true_forces(t, &p.force_n, &axes, tau_s, h);
                let params = vec![("tau_s".into(), tau_s), ("hysteresis".into(), h)];
                force_grid.push(force_column(params.clone(), &f));
                grid.push((params, force_channel::frames_with_forces(rec, &f, thr)));
            }
        }
        let force = heldout_fit(&obs, seg, &force_grid);
        let confirmed = force_channel::confirm(
            grid,
            rec,
            seg,
            p,
            sim,
            cx.settings.refit_compliance_scale,
            scored,
            "true force through the inverse FSR chain (lag tau, play hysteresis)",
            "default model under the true force through the inverse FSR chain (lag tau, play hysteresis)",
        )?;
        Ok(confirmed.map(|c| Confirmed { force, ..c }))
    }

    /// The FSR chain itself ([`crate::sensor::reading`]) at the force fit's lag and play: the
    /// first-order approach after each ramp corner.
    fn reading_of(&self, params: &[(String, f64)], t: &[f64], force_n: &[f64]) -> Option<Vec<f64>> {
        let tau_s = param(params, "tau_s")?;
        let h = param(params, "hysteresis").unwrap_or(0.0);
        Some(crate::sensor::reading(t, force_n, tau_s, h, false).0)
    }

    /// The FSR chain to first order on the force channel: y = a f + o / c + τ ḟ + h sgn(ḟ) f
    /// (the true force behind a lagging, looping reading f; τ, h ≥ 0).
    fn force_candidates(
        &self,
        cx: &Context<'_>,
        obs: &ForceObservations,
    ) -> Option<Vec<ForceCandidate>> {
        let f = &obs.reading_n;
        let d = derivative(&cx.prepared.times_s, f);
        let mut cols = obs.nuisance();
        cols.push(Column::nonneg("tau_s", d.clone()));
        let peak = f.iter().fold(0.0f64, |a, b| a.max(b.abs()));
        let side = play_side(&d, 0.05 * peak);
        cols.push(Column::nonneg(
            "hysteresis",
            f.iter().zip(&side).map(|(f, s)| f * s).collect(),
        ));
        Some(vec![(Vec::new(), cols)])
    }
}

/// The side of the play band the reading sits on per frame: +1 after the force last rose, −1
/// after it last fell (a play operator keeps its side while the force holds), 0 before it first
/// moved; a rate |ḟ| below `dead_n_per_s` is holding.
fn play_side(rate: &[f64], dead_n_per_s: f64) -> Vec<f64> {
    let mut side = 0.0;
    rate.iter()
        .map(|&d| {
            if d.abs() > dead_n_per_s {
                side = d.signum();
            }
            side
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn delagging_inverts_a_first_order_sensor_on_a_smooth_signal() {
        // f(t) = 1 + ½ sin(2π t) along the axis: the lagged reading f_m solves τ ḟ_m = f − f_m;
        // the sensor inverse (no play) recovers f.
        let tau = 0.2;
        let t: Vec<f64> = (0..400).map(|k| 0.005 * k as f64).collect();
        let f: Vec<_> = t
            .iter()
            .map(|&x| Vector3::new(1.0 + 0.5 * (std::f64::consts::TAU * x).sin(), 0.0, 0.0))
            .collect();
        let m = crate::signal::low_pass(&t, &f, tau);
        let back = crate::sensor::true_forces(&t, &m, &vec![Vector3::x(); t.len()], tau, 0.0);
        for k in 0..400 {
            assert!(
                (back[k].x - f[k].x).abs() < 2e-3,
                "{k}: {} vs {}",
                back[k].x,
                f[k].x
            );
        }
    }
}
