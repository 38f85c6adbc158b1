//! `softcap tissue reshape`: template reshaping by per-tet plastic strains (saito-barbic).
//!
//! | module | what | paper |
//! |---|---|---|
//! | [`cv`] | α̂ by k-fold cross-validation on held-out ICP markers or correspondences (`smoothness = "cv"`) | |
//! | [`problem`] | landmarks, ICP markers, attachments, closest points (parry3d) | §3.1, eq. 5 |
//! | [`laplacian`] | plastic-strain Laplacian, its null space, A⁻¹ by the singular lemma | Appendix A, §3.5 |
//! | [`equilibrium`] | Newton equilibrium under plastic strains and attachment springs | §3.2–3.3, eq. 1, 4, 7 |
//! | [`gauge`] | free-flying objects: canonical frame, its derivative, 3-2-1 pins, rigid block | §3.6–3.7, eq. 17–24 |
//! | [`step`] | Gauss–Newton step: exact by the Woodbury identity, inexact by CG preconditioned with its base; CG baseline | §3.4, eq. 8–14, Table 1 |
//! | [`solve`] | stages, line search, stopping rules → [`ReshapeOutcome`] | §3.4 |
//! | [`target`] | the TARGET folder (target.toml, CSVs, surface.obj) with file:line errors; its writer | |
//! | [`known_truth`] | the known-truth box of Fig. 21 (tests, example, benches) | Fig. 21 |
//! | [`run`](mod@run) | `softcap tissue reshape`: [`ReshapeConfig`] → reshaped.mcap (+ report) | |
//! | [`output`] | reshaped.mcap channels and report entries | |
//! | [`report`] | report.md, error histogram (Fig. 16), convergence (Fig. 9), before/after renders | |

pub mod cv;
pub mod equilibrium;
pub mod gauge;
pub mod known_truth;
pub mod laplacian;
pub mod output;
pub mod problem;
pub mod report;
pub mod run;
pub mod solve;
pub mod step;
pub mod target;

pub use cv::{
    CrossValidationReport, CrossValidationScore, CrossValidationSettings, CvRule, FoldSplit,
    HoldOut, Smoothness,
};
pub use equilibrium::{Equilibrium, EquilibriumOutcome, EquilibriumSettings, EquilibriumStatus};
pub use problem::{
    Attachment, ConstraintKind, IcpMarker, Landmark, MaterialPoint, ReshapeProblem,
    SurfaceProjector,
};
pub use run::{ReshapeConfig, ReshapeRun, run, summary_line};
pub use solve::{
    ConstraintError, FirstStep, IcpRows, IterationRecord, ReshapeOutcome, ReshapeSettings,
    ReshapeStatus, StageReport, StopReason, clamp_plastic, reshape,
};
pub use step::StepSolver;
pub use target::{LoadedTarget, TargetSpec, load_target, write_target};
