//! `viscoelasticity`: rate dependence and creep — the force relaxes in the holds at fixed depth.
//!
//! Screen: creep of a standard linear solid, f_eff = (1 + a) f + g·LP_τ(f) (LP_τ the first-order
//! low-pass of [`crate::signal::low_pass`]) through the tangent response, each location's creep
//! kept under that location's markers ([`creep_field`]); τ on a log grid, a and
//! g ≥ 0 linear. Signature: the hold force drifts down ([`RELAXATION_DRIFT`]); a relaxing hold
//! sends it to re-simulation before the screen's candidates. Confirmation: one Prony branch
//! G(t)/G∞ = 1 + g e^{−t/τ} over the default model (generalized Maxwell, Simo & Hughes 1998
//! §10.3, `softcap_fem::ViscoelasticModel`) re-simulated over the recording under the measured
//! force — a 5 × 3 grid around the centre ([`hold_relaxation`] when the holds relax, else the
//! screen's creep estimate), and on the refined fit mesh along the hold fit's g–τ ridge
//! ([`PRONY_RIDGE_STEPS`]) unless the template already resolves the footprint —
//! leave-one-location-out with the material's compliance scale.

use super::Effect;
use super::contract::{Context, Hypothesis, SignatureRoute, param};
use crate::DiagnoseError;
use crate::Result;
use crate::baseline::Prepared;
use crate::cells::touched_balls;
use crate::confirm::{Candidate, ComplianceScale, Confirmed, Lolo, lolo_choices, lolo_confirm};
use crate::recording::Recording;
use crate::resim::{contact_sequence, sequence_candidates};
use crate::screen::{Basis, Refit, Variant};
use crate::segment::Segmentation;
use crate::signal::{low_pass, median_dt};
use crate::signatures::Signatures;
use crate::sim::{Extension, ProbeSimulator, SequenceFrame, SequenceJob};
use nalgebra::Vector3;

/// The viscoelasticity hypothesis.
pub struct Viscoelasticity;

/// Hold-force drift (the `hold_force_drift` signature: (last − first)/peak over the holds) at or
/// below which the force relaxes beyond any elastic explanation. Then viscoelasticity is
/// confirmed by re-simulation even when its linearised screen does not qualify — the linear creep
/// field T(t)·δf around the baseline is a poor proxy once the relaxation is a large fraction of
/// the force — with its grid centred on the hold relaxation fit ([`hold_relaxation`]). Issue 8's
/// signature: force relaxing in the holds at fixed geometry means the material. The suite's other
/// sessions drift by at most ±1.2 % (controls ≤ 0.5 %), sensor-lag and clock-offset upward.
pub const RELAXATION_DRIFT: f64 = -0.10;

/// True when the holds relax beyond any elastic explanation ([`RELAXATION_DRIFT`]) and the
/// surface does not rebound past its rest shape after release
/// ([`super::inertia_damping::rebounds`]): a body ringing against the held tip also loses hold
/// force, but creep recovery never overshoots rest.
pub fn relaxes(sig: &Signatures) -> bool {
    sig.hold_force_drift <= RELAXATION_DRIFT && !super::inertia_damping::rebounds(sig)
}

