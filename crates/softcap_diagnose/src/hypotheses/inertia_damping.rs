//! `inertia-damping`: the response is dynamic, not quasi-static — M ü + D u̇ act on the body.
//!
//! Screen: x = x₀ − c u̇₀ − m ü₀ with the baseline's marker velocity and acceleration (central
//! differences over the frame times), c, m ≥ 0. It cannot see the motion after the probe lets go
//! (the baseline is at rest there), so a rebound past the rest shape after release
//! ([`crate::signatures::release_rebound`], ≥ [`REBOUND_SIGMAS`] σ) sends it to re-simulation
//! before the screen's candidates. Confirmation: the default model's implicit dynamics
//! M ü + D u̇ + f_int(u) = f_ext + f_c with Rayleigh damping D = α M + β K (wang2015 eq. 3, lumped
//! M of density ρ; `crate::sim::Extension::Dynamic`) with the session's rigid tip at its measured
//! poses (penalty contact f_c; the contact is lost at once when the probe lets go, as a fast
//! release does) — driven by the measured force instead when the session has no tip geometry —
//! with (ρ, α, β) fitted per fold on its training locations by a compass search
//! ([`fit_dynamics`]) and the held-out location predicted.

use super::Effect;
use super::contract::{Context, Hypothesis, SignatureRoute};
use crate::DiagnoseError;
use crate::Result;
use crate::baseline::Prepared;
use crate::cells::{contact_radius_m, touched_balls};
use crate::confirm::{
    Candidate, ComplianceScale, Confirmed, Lolo, lolo_choices_among, lolo_confirm_among,
};
use crate::recording::Recording;
use crate::residual::{residuals, rest_mean};
use crate::resim::{contact_sequence, pose_sequence};
use crate::screen::{Basis, Refit, Variant};
use crate::segment::Segmentation;
use crate::signal::derivative;
use crate::signatures::Signatures;
use crate::signatures::released_blocks;
use crate::sim::{Extension, Field, MarkerMode, ProbeSimulator, SequenceJob};
use nalgebra::Vector3;
use std::collections::BTreeMap;

/// The inertia-damping hypothesis.
pub struct InertiaDamping;

/// Rebound after release (`Signatures::release_rebound_m`) in marker noise σ at or above which
/// the dynamic model is re-simulated before the screen's candidates: the markers under the probe
/// spring back past their rest shape, which creep recovery and a plastic set never do (they
/// approach rest from the pressed side) and which the quasi-static default model, at rest once
/// the force is zero, cannot follow.
pub const REBOUND_SIGMAS: f64 = 4.0;

/// True when the surface rebounds past its rest shape after release ([`REBOUND_SIGMAS`]).
pub fn rebounds(sig: &Signatures) -> bool {
    sig.noise_sigma_m > 0.0 && sig.release_rebound_m >= REBOUND_SIGMAS * sig.noise_sigma_m
}

impl Hypothesis for InertiaDamping {
    fn effect(&self) -> Effect {
        Effect::InertiaDamping
    }

    fn term(&self) -> &'static str {
        "M d2u/dt2 + (alpha M + beta K) du/dt + f_int(u) = f_ext (lumped M of density rho; screen: x = x0 - damping_s dx0/dt - mass_s2 d2x0/dt2)"
    }

    fn variants(&self, cx: &Context<'_>) -> Vec<Variant> {
        let p = cx.prepared;
        let t = &p.times_s;
        let (nt, nm) = (t.len(), p.num_markers());
        let per_marker: Vec<Vec<Vector3<f64>>> = (0..nm)
            .map(|m| (0..nt).map(|k| p.baseline_m[k][m]).collect())
            .collect();
        let v: Vec<Vec<Vector3<f64>>> = per_marker.iter().map(|x| derivative(t, x)).collect();
        let a: Vec<Vec<Vector3<f64>>> = v.iter().map(|x| derivative(t, x)).collect();
        let tr = |g: &Vec<Vec<Vector3<f64>>>| -> Field {
            (0..nt)
                .map(|k| (0..nm).map(|m| -g[m][k]).collect())
                .collect()
        };
        vec![Variant {
            fixed: vec![],
            offset: None,
            bases: vec![
                Basis {
                    name: "damping_s",
                    nonneg: true,
                    field: tr(&v),
                },
                Basis {
                    name: "mass_s2",
                    nonneg: true,
                    field: tr(&a),
                },
            ],
        }]
    }

    fn signature_support(&self, s: &Signatures) -> f64 {
        if rebounds(s) { 1.0 } else { 0.0 }
    }

    fn signature_route(&self, s: &Signatures) -> Option<SignatureRoute> {
        rebounds(s).then_some(SignatureRoute::BeforeScreen)
    }

    /// The rigid-tip dynamic replay (position control, compliance scale 1; force-driven with the
    /// material's compliance scale without a tip) with (ρ, α, β) fitted per fold
    /// ([`fit_dynamics`]), leave-one-location-out.
    fn confirm(
        &self,
        cx: &Context<'_>,
        _: &Refit,
        scored: &dyn Fn(usize, usize) -> bool,
        sim: &mut dyn ProbeSimulator,
    ) -> Result<Option<Confirmed>> {
        let (rec, seg, p) = (cx.rec, cx.seg, cx.prepared);
        // the fit mesh refined 1 -> 8 where it does not resolve the tip's footprint: the coarse
        // contact nodes overshoot under a fast press and no dynamics beats the quasi-static
        // replay there (docs/diagnose.md)
        let balls = touched_balls(rec, seg);
        let tips: Vec<Vector3<f64>> = balls.iter().map(|b| b.centre_m).collect();
        let mut fine = if sim.resolves_footprint(rec.tip_radius_m, &tips) {
            None
        } else {
            sim.refined(&balls)?
        };
        let refined = fine.is_some();
        let plan = if refined {
            DynamicSearch::REFINED
        } else {
            DynamicSearch::FIT_MESH
        };
        let sim: &mut dyn ProbeSimulator = match fine.as_deref_mut() {
            Some(f) => f,
            None => sim,
        };
        // the density line (and the Rayleigh line) about the modal estimate where the plan has
        // one (wang2015 §6.3)
        let modal = if plan.modal_line.is_empty() {
            None
        } else {
            modal_estimate(rec, seg, p, sim)?
        };
        // the rigid tip at its measured poses (position control: compliance scale 1), else the
        // measured force (force-driven: the material's compliance scale refitted)
        let poses = pose_sequence(rec);
        let measured = contact_sequence(rec, seg, &p.force_n);
        let mut rigid = true;
        let mut simulate = |exts: &[Extension]| -> (Vec<Result<Field>>, bool) {
            if rigid {
                let out = sim.simulate_sequences_rigid_tip(exts, &poses);
                if !out.iter().any(|r| matches!(r, Ok(None))) {
                    let out = out.into_iter().map(|r| r.map(Option::unwrap_or_default));
                    return (out.collect(), true);
                }
                rigid = false; // no tip geometry: force-driven from here on
            }
            let jobs: Vec<SequenceJob> = exts.iter().map(|e| (*e, measured.clone())).collect();
            (sim.simulate_sequences(&jobs), false)
        };
        let lolo = Lolo {
            rec,
            seg,
            p,
            scale: ComplianceScale::new(cx.settings.refit_compliance_scale, 0.1, 10.0),
            scored,
            train_on_scored: false,
        };
        let nf = seg.num_folds();
        let train = |cands: &[Candidate], eligible: &dyn Fn(usize, Option<usize>) -> bool| {
            lolo_choices_among(cands, eligible, &lolo)
        };
        let mut fit = fit_dynamics(&mut simulate, nf, train, &plan, modal)?;
        for c in &mut fit.candidates {
            c.params
                .push(("refined_mesh".into(), if refined { 1.0 } else { 0.0 }));
        }
        let eligible = |i: usize, fold: Option<usize>| fit.eligible(i, fold);
        let driven = if fit.position_controlled {
            "the rigid tip replayed at its measured poses, contact lost at once on release"
        } else {
            "driven by the measured force, compliance scale"
        };
        lolo_confirm_among(
            &fit.candidates,
            Some(&eligible),
            &lolo,
            None,
            format!(
                "re-simulated extended model (implicit dynamics, Newmark, Rayleigh damping, {driven}; density, alpha, beta fitted per fold by a compass search{}{}, {} sequences on the {}, {} failed), leave-one-location-out",
                match modal {
                    Some(m) if fit.on_rayleigh_line => format!(
                        " from the modal density {:.0} kg/m^3 along the Rayleigh line of its damping ratio {:.3}",
                        m.density_kg_m3, m.damping_ratio
                    ),
                    Some(m) => format!(" from the modal density {:.0} kg/m^3", m.density_kg_m3),
                    None => String::new(),
                },
                if fit.on_rayleigh_line && plan.lame_rounds > 0 {
                    ", then the Lame ratio lambda/mu at the fitted E (nu) and the density again"
                } else {
                    ""
                },
                fit.candidates.len(),
                if refined {
                    "fit mesh refined 1 -> 8"
                } else {
                    "fit mesh"
                },
                fit.failed
            ),
        )
    }
}

