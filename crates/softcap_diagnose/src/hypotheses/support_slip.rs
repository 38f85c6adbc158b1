//! `support-slip`: the object slides on its support instead of being bonded to it.
//!
//! Screen: a rigid translation of the whole body along the support plane, c·P_t f (elastic) +
//! c_p·P_t f at the running maximum (stick-slip), c, c_p ≥ 0 (P_t the projection on the support
//! plane, or on the plane across gravity without a support). Effect cells: contact frames,
//! markers away from the active contact. Signature: the attached markers move in contact, or the
//! markers away from the probe follow an oblique push
//! ([`crate::signatures::far_field_push`]), above 3σ; that signature alone also sends it to
//! re-simulation after the screen's candidates ([`slides`]): the rigid translation is the slip of
//! a support much softer than the body, and a stiffer interface slips more under the load than
//! away from it, which the screen's translation does not follow. Confirmation: the default model
//! on a `softcap_fem::SupportPlane` with tangential springs under the attached face instead of
//! fixed nodes, the total stiffness k on a √2 log grid from an eighth of the indentation stiffness
//! up to the stiffness whose slip under the largest tangential force is the signature's 3σ
//! ([`stiffness_grid`]), each point and a bonded one with the homogeneous (E, ν) refitted with
//! its springs per training set ([`confirm_with_material_refit`]); a simulator that cannot refit
//! its material confirms the plain grid with the compliance scale d (the family (material
//! stiffness / d, k / d)).

use super::Effect;
use super::contract::{Context, Hypothesis, SignatureRoute};
use super::force_channel::hold_example;
use crate::cells::{EffectCells, contact_cells};
use crate::confirm::{ComplianceScale, Confirmed, Lolo, Refitted, lolo_confirm_each_refitted};
use crate::recording::Recording;
use crate::resim::{GridPoint, Replays, contact_sequence};
use crate::screen::{Basis, Refit, Variant};
use crate::segment::Segmentation;
use crate::signatures::Signatures;
use crate::sim::{Extension, MaterialRefitOutcome, ProbeSimulator, SequenceFrame};
use crate::{DiagnoseError, Result};
use nalgebra::Vector3;
use softcap_probing::ProbeExample;

/// The support-slip hypothesis.
pub struct SupportSlip;

/// Name of the effect cells.
const CELLS: &str = "contact/away-from-probe";

/// The body slides on its support beyond the noise: the attached markers move in contact, or the
/// markers away from the probe follow an oblique push ([`crate::signatures::far_field_push`]), by
/// more than three marker noise σ.
pub fn slides(s: &Signatures) -> bool {
    s.attached_motion_m > s.three_sigma_m() || s.far_field_push_m > s.three_sigma_m()
}

/// The total tangential stiffnesses of the support springs the confirmation re-simulates, N/m:
/// k_ind · 2^{i/2} from i = −6 (an eighth of the indentation stiffness `k_ind`, a support far
/// softer than the body) up to the first point at or above k_max = F_t / (3σ) — the stiffness
/// whose rigid slip F_t / k under the largest tangential force F_t is the far-field signature's
/// 3σ threshold (a stiffer support slips less than the signature can see) — at least 4 k_ind and
/// at most 64 k_ind.
pub fn stiffness_grid(k_ind: f64, max_tangential_n: f64, noise_sigma_m: f64) -> Vec<f64> {
    let k_max = max_tangential_n / (3.0 * noise_sigma_m).max(1e-300);
    let top = (2.0 * (k_max / k_ind).log2()).ceil();
    let top = if top.is_nan() {
        4
    } else {
        top.clamp(4.0, 12.0) as i32
    };
    (-6..=top)
        .map(|i| k_ind * 2f64.powf(0.5 * i as f64))
        .collect()
}

impl Hypothesis for SupportSlip {
    fn effect(&self) -> Effect {
        Effect::SupportSlip
    }