/// The screen's creep field LP_τ(f) through the tangent response, with each location's memory
/// kept where its force acted: Σ_l R_l(k) LP_τ(f_l)(k), f_l the measured force at the frames of
/// location l (zero elsewhere; frames of no location form one more term) and R_l(k) the tangent
/// response of frame k while l is in contact, else of l's peak frame. The creep strain a press
/// leaves is the Maxwell branches' internal strain of that press's stress field (Simo & Hughes
/// 1998 §10.3), which recovers with τ under the markers it was left at — not under the next
/// press, whose response the frame's own tangent carries.
pub fn creep_field(p: &Prepared, seg: &Segmentation, tau_s: f64) -> Vec<Vec<Vector3<f64>>> {
    let (f, t) = (&p.force_n, &p.times_s);
    let nt = f.len();
    let groups: Vec<Option<usize>> = std::iter::once(None)
        .chain((0..seg.num_folds()).map(Some))
        .collect();
    let mut field = vec![vec![Vector3::zeros(); p.num_markers()]; nt];
    for g in groups {
        let fg: Vec<Vector3<f64>> = (0..nt)
            .map(|k| match seg.fold_of_frame.get(k).copied().flatten() == g {
                true => f[k],
                false => Vector3::zeros(),
            })
            .collect();
        if fg.iter().all(|v| *v == Vector3::zeros()) {
            continue;
        }
        let lp = low_pass(t, &fg, tau_s);
        let peak = g.and_then(|l| seg.locations.get(l)).map(|l| l.peak_frame);
        for k in 0..nt {
            let own = seg.fold_of_frame.get(k).copied().flatten() == g
                && seg.phases.get(k).is_some_and(|ph| ph.in_contact());
            let frame = match (own, peak) {
                (false, Some(pk)) => pk,
                _ => k,
            };
            for (acc, r) in field[k].iter_mut().zip(p.apply(frame, &lp[k])) {
                *acc += r;
            }
        }
    }
    field
}

impl Hypothesis for Viscoelasticity {
    fn effect(&self) -> Effect {
        Effect::Viscoelasticity
    }