/// The start grid of the dynamic fit on the fit mesh (every fold starts from its best point):
/// density ρ, kg/m³ — from a light foam to a dense filled gel, a factor 4 apart (a factor 2 in the
/// frequencies).
pub const START_DENSITY_KG_M3: [f64; 4] = [250.0, 1000.0, 4000.0, 16000.0];
/// … Rayleigh α, 1/s.
pub const START_ALPHA_PER_S: [f64; 2] = [2.0, 20.0];
/// … Rayleigh β, s.
pub const START_BETA_S: [f64; 2] = [2e-4, 4e-3];

/// The start line of the dynamic fit on the refined mesh: density ρ, kg/m³, a factor 4 apart,
/// one octave higher than [`START_DENSITY_KG_M3`] at the top (position control: only E/ρ moves
/// the markers, and a fitted material that is too stiff is matched by a heavier body).
pub const REFINED_START_DENSITY_KG_M3: [f64; 4] = [1000.0, 4000.0, 16000.0, 64000.0];
/// … at the geometric middle of [`START_ALPHA_PER_S`], 1/s …
pub const REFINED_START_ALPHA_PER_S: [f64; 1] = [6.324555320336759];
/// … and of [`START_BETA_S`], s.
pub const REFINED_START_BETA_S: [f64; 1] = [8.94427190999916e-4];

/// The refined start line about the modal density estimate: 2^{-1/2}, 1 and 2^{1/2} times it.
/// Half an octave either side brackets the estimate's uncertainty (the measured frequency
/// differs by ±5 % between the projections on the lowest modes, ±10 % in ρ; the two modes the
/// ringing shows most give ρ 0.37 octave apart on the suite's session), and it is the
/// compass's step in ρ from this line ([`DynamicSearch::modal_step`]), so a search whose best
/// line point is the estimate proposes no new density.
pub const MODAL_LINE: [f64; 3] = [
    std::f64::consts::FRAC_1_SQRT_2,
    1.0,
    std::f64::consts::SQRT_2,
];

/// Density of the modal analysis, kg/m³ (any positive value: ω² ∝ 1/ρ at a fixed stiffness).
const MODAL_REFERENCE_DENSITY_KG_M3: f64 = 1000.0;

/// The modal estimate of the measured body's dynamics ([`modal_estimate`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ModalEstimate {
    /// ρ̂, kg/m³: the density at which the model's chosen mode rings at the measured frequency.
    pub density_kg_m3: f64,
    /// The chosen mode's natural frequency f₀ at [`Self::reference_density_kg_m3`], Hz.
    pub reference_frequency_hz: f64,
    /// ρ₀, kg/m³.
    pub reference_density_kg_m3: f64,
    /// The measured ringing's damping ratio ζ ([`ringing`]).
    pub damping_ratio: f64,
}

impl ModalEstimate {
    /// The chosen mode's natural angular frequency at density ρ, rad/s: ω = 2π f₀ √(ρ₀ / ρ)
    /// (K φ = ω² M φ with M ∝ ρ; at ρ̂ the measured one).
    pub fn omega_at(&self, density_kg_m3: f64) -> f64 {
        2.0 * std::f64::consts::PI
            * self.reference_frequency_hz
            * (self.reference_density_kg_m3 / density_kg_m3).sqrt()
    }

    /// The Rayleigh coefficients (α in 1/s, β in s) that give the chosen mode, at density ρ, the
    /// measured damping ratio ζ with the share `alpha_share` of it from the mass term: in the
    /// modal coordinates of wang2015 §6.3 (u = Φ z, K φ = ω² M φ) the damping D = α M + β K of
    /// wang2015 eq. 3 decouples into z̈ + (α + β ω²) ż + ω² z = 0, so
    /// ζ = α / (2ω) + β ω / 2; α = 2 ω ζ s and β = 2 ζ (1 − s) / ω with s = `alpha_share`.
    pub fn rayleigh_at(&self, density_kg_m3: f64, alpha_share: f64) -> (f64, f64) {
        let omega = self.omega_at(density_kg_m3);
        let zeta = self.damping_ratio;
        (
            2.0 * omega * zeta * alpha_share,
            2.0 * zeta * (1.0 - alpha_share) / omega,
        )
    }
}

