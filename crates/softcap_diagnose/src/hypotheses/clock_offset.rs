//! `clock-offset`: the camera and force clocks disagree by a constant offset.
//!
//! Screen: the force trace shifted in time, f_eff(t) = f(t + δ), δ on a grid of a quarter of the
//! median frame interval over ±0.3 s (a fixed offset field through the tangent response), and δ
//! continuous in its small-offset limit f + δ ḟ (`first_order_variant`).
//! Signature: the force still rising in the holds (a late reading, as a lag's), and force delays
//! at 10 % and 50 % of the ramp that do not grow as a lag's would, beyond their standard error
//! (a pure time shift). Confirmation: the default model under the shifted force, δ around the
//! screen's estimate, with the material refitted to the shifted forces (`force_channel`).
//! Force channel (`crate::indentation`): the force the default model needs at the tracked tip
//! depth against the reading read through the shifted clock, y ≈ a f(t + δ) + o / c — the model
//! the lag's y ≈ a f + o / c + τ ḟ + h sgn(ḟ) f competes with on the same observations.

use super::Effect;
use super::contract::{Context, Hypothesis, param};
use super::force_channel;
use crate::Result;
use crate::confirm::Confirmed;
use crate::indentation::{ForceCandidate, ForceObservations, heldout_fit};
use crate::screen::{Basis, FrameStats, Refit, Variant, bounded_least_squares};
use crate::signal::{derivative, median_dt, sample};
use crate::signatures::Signatures;
use crate::sim::ProbeSimulator;
use nalgebra::Vector3;

/// The clock-offset hypothesis.
pub struct ClockOffset;

/// Force trace shifted in time, f_eff(t_k) = f(t_k + δ) (linear interpolation, held at the ends).
pub fn shifted_forces(t: &[f64], f: &[Vector3<f64>], offset_s: f64) -> Vec<Vector3<f64>> {
    t.iter().map(|&tk| sample(t, f, tk + offset_s)).collect()
}

/// The hold force drift ((last − first)/peak over the holds) above which the force is still
/// rising in the holds: the reading behind the force (`sensor_lag` reads it the same way).
pub const RISING_HOLD_DRIFT: f64 = 0.005;

/// The screen's variant of offset δ: the load of f(t + δ) − f(t) through the tangent response.
fn offset_variant(cx: &Context<'_>, delta: f64) -> Variant {
    let p = cx.prepared;
    let (f, t) = (&p.force_n, &p.times_s);
    let df: Vec<_> = (0..t.len())
        .map(|k| sample(t, f, t[k] + delta) - f[k])
        .collect();
    Variant {
        fixed: vec![("offset_s", delta)],
        offset: Some(p.load_field(&df)),
        bases: vec![],
    }
}

/// The offset as a continuous parameter in its small-offset limit: f(t + δ) = f + δ ḟ + O(δ² f̈),
/// ḟ by central differences — a free-sign linear basis fitted per leave-one-location-out fold
/// like any other. The interpolated shift of a grid point re-samples the force between frames and
/// cuts the ramp corners, which a shift shorter than a frame leaves as sharp as they were: on
/// 50 ms frames a 12 ms offset scored 0.0127 mm held-out at the 10 ms grid point and 0.0120 mm at
/// the RSS-optimal interpolated offset (10.9 ms by a golden-section search), against 0.0096 mm for
/// the lag's first-order term τ ḟ on the same session. This is the lag's term without τ ≥ 0 and
/// the play: below a frame the two screens read the same samples, and the signatures and the
/// confirmations decide between them, or the verdict is `inconclusive`. The limit holds only
/// below half a frame: `None` when δ fitted on all observations is longer (the grid resolves
/// such an offset, and a longer lag's first-order term would pass for one: a 120 ms lag's
/// screen, τ ḟ, is this field at δ = τ).
fn first_order_variant(cx: &Context<'_>) -> Option<Variant> {
    let p = cx.prepared;
    let v = Variant {
        fixed: vec![],
        offset: None,
        bases: vec![Basis {
            name: "offset_s",
            nonneg: false,
            field: p.load_field(&derivative(&p.times_s, &p.force_n)),
        }],
    };
    let (g, h, _, _) = FrameStats::new(cx.rec, p, &v).sum(|_| true);
    let delta = bounded_least_squares(&g, &h, &[false]);
    (delta.len() == 1 && delta[0].abs() < 0.5 * median_dt(&p.times_s)).then_some(v)
}

/// The screen's offsets: a quarter of the median frame interval (1–10 ms) over ±0.3 s, 0 left out.
fn screen_offsets(times_s: &[f64]) -> Vec<f64> {
    let step = (median_dt(times_s) / 4.0).clamp(1e-3, 0.01);
    let nsteps = (0.3 / step).round() as i64;
    (-nsteps..=nsteps)
        .filter(|&i| i != 0)
        .map(|i| i as f64 * step)
        .collect()
}

