//! `plasticity`: the probing left a permanent set.
//!
//! Screen: a permanent set proportional to the elastic response at each location's peak, growing
//! with the running maximum force above a yield force f_y (grid), fraction β ≥ 0. Effect cells:
//! released frames, markers within the contact radius of a location touched before. Signature:
//! the released residual minus the same marker's rest residual above 3σ (a template offset cancels,
//! a plastic set exists only after release) that persists at the later releases (creep recovers). Confirmation: J2 plasticity with linear isotropic
//! hardening (`softcap_fem::ElastoplasticModel`, Simo & Hughes 1998 Box 3.1–3.2) over the default
//! (λ, α), driven by the measured force over the patch (bickel2009 §4.1; σ_y and H as fractions
//! of the peak contact pressure) AND replayed with the session's rigid tip at every measured pose
//! (§3.4 position control: the tip's rim sets the stress the material yields under; σ_y and H as
//! fractions of the fit's Young's modulus, [`RIGID_YIELD_STRAINS`]) on the fit
//! mesh's 10-node tets (`ProbeSimulator::quadratic`, small-strain J2: linear tets, even refined
//! 1 → 8, lock under the isochoric flow and leave the set too shallow) — or, with
//! `plasticity_quadratic_replays` off, on the fit mesh refined 1 → 8 (`ProbeSimulator::refined`)
//! —, also with ν = 0.45 (the tissue fit's ν is biased by the plastic flow it did not model).
//! With `plasticity_refined_replays` = n > 0 the eight rigid-tip points are ranked first on a
//! cheaper linear mesh — the fit mesh before the 10-node replays; before the 1 → 8 ones the fit
//! mesh, or with `plasticity_ranking_refinement` = r > 1 the fit mesh bisected to r × its tets
//! (`ProbeSimulator::bisected`) — each fold keeps its best per
//! yield strain (per ν for the 1 → 8 replays), and only the n points kept most often (one per
//! family first) are replayed again on the 10-node tets, which decide between them. The grid points are
//! picked on the other locations' effect cells only: in a rigid-tip replay the contact frames carry the coarse mesh's contact error,
//! which would otherwise decide the pick.

use super::Effect;
use super::contract::{Context, Hypothesis};
use crate::Result;
use crate::cells::{EffectCells, contact_radius_m};
use crate::confirm::{ComplianceScale, Confirmed, Lolo};
use crate::recording::Recording;
use crate::resim::{GridPoint, Replays, RigidPoint};
use crate::screen::{Basis, Refit, Variant};
use crate::segment::{Phase, Segmentation};
use crate::signatures::Signatures;
use crate::sim::{Extension, ProbeSimulator};
use nalgebra::Vector3;

/// The plasticity hypothesis.
pub struct Plasticity;

/// Persistence of the released set (`Signatures::released_set_persistence`) below which the set
/// recovers rather than stays: less than half of it is left at the later releases. A plastic
/// set is permanent (≈ 1); a viscoelastic one recovers by e^{−Δt/τ} over the seconds between
/// releases.
pub const RECOVERED_PERSISTENCE: f64 = 0.5;

/// Persistence of a permanent set: it does not decay over the gaps between releases (a plastic
/// set stays; the suites measure 1.03–1.13). A creep recovering at zero load with the
/// retardation time τ' leaves e^{−Δt/τ'} of its set over a gap Δt, below 1 however slow (Simo &
/// Hughes 1998 §10.3: the Maxwell branches' internal strains only decay without load). A set
/// whose persistence lies below this by more than [`PERSISTENCE_Z`] of its own standard error
/// (`Signatures::released_set_persistence_se`) decays: between [`RECOVERED_PERSISTENCE`] and
/// there the signature abstains (support 0) rather than rank plasticity above a slow creep. The
/// in-memory creep g 1, τ 5 s (τ' = τ(1 + g) = 10 s over gaps of 0.85 s, e^{−0.085} = 0.92)
/// measures 0.913, and "permanent" at 0.9 named it `plasticity`.
pub const PERMANENT_PERSISTENCE: f64 = 1.0;

