//! `probe-friction`: a tangential traction under the tip that the shaft-axis force sensor cannot
//! see (bickel2009 §7; the Coulomb kernels are [`crate::friction`]).
//!
//! Screen: the traction μ‖f‖ŝ along each location's tangential tip travel ŝ at the contact patch,
//! or sliding along the tip's travel and reversing when it slides back
//! ([`crate::friction::sliding_direction`]), through the tangent response. Effect cells: contact
//! frames, markers under the active contact. Signature: the surface around the patch dragged
//! along with the tip ([`crate::signatures::Signatures::contact_drag_m`]). Confirmation: the
//! default model under the measured force plus the Coulomb traction of the tip's travel (return
//! mapping under the measured normal force, a (μ, k_t) grid; or constant sense μ‖f‖ŝ with and
//! without reversal while unloading) AND the rigid tip replayed at its measured poses with Coulomb
//! friction (`Extension::ProbeFriction`: the truth's law and lagged iterations, on the fit mesh
//! refined until the tip spans several surface nodes, `crate::sim::friction_refinement`), its μ
//! grid extended until it brackets the optimum (`bracket_friction`). The grid points are picked
//! on the other locations' effect cells only: the markers away from the patch carry the default
//! model's far-field form error, which no μ explains, and μ and the compliance scale would trade
//! against it.

use super::Effect;
use super::contract::{Context, Hypothesis, SignatureRoute};
use crate::Result;
use crate::baseline::Prepared;
use crate::cells::{EffectCells, contact_cells};
use crate::confirm::{Candidate, ComplianceScale, Confirmed, Lolo, lolo_choices};
use crate::friction::{indentation_stiffness_n_per_m, sliding_direction, traction_history};
use crate::recording::Recording;
use crate::resim::{GridPoint, Replays, RigidPoint, simulate_rigid_grid};
use crate::screen::{Basis, Refit, Variant};
use crate::segment::{Phase, Segmentation};
use crate::signatures::Signatures;
use crate::sim::{Extension, ProbeSimulator};
use nalgebra::Vector3;

/// The probe-friction hypothesis.
pub struct ProbeFriction;

/// Name of the effect cells.
const CELLS: &str = "contact/under-probe";

impl Hypothesis for ProbeFriction {
    fn effect(&self) -> Effect {
        Effect::ProbeFriction
    }

