//! The temporal hypotheses — `viscoelasticity`, `sensor-lag`, `clock-offset` — confirmed by
//! re-simulating the whole recording in time order with the extended model (not linearised):
//!
//! | hypothesis | extended model re-simulated | grid |
//! |---|---|---|
//! | viscoelasticity | `softcap_fem::ViscoelasticModel` over the default model, one Prony branch G(t)/G∞ = 1 + g e^{−t/τ} (generalized Maxwell, Simo & Hughes 1998 §10.3, exact exponential recurrence), driven by the measured force | g, τ around the linearised creep estimate |
//! | sensor-lag | default model under the de-lagged force of a first-order sensor, τ ḟ_m = f − f_m ⇒ f = f_m + τ ḟ_m | τ around the linearised estimate |
//! | clock-offset | default model under the time-shifted force f_eff(t) = f_m(t + δ) | δ around the linearised estimate |
//!
//! The linearised screen ([`crate::hypothesis`]) proposes the parameters; every grid point is
//! simulated over all frames (`ProbeSimulator::simulate_sequence`, warm-started frame to frame,
//! history committed after each frame), then leave-one-location-out: per held-out location the
//! grid point and the material compliance scale with the least error on the other locations (the
//! tissue fit saw the distorted forces, so its overall stiffness is biased by the same effect),
//! scored on the held-out location's affected cells ([`crate::diagnose::focus_cells`]).
//!
//! Signatures separating the three (issue 8): geometry hysteretic against depth with the force
//! relaxing in the holds → material (viscoelasticity); geometry elastic with only the force
//! lagging, still rising in the holds → sensor-lag; equal force delays at 10 % and 50 % of the
//! ramp → a pure time shift (clock-offset) — see [`crate::diagnose::signature_support`].

use crate::confirm::{Candidate, ComplianceScale, Confirmed, contact_sequence, lolo_confirm};
use crate::extend::{Extension, SequenceFrame};
use crate::hypothesis::{Field, Hypothesis, Prepared, Refit};
use crate::recording::Recording;
use crate::segment::Segmentation;
use crate::signal::{derivative, sample};
use crate::sim::{ProbeLoad, ProbeSimulator, SimLoad};
use crate::{DiagnoseError, Result};
use nalgebra::Vector3;
use softcap_fem::probing::{ObservedMarker, ProbeExample};

/// True for the hypotheses this module confirms.
pub fn is_temporal(h: Hypothesis) -> bool {
    matches!(
        h,
        Hypothesis::Viscoelasticity | Hypothesis::SensorLag | Hypothesis::ClockOffset
    )
}

fn param(refit: &Refit, name: &str) -> Option<f64> {
    refit.params.iter().find(|x| x.0 == name).map(|x| x.1)
}

fn median_dt(t: &[f64]) -> f64 {
    let mut d: Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).collect();
    d.sort_by(f64::total_cmp);
    d.get(d.len() / 2).copied().unwrap_or(0.05).max(1e-3)
}

/// De-lagged force of a first-order sensor with time constant `tau_s`: the sensor obeys
/// τ ḟ_m = f − f_m, so the force on it is f = f_m + τ ḟ_m (ḟ_m by central differences over the
/// frames).
pub fn delagged_forces(t: &[f64], f: &[Vector3<f64>], tau_s: f64) -> Vec<Vector3<f64>> {
    let d = derivative(t, f);
    f.iter().zip(&d).map(|(a, b)| a + b * tau_s).collect()
}

/// Force trace shifted in time, f_eff(t_k) = f(t_k + δ) (linear interpolation, held at the ends).
pub fn shifted_forces(t: &[f64], f: &[Vector3<f64>], offset_s: f64) -> Vec<Vector3<f64>> {
    t.iter().map(|&tk| sample(t, f, tk + offset_s)).collect()
}

/// The sequence to simulate under per-frame probe forces `forces`: a frame carries a probe load
/// when its force exceeds `threshold_n` (shifted / de-lagged forces may move load into frames the
/// measured force called out of contact), at that frame's tip and axis.
fn frames_with_forces(
    rec: &Recording,
    forces: &[Vector3<f64>],
    threshold_n: f64,
) -> Vec<SequenceFrame> {
    rec.frames
        .iter()
        .zip(forces)
        .map(|(f, fe)| SequenceFrame {
            time_s: f.time_s,
            load: SimLoad {
                probe: (fe.norm() > threshold_n).then_some(ProbeLoad {
                    tip_m: f.tip_m,
                    axis: f.axis,
                    force_n: *fe,
                }),
                body_force_n_m3: Vector3::zeros(),
            },
        })
        .collect()
}

