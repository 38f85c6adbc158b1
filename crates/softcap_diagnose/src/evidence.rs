//! The diagnosis document (`--json`, issue 8 schema): the verdict, every hypothesis ranked with
//! its held-out errors, parameters and typed [`Evidence`], and where the default model's error
//! lives. The evidence is serialized only here, as a JSON object with sorted keys.

use crate::residual::Located;
use crate::signatures::Signatures;
use serde::{Deserialize, Serialize, Serializer};
use std::collections::BTreeMap;

/// The diagnosis document (`--json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Diagnosis {
    /// Name of the missing physics, or `none`.
    pub verdict: String,
    /// Every hypothesis, best first (`none` included).
    pub ranked: Vec<RankedHypothesis>,
    /// Where the default model's error lives, largest first.
    pub located: Vec<Located>,
    /// Every named effect in the order forward selection added it (the verdict first; empty for
    /// `none` and `inconclusive`): each with its parameters in the joint model and its held-out
    /// errors alone, without it and with it.
    #[serde(default)]
    pub effects: Vec<NamedEffect>,
    /// Confidence of the verdict, 0 … 1: of the first named effect (its held-out gain above the
    /// naming threshold over the folds); for `inconclusive` of its first candidate; for `none`
    /// one minus the largest confidence of a hypothesis that passed the screen and was not
    /// re-simulated (a re-simulated one that did not keep its gain is rejected).
    #[serde(default)]
    pub confidence: f64,
    /// `inconclusive`: the look-alikes the data cannot separate, best first. Beside named effects:
    /// a later effect read on the force channel and its force look-alikes, which that channel
    /// cannot separate (fold gains on the force channel; no effect of the pair is named).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub candidates: Vec<Candidate>,
    /// The protocol whose recording would separate the (first two) candidates.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub next_experiment: Option<NextExperiment>,
    /// Outlier markers: runs of a marker's observations whose residual stepped away from the
    /// default model and back (a marker on the wrong blob), left out of every score.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub outliers: Vec<crate::outliers::OutlierRun>,
    /// `unexplained`: where the default model misses far above the noise floor while no catalog
    /// entry (nor the stiffness-scale nuisance) explains it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub unexplained: Option<Unexplained>,
}

/// Where an `unexplained` mismatch lives and how far it is above the noise floor.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Unexplained {
    /// The default model's held-out RMS on the focus cells, m.
    pub heldout_rmse_m: f64,
    /// What is left of `heldout_rmse_m` after the best catalog entry's refit (scaled by the
    /// after / before ratio it reached on its own cells) or the stiffness-scale nuisance, m.
    pub best_explained_rmse_m: f64,
    /// The noise floor: the marker-noise RMS √3σ estimated from the data, m.
    pub noise_floor_m: f64,
    /// The cell with the largest error: `region/phase`.
    pub cell: String,
    /// Its RMS, m.
    pub cell_rmse_m: f64,
    /// The probe location (fold index) with the largest error in the cell.
    pub location: Option<usize>,
    /// The markers with the largest error in the cell, largest first: (id, RMS m).
    pub markers: Vec<(String, f64)>,
}

/// One named effect of the joint extended model.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct NamedEffect {
    /// Catalog name.
    pub hypothesis: String,
    /// Parameters: the first effect's as confirmed; a later one's fitted on top of the earlier
    /// ones (the joint extended model); one read on the force channel, its force fit (with the
    /// nuisance's `force_scale` and `tip_offset_m`).
    pub params: BTreeMap<String, f64>,
    /// Confidence that its held-out gain exceeds the naming threshold (`min_heldout_gain`), from
    /// the fold gains' mean and spread.
    pub confidence: f64,
    /// The cells it is scored on.
    pub scored_cells: Vec<String>,
    /// Held-out RMS of the default model on those cells, m.
    pub heldout_rmse_before_m: f64,
    /// … of the effects named before it (the default model for the first), m.
    pub heldout_rmse_without_m: f64,
    /// … of this effect alone on the default model, m.
    pub heldout_rmse_single_m: f64,
    /// … of the joint model with it and the effects before it, m.
    pub heldout_rmse_after_m: f64,
    /// Per probe location: 1 − after / without of the held-out mean-square error (one named on
    /// the force channel: of its force MSE against the nuisance).
    pub fold_gains: Vec<f64>,
}

/// A look-alike of an `inconclusive` verdict.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Candidate {
    /// Catalog name.
    pub hypothesis: String,
    /// Held-out RMS of its linearised refit on its cells, m.
    pub heldout_rmse_after_m: f64,
    /// Per probe location: 1 − after / before of the held-out mean-square error (the screen).
    pub fold_gains: Vec<f64>,
    /// Confidence that its gain exceeds the naming threshold.
    pub confidence: f64,
    /// Parameters of its full-data refit.
    pub params: BTreeMap<String, f64>,
}