    fn term(&self) -> &'static str {
        "creep: f_eff = (1 + instant_scale) f + creep_g LP_tau(f) (standard linear solid)"
    }

    fn variants(&self, cx: &Context<'_>) -> Vec<Variant> {
        let p = cx.prepared;
        let scale = p.load_field(&p.force_n);
        (0..13)
            .map(|i| 0.03 * 10f64.powf(i as f64 * 2.5 / 12.0))
            .map(|tau| Variant {
                fixed: vec![("tau_s", tau)],
                offset: None,
                bases: vec![
                    Basis {
                        name: "instant_scale",
                        nonneg: false,
                        field: scale.clone(),
                    },
                    Basis {
                        name: "creep_g",
                        nonneg: true,
                        field: creep_field(p, cx.seg, tau),
                    },
                ],
            })
            .collect()
    }

    /// The hold-force drift's sign (+1 also when the tip creeps under a held load,
    /// [`Signatures::holds_creep`]), and no opinion when the surface rebounds past its rest
    /// shape after release ([`super::inertia_damping::rebounds`]): creep recovery never
    /// overshoots rest, and a body ringing against the held tip loses hold force too.
    fn signature_support(&self, s: &Signatures) -> f64 {
        if super::inertia_damping::rebounds(s) {
            0.0
        } else if s.hold_force_drift < -0.01 || s.holds_creep() {
            1.0
        } else if s.hold_force_drift > 0.01 {
            -1.0
        } else {
            0.0
        }
    }

    /// Before the screen's candidates when the holds relax beyond any elastic explanation
    /// ([`relaxes`]); after them when they relax beyond their noise
    /// ([`Signatures::holds_relax`], no rebound): then the rate-independent look-alike is ruled
    /// out (`super::plasticity`) and the creep is re-simulated even when its linearised screen
    /// (a poor proxy of a slow creep over short holds) does not qualify.
    fn signature_route(&self, s: &Signatures) -> Option<SignatureRoute> {
        if relaxes(s) {
            Some(SignatureRoute::BeforeScreen)
        } else if s.holds_relax() && !super::inertia_damping::rebounds(s) {
            Some(SignatureRoute::AfterScreen)
        } else {
            None
        }
    }

    /// Not a confirmation when the full-data compliance scale sits at its bound
    /// ([`MAX_COMPLIANCE_SCALE`]).
    fn fit_at_bound(&self, c: &Confirmed) -> Option<String> {
        let d = param(&c.params, "compliance_scale")?;
        let at_bound =
            d >= MAX_COMPLIANCE_SCALE * (1.0 - 1e-9) || d <= (1.0 + 1e-9) / MAX_COMPLIANCE_SCALE;
        at_bound.then(|| {
            let g = param(&c.params, "prony_g").unwrap_or(f64::NAN);
            format!(
                "not confirmed: the Prony fit (g {g:.3}) reaches the data only with the compliance scale at its bound ({d:.3}; 1/{MAX_COMPLIANCE_SCALE} to {MAX_COMPLIANCE_SCALE})"
            )
        })
    }

    /// The Prony grid on the template and the ridge on the refined fit mesh (module docs),
    /// extended until the ridge brackets the full-data choice ([`PRONY_RIDGE_EXTENSIONS`]); every
    /// fold picks among all simulated candidates on its training locations only.
    fn confirm(
        &self,
        cx: &Context<'_>,
        refit: &Refit,
        scored: &dyn Fn(usize, usize) -> bool,
        sim: &mut dyn ProbeSimulator,
    ) -> Result<Option<Confirmed>> {
        let (rec, seg, p) = (cx.rec, cx.seg, cx.prepared);
        let centre = prony_centre(rec, seg, p, refit, cx.signatures);
        let measured = contact_sequence(rec, seg, &p.force_n);
        let grid = template_grid(centre, &measured);
        let mut total = grid.len();
        let (points, jobs): (Vec<_>, Vec<SequenceJob>) = grid
            .into_iter()
            .map(|(q, e, seq)| ((q, seq.clone()), (e, seq)))
            .unzip();
        // On the refined fit mesh (`ProbeSimulator::refined`: 1 → 8, or around the touched
        // locations with `refinement.local`) — unless the template already resolves the
        // footprint: then the grid above is that model.
        let balls = touched_balls(rec, seg);
        let tips: Vec<Vector3<f64>> = balls.iter().map(|b| b.centre_m).collect();
        let mut fine = if sim.resolves_footprint(rec.tip_radius_m, &tips) {
            Ok(None)
        } else {
            sim.refined(&balls)
        };
        // independent sequences, simulated in parallel by the simulator; taken in grid order
        let (results, fine_results) = match fine.as_mut() {
            Ok(Some(f)) => {
                let fine = f.as_mut();
                let ridge_jobs: Vec<SequenceJob> = PRONY_RIDGE_STEPS
                    .iter()
                    .map(|&m| (refined_prony_point(centre, m).1, measured.clone()))
                    .collect();
                rayon::join(
                    || sim.simulate_sequences(&jobs),
                    || fine.simulate_sequences(&ridge_jobs),
                )
            }
            _ => (sim.simulate_sequences(&jobs), Vec::new()),
        };
        let (mut cands, _) = sequence_candidates(points, results)?;
        // errors in the serial order: the template grid's, the refinement's, the ridge's
        let mut fine = fine?;
        // (ridge step, candidate index) of the refined Prony models
        let mut ridge: Vec<(f64, usize)> = Vec::new();
        for (&m, result) in PRONY_RIDGE_STEPS.iter().zip(fine_results) {
            total += 1;
            match result {
                Ok(prediction) => {
                    ridge.push((m, cands.len()));
                    let params = refined_prony_point(centre, m).0;
                    cands.push(Candidate {
                        params,
                        prediction,
                        position_controlled: false,
                    });
                }
                Err(DiagnoseError::Simulation { .. }) => continue,
                Err(e) => return Err(e),
            }
        }
        let scale = ComplianceScale::new(
            cx.settings.refit_compliance_scale,
            1.0 / MAX_COMPLIANCE_SCALE,
            MAX_COMPLIANCE_SCALE,
        );
        let lolo = Lolo {
            rec,
            seg,
            p,
            scale,
            scored,
            train_on_scored: false,
        };
        if let Some(f) = fine.as_deref_mut() {
            total += extend_ridge(f, &mut cands, &mut ridge, centre, &measured, |c| {
                lolo_choices(c, &lolo)
            })?;
        }
        drop(fine);
        let n = cands.len();
        let model = if ridge.is_empty() {
            "ViscoelasticModel, one Prony branch".to_string()
        } else {
            format!(
                "ViscoelasticModel, one Prony branch, driven by the measured force ({} of them along the hold fit's g-tau ridge on the refined fit mesh)",
                ridge.len()
            )
        };
        lolo_confirm(
            &cands,
            &lolo,
            None,
            format!(
                "re-simulated extended model ({n} grid points of {total}, {model}), compliance scale, leave-one-location-out"
            ),
        )
    }
}