    fn term(&self) -> &'static str {
        "tangential traction mu |f| s_hat at the contact patch"
    }

    fn variants(&self, cx: &Context<'_>) -> Vec<Variant> {
        let (rec, seg, p) = (cx.rec, cx.seg, cx.prepared);
        let f = &p.force_n;
        let nt = p.times_s.len();
        let df: Vec<_> = (0..nt)
            .map(|k| match seg.fold_of_frame[k] {
                Some(l) if seg.phases[k].in_contact() => p.friction_dir[l] * f[k].norm(),
                _ => Vector3::zeros(),
            })
            .collect();
        if df.iter().all(|v| *v == Vector3::zeros()) {
            return vec![];
        }
        let mut out = vec![Variant {
            fixed: vec![],
            offset: None,
            bases: vec![Basis {
                name: "mu",
                nonneg: false,
                field: p.load_field(&df),
            }],
        }];
        // Sliding Coulomb traction μ f_n along the tip's travel, reversing when the tip slides
        // back (crate::friction::sliding_direction), where the tip travels.
        let k_ind = indentation_stiffness_n_per_m(seg);
        let dir = sliding_direction(rec, seg, f, k_ind);
        let slide: Vec<_> = (0..nt)
            .map(|k| match seg.fold_of_frame[k] {
                Some(_) if seg.phases[k].in_contact() => dir[k] * f[k].norm(),
                _ => Vector3::zeros(),
            })
            .collect();
        if slide.iter().any(|v| *v != Vector3::zeros()) {
            out.push(Variant {
                fixed: vec![("sliding_reverses", 1.0)],
                offset: None,
                bases: vec![Basis {
                    name: "mu",
                    nonneg: false,
                    field: p.load_field(&slide),
                }],
            });
        }
        out
    }

    fn not_applicable_reason(&self) -> &'static str {
        "no tangential probe travel or tilt at any location"
    }

    fn effect_cells(&self, rec: &Recording, seg: &Segmentation) -> Option<EffectCells> {
        Some(EffectCells {
            name: CELLS,
            mask: contact_cells(rec, seg, true),
        })
    }

    fn signature_support(&self, s: &Signatures) -> f64 {
        // the surface dragged along with the tip
        if drags(s) {
            1.0
        } else if s.contact_tangential_m > s.three_sigma_m() {
            0.5
        } else {
            0.0
        }
    }

    /// Re-simulated after the screen's candidates when the residual under the tip is tangential
    /// beyond 3σ and the body does not slide on its support ([`super::support_slip::slides`]: a
    /// sliding body moves the surface under the tip too): a patch that sticks (μ above the
    /// stick's need) holds the surface forward after the tip turns back, so neither the drag
    /// signature nor the screen's traction along the travel sees it, but the rigid tip replayed
    /// with Coulomb friction does.
    fn signature_route(&self, s: &Signatures) -> Option<SignatureRoute> {
        (s.contact_tangential_m > s.three_sigma_m() && !super::support_slip::slides(s))
            .then_some(SignatureRoute::AfterScreen)
    }

    fn confirm(
        &self,
        cx: &Context<'_>,
        _: &Refit,
        scored: &dyn Fn(usize, usize) -> bool,
        sim: &mut dyn ProbeSimulator,
    ) -> Result<Option<Confirmed>> {
        let (rec, seg, p) = (cx.rec, cx.seg, cx.prepared);
        // The Coulomb return mapping of the tip's measured travel under the measured (lagged)
        // normal force, and the constant-sense traction.
        // Only when the surface is seen dragged along the travel (`drag`, above 3σ): these
        // histories are a traction along the travel by construction.
        let grid: Vec<GridPoint> = if drags(cx.signatures) {
            confirmation_grid(rec, seg, p)
                .into_iter()
                .map(|(params, forces)| (params, Extension::Elastic, forces))
                .collect()
        } else {
            vec![]
        };
        // The rigid tip replayed at its measured poses WITH Coulomb friction: the stuck patch
        // drags the surface as in the recording, and under position control the depth is the
        // measured one whatever stiffness the tissue fit gave the material (it was fitted on
        // forces missing the traction).
        let rigid: Vec<RigidPoint> = RIGID_MU_GRID
            .iter()
            .map(|&mu| {
                (
                    vec![("mu".into(), mu), ("rigid_tip_replay".into(), 1.0)],
                    Extension::ProbeFriction { mu },
                )
            })
            .collect();
        let mut replays = Replays::run(sim, grid, rigid, rec, seg, p, true)?;
        let refined = replays.replay_mesh.is_some();
        let replay: &mut dyn ProbeSimulator = match replays.replay_mesh.as_deref_mut() {
            Some(f) => f,
            None => sim,
        };
        let converged: Vec<f64> = replays.rigid.iter().filter_map(mu_of).collect();
        let failed: Vec<f64> = RIGID_MU_GRID
            .into_iter()
            .filter(|mu| !converged.iter().any(|m| (m - mu).abs() <= 1e-9 * mu))
            .collect();
        replays.total += bracket_friction(
            replay,
            &mut replays.rigid,
            failed,
            rec,
            seg,
            p,
            scored,
            refined,
        )?;
        let lolo = Lolo {
            rec,
            seg,
            p,
            scale: ComplianceScale::new(true, 0.1, 10.0),
            scored,
            train_on_scored: true,
        };
        replays.confirm(&lolo, "default model under Coulomb traction", CELLS)
    }
}

/// Whether the surface around the patch is dragged along the tip's travel beyond 3σ
/// ([`Signatures::contact_drag_m`]).
fn drags(s: &Signatures) -> bool {
    s.contact_drag_m > s.three_sigma_m()
}

/// Probe force plus the constant-sense traction μ‖f‖ŝ_l along the location's tangential travel
/// (`Prepared::friction_dir`), reversed while unloading when `reverse`.
pub fn constant_sense_forces(
    seg: &Segmentation,
    p: &Prepared,
    mu: f64,
    reverse: bool,
) -> Vec<Vector3<f64>> {
    p.force_n
        .iter()
        .enumerate()
        .map(|(k, f)| match seg.fold_of_frame[k] {
            Some(l) if seg.phases[k].in_contact() => {
                let sign = if reverse && seg.phases[k] == Phase::Unloading {
                    -1.0
                } else {
                    1.0
                };
                f + p.friction_dir[l] * (sign * mu * f.norm())
            }
            _ => *f,
        })
        .collect()
}