/// The force-channel models of a shifted clock (`ClockOffset::force_candidates`): per offset δ
/// of `offsets`, y ≈ a f(t + δ) + o / c with f the recorded `forces` at the frames of `rec`
/// (times `t`) read along each frame's axis.
pub(crate) fn offset_force_candidates(
    obs: &ForceObservations,
    rec: &crate::recording::Recording,
    t: &[f64],
    forces: &[Vector3<f64>],
    offsets: &[f64],
) -> Vec<ForceCandidate> {
    offsets
        .iter()
        .map(|&d| {
            let params = vec![("offset_s".into(), d)];
            force_channel::corrected_force_candidate(
                obs,
                params,
                &shifted_forces(t, forces, d),
                rec,
            )
        })
        .collect()
}

impl Hypothesis for ClockOffset {
    fn effect(&self) -> Effect {
        Effect::ClockOffset
    }

    fn term(&self) -> &'static str {
        "force time base shifted: f_eff(t) = f(t + offset_s)"
    }

    fn variants(&self, cx: &Context<'_>) -> Vec<Variant> {
        screen_offsets(&cx.prepared.times_s)
            .into_iter()
            .map(|d| offset_variant(cx, d))
            .chain(first_order_variant(cx))
            .collect()
    }

    /// A late reading (δ > 0) still rises into the holds, as a lag's does (the hold force
    /// drift); a delay that does not grow as a lag's would ([`Signatures::delays_like_a_time_shift`],
    /// decided against its own standard error) is a time shift's alone, one that grows as a
    /// lag's ([`Signatures::delays_like_a_lag`]) contradicts it.
    fn signature_support(&self, s: &Signatures) -> f64 {
        let mut v = 0.0;
        if s.hold_force_drift > RISING_HOLD_DRIFT {
            v += 1.0;
        }
        if s.delays_like_a_time_shift() {
            v += 1.0;
        } else if s.delays_like_a_lag() {
            v -= 1.0;
        }
        v
    }

    /// The shifted force itself, f(t + δ) at the fitted δ: below a frame the screen's f + δ ḟ
    /// is the lag's first-order term, and only the shift tells them apart under another program.
    fn planning_variant(&self, cx: &Context<'_>, refit: &Refit) -> Option<Variant> {
        param(&refit.params, "offset_s").map(|d| offset_variant(cx, d))
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
        let obs = ForceObservations::new(rec, seg, p);
        let mut force_grid = Vec::new();
        let grid = (-4..=4)
            .map(|i| {
                let offset_s = d0 + i as f64 * step;
                let f = shifted_forces(t, &p.force_n, offset_s);
                let params = vec![("offset_s".into(), offset_s)];
                force_grid.push(force_channel::corrected_force_candidate(
                    &obs,
                    params.clone(),
                    &f,
                    rec,
                ));
                (params, force_channel::frames_with_forces(rec, &f, thr))
            })
            .collect();
        let force = heldout_fit(&obs, seg, &force_grid);
        let confirmed = force_channel::confirm(
            grid,
            rec,
            seg,
            p,
            sim,
            cx.settings.refit_compliance_scale,
            scored,
            "time-shifted force f(t + offset)",
            "default model under the time-shifted force f(t + offset)",
        )?;
        Ok(confirmed.map(|c| Confirmed { force, ..c }))
    }

    /// The force read through the shifted clock, r(t) = f(t − δ) at the force fit's δ (the
    /// screen reads f_eff(t) = r(t + δ)): a rigid translation in time.
    fn reading_of(&self, params: &[(String, f64)], t: &[f64], force_n: &[f64]) -> Option<Vec<f64>> {
        let d = param(params, "offset_s")?;
        let f: Vec<Vector3<f64>> = force_n.iter().map(|&x| Vector3::new(x, 0.0, 0.0)).collect();
        Some(shifted_forces(t, &f, -d).iter().map(|v| v.x).collect())
    }

    /// The reading through the shifted clock on the force channel: y = a f(t + δ) + o / c, δ on
    /// the screen's grid (each δ a candidate, chosen per held-out location as the lag's columns
    /// are fitted): the model of a late or early reading, so that the shift and the lag compete
    /// on the same evidence where the markers cannot tell them apart.
    fn force_candidates(
        &self,
        cx: &Context<'_>,
        obs: &ForceObservations,
    ) -> Option<Vec<ForceCandidate>> {
        let p = cx.prepared;
        let offsets = screen_offsets(&p.times_s);
        Some(offset_force_candidates(
            obs, cx.rec, &p.times_s, &p.force_n, &offsets,
        ))
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