/// The Prony models on the template: g and τ around `centre` (× 0.5 … 2 and × 0.5, 1, 2), driven
/// by the measured force `measured`.
fn template_grid(
    centre: (f64, f64),
    measured: &[SequenceFrame],
) -> Vec<(Vec<(String, f64)>, Extension, Vec<SequenceFrame>)> {
    let (g0, tau0) = centre;
    let mut out = Vec::new();
    for gm in [0.5, 0.75, 1.0, 1.5, 2.0] {
        for tm in [0.5, 1.0, 2.0] {
            let (g, tau_s) = (g0 * gm, tau0 * tm);
            out.push((
                vec![("prony_g".into(), g), ("prony_tau_s".into(), tau_s)],
                Extension::Viscoelastic { g, tau_s },
                measured.to_vec(),
            ));
        }
    }
    out
}

/// Extends the refined ridge while the full-data choice (`choose(cands).last()`) is its smallest
/// or largest point: the next point beyond it (÷ or × [`PRONY_RIDGE_STEP`]) is simulated on
/// `fine`, at most [`PRONY_RIDGE_EXTENSIONS`] times. Returns the number of points attempted.
fn extend_ridge(
    fine: &mut dyn ProbeSimulator,
    cands: &mut Vec<Candidate>,
    ridge: &mut Vec<(f64, usize)>,
    centre: (f64, f64),
    measured: &[SequenceFrame],
    choose: impl Fn(&[Candidate]) -> Vec<usize>,
) -> Result<usize> {
    let mut attempted = 0;
    for _ in 0..PRONY_RIDGE_EXTENSIONS {
        let steps = ridge.iter().map(|r| r.0);
        let (Some(lo), Some(hi)) = (steps.clone().reduce(f64::min), steps.reduce(f64::max)) else {
            break;
        };
        let choices = choose(cands);
        let Some(&(m, _)) = choices
            .last()
            .and_then(|&best| ridge.iter().find(|r| r.1 == best))
        else {
            break;
        };
        let next = if m <= lo {
            lo / PRONY_RIDGE_STEP
        } else if m >= hi {
            hi * PRONY_RIDGE_STEP
        } else {
            break;
        };
        attempted += 1;
        let (params, ext) = refined_prony_point(centre, next);
        match fine.simulate_sequence(&ext, measured) {
            Ok(prediction) => {
                ridge.push((next, cands.len()));
                cands.push(Candidate {
                    params,
                    prediction,
                    position_controlled: false,
                });
            }
            Err(DiagnoseError::Simulation { .. }) => break,
            Err(e) => return Err(e),
        }
    }
    Ok(attempted)
}