/// The measurement that separates the candidates of an `inconclusive` verdict: each alternative
/// protocol simulated with every candidate's fitted model; the one with the largest predicted
/// difference is recommended.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct NextExperiment {
    /// The recommended protocol.
    pub protocol: String,
    /// What to record.
    pub description: String,
    /// RMS marker difference between the two leading candidates' predictions under it, net of
    /// what a refitted global stiffness scale takes up (`protocols` module docs), m.
    pub predicted_difference_m: f64,
    /// The same under the recorded protocol, m.
    pub recorded_difference_m: f64,
    /// Every protocol tried, with its predicted difference.
    pub protocols: Vec<ProtocolPrediction>,
}

/// One alternative protocol's predicted difference between the candidates.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ProtocolPrediction {
    /// Protocol name.
    pub protocol: String,
    /// RMS marker difference between the two leading candidates' predictions, net of what a
    /// refitted global stiffness scale takes up, m.
    pub predicted_difference_m: f64,
    /// RMS difference of their predicted force readings over the planned contact frames, N,
    /// when both are force-channel models (then it chooses the protocol).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub predicted_force_difference_n: Option<f64>,
}

/// One ranked hypothesis (the JSON schema of issue 8).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RankedHypothesis {
    /// Catalog name.
    pub hypothesis: String,
    /// Fraction of the held-out mean-square error the extension explains, 1 − after²/before².
    pub score: f64,
    /// Held-out RMS marker error of the default model, m.
    pub heldout_rmse_before_m: f64,
    /// Held-out RMS marker error with the extension refitted on the other locations, m.
    pub heldout_rmse_after_m: f64,
    /// Full-data parameters.
    pub params: BTreeMap<String, f64>,
    /// Evidence: information criterion, signatures, re-simulation.
    #[serde(serialize_with = "sorted_keys")]
    pub evidence: Evidence,
}

/// What a ranked row rests on. Which parts are present depends on the row: a hypothesis that was
/// screened carries [`Screened`] (and [`Resimulated`] or `confirmation_failed` when it was sent
/// to re-simulation), one that cannot act on the recording [`NotApplicable`], the `none` row
/// [`Baseline`]. Written as one flat JSON object (keys sorted).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Evidence {
    /// Signature features of the recording and the baseline residual (every row).
    pub signatures: Signatures,
    /// The default model: which material of material.mcap it is (set by the stage run).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub default_model: Option<String>,
    /// Where the held-out errors are scored: `all`, the focus cells `region/phase`, or the
    /// hypothesis's own effect cells (screened rows and `none`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scored_cells: Option<Vec<String>>,
    /// Held-out RMS of the default model over every observation of the locations, m (screened
    /// rows and `none`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub heldout_rmse_all_before_m: Option<f64>,
    /// The linearised screen of a hypothesis.
    #[serde(flatten, default, skip_serializing_if = "Option::is_none")]
    pub screened: Option<Screened>,
    /// The confirmation by re-simulation, when it ran.
    #[serde(flatten, default, skip_serializing_if = "Option::is_none")]
    pub resimulated: Option<Resimulated>,
    /// Why the re-simulation failed, when it did.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub confirmation_failed: Option<String>,
    /// The hypothesis cannot act on this recording.
    #[serde(flatten, default, skip_serializing_if = "Option::is_none")]
    pub not_applicable: Option<NotApplicable>,
    /// The `none` row: the default model against the noise and the stiffness-scale nuisance.
    #[serde(flatten, default, skip_serializing_if = "Option::is_none")]
    pub baseline: Option<Baseline>,
    /// A hypothesis that changes the force–indentation relation, judged on the force channel
    /// (`crate::indentation`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub force_channel: Option<ForceChannel>,
}

/// A hypothesis on the force channel (`crate::indentation`): the force the default model needs
/// for the measured tip depth against the reading, leave-one-location-out.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ForceChannel {
    /// Its linearised extension against the nuisance (a f + o / c).
    pub screened: crate::indentation::ForceScore,
    /// It passed the force screen: the nuisance's held-out force MSE above the noise rule (the
    /// marker rule's factors on the force noise σ), held-out gain and BIC as on the markers, its
    /// signatures not against it.
    pub qualifies: bool,
    /// Its re-simulated extended model on the force channel, when it was confirmed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub resimulated: Option<crate::indentation::ForceScore>,
}

