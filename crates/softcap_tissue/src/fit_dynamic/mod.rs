//! `softcap tissue fit-dynamic`: deformation parameters from tracked trajectories alone
//! (wang2015 §6): Young's modulus at a few control points blended over the mesh, a shared
//! Poisson ratio, Rayleigh damping (α, β) and the rest shape X.
//!
//! | module | what | paper |
//! |---|---|---|
//! | [`sequence`] | tracked trajectories, free-motion segments, smoothed initial state and velocity | eq. 6/9 |
//! | [`forward`] | segments simulated with eq. 3 (corotational, Rayleigh, implicit Newmark), residuals | eq. 3, 9 |
//! | [`blend`] | control points, linear (axial) or harmonic weights | §6.2 |
//! | [`warm`] | modal warm start: frequencies and damping of the tracked motion on the modes | §6.3 |
//! | [`fit`] | Algorithm 1: rest shape (eq. 7–8) ↔ parameters (eq. 9), Nelder–Mead or LM | §6, Alg. 1 |
//! | [`next_pass`] | the next tracking pass's parameters: the plain loop or Anderson-accelerated | §7 |
//! | [`run`] | the commands: track.mcap → dynamic.mcap (+ JSON, report); simulate-dynamic → sim.mcap | |
//! | [`report`] | report.md, trajectories.png | |
//! | [`synthetic`] | known-truth sequences of softcap's own dynamics (tests, examples, benches) | §7, Table 1 |

pub mod blend;
pub mod fit;
pub mod forward;
pub mod next_pass;
pub mod report;
pub mod run;
pub mod sequence;
pub mod synthetic;
pub mod warm;

pub use blend::{Blending, ControlPoints, control_points};
pub use fit::{
    DynamicFit, EarlyFit, Elements, FitDynamicSettings, JacobianMethod, OBSERVABLE_CORRELATION,
    OBSERVABLE_SIGMA, Optimizer, fit_sequence, young_for_tracking,
};
pub use forward::{
    DynamicParams, FitModel, FitTiming, Forward, ForwardSettings, Near, Perturbed, StepTrack,
};
pub use next_pass::{LoopPass, anderson_next};
pub use run::{FitDynamicConfig, SimulateDynamicConfig, SimulateDynamicOutcome, simulate};
pub use sequence::{Segment, TrackedSequence};