/// How many standard errors below [`PERMANENT_PERSISTENCE`] a measured persistence must lie to
/// say that the set decays: one-sided, a permanent set is read as decaying in 2.3 % of sessions
/// (normal noise). Fixed before any verdict was looked at (issue 37: the in-memory weak plastic
/// set, 1.4 × √3σ, measured 0.988 on one noise draw and was read as decaying, exactly).
pub const PERSISTENCE_Z: f64 = 2.0;

/// The rigid-tip replays' yield stresses σ_y as fractions of the fit's Young's modulus E (yield
/// strains; `ProbeSimulator::young_pa`). Under position control (the measured tip pose sets the
/// depth) a J2 replay's displacements depend on σ_y/E, H/E and ν only (Simo & Hughes 1998
/// Box 3.1: at fixed strains the trial stress, the yield function and the return all scale with
/// E), so a grid in units of the peak contact pressure p — a force scale — moves with the
/// session's p/E. The values are the former grid's, 0.3 and 0.4 p, on the own rig's plasticity
/// case where it was chosen (p 10.26 kPa, fit E 35.23 kPa: p/E = 0.2912), so that case replays
/// the same points. On the third-party plasticity case (p 13.76 kPa, fit E 23.98 kPa, truth
/// 50 kPa) the former grid's 0.3 p was 0.17 E, twice the truth's yield strain σ_y/E = 0.09,
/// and the replays' released set came out 2–2.5× too shallow (the force-driven point won).
pub const RIGID_YIELD_STRAINS: [f64; 2] = [0.087358, 0.116477];

/// The rigid-tip replays' hardening moduli H as fractions of the fit's Young's modulus E: the
/// former 0.2 and 0.5 p on the own rig's case ([`RIGID_YIELD_STRAINS`]).
pub const RIGID_HARDENING_RATIOS: [f64; 2] = [0.058239, 0.145597];

/// Name of the effect cells.
const CELLS: &str = "released/near-touched";

impl Hypothesis for Plasticity {
    fn effect(&self) -> Effect {
        Effect::Plasticity
    }

