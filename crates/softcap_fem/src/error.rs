//! The crate's error type.

/// Everything that can go wrong in `softcap_fem`. Non-convergence of an iterative solver is *not* an
/// error: it is reported in the solver's status ([`crate::SolveStatus`]).
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum FemError {
    /// Poisson ratio outside the physically valid open interval (−1, 0.5).
    #[error("Poisson ratio {nu} outside the physically valid range (-1, 0.5)")]
    InvalidPoissonRatio {
        /// offending value
        nu: f64,
    },
    /// Young's modulus must be positive and finite.
    #[error("Young's modulus {young_pa} Pa must be positive and finite")]
    InvalidYoungModulus {
        /// offending value
        young_pa: f64,
    },
    /// (λ, α) parameters of bickel2009 eq. 6 that map to no valid (E, ν).
    #[error(
        "element {element}: (lambda, alpha) = ({lambda}, {alpha}) is not a valid isotropic material (needs lambda > 0, -1 < alpha/lambda < 0.5)"
    )]
    InvalidParameters {
        /// element index (usize::MAX when not tied to an element)
        element: usize,
        /// bickel2009 λ
        lambda: f64,
        /// bickel2009 α (Lamé's first parameter)
        alpha: f64,
    },
    /// Lamé parameters with μ ≤ 0 or bulk modulus ≤ 0.
    #[error("Lame parameters (lambda = {lambda}, mu = {mu}) are not positive definite")]
    InvalidLame {
        /// Lamé's first parameter
        lambda: f64,
        /// shear modulus
        mu: f64,
    },
    /// A tet of the rest mesh is degenerate (zero volume) or has an out-of-range / non-finite vertex.
    #[error("tet {tet}: degenerate rest element (signed volume {volume_m3} m^3)")]
    DegenerateElement {
        /// tet index
        tet: usize,
        /// signed volume
        volume_m3: f64,
    },
    /// A tet references a vertex that does not exist.
    #[error("tet {tet}: vertex index {vertex} out of range (mesh has {num_vertices} vertices)")]
    VertexOutOfRange {
        /// tet index
        tet: usize,
        /// bad index
        vertex: usize,
        /// number of vertices
        num_vertices: usize,
    },
    /// A slice argument has the wrong length.
    #[error("{what}: expected length {expected}, got {got}")]
    LengthMismatch {
        /// which argument
        what: &'static str,
        /// expected length
        expected: usize,
        /// actual length
        got: usize,
    },
    /// A degree of freedom index out of range.
    #[error("degree of freedom {dof} out of range ({num_dofs} dofs)")]
    DofOutOfRange {
        /// bad dof
        dof: usize,
        /// number of dofs
        num_dofs: usize,
    },
    /// A non-finite value where a finite one is required.
    #[error("non-finite value in {what}")]
    NonFinite {
        /// which quantity
        what: &'static str,
    },
    /// A setting or model parameter outside its valid range (time step, Prony branch, density, …).
    #[error("{what} = {value} is outside its valid range")]
    InvalidSetting {
        /// which setting
        what: &'static str,
        /// offending value
        value: f64,
    },
    /// The sparse factorization failed (matrix singular or not positive definite even for LDLᵀ).
    #[error("sparse factorization failed: {reason}")]
    Factorization {
        /// faer's message
        reason: String,
    },
    /// Every degree of freedom is constrained: there is nothing to solve.
    #[error("no free degrees of freedom")]
    NoFreeDofs,
    /// A probe triangle mesh is unusable.
    #[error("probe mesh: {reason}")]
    InvalidProbe {
        /// explanation
        reason: String,
    },
    /// J2 plasticity parameters out of range (σ_y > 0, H ≥ 0).
    #[error(
        "element {element}: plasticity (yield {yield_stress_pa} Pa, hardening {hardening_modulus_pa} Pa) needs yield > 0 and hardening >= 0"
    )]
    InvalidPlasticity {
        /// element index
        element: usize,
        /// σ_y
        yield_stress_pa: f64,
        /// H
        hardening_modulus_pa: f64,
    },
    /// A plastic deformation gradient with det F_p ≤ 0 or not invertible.
    #[error("tet {tet}: plastic deformation gradient has det {det} (must be > 0)")]
    InvalidPlasticGradient {
        /// tet index
        tet: usize,
        /// det F_p
        det: f64,
    },
    /// A stiffness matrix that is not positive definite (e.g. transversely isotropic parameters).
    #[error(
        "element {element}: stiffness not positive definite (smallest eigenvalue {min_eigenvalue_pa} Pa)"
    )]
    NotPositiveDefinite {
        /// element index (usize::MAX when not tied to an element)
        element: usize,
        /// smallest eigenvalue (Mandel basis)
        min_eigenvalue_pa: f64,
    },
    /// Friction parameters out of range (μ ≥ 0, slip distance > 0).
    #[error("friction: mu = {mu} must be >= 0 and slip distance {slip_distance_m} m > 0")]
    InvalidFriction {
        /// Coulomb coefficient
        mu: f64,
        /// regularization slip
        slip_distance_m: f64,
    },
    /// A contact surface triangle that cannot carry surface quadrature (a vertex out of range, a
    /// degenerate triangle).
    #[error("contact surface triangle {triangle}: {reason}")]
    InvalidContactSurface {
        /// triangle index
        triangle: usize,
        /// explanation
        reason: String,
    },
    /// Probing-example input or fit problem (marker embedding, samples, probe placement).
    #[error("probing: {what}")]
    Probing {
        /// what is wrong
        what: String,
    },
}