/// The density at which the model rings as the measured body does after release, and the
/// ringing's damping ratio (wang2015 §6.3, the modal warm start, with ρ in the place of E): with
/// the material fixed, every natural frequency of K φ = ω² M φ scales as 1/√ρ, so a mode of
/// frequency f₀ at a reference density ρ₀ ([`ProbeSimulator::natural_modes`]) matches the
/// measured frequency f at ρ = ρ₀ (f₀ / f)². f is read, as wang2015 reads ω₁, from the captured
/// displacements projected onto the mode: per block of released frames after a press (the
/// probe has let go, so the body rings freely about its rest shape), the markers within
/// [`contact_radius_m`] of the press's contact point, their baseline residual less its mean at
/// rest projected onto the mode's marker shape; the frequency and damping ratio of a damped
/// oscillation fitted to those projections ([`ringing`]). The mode is the one of the lowest six
/// whose shape explains the largest share of those displacements, not wang2015's first mode:
/// their bar rings in its first mode, while a block pressed straight down at its top rings in a
/// vertical mode above its two lateral sway modes (suite session: sway 22.6 Hz at ρ₀ gives ρ
/// 4428 kg/m³ and a held-out error of 0.1420 mm; the mode explaining most, 37.0 Hz, 11428 kg/m³,
/// against the fitted 16208). The position-controlled replay moves the markers through E/ρ only
/// (the fitted material's E stands), so this is the density the search looks for; it replaces
/// the fixed start line and its light end, the dearest replays. `None` when the simulator has
/// no modes, the recording no ringing (fewer than 3 triples of consecutive released frames), or
/// the fitted oscillation is not underdamped.
pub fn modal_estimate(
    rec: &Recording,
    seg: &Segmentation,
    p: &Prepared,
    sim: &dyn ProbeSimulator,
) -> Result<Option<ModalEstimate>> {
    let Some(modes) = sim.natural_modes(MODAL_REFERENCE_DENSITY_KG_M3, 6)? else {
        return Ok(None);
    };
    let h = frame_interval_s(&p.times_s);
    let res = residuals(rec, &p.baseline_m);
    let rest = rest_mean(&res, seg, rec.num_markers());
    let radius = contact_radius_m(rec);
    let blocks = released_blocks(seg, res.len());
    // per block, the projections z_k = φ·d_k / |φ|² and the share (φ·d_k)² / |φ|² of |d_k|²
    // they explain, over the observed near markers
    let project = |mode: &MarkerMode| -> (Vec<Vec<f64>>, f64) {
        let mut explained = 0.0;
        let z = blocks
            .iter()
            .map(|(l, frames)| {
                let tip = seg.locations[*l].contact_tip_m;
                let near: Vec<usize> = (0..rec.num_markers())
                    .filter(|&m| (tip - rec.rest_markers_m[m]).norm() <= radius)
                    .collect();
                frames
                    .iter()
                    .map(|&k| {
                        let (mut num, mut den) = (0.0, 0.0);
                        for &m in &near {
                            if let Some(r) = res[k][m] {
                                num += mode.markers[m].dot(&(r - rest[m]));
                                den += mode.markers[m].norm_squared();
                            }
                        }
                        if den > 0.0 {
                            explained += num * num / den;
                            num / den
                        } else {
                            0.0
                        }
                    })
                    .collect()
            })
            .collect();
        (z, explained)
    };
    let projected: Vec<(Vec<Vec<f64>>, f64)> = modes.iter().map(project).collect();
    // the mode the ringing shows most: the largest share of the released displacement
    let Some((mode, (z, _))) = modes
        .iter()
        .zip(&projected)
        .max_by(|a, b| a.1.1.total_cmp(&b.1.1))
    else {
        return Ok(None);
    };
    let Some(ring) = ringing(z, h) else {
        return Ok(None);
    };
    Ok(Some(ModalEstimate {
        density_kg_m3: MODAL_REFERENCE_DENSITY_KG_M3
            * (mode.frequency_hz / ring.frequency_hz).powi(2),
        reference_frequency_hz: mode.frequency_hz,
        reference_density_kg_m3: MODAL_REFERENCE_DENSITY_KG_M3,
        damping_ratio: ring.damping_ratio,
    }))
}

/// The median interval between consecutive frame times, s.
fn frame_interval_s(times_s: &[f64]) -> f64 {
    let mut dt: Vec<f64> = times_s.windows(2).map(|w| w[1] - w[0]).collect();
    if dt.is_empty() {
        return 0.0;
    }
    dt.sort_by(f64::total_cmp);
    dt[dt.len() / 2]
}

/// A free damped oscillation z̈ + 2ζω ż + ω² z = 0 ([`ringing`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ringing {
    /// The undamped natural frequency ω / 2π, Hz.
    pub frequency_hz: f64,
    /// The damping ratio ζ (negative when the oscillation grows).
    pub damping_ratio: f64,
}

/// The free damped oscillation z̈ + 2ζω ż + ω² z = 0 shared by the sampled signals `z` (frame
/// interval `h_s`): sampled, each obeys the linear prediction z_{k+1} = a₁ z_k + a₂ z_{k−1} whose
/// characteristic roots r e^{±iθ} are e^{(−ζω ± iω_d) h} (Prony's method with two poles), so
/// a₁, a₂ are fitted by least squares over every signal's triples; then ln(r e^{iθ}) = (−ζω + iω_d) h
/// gives ω = √(ln² r + θ²) / h and ζ = −ln r / (ω h) (the modal coordinate's decay, wang2015
/// §6.3). `None` with fewer than 3 equations in all or when the roots are real (no oscillation).
pub fn ringing(z: &[Vec<f64>], h_s: f64) -> Option<Ringing> {
    let (mut s11, mut s12, mut s22, mut b1, mut b2, mut n) = (0.0, 0.0, 0.0, 0.0, 0.0, 0usize);
    for w in z.iter().flat_map(|sig| sig.windows(3)) {
        let (zm, z0, zp) = (w[0], w[1], w[2]);
        s11 += z0 * z0;
        s12 += z0 * zm;
        s22 += zm * zm;
        b1 += z0 * zp;
        b2 += zm * zp;
        n += 1;
    }
    let det = s11 * s22 - s12 * s12;
    if n < 3 || !h_s.is_finite() || h_s <= 0.0 || !det.is_finite() || det <= 1e-12 * s11 * s22 {
        return None;
    }
    let a1 = (b1 * s22 - b2 * s12) / det;
    let a2 = (s11 * b2 - s12 * b1) / det;
    // roots of r² − a₁ r − a₂ = 0: complex when a₁² + 4 a₂ < 0, then r² = −a₂
    let discriminant = a1 * a1 + 4.0 * a2;
    if discriminant.is_nan() || discriminant >= 0.0 {
        return None;
    }
    let r = (-a2).sqrt();
    let theta = (a1 / (2.0 * r)).clamp(-1.0, 1.0).acos();
    let omega_h = (r.ln().powi(2) + theta * theta).sqrt();
    Some(Ringing {
        frequency_hz: omega_h / h_s / (2.0 * std::f64::consts::PI),
        damping_ratio: -r.ln() / omega_h,
    })
}