/// Force relaxation over the holds (position-controlled probing: the depth is held, the force
/// relaxes) as a standard linear solid, or `None` when fewer than 3 hold frames per location or
/// no relaxation (B ≤ 10⁻³ A) at most locations.
///
/// Per location l with ≥ 3 hold frames, ‖f(t)‖ = A_l + B_l e^{−(t − t_h)/τ_l} over its hold
/// frames (t_h its first hold frame), τ_l of the location (log grid 0.01–10 s, 1.5 % steps; A_l,
/// B_l by linear least squares). For G(t) = G∞ (1 + g e^{−t/τ}) (one Prony branch, Simo & Hughes
/// 1998 §10.3) under a strain ramp of duration T_r then held, the hereditary integral gives
/// A = G∞ ε̇ T_r and B = G∞ ε̇ g τ (1 − e^{−T_r/τ}), so
///
///   g = (B / A) · T_r / (τ (1 − e^{−T_r/τ})),
///
/// T_r = time from the location's last unloaded frame to its first hold frame. Returns the
/// medians of g_l and of τ_l over the locations that relax (A_l > 0, B_l > 10⁻³ A_l).
///
/// Per location, not one τ for the recording: one location whose hold force jumps (a change of
/// the contact state mid-hold) dragged a common τ — in the suite's viscoelasticity session
/// (truth g 2, τ 0.3 s) to 0.57 s and g to 14; per location that hold gives A_l < 0 and drops
/// out, the others give τ_l 0.36–0.44 s, g_l 2.5–4.1 (docs/diagnose.md, session 13 (visco)).
pub fn hold_relaxation(rec: &Recording, seg: &Segmentation) -> Option<(f64, f64)> {
    let t = rec.times_s();
    let dt = median_dt(&t);
    // (hold times from t_h, normalised force magnitudes, ramp duration) per location
    let mut holds: Vec<(Vec<f64>, Vec<f64>, f64)> = Vec::new();
    for l in &seg.locations {
        let hold = seg.hold_frames(l);
        let (Some(&h0), Some(&c0)) = (hold.first(), l.contact_frames.first()) else {
            continue;
        };
        if hold.len() < 3 || l.peak_force_n <= 0.0 {
            continue;
        }
        let ramp_s = t[h0] - t[c0] + dt;
        holds.push((
            hold.iter().map(|&k| t[k] - t[h0]).collect(),
            hold.iter()
                .map(|&k| rec.frames[k].force_n.norm() / l.peak_force_n)
                .collect(),
            ramp_s,
        ));
    }
    if holds.is_empty() {
        return None;
    }
    // per location: least squares of y ≈ A + B e^{−s/τ}; returns (A, B, rss)
    let fit = |s: &[f64], y: &[f64], tau: f64| -> Option<(f64, f64, f64)> {
        let (mut n, mut se, mut see, mut sy, mut sye) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for (&si, &yi) in s.iter().zip(y) {
            let e = (-si / tau).exp();
            n += 1.0;
            se += e;
            see += e * e;
            sy += yi;
            sye += yi * e;
        }
        let det = n * see - se * se;
        if det.abs() < 1e-12 * n * see.max(1e-300) {
            return None;
        }
        let a = (see * sy - se * sye) / det;
        let b = (n * sye - se * sy) / det;
        let rss = s
            .iter()
            .zip(y)
            .map(|(&si, &yi)| (yi - a - b * (-si / tau).exp()).powi(2))
            .sum();
        Some((a, b, rss))
    };
    // per location: its best τ_l, then (g_l, τ_l) when it relaxes
    let mut fits: Vec<(f64, f64)> = holds
        .iter()
        .filter_map(|(s, y, ramp_s)| {
            let mut best: Option<(f64, f64)> = None; // (rss, tau)
            let mut tau = 0.01;
            while tau <= 10.0 {
                if let Some((_, _, r)) = fit(s, y, tau)
                    && best.is_none_or(|b| r < b.0)
                {
                    best = Some((r, tau));
                }
                tau *= 1.015;
            }
            let (_, tau) = best?;
            let (a, b, _) = fit(s, y, tau)?;
            (a > 0.0 && b > 1e-3 * a).then(|| {
                let g = b / a * ramp_s / (tau * (1.0 - (-ramp_s / tau).exp()));
                (g, tau)
            })
        })
        .collect();
    if fits.len() * 2 < holds.len().max(1) {
        return None;
    }
    let mid = fits.len() / 2;
    fits.sort_by(|x, y| x.0.total_cmp(&y.0));
    let g = fits[mid].0;
    fits.sort_by(|x, y| x.1.total_cmp(&y.1));
    Some((g, fits[mid].1))
}

/// The centre (g, τ) of the viscoelasticity grids: the linearised creep estimate of `refit`, or,
/// when the holds relax beyond any elastic explanation ([`RELAXATION_DRIFT`]), the hold
/// relaxation fit ([`hold_relaxation`]: under position control the held force measures G(t)
/// directly).
fn prony_centre(
    rec: &Recording,
    seg: &Segmentation,
    p: &Prepared,
    refit: &Refit,
    sig: &Signatures,
) -> (f64, f64) {
    let dt = median_dt(&p.times_s);
    let param = |name| param(&refit.params, name);
    // Linearised creep f_eff = (1 + a) f + c LP_τc(f): for a standard linear solid the creep
    // compliances give J∞/J0 = 1 + g = (1 + a + c)/(1 + a) and the creep time τc = (1 + g) τ of
    // the relaxation time τ.
    let a = param("instant_scale").unwrap_or(0.0);
    let c = param("creep_g").unwrap_or(0.0);
    let tau_c = param("tau_s").unwrap_or(4.0 * dt);
    let g0 = if 1.0 + a > 0.05 {
        (c / (1.0 + a)).clamp(0.1, 5.0)
    } else {
        1.0
    };
    let tau0 = (tau_c / (1.0 + g0)).max(0.5 * dt);
    // a relaxing hold force is measured directly: centre the grid there
    match hold_relaxation(rec, seg) {
        Some((g, tau)) if relaxes(sig) && g > 0.05 => (g.min(20.0), tau.max(0.5 * dt)),
        _ => (g0, tau0),
    }
}

