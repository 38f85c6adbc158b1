//! # softcap_design — materials with desired deformation behaviour (thesis ch. 8)
//!
//! Measure base materials, predict stacked composites and search for the composite whose
//! force–displacement behaviour best matches a goal (bickel2010 ch. 8).
//!
//! | module | what | thesis |
//! |---|---|---|
//! | [`material`] | isotropic RBF over strain invariants → (λ, μ); transversely isotropic RBF over strain → (E11, E12, E13, E33, E44) with PD projection | eq. 8.1, 8.2, 8.5; §8.3 |
//! | [`fit`] | base-material fit (isotropic and transversely isotropic): linear pre-fit, centres from its strains, LM over all examples, missing tangential forces | §8.3, eq. 8.3, 8.5 |
//! | [`model`] | corotational composite model with per-element E(p(ε)) | §8.2 |
//! | [`composite`] | layered 4 × 5 × 2.5 cm block, probe load, design simulation | §8.4.1, §8.5 |
//! | [`experiment`] | the §8.6 validation: random targets, search vs exhaustive optimum | §8.6 |
//! | [`output`] | design.mcap (`/design/report`), design / target JSON, force–displacement PNG | |
//! | [`print`](mod@print) | multi-material 3MF (one object per material) via `threemf` | §8.5 |
//! | [`recording`] | capture.mcap of a probed base-material block → measurements | §8.3, §8.5 |
//! | [`rubber`] | the invariant model fitted to Treloar uniaxial + Kawabata biaxial rubber data at once | eq. 8.1–8.2, §8.3 |
//! | [`search`] | branch-and-bound with clustering, exhaustive reference | §8.4.2, eq. 8.4 |
//! | [`cli`] | the `softcap-design` command line ([`cli::Cli::run`]) | |
//!
//! ```
//! use softcap_design::{BaseMaterial, InvariantMaterial, CompositeSettings, CompositeSimulator, LayeredBlock};
//! use std::sync::Arc;
//! let settings = CompositeSettings { layers: 2, forces_n: vec![1.0], ..CompositeSettings::default() };
//! let block = Arc::new(LayeredBlock::uniform(&settings)?);
//! let mats = Arc::new(vec![
//!     BaseMaterial::Isotropic(InvariantMaterial::from_young_poisson(2.0e5, 0.3)),
//!     BaseMaterial::Isotropic(InvariantMaterial::from_young_poisson(8.0e5, 0.3)),
//! ]);
//! let mut sim = CompositeSimulator::new(block, mats, &settings)?;
//! let soft_top = sim.simulate(&[1, 0])?;
//! let hard_top = sim.simulate(&[0, 1])?;
//! assert!(soft_top.probe_displacement_m[0] > 0.0 && hard_top.probe_displacement_m[0] > 0.0);
//! # Ok::<(), softcap_design::DesignError>(())
//! ```

pub mod cli;
pub mod composite;
mod error;
pub mod experiment;
pub mod fit;
pub mod material;
pub mod model;
pub mod output;
pub mod print;
pub mod recording;
pub mod rubber;
pub mod search;

pub use composite::{
    CompositeResponse, CompositeSettings, CompositeSimulator, LayeredBlock, rms_displacement_error,
};
pub use error::{DesignError, Result};
pub use experiment::{
    ExperimentReport, ExperimentSettings, ParallelEvaluator, ResponseTable, Target, TargetOutcome,
    load_or_compute_table, random_targets, read_table, reference_library, run_experiment,
    write_table,
};
pub use fit::{
    BaseFitReport, BaseFitSettings, BaseMeasurements, ProbeExample, fit_base, fit_isotropic,
    fit_transverse, simulate_block_probes, simulate_examples, simulate_positions,
    synthesize_measurements, tangential_forces,
};
pub use material::{
    BaseMaterial, InvariantMaterial, IsotropicBounds, StrainRbf, TransverseBounds,
    TransverseMaterial, TransverseParams, isotropic_matrix, project_lame, project_lame_jacobian,
    project_transverse, strain_invariant_gradient, strain_invariants, strain_tensor,
};
pub use model::{CompositeModel, ElementState};
pub use output::{
    DesignRecord, DesignTarget, design_report, plot_force_displacement, read_json,
    write_design_mcap, write_json,
};
pub use print::{PrintPart, read_design_3mf, write_design_3mf};
pub use recording::{CaptureMappingSettings, measurements_from_capture};
pub use rubber::{
    DataSetError, RubberFitReport, RubberFitSettings, RubberPoint, fit_rubber, nominal_stress,
    read_biaxial, read_uniaxial, rubber_errors,
};
pub use search::{
    AdditiveMargin, AdditiveResidual, BoundCheck, BoundMargin, BoxExcess, CellOrder,
    DesignEvaluator, LevelReport, Response, SearchReport, SearchSettings, TableEvaluator,
    additive_residual, additive_residual_of, bound_violations, box_excess, box_excess_of,
    branch_and_bound, design_from_index, design_index, exhaustive_optimum, exhaustive_table,
    point_box_distance,
};

pub use softcap_fem;