    fn term(&self) -> &'static str {
        "rigid support translation slip_compliance P_t f + stick_slip_compliance P_t f_max"
    }

    fn variants(&self, cx: &Context<'_>) -> Vec<Variant> {
        let (rec, p) = (cx.rec, cx.prepared);
        let f = &p.force_n;
        let (nt, nm) = (p.times_s.len(), p.num_markers());
        let n = match (&rec.support, rec.gravity_dir()) {
            (Some(s), _) => s.normal,
            (None, g) if g != Vector3::zeros() => g,
            _ => return vec![],
        };
        let pt = |v: &Vector3<f64>| v - n * n.dot(v);
        let mut elastic = Vec::with_capacity(nt);
        let mut stick = Vec::with_capacity(nt);
        let mut best = Vector3::zeros();
        for k in 0..nt {
            let ft = pt(&f[k]);
            if ft.norm() > best.norm() {
                best = ft;
            }
            elastic.push(vec![ft; nm]);
            stick.push(vec![best; nm]);
        }
        vec![Variant {
            fixed: vec![],
            offset: None,
            bases: vec![
                Basis {
                    name: "slip_compliance_m_per_n",
                    nonneg: true,
                    field: elastic,
                },
                Basis {
                    name: "stick_slip_compliance_m_per_n",
                    nonneg: true,
                    field: stick,
                },
            ],
        }]
    }

    fn not_applicable_reason(&self) -> &'static str {
        "no support plane and no gravity direction"
    }

    fn effect_cells(&self, rec: &Recording, seg: &Segmentation) -> Option<EffectCells> {
        Some(EffectCells {
            name: CELLS,
            mask: contact_cells(rec, seg, false),
        })
    }

    fn signature_support(&self, s: &Signatures) -> f64 {
        if slides(s) { 1.0 } else { -1.0 }
    }

    /// Re-simulated after the screen's candidates when it [`slides`]: the screen's rigid
    /// translation misses the non-uniform slip of a support stiffer than the body.
    fn signature_route(&self, s: &Signatures) -> Option<SignatureRoute> {
        slides(s).then_some(SignatureRoute::AfterScreen)
    }

    fn confirm(
        &self,
        cx: &Context<'_>,
        _: &Refit,
        scored: &dyn Fn(usize, usize) -> bool,
        sim: &mut dyn ProbeSimulator,
    ) -> Result<Option<Confirmed>> {
        let (rec, seg, p) = (cx.rec, cx.seg, cx.prepared);
        // the indentation stiffness: peak force over the deepest travel from first contact
        let depth_m = seg
            .locations
            .iter()
            .map(|l| (l.peak_tip_m - l.contact_tip_m).norm())
            .fold(0.0, f64::max)
            .max(1e-5);
        let k_ind = seg.peak_force_n() / depth_m;
        // Slip ≈ rigid translation F_t / k: a log grid in steps of √2 from k_ind / 8 up to the
        // stiffness whose slip the far-field signature can still see.
        let normal = rec
            .support
            .as_ref()
            .map(|s| s.normal)
            .unwrap_or(rec.gravity_dir());
        let max_tangential_n = p
            .force_n
            .iter()
            .map(|f| (f - normal * normal.dot(f)).norm())
            .fold(0.0, f64::max);
        let ks = stiffness_grid(k_ind, max_tangential_n, cx.signatures.noise_sigma_m);
        if let Some(c) = confirm_with_material_refit(cx, &ks, scored, sim)? {
            return Ok(Some(c));
        }
        let grid: Vec<GridPoint> = ks
            .into_iter()
            .map(|k| {
                (
                    vec![(STIFFNESS.into(), k)],
                    Extension::SupportSprings {
                        stiffness_n_per_m: k,
                    },
                    p.force_n.clone(),
                )
            })
            .collect();
        let replays = Replays::run(sim, grid, Vec::new(), rec, seg, p, false)?;
        let lolo = Lolo {
            rec,
            seg,
            p,
            scale: ComplianceScale::new(true, 0.1, 10.0),
            scored,
            train_on_scored: false,
        };
        replays.confirm(&lolo, "SupportPlane springs", CELLS)
    }
}

/// Name of the support springs' total stiffness among the parameters.
const STIFFNESS: &str = "support_tangential_stiffness_n_per_m";

/// Names of the refitted material's parameters.
const YOUNG: &str = "young_pa";
const POISSON: &str = "poisson";

/// The value of parameter `name` in `params`.
fn param(params: &[(String, f64)], name: &str) -> Option<f64> {
    params.iter().find(|(n, _)| n == name).map(|&(_, v)| v)
}

/// One material refit of [`confirm_with_material_refit`]: the grid point, the held-out location
/// (`None`: the full data) and the outcome (its Levenberg–Marquardt iterations and equilibrium
/// solves at the iteration cap, or why it declined).
struct RefitStatus {
    index: usize,
    point: (String, f64),
    skip: Option<usize>,
    outcome: std::result::Result<(usize, usize), String>,
}

impl std::fmt::Display for RefitStatus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let data = match self.skip {
            Some(l) => format!("without location {l}"),
            None => "full data".into(),
        };
        match &self.outcome {
            Ok((iterations, stalled)) => write!(
                f,
                "{} {:.4}, {data}: {iterations} LM iterations, {stalled} equilibrium solves at the cap",
                self.point.0, self.point.1
            ),
            Err(why) => write!(
                f,
                "{} {:.4}, {data}: declined ({why})",
                self.point.0, self.point.1
            ),
        }
    }
}