/// The linearised screen of one hypothesis (leave-one-location-out, BIC).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Screened {
    /// BIC of the extension minus the default model's (< 0: the extension is preferred).
    pub delta_bic: f64,
    /// How strongly the signatures support it (−1 contradicted … 1 supported).
    pub signature_support: f64,
    /// It passed the screen (held-out gain, BIC, noise, stiffness-scale nuisance).
    pub qualifies: bool,
    /// Sent to re-simulation by its signature alone (written only when true).
    #[serde(default, skip_serializing_if = "is_false")]
    pub confirmed_by_signature: bool,
    /// Number of parameters of the chosen variant (grid + linear).
    pub num_params: usize,
    /// How the row's `heldout_rmse_after_m` was obtained: the linearised refit or the
    /// re-simulated extended model.
    pub method: String,
    /// Held-out RMS of the linearised refit, m.
    pub heldout_rmse_linearised_m: f64,
}

/// The extended model re-simulated over the recording, leave-one-location-out.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Resimulated {
    /// Held-out RMS on the scored cells, m.
    pub heldout_rmse_resimulated_m: f64,
    /// Held-out RMS on every observation of the locations, m.
    pub heldout_rmse_all_after_m: f64,
}

/// A hypothesis that cannot act on the recording.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct NotApplicable {
    /// Always false.
    pub applicable: bool,
    /// Why not.
    pub reason: String,
}

/// The `none` row's evidence.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Baseline {
    /// Marker noise σ per coordinate, m.
    pub noise_sigma_m: f64,
    /// The default model's held-out MSE exceeds the noise floor (settings' factor × 3σ²).
    pub explainable_beyond_noise: bool,
    /// Held-out RMS with only the material's stiffness refitted (the nuisance model), m.
    pub heldout_rmse_stiffness_scale_only_m: f64,
}

fn is_false(b: &bool) -> bool {
    !*b
}

/// Serializes through a `serde_json::Value`, whose objects keep their keys sorted: the evidence
/// object (and its signatures) is written in key order, whatever the struct's field order.
fn sorted_keys<S: Serializer>(e: &Evidence, s: S) -> Result<S::Ok, S::Error> {
    serde_json::to_value(e)
        .map_err(serde::ser::Error::custom)?
        .serialize(s)
}

impl Evidence {
    /// The evidence as the JSON object written to the document (keys sorted).
    pub fn to_json(&self) -> serde_json::Value {
        serde_json::to_value(self).unwrap_or_default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn screened_row() -> Evidence {
        Evidence {
            signatures: Signatures {
                noise_sigma_m: 1e-5,
                ..Default::default()
            },
            default_model: Some("homogeneous".into()),
            scored_cells: Some(vec!["probed/hold".into()]),
            heldout_rmse_all_before_m: Some(2e-4),
            screened: Some(Screened {
                delta_bic: -42.0,
                signature_support: 1.0,
                qualifies: true,
                confirmed_by_signature: false,
                num_params: 3,
                method: "re-simulated".into(),
                heldout_rmse_linearised_m: 1e-4,
            }),
            resimulated: Some(Resimulated {
                heldout_rmse_resimulated_m: 5e-5,
                heldout_rmse_all_after_m: 6e-5,
            }),
            ..Default::default()
        }
    }

    /// The JSON keys of a screened, re-simulated row are the documented flat ones, sorted; the
    /// document reads back to the same typed evidence.
    #[test]
    fn evidence_is_one_flat_sorted_object_and_reads_back() {
        let e = screened_row();
        let v = e.to_json();
        let keys: Vec<&str> = v.as_object().unwrap().keys().map(|k| k.as_str()).collect();
        assert_eq!(
            keys,
            [
                "default_model",
                "delta_bic",
                "heldout_rmse_all_after_m",
                "heldout_rmse_all_before_m",
                "heldout_rmse_linearised_m",
                "heldout_rmse_resimulated_m",
                "method",
                "num_params",
                "qualifies",
                "scored_cells",
                "signature_support",
                "signatures",
            ]
        );
        let row = RankedHypothesis {
            hypothesis: "viscoelasticity".into(),
            score: 0.9,
            heldout_rmse_before_m: 2e-4,
            heldout_rmse_after_m: 5e-5,
            params: BTreeMap::new(),
            evidence: e.clone(),
        };
        let text = serde_json::to_string(&row).unwrap();
        assert!(text.contains(r#""evidence":{"default_model":"homogeneous","delta_bic":-42.0,"#));
        let back: RankedHypothesis = serde_json::from_str(&text).unwrap();
        assert_eq!(back.evidence, e);
        // the `none` row and a row that is not applicable read back too
        for e in [
            Evidence {
                baseline: Some(Baseline {
                    noise_sigma_m: 1e-5,
                    explainable_beyond_noise: true,
                    heldout_rmse_stiffness_scale_only_m: 1e-4,
                }),
                scored_cells: Some(vec!["all".into()]),
                ..Default::default()
            },
            Evidence {
                not_applicable: Some(NotApplicable {
                    applicable: false,
                    reason: "no gravity in the session".into(),
                }),
                ..Default::default()
            },
        ] {
            let back: Evidence = serde_json::from_value(e.to_json()).unwrap();
            assert_eq!(back, e);
        }
    }
}