/// Bound of the compliance scale d refitted with the Prony models (1/d to d). A fit that needs d
/// at this bound is not a confirmation ([`Hypothesis::fit_at_bound`]): the material 10× softer
/// at long times than the calibrated one with the instantaneous modulus kept by g ≈ 10
/// (G∞(1 + g)/d ≈ G∞) is a creep whose retardation time τ(1 + g) dwarfs the session, so nothing
/// it builds recovers over the gaps between releases — a permanent set dressed as creep. A
/// standard linear solid recovers its creep at zero load (the Maxwell branches' internal strains
/// decay with τ, Simo & Hughes 1998 §10.3); the own-rig plasticity session (released-set
/// persistence 1.13, a set that does not recover) was fitted exactly so: g 10 (the template's
/// largest, 2 × the screen centre's clamp 5) and d 10, held-out 0.2874 mm against plasticity's
/// 0.3197 mm.
pub const MAX_COMPLIANCE_SCALE: f64 = 10.0;

/// Relative steps of the refined Prony models along the hold fit's g–τ ridge around the
/// viscoelasticity grids' centre ([`hold_relaxation`] when the holds relax), applied to g and τ together. The centre comes from the held force, which
/// measures G(t) directly, but over a hold of about τ the fit of A + B e^{−s/τ} trades τ against
/// B/A: a longer τ puts the asymptote A lower, so g and τ err together (suite viscoelasticity
/// session, per location τ_l / g_l 0.356 / 2.47, 0.397 / 2.68, 0.409 / 3.22, 0.444 / 4.11 for the
/// truth's 0.3 / 2; on the g 3 session the centre is (4.77, 0.378 s) for the truth's (3, 0.3 s)).
/// The steps follow that ridge, a factor [`PRONY_RIDGE_STEP`] either way: three points, each
/// re-simulated on the refined fit mesh (8× the tets), then extended until they bracket the
/// choice ([`PRONY_RIDGE_EXTENSIONS`]).
pub const PRONY_RIDGE_STEPS: [f64; 3] = [1.0 / PRONY_RIDGE_STEP, 1.0, PRONY_RIDGE_STEP];

/// The factor between neighbouring points of the refined Prony ridge ([`PRONY_RIDGE_STEPS`]).
pub const PRONY_RIDGE_STEP: f64 = 1.5;

/// At most this many points are added to the refined Prony ridge beyond [`PRONY_RIDGE_STEPS`]:
/// while the full-data choice is the ridge's smallest or largest point, the next one beyond it
/// (÷ or × [`PRONY_RIDGE_STEP`]) is simulated — a factor 1.5³ ≈ 3.4 either way of the hold fit.
pub const PRONY_RIDGE_EXTENSIONS: usize = 2;

