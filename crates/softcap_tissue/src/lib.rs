//! # softcap_tissue — material capture and synthesis of soft tissue (bickel2009 §3–4)
//!
//! The tissue stage: `capture.mcap` + a tet mesh → a heterogeneous, non-linear material
//! (`material.mcap`), and synthesis of novel probe deformations with it. The kernels (marker
//! embedding, eq. 9 per-example fits with the adjoint Jacobian, the eq. 8 strain-space RBF with
//! greedy basis, probe-contact synthesis) live in [`softcap_probing`]; this crate turns a
//! recorded session into examples, runs them and writes/reads the files.
//!
//! | module | what |
//! |---|---|
//! | [`session`] | capture + mesh → [`PreparedSession`]: SI mesh, embedded markers, attached region, [`SessionExample`]s |
//! | [`fit`] | `softcap tissue fit`: [`FitConfig`], [`FitSettings`], [`fit::run`] → [`FitOutcome`]; [`fit_session`] in memory |
//! | [`output`] | material.mcap writer ([`write_material`]) and reader ([`read_material`] → [`LoadedMaterial`]) |
//! | [`simulate`] | `softcap tissue simulate`: [`SimulateConfig`], [`ProbeSpec`] → sim.mcap (§3.4 incremental loading with probe contact) |
//! | [`report`] | report.md + PNGs: per-example error, error vs basis size (plotters) |
//! | [`cli`] | the `softcap-tissue` command line ([`cli::Cli::run`]) |
//! | [`fit_dynamic`] | `softcap tissue fit-dynamic` (wang2015 §6): E at control points, ν, Rayleigh α/β and rest shape from tracked trajectories (Algorithm 1) |
//! | [`track`] | `softcap tissue track` (wang2015 §5): EM tracking of a tet mesh through the point clouds of a dynamic capture → track.mcap |
//! | [`error`] | [`TissueError`] (`is_bad_input()` → exit code 2) |
//!
//! ```
//! use softcap_tissue::{FitSettings, basis_message};
//! use softcap_probing::{StrainBasisSettings, StrainSample, StrainSpaceMaterial};
//! use softcap_fem::LinearParams;
//! // The fit's budget knobs: examples per probe location, LM iterations, basis size.
//! let s = FitSettings::default();
//! assert!(s.examples.examples_per_location >= 1 && s.example_fit.max_iterations >= 1);
//! // A one-tet strain-space material and its /tissue/basis message (per-tet centre counts).
//! let p = |l: f64| LinearParams { lambda: l, alpha: 0.4 * l };
//! let samples = vec![vec![
//!     StrainSample { strain: [0.0; 6], params: p(1e5) },
//!     StrainSample { strain: [0.0, 0.0, -0.1, 0.0, 0.0, 0.0], params: p(2e5) },
//! ]];
//! let (m, _) = StrainSpaceMaterial::fit(&samples, &StrainBasisSettings::default()).unwrap();
//! let b = basis_message(&m);
//! assert_eq!(b.centers_per_tet.len(), 1);
//! assert_eq!(b.weights.len(), 2 * b.center_examples.len());
//! ```

pub mod cli;
pub mod error;
pub mod fit;
pub mod fit_dynamic;
pub mod output;
pub mod report;
pub mod reshape;
pub mod session;
pub mod simulate;
pub mod track;

pub use error::{Result, TissueError};
pub use fit::{
    ExampleSummary, FitConfig, FitOutcome, FitSettings, GammaPriorScore, HeldoutComparison,
    LeaveOneLocationOut, ReferenceField, SessionFit, compare_heldout, fit_session,
    leave_one_location_out, leave_one_location_out_from, marker_errors, resimulate,
    resimulate_from, select_gamma_prior, simulate_example, strain_samples,
    strain_samples_with_reference,
};
pub use output::{LoadedMaterial, basis_message, read_material, report_message, write_material};
pub use report::write_report;
pub use session::{
    ExampleSelection, PreparedSession, SessionExample, examples_from_frames, prepare,
    read_volume_mesh, read_volume_mesh_mapped, select_examples,
};
pub use simulate::{ProbeShape, ProbeSpec, SimulateConfig, SimulateOutcome, SimulateSettings};
pub use softcap_app::Progress;
pub use track::{TrackConfig, TrackMaterial, TrackOutcome, TrackSettings};

pub use softcap_fem;
pub use softcap_mcap;