/// The grid of extended models of a temporal hypothesis `h`, centred on the linearised estimate
/// of `refit`: (named parameters, extension, frames with their loads).
pub fn temporal_grid(
    h: Hypothesis,
    rec: &Recording,
    seg: &Segmentation,
    p: &Prepared,
    refit: &Refit,
) -> Vec<(Vec<(String, f64)>, Extension, Vec<SequenceFrame>)> {
    let t = &p.times_s;
    let dt = median_dt(t);
    let peak_n = seg
        .locations
        .iter()
        .map(|l| l.peak_force_n)
        .fold(0.0, f64::max);
    let thr = 1e-3 * peak_n.max(1e-9);
    let measured = contact_sequence(rec, seg, &p.force_n);
    let mut out = Vec::new();
    match h {
        Hypothesis::Viscoelasticity => {
            // Linearised creep f_eff = (1 + a) f + c LP_τc(f): for a standard linear solid the
            // creep compliances give J∞/J0 = 1 + g = (1 + a + c)/(1 + a) and the creep time
            // τc = (1 + g) τ of the relaxation time τ.
            let a = param(refit, "instant_scale").unwrap_or(0.0);
            let c = param(refit, "creep_g").unwrap_or(0.0);
            let tau_c = param(refit, "tau_s").unwrap_or(4.0 * dt);
            let g0 = if 1.0 + a > 0.05 {
                (c / (1.0 + a)).clamp(0.1, 5.0)
            } else {
                1.0
            };
            let tau0 = (tau_c / (1.0 + g0)).max(0.5 * dt);
            for gm in [0.5, 0.75, 1.0, 1.5, 2.0] {
                for tm in [0.5, 1.0, 2.0] {
                    let (g, tau_s) = (g0 * gm, tau0 * tm);
                    out.push((
                        vec![("prony_g".into(), g), ("prony_tau_s".into(), tau_s)],
                        Extension::Viscoelastic { g, tau_s },
                        measured.clone(),
                    ));
                }
            }
        }
        Hypothesis::SensorLag => {
            let tau0 = param(refit, "tau_s").unwrap_or(dt).max(0.25 * dt);
            for m in [0.6, 0.75, 0.9, 1.0, 1.1, 1.25, 1.5, 2.0] {
                let tau_s = tau0 * m;
                let f = delagged_forces(t, &p.force_n, tau_s);
                out.push((
                    vec![("tau_s".into(), tau_s)],
                    Extension::Elastic,
                    frames_with_forces(rec, &f, thr),
                ));
            }
        }
        Hypothesis::ClockOffset => {
            let d0 = param(refit, "offset_s").unwrap_or(0.0);
            let step = (dt / 8.0).clamp(1e-3, 0.01);
            for i in -4..=4 {
                let offset_s = d0 + i as f64 * step;
                let f = shifted_forces(t, &p.force_n, offset_s);
                out.push((
                    vec![("offset_s".into(), offset_s)],
                    Extension::Elastic,
                    frames_with_forces(rec, &f, thr),
                ));
            }
        }
        _ => {}
    }
    out
}

/// Confirms a temporal hypothesis by re-simulating its grid (module docs) with
/// leave-one-location-out selection ([`crate::confirm::lolo_confirm`]); `None` when `h` is not
/// temporal or no grid point converged. Force-channel hypotheses (sensor-lag, clock-offset) are
/// confirmed with the material refit on the corrected forces when the simulator can refit
/// ([`material_refit`]), else with the compliance scale only.
#[allow(clippy::too_many_arguments)]
pub(crate) fn confirm_temporal(
    h: Hypothesis,
    refit: &Refit,
    rec: &Recording,
    seg: &Segmentation,
    p: &Prepared,
    sim: &mut dyn ProbeSimulator,
    fit_scale: bool,
    scored: &dyn Fn(usize, usize) -> bool,
) -> Result<Option<Confirmed>> {
    let grid = temporal_grid(h, rec, seg, p, refit);
    let total = grid.len();
    let mut cands = Vec::with_capacity(total);
    let mut frames = Vec::with_capacity(total);
    for (params, ext, seq) in grid {
        match sim.simulate_sequence(&ext, &seq) {
            Ok(prediction) => {
                cands.push(Candidate { params, prediction });
                frames.push(seq);
            }
            Err(DiagnoseError::Simulation { .. }) => continue,
            Err(e) => return Err(e),
        }
    }
    let n = cands.len();
    let bounds = |fit| ComplianceScale::new(fit, 0.1, 10.0);
    if matches!(h, Hypothesis::SensorLag | Hypothesis::ClockOffset) && n > 0 {
        let method = format!(
            "re-simulated: {} with the material refit on the corrected forces (homogeneous (lambda, alpha), bickel2009 §6), grid of {n} points, leave-one-location-out",
            if h == Hypothesis::SensorLag {
                "de-lagged force f + tau df/dt"
            } else {
                "time-shifted force f(t + offset)"
            },
        );
        let mut run = material_refit(rec, seg, &frames, sim);
        let c = lolo_confirm(
            &cands,
            rec,
            seg,
            p,
            bounds(true),
            scored,
            false,
            Some(&mut run),
            method,
        )?;
        if c.is_some() {
            return Ok(c);
        }
    }
    let method = format!(
        "re-simulated extended model ({n} grid points of {total}, {}), compliance scale, leave-one-location-out",
        match h {
            Hypothesis::Viscoelasticity => "ViscoelasticModel, one Prony branch",
            Hypothesis::SensorLag => "default model under the de-lagged force f + tau df/dt",
            _ => "default model under the time-shifted force f(t + offset)",
        }
    );
    lolo_confirm(
        &cands,
        rec,
        seg,
        p,
        bounds(fit_scale),
        scored,
        false,
        None,
        method,
    )
}

