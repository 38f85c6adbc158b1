//! The model simulator the diagnosis compares a recording with.
//!
//! [`ProbeSimulator`] is the contract: quasi-static marker positions under one probe load (force
//! applied over the contact patch around the tip, bickel2009 §4.1 force boundary condition) plus an
//! optional body force (gravity, wang2015 eq. 7), and the tangent response ∂x_markers/∂f of the
//! converged state (three columns, one per force axis), which the hypothesis machinery uses for its
//! linearised refits. [`FemProbeSimulator`] implements it on a `softcap_fem` corotational model
//! through the shared probing kernels of `softcap_probing` (the ones the tissue fit uses):
//! marker embedding, attached region, contact patch and area-weighted nodal forces.
//!
//! The extended models ([`Extension`]): the default model with one physical term added, from the
//! FEM physics of `softcap_fem`, re-simulated over the whole recording in time order (history-dependent terms
//! need the sequence: creep, plastic flow, stick of the support).
//!
//! | extension | `softcap_fem` model | parameters |
//! |---|---|---|
//! | [`Extension::Viscoelastic`] | `ViscoelasticModel` over the default corotational model, one Prony branch G(t)/G∞ = 1 + g e^{−t/τ} (generalized Maxwell, Simo & Hughes 1998 §10.3), exact exponential recurrence between frames | g, τ |
//! | [`Extension::Plastic`] | `ElastoplasticModel` (J2 radial return on the corotational element, Simo & Hughes 1998 Box 3.1–3.2), the default model's (λ, α) per element, state committed after every frame | σ_y, H |
//! | [`Extension::PlasticPoisson`] | as above with the Poisson ratio of every element replaced (Young's modulus kept) | σ_y, H, ν |
//! | [`Extension::SupportSprings`] | `SupportPlane` with tangential springs on the attached nodes instead of fixed nodes (bilateral normal penalty), `NodalSolver` | total tangential stiffness k |
//! | [`Extension::Anisotropic`] | `AnisotropicModel`, transversely isotropic (thesis eq. 8.5) with the default model's isotropic (E, ν) across the fibre and E_a = r E along it | fibre a, ratio r |
//! | [`Extension::FibreFamilies`] | `AnisotropicModel::with_fibre_families`: the default model's isotropic (E, ν) plus two HGO fibre families at ±θ (HGO 2000 §4.2, linearized), each 4 k1 = r E | fibres a±, ratio r |
//! | [`Extension::TransverselyIsotropic`] | `AnisotropicModel` as above with the Poisson ratios fitted too: ν_t across the fibre, ν_a fibre–transverse (thesis eq. 8.5, `TransverselyIsotropicParams::from_engineering`) | fibre a, ratio r, ν_t, ν_a |
//! | [`Extension::ProbeFriction`] | the default model with regularized Coulomb friction between the rigid tip and the surface (`FrictionalContact`, IPC f₁ mollifier, stick anchors, normal forces lagged per solve and re-lagged until they settle, `softcap_fem::solve_lagged`), `NodalSolver`; rigid-tip replay only | μ |
//! | [`Extension::Dynamic`] | the default model's implicit dynamics M ü + D u̇ + f_int(u) = f_ext with lumped mass of density ρ and Rayleigh damping D = αM + βK (wang2015 eq. 3), `DynamicSolver`, Newmark average acceleration, [`DYNAMIC_STEPS_PER_FRAME`] steps per frame interval, the measured force interpolated linearly between frames; the Lamé ratio λ_L/μ scaled at fixed E ([`with_lame_ratio`]) | ρ, α, β, λ_L/μ factor |
//! | [`Extension::Elastic`] | the default model itself (used with changed loads: gravity body force wang2015 eq. 7, shifted / de-lagged forces) | — |
//!
//! The probe force of every frame is spread over its contact patch exactly as in the baseline
//! (bickel2009 §4.1 force boundary condition, [`FemProbeSimulator::probe_forces`]), or —
//! [`FemProbeSimulator::simulate_sequence_rigid_tip`] — the probe is replayed as the rigid tip of
//! the session at each frame's measured pose (bickel2009 §3.4 rigid-probe contact, penalty
//! springs of `softcap_fem::contact`): position control, so the stress under the tip rim is the
//! one the tip's geometry imposes (a J2 material yields there as it did in the recording) rather
//! than the uniform pressure of the force boundary condition.

mod contract;
mod extend;
mod fem;
mod quadratic;
mod resolution;

pub use contract::{
    Extension, Field, LoadPoint, MarkerMode, MaterialRefit, MaterialRefitOutcome, ProbeLoad,
    ProbeSimulator, SequenceFrame, SequenceJob, SimLoad, SimOutput,
};
pub use extend::{
    DYNAMIC_STEPS_PER_FRAME, transverse_from_isotropic, transverse_with_poisson, with_lame_ratio,
};
pub use fem::{FemProbeSimulator, FemSimSettings, RefinementSettings};
pub use resolution::{friction_refinement, friction_slip_distance_m, surface_spacing_near};
