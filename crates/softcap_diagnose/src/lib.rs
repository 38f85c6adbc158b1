//! # softcap_diagnose — locate a model/recording mismatch, name the physics left out, model it
//!
//! The diagnosis stage of DESIGN.md ("Missing-physics diagnosis"), issue 8.
//!
//! Modules from the bottom up: each uses only the ones above it in this table (no import cycles,
//! `scripts/module-cycles crates/softcap_diagnose`).
//!
//! | module | what |
//! |---|---|
//! | [`profile`] | where the diagnosis's time goes (`SOFTCAP_DIAGNOSE_PROFILE`) |
//! | [`recording`], [`segment`] | the in-memory recording (frames: time, probe pose, force, markers); its phases, probe locations (the held-out unit) and marker regions |
//! | [`signal`], [`sensor`], [`friction`] | kernels on frame-time traces: low-pass, derivative, time shift; the FSR chain and its inverse; the Coulomb return mapping of the tip's travel |
//! | [`residual`], [`cells`] | residual components and where the error lives; noise σ; the focus cells and the hypotheses' effect cells |
//! | [`folds`] | per-location held-out gains, their spread, the confidence of a named effect |
//! | [`signatures`](mod@signatures) | the signature features that separate look-alike hypotheses |
//! | [`sim`] | the [`ProbeSimulator`] contract, [`FemProbeSimulator`] and the extended FEM models ([`Extension`]) re-simulated over a recording |
//! | [`baseline`] | the default model at every frame with its tangent response ([`Prepared`]) |
//! | [`screen`] | linearised extensions ([`screen::Variant`]) refitted leave-one-location-out ([`refit`]) |
//! | [`confirm`], [`resim`] | the re-simulation harness (grids of extended models, rigid-tip replays) and the leave-one-location-out selection of re-simulated candidates |
//! | [`hypotheses`] | the [`Hypothesis`] trait and one module per catalog entry ([`Effect`]) |
//! | [`evidence`] | the diagnosis document: verdict, ranked hypotheses with typed [`Evidence`] |
//! | [`protocols`] | alternative probing protocols; the one that separates `inconclusive` look-alikes |
//! | [`diagnose`](mod@diagnose) | the phases: segment → locate → screen → confirm → verdict → extended model |
//! | [`output`], [`io`], `run` | JSON, report.md + figures, diagnosis.mcap; capture.mcap → [`Recording`], material.mcap → default model; the stage: [`run()`] with [`RunConfig`] / [`StageSettings`] |
//!
//! ```
//! use softcap_diagnose::{Phase, Recording, Frame, SegmentSettings, Segmentation};
//! use softcap_diagnose::nalgebra::Vector3;
//! let frames = (0..6u64)
//!     .map(|k| {
//!         let p = [0.0, 0.5, 1.0, 1.0, 0.0, 0.0][k as usize];
//!         Frame {
//!             frame: k,
//!             time_s: 0.1 * k as f64,
//!             tip_m: Vector3::new(0.0, 0.0, 0.01 - 0.002 * p),
//!             axis: -Vector3::z(),
//!             force_n: -Vector3::z() * p,
//!             markers_m: vec![None],
//!         }
//!     })
//!     .collect();
//! let rec = Recording {
//!     marker_ids: vec!["m0".into()],
//!     rest_markers_m: vec![Vector3::new(0.0, 0.0, 0.01)],
//!     normals: vec![Vector3::z()],
//!     gravity_m_s2: Vector3::new(0.0, 0.0, -9.81),
//!     support: None,
//!     tip_radius_m: 0.002,
//!     frames,
//! };
//! let seg = Segmentation::new(&rec, &SegmentSettings::default());
//! assert_eq!(seg.phases[0], Phase::Rest);
//! assert_eq!(seg.phases[2], Phase::Hold);
//! assert_eq!(seg.phases[5], Phase::Released);
//! ```

pub mod baseline;
pub mod cells;
pub mod cli;
pub mod confirm;
pub mod diagnose;
mod error;
pub mod evidence;
pub mod folds;
pub mod friction;
pub mod hypotheses;
pub mod indentation;
pub mod io;
pub mod outliers;
pub mod output;
pub mod profile;
pub mod protocols;
pub mod recording;
pub mod residual;
pub mod resim;
mod run;
pub mod screen;
pub mod segment;
pub mod sensor;
mod settings;
pub mod signal;
pub mod signatures;
pub mod sim;

pub use baseline::{Prepared, prepare};
pub use diagnose::{DiagnosisRun, diagnose, diagnose_with_progress};
pub use error::{DiagnoseError, Result};
pub use evidence::{
    Baseline, Candidate, Diagnosis, Evidence, ForceChannel, NamedEffect, NextExperiment,
    NotApplicable, ProtocolPrediction, RankedHypothesis, Resimulated, Screened, Unexplained,
};
pub use hypotheses::Effect;
pub use hypotheses::Hypothesis;
pub use io::{
    MaterialModel, MaterialSource, material_model, material_model_from, read_material,
    read_material_from, recording_from_capture, strain_space_material,
};
pub use output::{write_json, write_mcap, write_report};
pub use recording::{Frame, Recording, SupportPlane, surface_normals};
pub use residual::{
    Component, Located, Residuals, component, frame_axes, locate, noise_sigma_m, residuals, rmse_m,
};
pub use resim::{contact_sequence, pose_sequence};
pub use run::{RunConfig, StageSettings, run};
pub use screen::{Refit, bounded_least_squares, refit};
pub use segment::{Location, Phase, Region, SegmentSettings, Segmentation};
pub use settings::DiagnoseSettings;
pub use signatures::{Signatures, signatures};
pub use sim::{
    Extension, FemProbeSimulator, FemSimSettings, LoadPoint, ProbeLoad, ProbeSimulator,
    SequenceFrame, SimLoad, SimOutput, transverse_from_isotropic, transverse_with_poisson,
    with_lame_ratio,
};

pub use nalgebra;