/// Friction coefficients of the confirmation grid (rubber / skin-like contacts span 0.2–1;
/// the material's compliance scale refitted with the traction lets the effective μ go higher).
pub const MU_GRID: [f64; 8] = [0.2, 0.35, 0.5, 0.65, 0.8, 1.0, 1.25, 1.5];
/// Friction coefficients the frictional rigid-tip replay starts from (`Extension::ProbeFriction`;
/// each point re-simulates the recording with frictional contact on the refined fit mesh, ≈ 1 min
/// in the test profile on the suite session, so the grid is coarse): log-spaced by
/// [`RIGID_MU_STEP`] across rubber on skin, μ 0.5–1. `bracket_friction` extends it by the same step until
/// the optimum is bracketed.
pub const RIGID_MU_GRID: [f64; 3] = [0.5, 0.5 * std::f64::consts::SQRT_2, 1.0];
/// Ratio between neighbouring μ of the frictional rigid-tip replay.
pub const RIGID_MU_STEP: f64 = std::f64::consts::SQRT_2;
/// At most this many μ added beyond the ends of [`RIGID_MU_GRID`] (down to 0.18, up to 2.8).
pub const RIGID_MU_EXTENSIONS: usize = 3;
/// μ the bracketing search stays within: a near-frictionless tip to a tacky one.
pub const RIGID_MU_RANGE: (f64, f64) = (0.1, 3.0);
/// Tangential stiffness of the stuck patch as multiples of the indentation stiffness K.
pub const STIFFNESS_GRID: [f64; 4] = [0.25, 0.5, 1.0, 2.0];

/// The confirmation grid of `probe-friction` (module docs): per point its parameters and the
/// per-frame force on the object (measured force + traction). Coulomb return mapping over
/// [`MU_GRID`] × [`STIFFNESS_GRID`], then the constant-sense traction over [`MU_GRID`] with and
/// without reversal while unloading.
pub fn confirmation_grid(
    rec: &Recording,
    seg: &Segmentation,
    p: &Prepared,
) -> Vec<(Vec<(String, f64)>, Vec<Vector3<f64>>)> {
    let k_ind = indentation_stiffness_n_per_m(seg);
    let mut grid = Vec::new();
    for c in STIFFNESS_GRID {
        for mu in MU_GRID {
            let t = traction_history(rec, seg, &p.force_n, mu, c * k_ind);
            if t.iter().all(|v| *v == Vector3::zeros()) {
                continue;
            }
            let forces = p.force_n.iter().zip(&t).map(|(f, t)| f + t).collect();
            grid.push((
                vec![
                    ("mu".into(), mu),
                    ("tangential_stiffness_n_per_m".into(), c * k_ind),
                ],
                forces,
            ));
        }
    }
    for reverse in [false, true] {
        for mu in MU_GRID {
            grid.push((
                vec![
                    ("mu".into(), mu),
                    ("constant_sense".into(), 1.0),
                    ("reverse_on_unloading".into(), f64::from(u8::from(reverse))),
                ],
                constant_sense_forces(seg, p, mu, reverse),
            ));
        }
    }
    grid
}

/// The next μ of the bracketing search (`bracket_friction`), or `None` when it ends.
/// `converged`: the μ replayed to the end; `failed`: the μ whose replay did not converge;
/// `best`: the full-data choice among `converged`. While `best` is the smallest (largest)
/// converged μ, the next is that μ ÷ (×) [`RIGID_MU_STEP`] within [`RIGID_MU_RANGE`], unless a
/// failed μ lies beyond it in that direction (the bracket ends there) or the next μ was already
/// attempted (within 1e-9 relative: 0.7071 × √2 after a failed 1.0).
pub fn next_bracket_mu(converged: &[f64], failed: &[f64], best: f64) -> Option<f64> {
    let lo = converged.iter().copied().reduce(f64::min)?;
    let hi = converged.iter().copied().reduce(f64::max)?;
    let attempted = |mu: f64| {
        converged
            .iter()
            .chain(failed)
            .any(|&m| (m - mu).abs() <= 1e-9 * mu.abs())
    };
    let down = (best <= lo && !failed.iter().any(|&m| m < lo)).then_some(lo / RIGID_MU_STEP);
    let up = (best >= hi && !failed.iter().any(|&m| m > hi)).then_some(hi * RIGID_MU_STEP);
    [down, up]
        .into_iter()
        .flatten()
        .find(|&mu| !attempted(mu) && (RIGID_MU_RANGE.0..=RIGID_MU_RANGE.1).contains(&mu))
}

