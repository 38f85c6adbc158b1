//! # softcap_probing — the probing layer the stages share
//!
//! Probing examples of bickel2009 §3–4 — one simulator and one set of fits for every stage that
//! needs them (tissue fits and synthesizes, diagnose re-simulates, design replays recordings).
//! It sits between the FEM kernels of `softcap_fem` and the stage crates (core ← mesh ← fem ←
//! probing ← stages), because stages may not import each other.
//!
//! | module | what | paper |
//! |---|---|---|
//! | [`setup`] | [`ProbingSetup`]: mesh, embedded markers, attached / boundary / load regions, umbrella adjacency; [`ProbeExample`]; [`support_nodes`]; elastostatic response to an example's force | bickel2009 §4.1 |
//! | [`footprint`] | [`FootprintLoad`], [`PatchSettings`]: the measured force over the contact patch — lumped, or the consistent loads of a uniform, flat-punch or Hertz pressure; a tilted disk's partial contact ([`FaceTilt`]) | bickel2009 §4.1, Fig. 7; Sneddon 1946; Hertz 1882; Johnson 1985 ch. 3, 5 |
//! | [`example_fit`] | the per-example fit [`fit_examples`] with [`ExampleFitSettings`]: projected LM over (ln λ, ν), adjoint marker Jacobian [`marker_jacobian`], umbrella smoothing, shrinkage, trust region | bickel2009 eq. 9, appendix eq. 10–12; Moré 1978 |
//! | [`lm_step`] | the damped normal equations of one LM step by preconditioned CG (Jacobi or Woodbury), the blocked J_mᵀ(J_m v) | bickel2009 eq. 9; Dembo et al. 1982 |
//! | [`homogeneous`] | [`fit_homogeneous`]: one (E, ν) for all tets and examples | bickel2009 §6, Fig. 8 |
//! | [`strain_space`] | [`StrainSpaceMaterial`]: per-tet RBF p(ε) = c + Σ wᵢ‖ε − εᵢ‖ by greedy basis selection | bickel2009 eq. 8, §4.2; Carr et al. 2001 |
//! | [`strain_model`] | [`StrainSpaceModel`]: parameters refreshed from the strain at every iteration (under-relaxed), equilibrium continued frame to frame | bickel2009 §3.4 |
//! | [`synthesis`] | [`simulate_probe_contact`]: a novel rigid probe pressed to a requested force | bickel2009 §3.4 |
//!
//! Errors are `softcap_fem::FemError` (input problems of this layer: `FemError::Probing`).
//!
//! ```
//! use softcap_fem::nalgebra::Vector3;
//! use softcap_fem::{CorotationalModel, EquilibriumSettings, LinearParams};
//! use softcap_probing::{
//!     ExampleFitSettings, FitStart, ObservedMarker, PatchSettings, ProbeExample, ProbingSetup,
//!     fit_examples, support_nodes,
//! };
//! // A 30 × 30 × 12 mm block on a table, 9 markers on top, pressed with 1 N at its centre.
//! let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [0.03, 0.03, 0.012], [3, 3, 1]);
//! let markers: Vec<_> = (0..9)
//!     .map(|k| Vector3::new(0.005 + 0.01 * (k % 3) as f64, 0.005 + 0.01 * (k / 3) as f64, 0.012))
//!     .collect();
//! let attached = support_nodes(&mesh, &Vector3::z(), 0.0, 1e-9);
//! let setup = ProbingSetup::new(mesh, &markers, attached)?;
//! let mut example = ProbeExample {
//!     frame: 1,
//!     time_s: 0.1,
//!     tip_m: Vector3::new(0.015, 0.015, 0.012),
//!     axis: -Vector3::z(),
//!     force_n: Vector3::new(0.0, 0.0, -1.0),
//!     observed: Vec::new(),
//! };
//! // "Measure" the markers on a 40 kPa block ...
//! let truth = LinearParams::from_young_poisson(4e4, 0.4)?;
//! let mut model = CorotationalModel::homogeneous(&setup.mesh, truth)?;
//! let forces = setup.nodal_forces(&example, &PatchSettings::default());
//! let mut x = setup.mesh.vertices.clone();
//! let mut solver = setup.solver(&model)?;
//! assert!(setup.simulate(&mut solver, &mut model, &mut x, &forces, &EquilibriumSettings::default()).converged());
//! example.observed = setup.marker_positions(&x).into_iter().enumerate()
//!     .map(|(marker, position_m)| ObservedMarker { marker, position_m }).collect();
//! // ... and fit eq. 9 from a 20 kPa guess: the marker error drops.
//! let guess = vec![LinearParams::from_young_poisson(2e4, 0.4)?; setup.num_elements()];
//! let fit = fit_examples(&setup, &[example], &guess, FitStart::Reference, &ExampleFitSettings::default())?;
//! assert!(fit.rms_m < 0.1 * fit.initial_rms_m[0]);
//! # Ok::<(), softcap_fem::FemError>(())
//! ```

pub mod example_fit;
pub mod footprint;
pub mod homogeneous;
pub mod lm_step;
pub mod setup;
pub mod strain_model;
pub mod strain_space;
pub mod synthesis;

pub use example_fit::{
    ExampleFit, ExampleFitSettings, FitStart, FitStop, JointFit, StepPreconditioner, fit_examples,
    marker_jacobian,
};
pub use footprint::{FaceTilt, FootprintLoad, PatchSettings};
pub use homogeneous::{
    HomogeneousFit, HomogeneousFitSettings, fit_homogeneous, fit_homogeneous_on_support,
};
pub use lm_step::{normal_product, normal_product_unblocked};
pub use setup::{ObservedMarker, ProbeExample, ProbingSetup, support_nodes};
pub use strain_model::{StrainSpaceModel, StrainSpaceSolve, StrainSpaceSolveSettings};
pub use strain_space::{
    BasisErrorStep, ElementRbf, StrainBasisSettings, StrainSample, StrainSpaceMaterial, StrainTail,
};
pub use synthesis::{
    ContactSynthesis, ContactSynthesisSettings, footprint_radius, probe_pose,
    simulate_probe_contact,
};

use softcap_fem::FemError;

/// An input or fit problem of this layer (marker embedding, samples, probe placement).
pub(crate) fn probing_error(what: impl Into<String>) -> FemError {
    FemError::Probing { what: what.into() }
}