/// log₂ bounds of (ρ [kg/m³], α [1/s], β [s]).
const LOG2_BOUNDS: [(f64, f64); 3] = [(5.0, 17.0), (-4.0, 9.0), (-17.0, -4.0)];

/// log₂ bounds of the Lamé ratio factor ([`crate::sim::with_lame_ratio`]): a factor 8 either
/// way takes ν 0.42 to 0.20 or 0.49.
const LOG2_LAME_BOUNDS: (f64, f64) = (-3.0, 3.0);

/// The coordinate a phase of the Rayleigh-line search steps along ([`fit_dynamics`]).
#[derive(Clone, Copy, Debug)]
enum LineCoordinate {
    /// The α-share of the mode's damping ratio, ρ and the Lamé ratio kept.
    Share,
    /// log₂ of the Lamé ratio factor, ρ, α and β kept.
    LameRatio,
    /// log₂ ρ, (α, β) moved along the Rayleigh line to the new ρ at the same share.
    Density,
}

/// How [`fit_dynamics`] searches (ρ, α, β): a start grid simulated once, then compass rounds in
/// log₂ units.
#[derive(Clone, Copy, Debug)]
pub struct DynamicSearch {
    /// Start grid: densities, kg/m³.
    pub densities_kg_m3: &'static [f64],
    /// … Rayleigh α, 1/s.
    pub alphas_per_s: &'static [f64],
    /// … Rayleigh β, s.
    pub betas_s: &'static [f64],
    /// The compass's first step along log₂ (ρ, α, β).
    pub first_step: [f64; 3],
    /// The step below which a coordinate is not refined further.
    pub last_step: [f64; 3],
    /// At most this many compass rounds.
    pub max_rounds: usize,
    /// The start line's densities as factors of the modal estimate ([`modal_estimate`]),
    /// which replace [`Self::densities_kg_m3`] when there is one; empty: always the fixed line.
    pub modal_line: &'static [f64],
    /// The compass's step along log₂ ρ (first and last) from the modal line.
    pub modal_step: f64,
    /// `Some(rounds)`: with a modal estimate whose damping ratio is in (0, 1), (α, β) lie on the
    /// chosen mode's Rayleigh line ([`ModalEstimate::rayleigh_at`]) — the start line at the
    /// α-share [`RAYLEIGH_START_SHARE`], then `rounds` compass rounds along the share alone
    /// (from a step of [`RAYLEIGH_SHARE_STEP`], halved when no point is better; ρ stays at the
    /// search's best start-line point) — in place of the α, β grid and the (ρ, α, β) compass.
    pub rayleigh_rounds: Option<usize>,
    /// On the Rayleigh line, after the share: this many compass rounds along log₂ of the Lamé
    /// ratio factor ([`Extension::Dynamic`]'s `lame_ratio_factor`: ν at the fitted E, wang2015
    /// §6.2's p = (E, ν, α, β) with E/ρ standing for E under position control) …
    pub lame_rounds: usize,
    /// … from this step (halved when no point is better) …
    pub lame_step: f64,
    /// … then this many rounds along log₂ ρ, (α, β) kept on the Rayleigh line at the search's
    /// share …
    pub density_rounds: usize,
    /// … from this step.
    pub density_step: f64,
}

/// The α-share s of the Rayleigh line's start point ([`ModalEstimate::rayleigh_at`]): the
/// mode's damping ratio half from the mass term, half from the stiffness term.
pub const RAYLEIGH_START_SHARE: f64 = 0.5;
/// The first step of the compass along the α-share: a quarter either side of the middle, both
/// damping terms kept. An end of the line leaves the model's high modes undamped by one term:
/// at s = 1 (β = 0) the rigid-tip replay's contact and release steps ring at every frequency
/// the mesh has, and on the suite session that replay cost 24 CPU-s against 9–12 for the others.
pub const RAYLEIGH_SHARE_STEP: f64 = 0.25;

impl DynamicSearch {
    /// On the fit mesh (a replay 1.5–3.3 CPU-s on the 648-tet suite template): the 16-point grid
    /// [`START_DENSITY_KG_M3`] × [`START_ALPHA_PER_S`] × [`START_BETA_S`], then up to 12 rounds
    /// from steps of an octave down to 2^{1/16} in ρ (2 % in the frequencies) and 2^{1/4} in α, β.
    pub const FIT_MESH: Self = Self {
        densities_kg_m3: &START_DENSITY_KG_M3,
        alphas_per_s: &START_ALPHA_PER_S,
        betas_s: &START_BETA_S,
        first_step: [1.0, 1.0, 1.0],
        last_step: [1.0 / 16.0, 0.25, 0.25],
        max_rounds: 12,
        modal_line: &[],
        modal_step: 1.0,
        rayleigh_rounds: None,
        lame_rounds: 0,
        lame_step: 1.0,
        density_rounds: 0,
        density_step: 0.25,
    };
    /// On the fit mesh refined 1 → 8 (a rigid-tip replay on the 5184-tet refined suite template
    /// costs ≈ 16× the fit mesh's, the light densities dearest: at ρ 1000 kg/m³ about 3× one at
    /// 16000, its free steps taking ≈ 8 chord updates each): few replays — the 1-D line
    /// [`MODAL_LINE`] about the modal density ([`modal_estimate`]) on the Rayleigh line of the
    /// measured damping ratio at the α-share 1/2, then one compass round along the share (1/4
    /// and 3/4 at each search's best density: 5 replays when the searches agree on it).
    /// Without a damping ratio the same density line at the middle damping, then one compass
    /// round of half an octave in ρ and a factor 4 in α, β (each search proposes at most 6
    /// points; points shared by several searches are replayed once); without a modal estimate
    /// the line [`REFINED_START_DENSITY_KG_M3`] and an octave in ρ. On the suite's
    /// inertia-damping session an octave line about the modal estimate (11428 kg/m³) kept ρ
    /// 11460 and missed the limit (0.1113 mm against 0.1101); the half-octave line reaches 16208.
    /// On the Rayleigh line, then two rounds along the Lamé ratio from an octave and two along ρ
    /// from a quarter octave: on the suite session the tissue fit's ν 0.4235 (truth 0.45) goes
    /// to 0.4586 (factor 2) and ρ from 18258 to 21713 kg/m³, the held-out error from 0.0903 to
    /// 0.0793 mm (6 more replays; `diagnose_floor` with the truth E and dynamics at ν 0.46: 0.0813).
    pub const REFINED: Self = Self {
        densities_kg_m3: &REFINED_START_DENSITY_KG_M3,
        alphas_per_s: &REFINED_START_ALPHA_PER_S,
        betas_s: &REFINED_START_BETA_S,
        first_step: [1.0, 2.0, 2.0],
        last_step: [1.0, 2.0, 2.0],
        max_rounds: 1,
        modal_line: &MODAL_LINE,
        modal_step: 0.5,
        rayleigh_rounds: Some(1),
        lame_rounds: 2,
        lame_step: 1.0,
        density_rounds: 2,
        density_step: 0.25,
    };
}