/// One force-driven Prony model of viscoelasticity on the refined fit mesh at the point
/// (g, τ) = `centre` × `step` of the hold fit's ridge (named parameters, extension): one Prony
/// branch G(t)/G∞ = 1 + g e^{−t/τ} over the default model (Simo & Hughes 1998 §10.3), driven by
/// the measured force (bickel2009 §4.1 force boundary condition) spread over the footprint by the
/// simulator's load — for a disk tip the rigid flat punch's pressure
/// p(r) = F / (2πa√(a² − r²)) (Sneddon 1946; `softcap_probing::FootprintLoad::FlatPunch`),
/// which the refined mesh resolves where the 648-tet template puts a 5 mm disk on 1–3 nodes.
///
/// It replaces session 13's rigid-tip Prony replays (position control at the measured poses): on
/// the suite's g 3 session every fold chose the force-driven model over them (held-out 0.0892 mm
/// either way; the replays cost 2× a force-driven sequence; docs/diagnose.md, session 14 (visco)).
fn refined_prony_point(centre: (f64, f64), step: f64) -> (Vec<(String, f64)>, Extension) {
    let (g, tau_s) = (centre.0 * step, centre.1 * step);
    (
        vec![
            ("prony_g".into(), g),
            ("prony_tau_s".into(), tau_s),
            ("refined_mesh".into(), 1.0),
        ],
        Extension::Viscoelastic { g, tau_s },
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hold_relaxation_recovers_a_standard_linear_solid() {
        // Position-controlled ramp (4 frames) / hold (8) / unload (3) at two places of a block
        // whose force is a standard linear solid in the depth d: F = k (d + g q),
        // q̇ = ḋ − q/τ (one Prony branch), integrated exactly for the piecewise-linear depth.
        use crate::recording::Frame;
        use crate::segment::SegmentSettings;
        let (g, tau, dt, k) = (1.5, 0.25, 0.05, 300.0);
        let mut profile = vec![0.0, 0.0];
        profile.extend((1..=4).map(|i| i as f64 / 4.0));
        profile.extend([1.0; 7]);
        profile.extend([0.66, 0.33, 0.0, 0.0, 0.0]);
        let mut frames = Vec::new();
        for tip in [Vector3::new(0.0, 0.0, 0.01), Vector3::new(0.03, 0.0, 0.01)] {
            let (mut q, mut prev) = (0.0, 0.0);
            for &s in &profile {
                let d = 0.002 * s;
                let rate = (d - prev) / dt;
                let decay = (-dt / tau).exp();
                q = q * decay + rate * tau * (1.0 - decay);
                prev = d;
                let k_frame = frames.len();
                frames.push(Frame {
                    frame: k_frame as u64,
                    time_s: k_frame as f64 * dt,
                    tip_m: tip - Vector3::z() * d,
                    axis: -Vector3::z(),
                    force_n: -Vector3::z() * (k * (d + g * q)).max(0.0),
                    markers_m: vec![None; 2],
                });
            }
        }
        let rec = Recording::two_marker_toy(frames);
        let seg = Segmentation::new(&rec, &SegmentSettings::default());
        assert_eq!(seg.num_folds(), 2);
        let (g_fit, tau_fit) = hold_relaxation(&rec, &seg).expect("relaxing holds");
        assert!((tau_fit / tau - 1.0).abs() < 0.02, "tau {tau_fit}");
        assert!((g_fit / g - 1.0).abs() < 0.03, "g {g_fit}");
        // an elastic block (g = 0) has nothing to fit
        let mut elastic = rec.clone();
        for (i, f) in elastic.frames.iter_mut().enumerate() {
            let s = profile[i % profile.len()];
            f.force_n = -Vector3::z() * k * 0.002 * s;
        }
        let seg = Segmentation::new(&elastic, &SegmentSettings::default());
        assert!(hold_relaxation(&elastic, &seg).is_none());
    }

    #[test]
    fn a_fit_with_the_compliance_scale_at_its_bound_is_no_confirmation() {
        let confirmed = |d: f64| Confirmed {
            after_scored_m: 1e-4,
            after_all_m: 1e-4,
            params: vec![
                ("prony_g".into(), 10.0),
                ("prony_tau_s".into(), 2.0),
                ("compliance_scale".into(), d),
            ],
            prediction: Vec::new(),
            method: String::new(),
            fold_rss_m2: Vec::new(),
            fold_n: Vec::new(),
            force: None,
        };
        let h = Viscoelasticity;
        for d in [MAX_COMPLIANCE_SCALE, 1.0 / MAX_COMPLIANCE_SCALE] {
            let why = h.fit_at_bound(&confirmed(d));
            assert!(
                why.as_deref().is_some_and(|w| w.contains("bound")),
                "{why:?}"
            );
        }
        for d in [1.0, 2.0, 0.5, 0.99 * MAX_COMPLIANCE_SCALE] {
            assert_eq!(h.fit_at_bound(&confirmed(d)), None, "d {d}");
        }
    }
}