/// Extends the frictional rigid-tip replay's μ grid ([`RIGID_MU_GRID`]) until
/// it brackets the optimum: while the full-data choice among the frictional replays (the
/// leave-one-location-out loop's pick on every location's effect cells, with the compliance
/// scale) is the smallest or the largest μ simulated, the next μ beyond it
/// ([`next_bracket_mu`]: never one attempted, never past a failed replay) is
/// replayed and added, at most [`RIGID_MU_EXTENSIONS`] times. Each fold still
/// picks among all simulated candidates on its training locations only. `failed`: the grid's μ
/// whose replay did not converge. Returns the number of replays attempted.
#[allow(clippy::too_many_arguments)]
fn bracket_friction(
    replay: &mut dyn ProbeSimulator,
    cands: &mut Vec<Candidate>,
    mut failed: Vec<f64>,
    rec: &Recording,
    seg: &Segmentation,
    p: &Prepared,
    scored: &dyn Fn(usize, usize) -> bool,
    refined: bool,
) -> Result<usize> {
    let mut attempted = 0;
    for _ in 0..RIGID_MU_EXTENSIONS {
        let mus: Vec<f64> = cands.iter().filter_map(mu_of).collect();
        let lolo = Lolo {
            rec,
            seg,
            p,
            scale: ComplianceScale::new(true, 0.1, 10.0),
            scored,
            train_on_scored: true,
        };
        let choices = lolo_choices(cands, &lolo);
        let Some(best) = choices.last().and_then(|&i| mu_of(&cands[i])) else {
            return Ok(attempted);
        };
        let Some(next) = next_bracket_mu(&mus, &failed, best) else {
            return Ok(attempted);
        };
        let params = vec![
            ("mu".into(), next),
            ("rigid_tip_replay".into(), 1.0),
            ("refined_mesh".into(), if refined { 1.0 } else { 0.0 }),
        ];
        let (more, tried) = simulate_rigid_grid(
            replay,
            vec![(params, Extension::ProbeFriction { mu: next })],
            rec,
        )?;
        attempted += tried;
        if more.is_empty() {
            if tried == 0 {
                return Ok(attempted);
            }
            failed.push(next);
        }
        cands.extend(more);
    }
    Ok(attempted)
}

/// The friction coefficient of a frictional rigid-tip replay's candidate.
fn mu_of(c: &Candidate) -> Option<f64> {
    c.params.iter().find(|(k, _)| k == "mu").map(|(_, v)| *v)
}

#[cfg(test)]
mod tests {
    use super::*;

    const S: f64 = RIGID_MU_STEP;

    #[test]
    fn bracket_extends_past_the_best_end() {
        let grid = RIGID_MU_GRID;
        assert_eq!(next_bracket_mu(&grid, &[], 1.0), Some(S));
        assert_eq!(next_bracket_mu(&grid, &[], 0.5), Some(0.5 / S));
        assert_eq!(next_bracket_mu(&grid, &[], grid[1]), None);
    }

    #[test]
    fn bracket_never_replays_an_attempted_mu() {
        // μ 1.0 failed: 0.7071 × √2 = 1.0000000000000002 is the same replay
        let (conv, failed) = ([0.5, 0.5 * S], [1.0]);
        assert_eq!(next_bracket_mu(&conv, &failed, 0.5 * S), None);
        // the other end still extends
        assert_eq!(next_bracket_mu(&conv, &failed, 0.5), Some(0.5 / S));
        assert_eq!(next_bracket_mu(&[0.5 * S, 1.0], &[0.5], 0.5 * S), None);
    }

    #[test]
    fn a_failed_mu_ends_the_bracket_in_its_direction() {
        // μ 2.0 failed after 1.4142 converged: nothing above 1.4142, even a μ between
        let conv = [0.5, 0.5 * S, 1.0, S];
        assert_eq!(next_bracket_mu(&conv, &[2.0 * S], S), None);
        assert_eq!(next_bracket_mu(&conv, &[2.0 * S], 0.5), Some(0.5 / S));
        // a single converged μ with a failed one above extends downwards only
        assert_eq!(next_bracket_mu(&[1.0], &[S], 1.0), Some(1.0 / S));
        assert_eq!(next_bracket_mu(&[1.0], &[1.0 / S, S], 1.0), None);
    }

    #[test]
    fn bracket_stays_in_range() {
        assert_eq!(next_bracket_mu(&[0.12, 0.2], &[], 0.12), None);
        assert_eq!(next_bracket_mu(&[1.5, 2.5], &[], 2.5), None);
        assert_eq!(next_bracket_mu(&[], &[], 1.0), None);
    }
}