/// The simulated dynamic models of [`fit_dynamics`] and which fold may choose each.
pub struct DynamicFit {
    /// Every converged sequence: the start grid, then the compass points in the order simulated.
    pub candidates: Vec<Candidate>,
    /// Per candidate: `None` for the start grid (chosen without data, every fold may take it),
    /// else the searches that proposed it (fold l, or `nf` for the full data).
    pub proposed_by: Vec<Option<Vec<usize>>>,
    /// Number of folds.
    pub folds: usize,
    /// Sequences that did not reach equilibrium.
    pub failed: usize,
    /// The sequences are rigid-tip replays (position control; else driven by the force).
    pub position_controlled: bool,
    /// (α, β) were searched along the modal Rayleigh line ([`DynamicSearch::rayleigh_rounds`]).
    pub on_rayleigh_line: bool,
}

impl DynamicFit {
    /// Fold `fold` (`None`: the full data) may choose candidate `i`: the start grid, or a point
    /// its own search proposed from its training locations.
    pub fn eligible(&self, i: usize, fold: Option<usize>) -> bool {
        let s = fold.unwrap_or(self.folds);
        match &self.proposed_by[i] {
            None => true,
            Some(by) => by.contains(&s),
        }
    }
}

/// A point of the search: log₂ (ρ, α, β, Lamé ratio factor) on a 1/64 lattice.
type Key = [i64; 4];

fn key(theta: [f64; 4]) -> Key {
    theta.map(|t| (t * 64.0).round() as i64)
}

fn theta(k: Key) -> [f64; 4] {
    k.map(|v| v as f64 / 64.0)
}

/// The parameters and the extension of the point `k`; the Lamé ratio factor is named only off
/// the default model's material (a factor ≠ 1).
fn extension(k: Key) -> (Vec<(String, f64)>, Extension) {
    let [rho, alpha, beta, lame] = theta(k).map(f64::exp2);
    let mut params = vec![
        ("density_kg_m3".into(), rho),
        ("rayleigh_alpha_per_s".into(), alpha),
        ("rayleigh_beta_s".into(), beta),
    ];
    if k[3] != 0 {
        params.push(("lame_ratio_factor".into(), lame));
    }
    (
        params,
        Extension::Dynamic {
            density_kg_m3: rho,
            alpha_per_s: alpha,
            beta_s: beta,
            lame_ratio_factor: lame,
        },
    )
}

/// The lattice key of the point (ρ, α, β), each clamped to its [`LOG2_BOUNDS`] (α or β 0 at an
/// end of the Rayleigh line: the bound's 2⁻⁴ 1/s or 2⁻¹⁷ s).
fn clamped_key(rho: f64, alpha: f64, beta: f64, log2_lame: f64) -> Key {
    let t = [rho, alpha, beta];
    key(std::array::from_fn(|d| match d {
        3 => log2_lame,
        _ => t[d].log2().clamp(LOG2_BOUNDS[d].0, LOG2_BOUNDS[d].1),
    }))
}

