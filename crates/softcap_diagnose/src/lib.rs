//! # softcap_diagnose — locate a model/recording mismatch, name the physics left out, model it
//!
//! The diagnosis stage of DESIGN.md ("Missing-physics diagnosis"), issue 8.
//!
//! | module | what |
//! |---|---|
//! | [`recording`] | the in-memory recording: frames (time, probe pose, force, markers), normals, support |
//! | [`segment`] | phases (rest, loading, hold, unloading, released), probe locations, marker regions |
//! | [`residual`] | residual components (normal, tangential, gravity, probe axis), the located table, noise σ |
//! | [`sim`] | the [`ProbeSimulator`] contract and the corotational FEM implementation |
//! | [`signal`] | low-pass, derivative, time shift on frame-time traces |
//! | [`hypothesis`] | the catalog, extension fields, linearised leave-one-location-out refits (screening) |
//! | [`temporal`] | viscoelasticity, sensor-lag, clock-offset: grids of extended models re-simulated in time order, leave-one-location-out with a compliance scale |
//! | [`extend`] | the extended FEM models (Prony, J2 plasticity, support springs, transverse isotropy) re-simulated over the recording |
//! | [`signatures`] | the signature features that separate look-alike hypotheses |
//! | [`evidence`] | the diagnosis document: verdict, ranked hypotheses with typed [`Evidence`] |
//! | [`output`] | JSON (issue 8 schema), report.md + PNG figures, diagnosis.mcap |
//! | [`io`] | capture.mcap → [`Recording`], material.mcap → default model |
//! | `run` | the stage: [`run()`] with [`RunConfig`] / [`StageSettings`] |
//! | [`spatial`] | plasticity, support-slip, anisotropy, probe-friction: effect cells and re-simulated confirmation |
//! | [`friction`] | probe-friction: the Coulomb traction of the tip's travel under the measured normal force (return mapping), its confirmation grid |
//! | [`diagnose`](mod@diagnose) | baseline simulation, signatures, ranking, verdict, re-simulation of the winner |
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

mod confirm;
pub mod diagnose;
mod error;
pub mod evidence;
pub mod extend;
pub mod friction;
pub mod hypothesis;
pub mod io;
pub mod output;
pub mod recording;
pub mod residual;
mod run;
pub mod segment;
pub mod sensor;
pub mod signal;
pub mod signatures;
pub mod sim;
pub mod spatial;
pub mod temporal;

pub use confirm::{contact_sequence, pose_sequence};
pub use diagnose::{DiagnoseSettings, DiagnosisRun, diagnose, prepare, signature_support};
pub use error::{DiagnoseError, Result};
pub use evidence::{
    Baseline, Diagnosis, Evidence, NotApplicable, RankedHypothesis, Resimulated, Screened,
};
pub use extend::{Extension, SequenceFrame, transverse_from_isotropic, transverse_with_poisson};
pub use hypothesis::{Hypothesis, Prepared, Refit, bounded_least_squares, refit};
pub use io::{
    MaterialModel, MaterialSource, material_model, material_model_from, read_material,
    read_material_from, recording_from_capture, strain_space_material,
};
pub use output::{write_json, write_mcap, write_report};
pub use recording::{Frame, Recording, SupportPlane, surface_normals};
pub use residual::{
    Component, Located, Residuals, component, frame_axes, locate, noise_sigma_m, residuals, rmse_m,
};
pub use run::{RunConfig, StageSettings, run};
pub use segment::{Location, Phase, Region, SegmentSettings, Segmentation};
pub use signatures::{Signatures, signatures};
pub use sim::{FemProbeSimulator, FemSimSettings, ProbeLoad, ProbeSimulator, SimLoad, SimOutput};

pub use nalgebra;
