//! # softcap_fem — tet FEM for soft-tissue capture
//!
//! The simulator the fitting stages stand on (bickel2009 §3 and appendix).
//!
//! | module | what | paper |
//! |---|---|---|
//! | [`material`] | (λ, α) parameters, G and H, (E, ν) and Lamé conversions; stable neo-Hookean parameters | bickel2009 eq. 2–6; Smith 2018 §3.4 |
//! | [`element`] | tet geometry, B_e, K_e = λ V BᵀGB + α V BᵀHB, corotational force R K (Rᵀx − X), warped and consistent stiffness | bickel2009 eq. 7; Müller & Gross 2004 |
//! | [`neohookean`] | stable neo-Hookean Ψ, PK1, ∂P/∂F, element force and tangent | Smith, de Goes & Kim 2018 |
//! | [`model`] | whole-mesh models, strain-dependent parameter hook p_e(ε_e) | bickel2009 §3.3–3.4 |
//! | [`assembly`] | Dirichlet elimination, faer sparse pattern, sparse Cholesky (symbolic once, many solves) | bickel2009 appendix |
//! | [`statics`] | equilibrium iterations, incremental loading, Newton with line search, eq. 10 with frozen rotations | bickel2009 §3.4, eq. 10 |
//! | [`contact`] | rigid probes (sphere, disk, cylinder, mesh) via parry3d, penalty linear force field | bickel2009 §3.4 |
//! | [`gravity`] | lumped masses m_a = Σ ρV_e/4, body force M g, rest shape X from a static shape: R K (Rᵀx_s − X) = M g by Newton with exact ∂f/∂X (corotational and neo-Hookean) | wang2015 §3, §6.1 eq. 3, 7–8 |
//! | [`viscoelastic`] | Prony series G(t)/G_∞ = 1 + Σ g_i e^{−t/τ_i} as QLV on the element stress in the unrotated frame, P = R(T + Σh_i), exact exponential recurrence h ← a h + b ΔT | Simo & Hughes 1998 §10.3; Puso & Weiss 1998 |
//! | [`dynamics`] | M ẍ + D ẋ + f_int(x) = f_ext, lumped M, Rayleigh D = αM + βK; implicit Euler (A = M/h² + D/h + K) and Newmark average acceleration (A = 4M/h² + 2D/h + K), Newton per step, probe contact, node-level terms (tracking's virtual forces, wang2015 eq. 5) | wang2015 eq. 3 |
//! | [`modal`] | smallest K φ = λ M φ: dense M^{-1/2} K M^{-1/2} eigen; shift-invert Lanczos on (K − σM)⁻¹M with locking/restarts for repeated (rigid-body) modes | wang2015 §7 |
//! | [`derivatives`] | ∂K/∂p, J = ∂x/∂p (columns, adjoint rows, Jᵀr) | bickel2009 appendix eq. 10–12 |
//! | [`anisotropy`] | transversely isotropic E with five parameters {E11, E12, E13, E33, E44} and a per-element fibre, σ = C ε on the corotated strain; E_a = E33 − 2E13²/(E11+E12); PD check and Mandel eigenvalue clipping | thesis §8.5 eq. 8.5; Rebonato & Jäckel 1999 |
//! | [`friction`] | regularized Coulomb at the probe: f_t = −μ f_n s(‖δ‖/ε) δ/‖δ‖, s(r) = 2r − r² (r < 1), 1 after; stick anchors in the probe frame, dragged to ε on commit | Li et al. 2020 (IPC) §5.1 f₁ mollifier; bickel2009 §3.4 contact |
//! | [`support`] | support slip: attached face on a plane ν·x = d, bilateral normal penalty, tangential springs −k_t P(x − a) or regularized Coulomb | issue 4 (support slip) |
//! | [`nodal`] | equilibrium with node-level terms (frictional contact, supports): A Δx = f_ext + Σ f_b − f_int | bickel2009 §3.4 iterations |
//! | [`quadratic`] | 10-node corotational tets (4-point rule, element rotation at the centroid), their implicit dynamics, statics and subspace-iteration modes | wang2015 §7 (coarse-mesh stiffness); Müller & Gross 2004 |
//! | [`plasticity`] | (a) additive J2 plastic strain on the corotational element, f = ‖dev σ‖ − √(2/3)(σ_y + Hᾱ), radial return + algorithmic tangent, permanent set ε_p = (Eε_max − σ_y)/(E + H) in 1D; (b) multiplicative F_e = F F_p⁻¹ on stable neo-Hookean, E_e = V det F_p Ψ(F_e) | Simo & Hughes 1998 Box 3.1–3.2; saito-barbic §3.2 eq. 1–2 |
//!
//! ```
//! use softcap_fem::{CorotationalModel, DirichletBc, EquilibriumSettings, LinearParams, StaticSolver};
//! use softcap_fem::nalgebra::Vector3;
//! let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [1.0, 0.2, 0.2], [5, 1, 1]);
//! let mut model = CorotationalModel::homogeneous(&mesh, LinearParams::from_young_poisson(1e4, 0.3)?)?;
//! let mut bc = DirichletBc::new();
//! for (i, v) in mesh.vertices.iter().enumerate() {
//!     if v.x == 0.0 { bc.fix_node(i, *v); }
//! }
//! let mut solver = StaticSolver::with_bc(&model, &bc)?;
//! let mut x = mesh.vertices.clone();
//! let mut f = vec![Vector3::zeros(); x.len()];
//! for (i, v) in mesh.vertices.iter().enumerate() {
//!     if v.x == 1.0 { f[i].z = -0.01; }
//! }
//! let report = solver.solve(&mut model, &mut x, &f, None, &EquilibriumSettings::default());
//! assert!(report.converged());
//! # Ok::<(), softcap_fem::FemError>(())
//! ```

