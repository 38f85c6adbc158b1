//! What a hypothesis is to the diagnosis: the [`Hypothesis`] trait and the [`Context`] it sees.

use super::Effect;
use crate::Result;
use crate::baseline::Prepared;
use crate::cells::EffectCells;
use crate::confirm::Confirmed;
use crate::indentation::{ForceCandidate, ForceObservations};
use crate::recording::Recording;
use crate::screen::{Refit, Variant};
use crate::segment::Segmentation;
use crate::settings::DiagnoseSettings;
use crate::signatures::Signatures;
use crate::sim::ProbeSimulator;

/// What a hypothesis sees of the diagnosis in progress.
#[derive(Clone, Copy)]
pub struct Context<'a> {
    /// The recording.
    pub rec: &'a Recording,
    /// Its phases, locations and regions.
    pub seg: &'a Segmentation,
    /// The baseline simulation and the tangent responses.
    pub prepared: &'a Prepared,
    /// The signature features of the recording and the baseline residual.
    pub signatures: &'a Signatures,
    /// The diagnosis settings.
    pub settings: &'a DiagnoseSettings,
}

/// When a hypothesis's signature alone sends it to re-simulation, whatever its screen says.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SignatureRoute {
    /// Confirmed before the screen's candidates (an unambiguous signature).
    BeforeScreen,
    /// Confirmed after the screen's candidates (they keep precedence); the re-simulation must
    /// also beat the stiffness-scale nuisance, as a screened row must.
    AfterScreen,
}

/// One catalog entry of the diagnosis.
pub trait Hypothesis: Sync {
    /// The catalog entry.
    fn effect(&self) -> Effect;

    /// The term the extension adds (report, extended model).
    fn term(&self) -> &'static str;

    /// The screen: the extension as a grid of linearised variants around the baseline. Empty
    /// when it cannot act on this recording.
    fn variants(&self, cx: &Context<'_>) -> Vec<Variant>;

    /// Why it cannot act on the recording (when [`Self::variants`] is empty).
    fn not_applicable_reason(&self) -> &'static str {
        "no extension field for this recording"
    }

    /// The observations where its effect lives, scored there instead of the focus cells.
    fn effect_cells(&self, rec: &Recording, seg: &Segmentation) -> Option<EffectCells> {
        let _ = (rec, seg);
        None
    }

    /// How strongly the signatures support it (0 = no opinion, 1 = supported, −1 = contradicted).
    fn signature_support(&self, s: &Signatures) -> f64;

    /// Why its re-simulated extended model `c` is no confirmation even though it keeps its gain:
    /// the fit reached the data only at a bound of its search, outside the physics the
    /// extension models. Then it is neither the verdict nor a look-alike, and the reason is
    /// reported as its failed confirmation. `None` (default): its gain decides.
    fn fit_at_bound(&self, c: &Confirmed) -> Option<String> {
        let _ = c;
        None
    }

    /// Why the signatures rule it out as the effect that explains the session: a feature its
    /// physics cannot produce (a rate-independent set cannot relax a held force). Then it is
    /// neither confirmed (not re-simulated: the reason is its failed confirmation) nor a
    /// look-alike of the verdict; forward selection may still add it on top of a named effect
    /// that explains that feature. `None` (default): the signatures only rank it
    /// ([`Self::signature_support`]).
    fn ruled_out(&self, s: &Signatures) -> Option<String> {
        let _ = s;
        None
    }

    /// Whether its signature alone sends it to re-simulation, and when.
    fn signature_route(&self, s: &Signatures) -> Option<SignatureRoute> {
        let _ = s;
        None
    }

    /// Its models of the force channel (`crate::indentation`): each a full set of columns for
    /// the force y the default model needs at the measured tip depth (the nuisance's a f and
    /// o / c included or replaced), for a hypothesis that changes the force–indentation relation
    /// (a sensor that lags the force). `None` (default) for the others. A hypothesis whose
    /// held-out force gain qualifies is sent to re-simulation even when its marker error is at
    /// the noise, and then judged on the force channel as well ([`Confirmed::force`]).
    fn force_candidates(
        &self,
        cx: &Context<'_>,
        obs: &ForceObservations,
    ) -> Option<Vec<ForceCandidate>> {
        let _ = (cx, obs);
        None
    }

    /// Its fitted extension planned under another probing protocol
    /// ([`crate::protocols::next_experiment`]), for an entry whose screen is only a first-order
    /// limit of the model its confirmation re-simulates: that model's load on `cx` (the planned
    /// program) with the screen's fitted parameters `refit`, as a variant without bases. `None`
    /// (default): the screen's own variant with its fitted parameters.
    fn planning_variant(&self, cx: &Context<'_>, refit: &Refit) -> Option<Variant> {
        let _ = (cx, refit);
        None
    }

    /// The force sensor's axial reading of the true axial force `force_n` (per frame, at times
    /// `t`) under its force-channel model with the parameters `params` of its force fit
    /// ([`crate::indentation::ForceScore::force_params`]): what the planner compares between two
    /// force-channel candidates under another program. `None` (default): no force-channel model.
    fn reading_of(&self, params: &[(String, f64)], t: &[f64], force_n: &[f64]) -> Option<Vec<f64>> {
        let _ = (params, t, force_n);
        None
    }

    /// Confirms it by re-simulating its extended model over the recording, leave-one-location-out,
    /// scored on `scored(k, m)`; `refit` is its screen. `Ok(None)` when it has no extended model
    /// to re-simulate here (the verdict then rests on the screen).
    fn confirm(
        &self,
        cx: &Context<'_>,
        refit: &Refit,
        scored: &dyn Fn(usize, usize) -> bool,
        sim: &mut dyn ProbeSimulator,
    ) -> Result<Option<Confirmed>>;
}

/// The value of parameter `name` in a parameter list.
pub(crate) fn param(params: &[(String, f64)], name: &str) -> Option<f64> {
    params.iter().find(|x| x.0 == name).map(|x| x.1)
}
