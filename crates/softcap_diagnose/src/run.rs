//! The stage entry point: `softcap diagnose capture.mcap material.mcap -o diagnosis.mcap
//! [--json FILE] [--report DIR]`.

use crate::diagnose::{DiagnosisRun, diagnose_with_progress};
use crate::evidence::Diagnosis;
use crate::io::{MaterialSource, read_material_from, recording_from_capture};
use crate::output::{write_json, write_mcap, write_report};
use crate::settings::DiagnoseSettings;
use crate::sim::{FemProbeSimulator, FemSimSettings};
use crate::{DiagnoseError, Result};
use serde::{Deserialize, Serialize};
use softcap_fem::{CorotationalModel, TipShape};
use softcap_mcap::Provenance;
use softcap_mcap::capture::CaptureData;
use softcap_probing::{FootprintLoad, StrainSpaceMaterial};
use std::path::PathBuf;
use std::sync::Arc;

/// Settings of the stage (loadable from TOML).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StageSettings {
    /// Diagnosis.
    pub diagnose: DiagnoseSettings,
    /// Simulator (contact patch, equilibrium).
    pub simulator: FemSimSettings,
    /// Which material of material.mcap is the default model.
    pub material: MaterialSource,
}

/// What to run.
#[derive(Clone, Debug)]
pub struct RunConfig {
    /// capture.mcap.
    pub capture: PathBuf,
    /// material.mcap.
    pub material: PathBuf,
    /// diagnosis.mcap to write.
    pub output: PathBuf,
    /// Optional JSON output.
    pub json: Option<PathBuf>,
    /// Optional report folder.
    pub report: Option<PathBuf>,
    /// Settings.
    pub settings: StageSettings,
    /// Full argument list (provenance).
    pub arguments: Vec<String>,
    /// Show the per-step status on stderr (only ever drawn when stderr is a terminal).
    pub progress: bool,
}

/// The rigid tip of the session (`/capture/session` `tip_shape`, `tip_radius_m`) for the
/// rigid-tip replay: a sphere, or a disk (its thickness is not recorded; one radius, enough for
/// the indentation depths of a probing session). `None` for a mesh tip or an unknown shape.
fn session_tip(shape: &str, radius_m: f64) -> Option<TipShape> {
    if !(radius_m > 0.0 && radius_m.is_finite()) {
        return None;
    }
    match shape {
        "sphere" => Some(TipShape::Sphere { radius_m }),
        "disk" => Some(TipShape::Disk {
            radius_m,
            thickness_m: radius_m,
        }),
        _ => None,
    }
}

/// Reads the inputs, diagnoses, writes every requested output. Inputs are read and validated
/// before anything is written.
pub fn run(cfg: &RunConfig) -> Result<Diagnosis> {
    let cap = CaptureData::read(&cfg.capture).map_err(|e| DiagnoseError::Mcap {
        path: cfg.capture.clone(),
        source: Box::new(e),
    })?;
    let mut material = read_material_from(&cfg.material, cfg.settings.material)?;
    let rec = recording_from_capture(&cap, &material.mesh)?;
    let Some(support) = rec.support else {
        return Err(DiagnoseError::BadInput {
            path: cfg.capture.clone(),
            what: "/capture/session has no support plane: the model needs its boundary condition"
                .into(),
        });
    };
    let fixed = support.nodes(&material.mesh);
    if fixed.is_empty() {
        return Err(DiagnoseError::BadInput {
            path: cfg.material.clone(),
            what: "no mesh node lies on the session's support plane".into(),
        });
    }
    let progress = softcap_app::Progress::new(cfg.progress).bar("diagnose", 0);
    if !progress.is_hidden() {
        progress.enable_steady_tick(std::time::Duration::from_millis(250));
    }
    // The force boundary condition replays the load the material was fitted under (recorded in
    // material.mcap; files without the entry keep the settings' load).
    let attempt = |model: CorotationalModel,
                   basis: Option<Arc<StrainSpaceMaterial>>,
                   load: Option<FootprintLoad>|
     -> Result<DiagnosisRun> {
        let mut settings = cfg.settings.simulator.clone();
        if let Some(load) = load {
            settings.patch.load = load;
        }
        let mut sim =
            FemProbeSimulator::new(&material.mesh, model, &fixed, &rec.rest_markers_m, settings)?
                .with_support_plane(&support.normal, support.offset_m);
        if let Some(b) = basis {
            sim = sim.with_strain_space(b)?;
        }
        if let Some(tip) = session_tip(&cap.session.tip_shape, cap.session.tip_radius_m) {
            sim = sim.with_rigid_tip(tip);
        }
        diagnose_with_progress(&rec, &mut sim, &cfg.settings.diagnose, &progress)
    };
    let mut result = match attempt(
        material.model.clone(),
        material.basis.clone(),
        material.footprint_load,
    ) {
        // `Auto` picked the strain-space basis from the fit report, but the default model does
        // not reach equilibrium on this recording: fall back to the homogeneous baseline and say
        // so in the evidence (non-convergence is a reported status, not a failed run).
        Err(DiagnoseError::Simulation { frame, reason })
            if cfg.settings.material == MaterialSource::Auto
                && material.source.starts_with("strain-space") =>
        {
            let fallback = read_material_from(&cfg.material, MaterialSource::Homogeneous)?;
            let frame = if frame == u64::MAX {
                "the unloaded state".to_string()
            } else {
                format!("frame {frame}")
            };
            material.source = format!(
                "{} (auto fallback: the strain-space basis did not converge at {frame}: {reason})",
                fallback.source
            );
            attempt(fallback.model, None, fallback.footprint_load)?
        }
        r => r?,
    };
    for r in &mut result.diagnosis.ranked {
        r.evidence.default_model = Some(material.source.clone());
    }
    // The content digest (`softcap inspect digest`): equal for equal material content whatever
    // the material file's own provenance timestamp, so reruns reproduce this file's digest.
    let sha = softcap_mcap::Recording::open(&cfg.material)
        .and_then(|r| r.digest())
        .map_err(|e| DiagnoseError::Mcap {
            path: cfg.material.clone(),
            source: Box::new(e),
        })?;
    let settings_toml = toml::to_string(&cfg.settings).unwrap_or_default();
    let mcap_err = |path: &PathBuf| {
        let path = path.clone();
        move |e| DiagnoseError::Mcap {
            path: path.clone(),
            source: Box::new(e),
        }
    };
    let provenance = Provenance::new("diagnose", env!("CARGO_PKG_VERSION"))
        .with_arguments(cfg.arguments.iter())
        .with_settings(settings_toml)
        .with_input(&cfg.capture)
        .map_err(mcap_err(&cfg.capture))?
        .with_input(&cfg.material)
        .map_err(mcap_err(&cfg.material))?;
    write_mcap(&cfg.output, &provenance, &rec, &result, &sha)?;
    if let Some(j) = &cfg.json {
        write_json(j, &result.diagnosis)?;
    }
    if let Some(d) = &cfg.report {
        write_report(d, &rec, &result)?;
    }
    Ok(result.diagnosis)
}
