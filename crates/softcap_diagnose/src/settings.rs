//! Settings of the diagnosis (the `[diagnose]` table of the stage's settings TOML).

use crate::outliers::OutlierSettings;
use crate::segment::SegmentSettings;
use serde::{Deserialize, Serialize};

/// Settings of the diagnosis.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DiagnoseSettings {
    /// Phase / location / region segmentation.
    pub segment: SegmentSettings,
    /// A hypothesis must explain at least this fraction of the held-out mean-square error …
    pub min_heldout_gain: f64,
    /// … lower the BIC by at least this much …
    pub min_delta_bic: f64,
    /// … and the baseline held-out MSE must exceed this multiple of the noise MSE (3σ²).
    pub noise_floor_factor: f64,
    /// Hypotheses whose held-out MSE is within this fraction of the best are look-alikes; their
    /// signatures decide.
    pub lookalike_margin: f64,
    /// Re-simulate the winner (load extensions) with the full model, per fold.
    pub confirm_with_resimulation: bool,
    /// Density of the gravity basis, kg/m³.
    pub reference_density_kg_m3: f64,
    /// Score held-out errors on the affected cells only: the (region, phase) cells whose
    /// baseline RMS is at least `focus_noise_factor` × the noise RMS √3σ and at least
    /// `focus_fraction_of_max` × the largest cell's RMS (found by the locate step before any
    /// hypothesis is fitted; the same cells for before, after and every hypothesis).
    pub score_on_focus: bool,
    /// See `score_on_focus`.
    pub focus_noise_factor: f64,
    /// See `score_on_focus`.
    pub focus_fraction_of_max: f64,
    /// Refit a displacement scale (the material's overall compliance) with every extended
    /// model, on the training locations.
    pub refit_compliance_scale: bool,
    /// Confirm at most this many qualifying hypotheses with the extended FEM model.
    pub max_confirmations: usize,
    /// Name at most this many effects (greedy forward selection on top of the confirmed first
    /// one; 1 = one effect only).
    pub max_effects: usize,
    /// A later effect is looked for only where the error left by the effects before it is at
    /// least this multiple of the noise RMS √3σ (stricter than `focus_noise_factor`: the earlier
    /// effects' full-data fit has already taken what it could of the noise).
    pub later_effect_noise_factor: f64,
    /// Outlier markers (`crate::outliers`): runs of a marker's residual that step away and back
    /// are flagged and left out of every score.
    pub outliers: OutlierSettings,
    /// Answer `unexplained` (instead of `none`) when the default model's held-out RMS on the
    /// focus cells, and the best any catalog entry or the stiffness-scale nuisance reaches
    /// there, are both at least this multiple of the noise RMS √3σ (0: never). 5: above the
    /// controls' discretisation floors (third-party 1.5×, virtual-rig suite up to ≈ 4× its
    /// nominal noise), far below a marker on the wrong blob (≈ 15×).
    pub unexplained_noise_factor: f64,
    /// Send a hypothesis whose force-channel screen qualifies (`crate::indentation`: the force
    /// the default model needs at the measured tip depth against the reading) to re-simulation
    /// even when its marker error is at the noise, and name it when its re-simulated model keeps
    /// the force rule without raising the marker error. On by default: measured with it on,
    /// every control of both suites (own virtual rig and third-party) stays `none`
    /// (docs/thirdparty.md, confusion tables).
    pub name_on_force_channel: bool,
    /// Plasticity's rigid-tip replays: 0 replays every grid point on the refined mesh; n > 0
    /// (the default 2) ranks them all on a cheaper mesh first (`plasticity_ranking_refinement`)
    /// and replays only the n points the folds keep most often (one per yield strain with
    /// `plasticity_quadratic_replays`, else one per ν first) on the 10-node tets or the refined
    /// mesh (`Replays::run_coarse_first`). Third-party plasticity with the default 2 on 10-node
    /// tets: 0.4918 → 0.1215 mm held-out in 260 CPU-s (every point refined: > 30 min).
    pub plasticity_refined_replays: usize,
    /// With `plasticity_refined_replays` > 0: the mesh the rigid-tip points are ranked on before
    /// the few best are replayed refined 1 → 8, as a multiple of the fit mesh's tets — 1: the
    /// fit mesh; r > 1 (the default 2): the fit mesh bisected along its longest edges to r × its
    /// tets (`ProbeSimulator::bisected`). The fit mesh's ranking is its linear tets' contact
    /// error, not the material's: on the own rig's plasticity case it ranks the 1 → 8 winner 6th
    /// of 8 in every fold, the fit mesh bisected once (r = 2) ranks it first in every fold (r = 4
    /// scrambles it again). Before the 10-node replays (one per yield strain) the points are
    /// ranked on the fit mesh itself: on the third-party plasticity case every fold keeps the
    /// two points the bisected mesh kept, at half its cost.
    pub plasticity_ranking_refinement: usize,
    /// With `plasticity_refined_replays` > 0: the kept rigid-tip points are replayed on the
    /// 10-node tets of the fit mesh (`ProbeSimulator::quadratic`, small-strain J2) instead of
    /// the linear tets refined 1 → 8, which lock under the isochoric plastic flow — where the fit
    /// mesh resolves the footprint (`ProbeSimulator::resolves_footprint`; a coarser one stays
    /// on 1 → 8: own rig 0.37–0.45 mm on its 10-node tets against 0.1676 refined).
    pub plasticity_quadratic_replays: bool,
    /// A verdict named on the markers whose look-alike it cannot out-explain there is still
    /// named when both have a force-channel model ([`crate::indentation`]), its own qualifies, and
    /// it out-explains the look-alike on the force channel by more than this many fold-to-fold
    /// spreads of their paired force fold-gain differences (`folds::outexplains_by`; twice the
    /// markers' one spread: that channel did not name the verdict). 0: never.
    pub force_tiebreak_spreads: f64,
}

impl Default for DiagnoseSettings {
    fn default() -> Self {
        Self {
            segment: SegmentSettings::default(),
            min_heldout_gain: 0.3,
            min_delta_bic: 10.0,
            noise_floor_factor: 1.5,
            lookalike_margin: 0.15,
            confirm_with_resimulation: true,
            reference_density_kg_m3: 1000.0,
            score_on_focus: true,
            focus_noise_factor: 2.0,
            focus_fraction_of_max: 0.5,
            refit_compliance_scale: true,
            max_confirmations: 2,
            max_effects: 2,
            later_effect_noise_factor: 3.0,
            outliers: OutlierSettings::default(),
            unexplained_noise_factor: 5.0,
            name_on_force_channel: true,
            plasticity_refined_replays: 2,
            plasticity_ranking_refinement: 2,
            plasticity_quadratic_replays: true,
            force_tiebreak_spreads: 2.0,
        }
    }
}