    fn term(&self) -> &'static str {
        "plastic set = plastic_fraction * T_peak (max(0, |f|_max - yield_force_n)) f_hat"
    }

    fn variants(&self, cx: &Context<'_>) -> Vec<Variant> {
        let (seg, p) = (cx.seg, cx.prepared);
        let f = &p.force_n;
        let (nt, nm) = (p.times_s.len(), p.num_markers());
        let peak = seg.peak_force_n();
        (0..8)
            .map(|i| i as f64 * 0.1 * peak)
            .map(|fy| {
                let mut field = vec![vec![Vector3::zeros(); nm]; nt];
                for l in &seg.locations {
                    let pk = l.peak_frame;
                    let dir = f[pk].try_normalize(1e-12).unwrap_or_else(Vector3::zeros);
                    let unit = p.apply(pk, &dir);
                    let mut run_max = 0.0f64;
                    for k in 0..nt {
                        if seg.fold_of_frame[k] == Some(l.index) && seg.phases[k].in_contact() {
                            run_max = run_max.max(f[k].norm());
                        }
                        let excess = (run_max - fy).max(0.0);
                        if excess > 0.0 {
                            for m in 0..nm {
                                field[k][m] += unit[m] * excess;
                            }
                        }
                    }
                }
                Variant {
                    fixed: vec![("yield_force_n", fy)],
                    offset: None,
                    bases: vec![Basis {
                        name: "plastic_fraction",
                        nonneg: true,
                        field,
                    }],
                }
            })
            .collect()
    }

    /// Released frames, markers within the contact radius of a location touched up to the frame.
    fn effect_cells(&self, rec: &Recording, seg: &Segmentation) -> Option<EffectCells> {
        let r = contact_radius_m(rec);
        let mut touched: Vec<usize> = Vec::new();
        let mask = (0..rec.frames.len())
            .map(|k| {
                if let Some(l) = seg.fold_of_frame[k]
                    && !touched.contains(&l)
                {
                    touched.push(l);
                }
                (0..rec.num_markers())
                    .map(|m| {
                        seg.fold_of_frame[k].is_some()
                            && seg.phases[k] == Phase::Released
                            && touched.iter().any(|&l| {
                                (seg.locations[l].peak_tip_m - rec.rest_markers_m[m]).norm() <= r
                            })
                    })
                    .collect()
            })
            .collect();
        Some(EffectCells { name: CELLS, mask })
    }

    /// Supported by a released set above 3σ that persists ([`PERMANENT_PERSISTENCE`] within
    /// [`PERSISTENCE_Z`] standard errors, or no later release to compare); contradicted without
    /// a set, or when the set recovers at the later releases ([`RECOVERED_PERSISTENCE`]): creep
    /// recovery. A set that only partly recovers over the gaps, beyond the noise, is neither
    /// (0): a slow creep or a permanent set.
    fn signature_support(&self, s: &Signatures) -> f64 {
        let p = s.released_set_persistence;
        let se = s.released_set_persistence_se.unwrap_or(0.0);
        if s.released_set_m <= s.three_sigma_m() || p.is_some_and(|p| p < RECOVERED_PERSISTENCE) {
            -1.0
        } else if p.is_some_and(|p| p + PERSISTENCE_Z * se < PERMANENT_PERSISTENCE) {
            0.0
        } else {
            1.0
        }
    }

    /// Ruled out when the held force relaxes beyond its noise ([`Signatures::holds_relax`]) or
    /// the tip sinks under a held load ([`Signatures::holds_creep`]), and the surface does not
    /// rebound past rest after release (a body ringing against the held tip loses hold force
    /// too, `super::inertia_damping::rebounds`): a rate-independent J2 body holds its force at a
    /// held depth and its depth at a held force (Simo & Hughes 1998 Box 3.1: no flow at fixed
    /// strain or at a stress that stops growing); a creep does neither. A slow creep's set
    /// persists over the gaps between releases as a plastic one does (issue 37's look-alike
    /// pair 1, under position and under force control); its holds give it away.
    fn ruled_out(&self, s: &Signatures) -> Option<String> {
        if super::inertia_damping::rebounds(s) {
            return None;
        }
        if s.holds_relax() {
            return Some(format!(
                "ruled out: the held force relaxes by {:.4} of the peak (standard error {:.4}), which a rate-independent set held at its depth does not",
                -s.hold_force_drift,
                s.hold_force_drift_se.unwrap_or(0.0)
            ));
        }
        s.holds_creep().then(|| {
            format!(
                "ruled out: the tip sinks by {:.4} of its depth under the held force (standard error {:.4}; the force drifts {:+.4}), which a rate-independent set at a held load does not",
                s.hold_tip_creep,
                s.hold_tip_creep_se.unwrap_or(0.0),
                s.hold_force_drift
            )
        })
    }

    fn confirm(
        &self,
        cx: &Context<'_>,
        _: &Refit,
        scored: &dyn Fn(usize, usize) -> bool,
        sim: &mut dyn ProbeSimulator,
    ) -> Result<Option<Confirmed>> {
        let (rec, seg, p) = (cx.rec, cx.seg, cx.prepared);
        let peak_n = seg.peak_force_n();
        let r_tip = rec.tip_radius_m.max(1e-4);
        let pressure_pa = peak_n / (std::f64::consts::PI * r_tip * r_tip);
        let mut grid: Vec<GridPoint> = Vec::new();
        for sy in [0.1, 0.2, 0.4] {
            for hh in [0.1, 0.5] {
                let (yield_stress_pa, hardening_pa) = (sy * pressure_pa, hh * pressure_pa);
                grid.push((
                    vec![
                        ("yield_stress_pa".into(), yield_stress_pa),
                        ("hardening_modulus_pa".into(), hardening_pa),
                    ],
                    Extension::Plastic {
                        yield_stress_pa,
                        hardening_pa,
                    },
                    p.force_n.clone(),
                ));
            }
        }
        // Rigid-tip replays (position control) with the tissue fit's ν and with ν = 0.45
        // (`Extension::PlasticPoisson`); under position control the displacements depend on
        // σ_y/E, H/E and ν only, so σ_y and H are set in units of the fit's E
        // ([`RIGID_YIELD_STRAINS`], [`RIGID_HARDENING_RATIOS`]); none without an E.
        let young_pa = sim.young_pa().filter(|e| e.is_finite() && *e > 0.0);
        let mut rigid: Vec<RigidPoint> = Vec::new();
        for nu in [None, Some(0.45)] {
            for sy in RIGID_YIELD_STRAINS {
                for hh in RIGID_HARDENING_RATIOS {
                    let Some(e) = young_pa else { continue };
                    let (yield_stress_pa, hardening_pa) = (sy * e, hh * e);
                    let mut params = vec![
                        ("yield_stress_pa".into(), yield_stress_pa),
                        ("hardening_modulus_pa".into(), hardening_pa),
                        ("rigid_tip_replay".into(), 1.0),
                    ];
                    let ext = match nu {
                        None => Extension::Plastic {
                            yield_stress_pa,
                            hardening_pa,
                        },
                        Some(poisson) => {
                            params.push(("poisson".into(), poisson));
                            Extension::PlasticPoisson {
                                yield_stress_pa,
                                hardening_pa,
                                poisson,
                            }
                        }
                    };
                    rigid.push((params, ext));
                }
            }
        }
        // every rigid-tip point replayed refined, or ranked on a cheaper mesh first: per ν
        // family for the 1 → 8 replays; per yield strain for the 10-node ones, since the linear
        // ranking mesh locks under the isochoric flow, its set comes out too shallow and it
        // ranks the lower σ_y/E first whatever the material (third-party plasticity: every fold
        // keeps σ_y/E 0.087, whose 10-node replay is 0.186 mm against 0.113 at 0.103). The
        // 10-node tets of the fit mesh only where it resolves the footprint
        // (`ProbeSimulator::resolves_footprint`): the own rig's 6.7 mm fit mesh under a 7 mm
        // punch leaves 0.37–0.45 mm on its 10-node tets against 0.17 on the 1 → 8 linear ones.
        let tips: Vec<Vector3<f64>> = seg.locations.iter().map(|l| l.peak_tip_m).collect();
        let quadratic = cx.settings.plasticity_quadratic_replays
            && sim.resolves_footprint(rec.tip_radius_m, &tips);
        let family = if quadratic {
            "yield_stress_pa"
        } else {
            "poisson"
        };
        // the ranking mesh: `plasticity_ranking_refinement` before the 1 → 8 replays (the fit
        // mesh's contact error scrambles the own rig's ν families there); before the 10-node
        // replays, which replay the best of each yield strain, the fit mesh itself (third-party
        // plasticity: every fold keeps the two points the bisected mesh kept, the same 0.1244
        // mm, its 8 replays 10–12 thread CPU-s each against 17–20)
        let ranking_refinement = if quadratic {
            1
        } else {
            cx.settings.plasticity_ranking_refinement
        };
        let replays = match cx.settings.plasticity_refined_replays {
            0 => Replays::run(sim, grid, rigid, rec, seg, p, false)?,
            n => Replays::run_coarse_first(
                sim,
                grid,
                rigid,
                rec,
                seg,
                p,
                false,
                scored,
                true,
                n,
                Some(family),
                ranking_refinement,
                quadratic,
            )?,
        };
        let lolo = Lolo {
            rec,
            seg,
            p,
            scale: ComplianceScale::new(true, 0.1, 10.0),
            scored,
            train_on_scored: true,
        };
        replays.confirm(&lolo, "ElastoplasticModel", CELLS)
    }
}