pub mod anisotropy;
pub mod assembly;
pub mod contact;
mod corotated;
pub mod derivatives;
pub mod dynamics;
pub mod element;
mod error;
pub mod friction;
pub mod gravity;
pub mod material;
pub mod modal;
pub mod model;
pub mod neohookean;
pub mod nodal;
pub mod plasticity;
pub mod quadratic;
pub mod quadratic_plasticity;
pub mod statics;
pub mod support;
pub mod viscoelastic;

pub use anisotropy::{
    AnisotropicModel, FibreFamily, TransverselyIsotropicParams, fibre_family_stiffness,
    material_frame, stiffness_in_frame, symmetric_fibre_pair, voigt_dyad,
};
pub use assembly::{DirichletBc, DofMap, FactorKind, SparseCholesky, SystemPattern};
pub use contact::{ContactProblem, ContactReport, ContactSettings, ContactSpring, Probe, TipShape};
pub use derivatives::{Sensitivity, alpha_index, element_stiffness_derivative, lambda_index};
pub use element::{
    CorotationalStepFrame, Matrix12, StiffnessKind, TetGeometry, corotated_strain,
    corotational_forces, corotational_parameter_forces, corotational_step_differential,
    corotational_step_frame, corotational_step_warped_product, corotational_tangent,
    element_stiffness, stiffness_basis, strain_voigt, tet_geometries, warped_stiffness,
};
pub use error::FemError;
pub use friction::{
    ContactDiscretisation, FrictionParams, FrictionReport, FrictionalContact, LaggedIterations,
    LaggedSolve, NormalForceLag, mollifier, regularized_coulomb, solve_lagged,
};
pub use material::{LinearParams, NeoHookeanParams, matrix_g, matrix_h};
pub use model::{
    CorotationalModel, ElasticModel, NeoHookeanModel, StepTangent, StrainDependentParams,
    with_serial_element_loops,
};
pub use neohookean::{
    energy_density, neohookean_energy, neohookean_forces, neohookean_tangent, pk1, pk1_derivative,
};
pub use nodal::{NodalSolver, NodalTerm};
pub use plasticity::{
    ElastoplasticModel, J2PlasticityParams, PlasticNeoHookeanModel, PlasticState, ReturnMapping,
    plastic_from_vector, plastic_to_vector, radial_return,
};
pub use statics::{
    EquilibriumReport, EquilibriumSettings, IncrementalReport, IncrementalSettings, LoadState,
    Refactorization, SolveStatus, StaticSolver, StepReport, incremental_loading,
};
pub use support::{SupportPlane, SupportReport, SupportTangential};

pub use gravity::{
    RestShape, RestShapeModel, RestShapeReport, RestShapeSettings, RestShapeStatus,
    STANDARD_GRAVITY_M_S2, VirtualForceSettings, element_rest_jacobian, gravity_forces,
    lumped_masses, lumped_masses_per_element, rest_shape_sensitivities, solve_rest_shape,
    solve_rest_shape_virtual_force,
};
pub use viscoelastic::{
    PronyBranch, PronySeries, ViscoelasticModel, viscoelastic_quasi_static_step,
};

pub use dynamics::{
    DynamicSolver, DynamicState, DynamicStepReport, DynamicStepStatus, DynamicsSettings,
    Integrator, RayleighDamping, SensitivitySettings, StepLoads,
};
pub use modal::{LanczosModes, LanczosReport, ModalSettings, Modes, dense_modes, lanczos_modes};
pub use quadratic::{
    QuadraticModel, QuadraticSolver, QuadraticTetMesh, quadratic_tets, shape_functions,
};
pub use quadratic_plasticity::{QuadraticElastoplasticModel, QuadraticRigidTipSolver};

pub use faer;
pub use nalgebra;
pub use parry3d;