/// The refits' status in one line: how many ran, how many had equilibrium solves at the
/// iteration cap, and every declined one with its reason.
fn refit_summary(log: &[RefitStatus]) -> String {
    let capped = log
        .iter()
        .filter(|r| matches!(r.outcome, Ok((_, stalled)) if stalled > 0))
        .count();
    let declined: Vec<String> = log
        .iter()
        .filter(|r| r.outcome.is_err())
        .map(|r| r.to_string())
        .collect();
    format!(
        "{} material refits, {} with equilibrium solves at the iteration cap (trial points rejected), {} declined{}{}",
        log.len(),
        capped,
        declined.len(),
        if declined.is_empty() { "" } else { ": " },
        declined.join("; ")
    )
}

/// The confirmation with the material refitted with the springs in place
/// ([`crate::confirm::lolo_confirm_each_refitted`]): for every grid stiffness k of `ks`, and a
/// bonded point (the default model's fixed support, k = ∞), the homogeneous (E, ν) is refitted
/// on every location's example (bickel2009 §6 at one force level per location: its hold frame of
/// largest force, `force_channel::hold_example`, where a time shift or lag of the force channel
/// does not bias the force — the refit is this hypothesis's model, and the forward selection
/// leaves the force channel's timing to its own entries) with the springs in every equilibrium
/// (`ProbeSimulator::refit_homogeneous`) and the recording re-simulated under the measured force;
/// per held-out location the point whose full-data refit has the least error on the training
/// observations is refitted without that location, starting from its full-data (E, ν), and
/// predicts it (at most `grid + locations` refits, not `grid × (locations + 1)`). The full-data
/// refits start with every other point on the line in ln k (the bonded point last) and add the
/// neighbours of each selection's least error until it is a local minimum on the line. Every
/// refit's status (iterations, equilibrium solves at the iteration cap, or why it declined) is
/// appended to the method. The
/// tissue fit saw the slip with a fixed support, so its material is biased by it (third-party
/// soft-mat session: E 30 kPa, ν 0.47 against its bonded pair's 59 kPa, 0.39): springs added to
/// that material over-predict the motion, which the compliance scale of the plain grid can only
/// scale, not re-shape (ν). The bonded point makes "no slip" a candidate of the same refit, so a
/// bonded base chooses it and gains nothing. `None` when the simulator cannot refit its
/// material or some selection has no refitted point (the compliance-scale grid then decides).
pub fn confirm_with_material_refit(
    cx: &Context<'_>,
    ks: &[f64],
    scored: &dyn Fn(usize, usize) -> bool,
    sim: &mut dyn ProbeSimulator,
) -> Result<Option<Confirmed>> {
    let (rec, seg, p) = (cx.rec, cx.seg, cx.prepared);
    let points: Vec<(Vec<(String, f64)>, Extension)> = ks
        .iter()
        .map(|&k| {
            (
                vec![(STIFFNESS.into(), k)],
                Extension::SupportSprings {
                    stiffness_n_per_m: k,
                },
            )
        })
        .chain([(vec![("bonded_support".into(), 1.0)], Extension::Elastic)])
        .collect();
    // Springs and the elastic material have no history: only the contact frames are solved,
    // every other frame is the unloaded model.
    let all = contact_sequence(rec, seg, &p.force_n);
    let solved: Vec<usize> = (0..rec.frames.len())
        .filter(|&k| seg.phases[k].in_contact())
        .collect();
    let frames: Vec<SequenceFrame> = solved.iter().map(|&k| all[k]).collect();
    let sim: &dyn ProbeSimulator = sim;
    // Every refit's status (candidate, held-out location, what happened), reported in the method.
    let log = std::sync::Mutex::new(Vec::<RefitStatus>::new());
    // A refit that panicked elsewhere poisons the lock; the statuses pushed so far stay valid.
    let record = |s: RefitStatus| {
        log.lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .push(s)
    };
    let refit = |i: usize, skip: Option<usize>, from: Option<&Refitted>| {
        let ext = &points[i].1;
        let examples: Vec<ProbeExample> = (0..seg.num_folds())
            .filter(|&l| Some(l) != skip)
            .flat_map(|l| hold_example(rec, seg, l, &p.force_n))
            .collect();
        let start = from.and_then(|f| Some((param(&f.params, YOUNG)?, param(&f.params, POISSON)?)));
        let status = |outcome: std::result::Result<(usize, usize), String>| RefitStatus {
            index: i,
            point: points[i].0[0].clone(),
            skip,
            outcome,
        };
        let mut m = match sim.refit_homogeneous(&examples, ext, start)? {
            MaterialRefitOutcome::Refitted(m) => m,
            MaterialRefitOutcome::Declined(why) => {
                record(status(Err(why)));
                return Ok(None);
            }
        };
        let x = match m.sim.simulate_sequence(ext, &frames) {
            Ok(x) => x,
            Err(DiagnoseError::Simulation { frame, reason }) => {
                let why = format!("replay: frame {frame}: {reason}");
                record(status(Err(why)));
                return Ok(None);
            }
            Err(e) => return Err(e),
        };
        record(status(Ok((m.iterations, m.stalled_solves))));
        let mut prediction = vec![p.rest_model_m.clone(); rec.frames.len()];
        for (row, &k) in x.into_iter().zip(&solved) {
            prediction[k] = row;
        }
        Ok(Some(Refitted {
            prediction,
            params: vec![(YOUNG.into(), m.young_pa), (POISSON.into(), m.poisson)],
        }))
    };
    let names: Vec<Vec<(String, f64)>> = points.iter().map(|p| p.0.clone()).collect();
    let method = format!(
        "re-simulated SupportPlane springs ({} stiffnesses and the bonded support) with the homogeneous (E, nu) refit with the springs on the full data (every other point, then the neighbours of each selection's least training error), the least training error's refit per held-out location from it (bickel2009 §6), leave-one-location-out on {CELLS}",
        ks.len()
    );
    // The points on one line in ln k, the bonded support (k = ∞) after the stiffest: a first
    // pass over every other point and the last, then each selection's neighbours (the
    // training error is smooth and unimodal in ln k: the soft-mat session's table).
    let last = points.len() - 1;
    let first_pass: Vec<usize> = (0..=last).filter(|&i| i % 2 == 0 || i == last).collect();
    let neighbours = |i: usize| -> Vec<usize> {
        [i.checked_sub(1), (i < last).then_some(i + 1)]
            .into_iter()
            .flatten()
            .collect()
    };
    let (mut c, scores) = lolo_confirm_each_refitted(
        &names,
        rec,
        seg,
        scored,
        false,
        &first_pass,
        &neighbours,
        &refit,
        method,
    )?;
    // in grid order (the refits ran in parallel): the method text is deterministic
    let mut log = log
        .into_inner()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    log.sort_by_key(|r| (r.index, r.skip.map_or(usize::MAX, |l| l)));
    if let Some(c) = c.as_mut() {
        c.method.push_str(&format!("; {}", refit_summary(&log)));
    }
    if crate::profile::enabled() {
        eprintln!("PROFILE-SUPPORT-SLIP refits: {}", refit_summary(&log));
        for r in &log {
            eprintln!("PROFILE-SUPPORT-SLIP refit {r}");
        }
        for s in &scores {
            eprintln!(
                "PROFILE-SUPPORT-SLIP {:?} in-sample {:.4} mm held-out {:.4} mm (locations {:?})",
                s.params,
                1e3 * s.in_sample_m,
                1e3 * s.heldout_m,
                s.chosen_for
            );
        }
    }
    Ok(c)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The in-memory rig's oblique session: k_ind 122 N/m, tangential force 0.0826 N, σ 5 µm →
    /// k_max = 0.0826 / 15 µm = 5,507 N/m, reached at i = 11 (122 · 2^5.5 = 5,521 N/m); the
    /// grid keeps its √2 steps and its lower end, and its top is clamped to [4, 64] k_ind.
    #[test]
    fn stiffness_grid_reaches_the_stiffness_the_signature_can_see() {
        let ks = stiffness_grid(122.0, 0.0826, 5e-6);
        assert_eq!(ks.len(), 18);
        assert!((ks[0] - 122.0 / 8.0).abs() < 1e-9);
        assert!(
            ks.windows(2)
                .all(|w| (w[1] / w[0] - 2f64.sqrt()).abs() < 1e-12)
        );
        let top = ks[ks.len() - 1];
        assert!((5507.0..5507.0 * 2f64.sqrt()).contains(&top), "{top}");
        // a straight probe (no tangential force): the old grid up to 4 k_ind
        let ks = stiffness_grid(122.0, 0.0, 5e-6);
        assert_eq!(ks.len(), 11);
        assert!((ks[10] - 4.0 * 122.0).abs() < 1e-9);
        // noise-free data: at most 64 k_ind
        let ks = stiffness_grid(122.0, 0.0826, 0.0);
        assert!((ks[ks.len() - 1] - 64.0 * 122.0).abs() < 1e-6);
    }
}