/// Fits the dynamic model's density ρ and Rayleigh α, β (wang2015 eq. 3: D = α M + β K) per
/// fold on its training locations: every fold and the full data start from the best point of
/// `plan`'s start grid (simulated once; its densities about the modal estimate `modal` when
/// `plan` has a modal line and the estimate is given), then a compass search — each round every
/// search tries ± its step along each coordinate, moves to the best of its points (training
/// error, `train`), and halves its steps when none is better, until they are below
/// `plan.last_step` or after `plan.max_rounds` rounds. The coordinates are log₂ (ρ, α, β), or,
/// with `plan.rayleigh_rounds` and the estimate's damping ratio ζ in (0, 1), the α-share s of the
/// mode's Rayleigh line ζ = α/(2ω) + βω/2 (wang2015 eq. 3 in the modal coordinates of §6.3,
/// [`ModalEstimate::rayleigh_at`]; ω the mode's frequency at each density) with ρ kept at the
/// search's best start-line point: the start line is then the density line at s =
/// [`RAYLEIGH_START_SHARE`]. The searches run in lockstep: one round's points of every search
/// are simulated together (in parallel, each point once however many searches propose it),
/// and a point is offered only to the searches that proposed it ([`DynamicFit::eligible`]), so a
/// held-out location never shapes its own model. `train` returns, per fold and then for the full
/// data, the eligible candidate with the least training error; `simulate` replays a batch of
/// extensions over the recording and says whether its replays are position-controlled.
pub fn fit_dynamics(
    simulate: &mut dyn FnMut(&[Extension]) -> (Vec<Result<Field>>, bool),
    folds: usize,
    train: impl Fn(&[Candidate], &dyn Fn(usize, Option<usize>) -> bool) -> Vec<Option<(usize, f64)>>,
    plan: &DynamicSearch,
    modal: Option<ModalEstimate>,
) -> Result<DynamicFit> {
    let modal = modal.filter(|_| !plan.modal_line.is_empty());
    // the Rayleigh line's mode, when the plan and the estimate have one
    let line = match (modal, plan.rayleigh_rounds) {
        (Some(m), Some(rounds)) if m.damping_ratio > 0.0 && m.damping_ratio < 1.0 => {
            Some((m, rounds))
        }
        _ => None,
    };
    let mut fit = DynamicFit {
        candidates: Vec::new(),
        proposed_by: Vec::new(),
        folds,
        failed: 0,
        position_controlled: false,
        on_rayleigh_line: line.is_some(),
    };
    // key -> candidate index (None: did not converge)
    let mut simulated: BTreeMap<Key, Option<usize>> = BTreeMap::new();
    let mut keys: Vec<Key> = Vec::new();
    let run = |fit: &mut DynamicFit,
               keys: &mut Vec<Key>,
               simulated: &mut BTreeMap<Key, Option<usize>>,
               simulate: &mut dyn FnMut(&[Extension]) -> (Vec<Result<Field>>, bool),
               batch: Vec<(Key, Option<Vec<usize>>)>|
     -> Result<()> {
        if batch.is_empty() {
            return Ok(());
        }
        let exts: Vec<Extension> = batch.iter().map(|(k, _)| extension(*k).1).collect();
        let (results, position_controlled) = simulate(&exts);
        fit.position_controlled = position_controlled;
        for ((k, by), result) in batch.into_iter().zip(results) {
            match result {
                Ok(prediction) => {
                    simulated.insert(k, Some(fit.candidates.len()));
                    fit.candidates.push(Candidate {
                        params: extension(k).0,
                        prediction,
                        position_controlled,
                    });
                    fit.proposed_by.push(by);
                    keys.push(k);
                }
                Err(DiagnoseError::Simulation { .. }) => {
                    simulated.insert(k, None);
                    fit.failed += 1;
                }
                Err(e) => return Err(e),
            }
        }
        Ok(())
    };
    // one round's proposals (point -> the searches proposing it): points already simulated
    // become eligible to their new proposers, the others are run
    let offer = |fit: &mut DynamicFit,
                 keys: &mut Vec<Key>,
                 simulated: &mut BTreeMap<Key, Option<usize>>,
                 simulate: &mut dyn FnMut(&[Extension]) -> (Vec<Result<Field>>, bool),
                 proposals: BTreeMap<Key, Vec<usize>>|
     -> Result<()> {
        let mut batch = Vec::new();
        for (k, by) in proposals {
            match simulated.get(&k) {
                Some(Some(i)) => {
                    if let Some(list) = fit.proposed_by[*i].as_mut() {
                        for s in by {
                            if !list.contains(&s) {
                                list.push(s);
                            }
                        }
                    }
                }
                Some(None) => {}
                None => batch.push((k, Some(by))),
            }
        }
        run(fit, keys, simulated, simulate, batch)
    };
    let choose = |fit: &DynamicFit| {
        let eligible = |i: usize, fold: Option<usize>| fit.eligible(i, fold);
        train(&fit.candidates, &eligible)
    };
    if let Some((mode, rounds)) = line {
        // the density line at the start share; per key its (ρ, α-share)
        let mut on_line: BTreeMap<Key, (f64, f64)> = BTreeMap::new();
        let point =
            |on_line: &mut BTreeMap<Key, (f64, f64)>, rho: f64, share: f64, lame: f64| -> Key {
                let (alpha, beta) = mode.rayleigh_at(rho, share);
                let k = clamped_key(rho, alpha, beta, lame);
                on_line.entry(k).or_insert((rho, share));
                k
            };
        let mut start = Vec::new();
        for f in plan.modal_line {
            let k = point(
                &mut on_line,
                f * mode.density_kg_m3,
                RAYLEIGH_START_SHARE,
                0.0,
            );
            start.push((k, None));
        }
        run(&mut fit, &mut keys, &mut simulated, simulate, start)?;
        // per search: its centre, carried from phase to phase
        let mut centres: Vec<Option<Key>> = choose(&fit)
            .iter()
            .map(|c| c.map(|(i, _)| keys[i]))
            .collect();
        let phases = [
            (LineCoordinate::Share, rounds, RAYLEIGH_SHARE_STEP),
            (LineCoordinate::LameRatio, plan.lame_rounds, plan.lame_step),
            (
                LineCoordinate::Density,
                plan.density_rounds,
                plan.density_step,
            ),
        ];
        for (coordinate, rounds, first) in phases {
            // per search: centre and step along this phase's coordinate
            let mut searches: Vec<Option<(Key, f64)>> =
                centres.iter().map(|c| c.map(|k| (k, first))).collect();
            for _ in 0..rounds {
                let mut proposals: BTreeMap<Key, Vec<usize>> = BTreeMap::new();
                for (s, search) in searches.iter().enumerate() {
                    let Some((centre, step)) = search else {
                        continue;
                    };
                    let Some(&(rho, share)) = on_line.get(centre) else {
                        continue;
                    };
                    let lame = theta(*centre)[3];
                    for sign in [-1.0, 1.0] {
                        let to = match coordinate {
                            LineCoordinate::Share => {
                                (rho, (share + sign * step).clamp(0.0, 1.0), lame)
                            }
                            LineCoordinate::LameRatio => (
                                rho,
                                share,
                                (lame + sign * step).clamp(LOG2_LAME_BOUNDS.0, LOG2_LAME_BOUNDS.1),
                            ),
                            LineCoordinate::Density => (rho * (sign * step).exp2(), share, lame),
                        };
                        if to != (rho, share, lame) {
                            let k = point(&mut on_line, to.0, to.1, to.2);
                            if k != *centre {
                                proposals.entry(k).or_default().push(s);
                            }
                        }
                    }
                }
                if proposals.is_empty() {
                    break;
                }
                offer(&mut fit, &mut keys, &mut simulated, simulate, proposals)?;
                for (search, choice) in searches.iter_mut().zip(choose(&fit)) {
                    let (Some((centre, step)), Some((i, _))) = (search.as_mut(), choice) else {
                        continue;
                    };
                    if keys[i] == *centre {
                        *step *= 0.5;
                    } else {
                        *centre = keys[i];
                    }
                }
            }
            centres = searches.iter().map(|s| s.map(|(k, _)| k)).collect();
        }
        return Ok(fit);
    }
    let (mut first_step, mut last_step) = (plan.first_step, plan.last_step);
    let densities: Vec<f64> = match modal {
        Some(m) => {
            (first_step[0], last_step[0]) = (plan.modal_step, plan.modal_step);
            plan.modal_line
                .iter()
                .map(|f| f * m.density_kg_m3)
                .collect()
        }
        None => plan.densities_kg_m3.to_vec(),
    };
    let mut start = Vec::new();
    for rho in &densities {
        for alpha in plan.alphas_per_s {
            for beta in plan.betas_s {
                start.push((key([rho.log2(), alpha.log2(), beta.log2(), 0.0]), None));
            }
        }
    }
    run(&mut fit, &mut keys, &mut simulated, simulate, start)?;
    // per search (fold l, then the full data): centre and steps
    let mut searches: Vec<Option<(Key, [f64; 3])>> = choose(&fit)
        .iter()
        .map(|c| c.map(|(i, _)| (keys[i], first_step)))
        .collect();
    for _ in 0..plan.max_rounds {
        // this round's points, each with the searches proposing it
        let mut proposals: BTreeMap<Key, Vec<usize>> = BTreeMap::new();
        for (s, search) in searches.iter().enumerate() {
            let Some((centre, step)) = search else {
                continue;
            };
            let c = theta(*centre);
            for d in 0..3 {
                if step[d] < last_step[d] {
                    continue;
                }
                for sign in [-1.0, 1.0] {
                    let mut t = c;
                    t[d] = (t[d] + sign * step[d]).clamp(LOG2_BOUNDS[d].0, LOG2_BOUNDS[d].1);
                    let k = key(t);
                    if k != *centre {
                        proposals.entry(k).or_default().push(s);
                    }
                }
            }
        }
        if proposals.is_empty() {
            break;
        }
        offer(&mut fit, &mut keys, &mut simulated, simulate, proposals)?;
        let choices = choose(&fit);
        for (search, choice) in searches.iter_mut().zip(choices) {
            let (Some((centre, step)), Some((i, _))) = (search.as_mut(), choice) else {
                continue;
            };
            if keys[i] == *centre {
                for (s, last) in step.iter_mut().zip(last_step) {
                    if *s >= last {
                        *s *= 0.5;
                    }
                }
            } else {
                *centre = keys[i];
            }
        }
    }
    Ok(fit)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// z_k = a e^{−ζω t_k} cos(ω_d t_k + φ), t_k = k h: the free damped oscillation of
    /// frequency `f_hz` and damping ratio `zeta` sampled over `n` frames.
    fn damped(f_hz: f64, zeta: f64, h: f64, n: usize, a: f64, phi: f64) -> Vec<f64> {
        let w = 2.0 * std::f64::consts::PI * f_hz;
        let wd = w * (1.0 - zeta * zeta).sqrt();
        (0..n)
            .map(|k| {
                let t = k as f64 * h;
                a * (-zeta * w * t).exp() * (wd * t + phi).cos()
            })
            .collect()
    }

    #[test]
    fn ringing_recovers_the_frequency_and_damping_ratio_of_a_sampled_damped_oscillation() {
        // 9 Hz, ζ 0.15, sampled at 60 fps over 12 frames, two blocks of different phase/amplitude:
        // the two-pole model is exact, so both to 1e-6 (relative)
        let h = 1.0 / 60.0;
        let z = vec![
            damped(9.0, 0.15, h, 12, 1e-3, 0.3),
            damped(9.0, 0.15, h, 12, -4e-4, 1.2),
        ];
        let got = ringing(&z, h).expect("an underdamped oscillation");
        assert!((got.frequency_hz - 9.0).abs() < 1e-6 * 9.0, "{got:?}");
        assert!((got.damping_ratio - 0.15).abs() < 1e-6 * 0.15, "{got:?}");
        // the suite session's ringing: ≈ 11 Hz at 60 fps (5.5 frames a period), ζ ≈ 0.14, over
        // 3 released blocks of 8 frames; and a lightly damped one, ζ 0.02
        for (f, zeta) in [(10.95, 0.141), (10.95, 0.02)] {
            let z: Vec<Vec<f64>> = (0..3)
                .map(|b| damped(f, zeta, h, 8, 1e-4 * (1.0 + b as f64), 0.7 * b as f64))
                .collect();
            let got = ringing(&z, h).expect("an underdamped oscillation");
            assert!((got.frequency_hz - f).abs() < 1e-6 * f, "{got:?}");
            assert!((got.damping_ratio - zeta).abs() < 1e-6 * zeta, "{got:?}");
        }
        // with white noise of 2 % of the first amplitude (deterministic: a fixed LCG), f within
        // 2 % and ζ within 10 % (got: 11.005 Hz, ζ 0.1396): noise on the regressors biases the
        // two-pole fit
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut noise = || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            ((state >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 2.0 * 3f64.sqrt()
        };
        let z: Vec<Vec<f64>> = (0..6)
            .map(|b| {
                damped(10.95, 0.141, h, 12, 1e-4, 0.9 * b as f64)
                    .into_iter()
                    .map(|v| v + 2e-6 * noise())
                    .collect()
            })
            .collect();
        let got = ringing(&z, h).expect("an underdamped oscillation");
        assert!((got.frequency_hz - 10.95).abs() < 0.02 * 10.95, "{got:?}");
        assert!((got.damping_ratio - 0.141).abs() < 0.10 * 0.141, "{got:?}");
        // a growing oscillation has a negative damping ratio
        let grow = damped(9.0, -0.05, h, 12, 1e-3, 0.0);
        let got = ringing(&[grow], h).expect("an oscillation");
        assert!((got.damping_ratio + 0.05).abs() < 1e-6, "{got:?}");
        // a decay without oscillation has real roots
        let decay: Vec<f64> = (0..12).map(|k| (-0.3 * k as f64).exp()).collect();
        assert_eq!(ringing(&[decay], h), None);
    }

    #[test]
    fn rayleigh_line_gives_the_mode_its_damping_ratio_at_every_share_and_density() {
        let m = ModalEstimate {
            density_kg_m3: 11428.0,
            reference_frequency_hz: 37.0,
            reference_density_kg_m3: 1000.0,
            damping_ratio: 0.14,
        };
        // at ρ̂ the mode rings at the measured 37 √(1000/11428) Hz
        let w_hat = 2.0 * std::f64::consts::PI * 37.0 * (1000.0f64 / 11428.0).sqrt();
        assert!((m.omega_at(11428.0) - w_hat).abs() < 1e-12 * w_hat);
        for rho in [8081.0, 11428.0, 16162.0] {
            let w = m.omega_at(rho);
            for share in [0.0, 0.25, 0.5, 1.0] {
                let (alpha, beta) = m.rayleigh_at(rho, share);
                let zeta = alpha / (2.0 * w) + beta * w / 2.0;
                assert!((zeta - 0.14).abs() < 1e-12, "ρ {rho}, s {share}: ζ {zeta}");
                assert!((alpha / (2.0 * w) - share * 0.14).abs() < 1e-12);
            }
        }
        assert_eq!(m.rayleigh_at(11428.0, 1.0).1, 0.0);
    }

    /// A fake replay whose training error is the distance in (log₂ ρ, α-share, log₂ Lamé ratio
    /// factor) from a target, the same for every fold: the Rayleigh-line search replays the
    /// 3-point density line and the share line a step either side (5 replays), the Lamé ratio
    /// an octave either side and then a further octave up (3), ρ a quarter and an eighth of an
    /// octave either side (4), and every search ends at the best of them.
    #[test]
    fn rayleigh_line_search_replays_the_density_line_the_share_the_lame_ratio_and_density() {
        let m = ModalEstimate {
            density_kg_m3: 10000.0,
            reference_frequency_hz: 30.0,
            reference_density_kg_m3: 1000.0,
            damping_ratio: 0.1,
        };
        let target_rho = 14142.0;
        let mut replayed: Vec<Extension> = Vec::new();
        let mut simulate = |exts: &[Extension]| -> (Vec<Result<Field>>, bool) {
            replayed.extend_from_slice(exts);
            (exts.iter().map(|_| Ok(Field::new())).collect(), true)
        };
        let folds = 4;
        let error = |c: &Candidate| -> f64 {
            let p = |n: &str| {
                c.params
                    .iter()
                    .find(|(k, _)| k == n)
                    .map(|(_, v)| *v)
                    .expect("named")
            };
            let rho = p("density_kg_m3");
            let w = m.omega_at(rho);
            let share = p("rayleigh_alpha_per_s") / (2.0 * w) / m.damping_ratio;
            // the Lamé ratio factor is named off 1 only
            let lame = c
                .params
                .iter()
                .find(|(k, _)| k == "lame_ratio_factor")
                .map_or(1.0, |(_, v)| *v);
            (rho / target_rho).log2().abs() + (share - 0.9).abs() + (lame.log2() - 1.0).abs()
        };
        let train = |cands: &[Candidate], eligible: &dyn Fn(usize, Option<usize>) -> bool| {
            (0..=folds)
                .map(|s| {
                    let fold = (s < folds).then_some(s);
                    (0..cands.len())
                        .filter(|&i| eligible(i, fold))
                        .map(|i| (i, error(&cands[i])))
                        .min_by(|a, b| a.1.total_cmp(&b.1))
                })
                .collect()
        };
        let fit = fit_dynamics(
            &mut simulate,
            folds,
            train,
            &DynamicSearch::REFINED,
            Some(m),
        )
        .expect("fake replays");
        assert!(fit.on_rayleigh_line);
        assert_eq!(replayed.len(), 5 + 3 + 4, "{replayed:?}");
        assert_eq!(fit.candidates.len(), 5 + 3 + 4);
        let lame: Vec<f64> = replayed[5..8]
            .iter()
            .map(|e| match e {
                Extension::Dynamic {
                    lame_ratio_factor, ..
                } => *lame_ratio_factor,
                _ => panic!("a dynamic replay"),
            })
            .collect();
        assert_eq!(lame, [0.5, 2.0, 4.0]);
        // the density line at the share 1/2, then a step either side at its best point ρ̂ √2
        for (i, f) in MODAL_LINE.iter().enumerate() {
            let Extension::Dynamic {
                density_kg_m3,
                alpha_per_s,
                beta_s,
                ..
            } = replayed[i]
            else {
                panic!("a dynamic replay")
            };
            let rho = f * m.density_kg_m3;
            let (alpha, beta) = m.rayleigh_at(rho, 0.5);
            assert!((density_kg_m3 / rho - 1.0).abs() < 0.011);
            assert!((alpha_per_s / alpha - 1.0).abs() < 0.011);
            assert!((beta_s / beta - 1.0).abs() < 0.011);
        }
        let best = (0..fit.candidates.len())
            .min_by(|&a, &b| error(&fit.candidates[a]).total_cmp(&error(&fit.candidates[b])))
            .expect("candidates");
        assert_eq!(fit.proposed_by[best], Some((0..=folds).collect::<Vec<_>>()));
        let (rho, alpha) = (
            fit.candidates[best].params[0].1,
            fit.candidates[best].params[1].1,
        );
        assert!((rho / (m.density_kg_m3 * std::f64::consts::SQRT_2) - 1.0).abs() < 0.011);
        assert_eq!(
            fit.candidates[best].params[3],
            ("lame_ratio_factor".to_string(), 2.0)
        );
        let (alpha_end, _) = m.rayleigh_at(
            m.density_kg_m3 * std::f64::consts::SQRT_2,
            RAYLEIGH_START_SHARE + RAYLEIGH_SHARE_STEP,
        );
        assert!(
            (alpha / alpha_end - 1.0).abs() < 0.011,
            "{alpha} against {alpha_end}"
        );
        // without a damping ratio in (0, 1): the density line at the middle damping and the
        // (ρ, α, β) compass
        let mut count = 0;
        let mut simulate = |exts: &[Extension]| -> (Vec<Result<Field>>, bool) {
            count += exts.len();
            (exts.iter().map(|_| Ok(Field::new())).collect(), true)
        };
        let off = ModalEstimate {
            damping_ratio: -0.01,
            ..m
        };
        let fit = fit_dynamics(
            &mut simulate,
            folds,
            train,
            &DynamicSearch::REFINED,
            Some(off),
        )
        .expect("fake replays");
        assert!(!fit.on_rayleigh_line);
        // the line, then ± a factor 4 in α and β and ± half an octave in ρ (one of them on the
        // line already when the best line point is an end)
        assert!((3 + 5..=3 + 6).contains(&count), "{count}");
    }

    #[test]
    fn lattice_keys_round_trip_and_name_the_parameters() {
        let k = key([10.0, 3.0, -9.0, 0.0]);
        assert_eq!(theta(k), [10.0, 3.0, -9.0, 0.0]);
        let (params, ext) = extension(k);
        assert_eq!(params[0], ("density_kg_m3".to_string(), 1024.0));
        assert_eq!(
            ext,
            Extension::Dynamic {
                density_kg_m3: 1024.0,
                alpha_per_s: 8.0,
                beta_s: 2f64.powi(-9),
                lame_ratio_factor: 1.0,
            }
        );
    }
}