/// Probe examples of location `l` (bickel2009 §4.1) under per-frame forces `forces`: its frame
/// of largest force and the frame before it whose force is nearest half of that (the two force
/// levels the tissue fit uses per location), with every observed marker.
fn location_examples(
    rec: &Recording,
    seg: &Segmentation,
    l: usize,
    forces: &[Vector3<f64>],
) -> Vec<ProbeExample> {
    let cf = &seg.locations[l].contact_frames;
    let Some(&pk) = cf
        .iter()
        .max_by(|&&a, &&b| forces[a].norm().total_cmp(&forces[b].norm()))
    else {
        return Vec::new();
    };
    let half = 0.5 * forces[pk].norm();
    let mid = cf.iter().copied().filter(|&k| k < pk).min_by(|&a, &b| {
        (forces[a].norm() - half)
            .abs()
            .total_cmp(&(forces[b].norm() - half).abs())
    });
    [mid, Some(pk)]
        .into_iter()
        .flatten()
        .filter(|&k| forces[k].norm() > 0.0)
        .map(|k| {
            let f = &rec.frames[k];
            ProbeExample {
                frame: f.frame,
                time_s: f.time_s,
                tip_m: f.tip_m,
                axis: f.axis,
                force_n: forces[k],
                observed: f
                    .markers_m
                    .iter()
                    .enumerate()
                    .filter_map(|(m, y)| {
                        y.map(|position_m| ObservedMarker {
                            marker: m,
                            position_m,
                        })
                    })
                    .collect(),
            }
        })
        .collect()
}

/// The refit closure of a force-channel hypothesis (sensor-lag, clock-offset) for
/// [`lolo_confirm`]: the complete extended model is the corrected forces AND the material refit
/// to them (the tissue fit saw the distorted forces). For candidate i (re-simulated over
/// `frames[i]`, which carry its corrected forces) without location `skip`: a homogeneous (λ, α)
/// refit on the other locations' examples under those forces (`ProbeSimulator::refit_homogeneous`,
/// bickel2009 §6), then the re-simulated sequence. `None` when the simulator cannot refit its
/// material or a refit simulation fails.
fn material_refit<'a>(
    rec: &'a Recording,
    seg: &'a Segmentation,
    frames: &'a [Vec<SequenceFrame>],
    sim: &'a mut dyn ProbeSimulator,
) -> impl FnMut(usize, Option<usize>) -> Result<Option<Field>> + 'a {
    move |i, skip| {
        let Some(seq) = frames.get(i) else {
            return Ok(None);
        };
        let forces: Vec<Vector3<f64>> = seq
            .iter()
            .map(|f| {
                f.load
                    .probe
                    .map(|q| q.force_n)
                    .unwrap_or_else(Vector3::zeros)
            })
            .collect();
        let examples: Vec<ProbeExample> = (0..seg.num_folds())
            .filter(|&l| Some(l) != skip)
            .flat_map(|l| location_examples(rec, seg, l, &forces))
            .collect();
        let Some(mut refit) = sim.refit_homogeneous(&examples)? else {
            return Ok(None);
        };
        match refit.simulate_sequence(&Extension::Elastic, seq) {
            Ok(x) => Ok(Some(x)),
            Err(DiagnoseError::Simulation { .. }) => Ok(None),
            Err(e) => Err(e),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn delagging_inverts_a_first_order_sensor_on_a_smooth_signal() {
        // f(t) = sin(2π t): the lagged reading f_m solves τ ḟ_m = f − f_m; f_m + τ ḟ_m recovers
        // f up to the central-difference error O(Δt²).
        let tau = 0.2;
        let t: Vec<f64> = (0..400).map(|k| 0.005 * k as f64).collect();
        let f: Vec<_> = t
            .iter()
            .map(|&x| Vector3::new((std::f64::consts::TAU * x).sin(), 0.0, 0.0))
            .collect();
        let m = crate::signal::low_pass(&t, &f, tau);
        let back = delagged_forces(&t, &m, tau);
        // skip the start-up transient of the filter (y(0) = f(0) ≠ steady state)
        for k in 200..399 {
            assert!(
                (back[k].x - f[k].x).abs() < 2e-3,
                "{k}: {} vs {}",
                back[k].x,
                f[k].x
            );
        }
    }

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
