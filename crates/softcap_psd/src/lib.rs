//! `softcap_psd` — pose-space details for faces (thesis ch. 5, bickel2008).
//!
//! Large-scale motion comes from the bi-Laplacian linear shell driven by H handle vertices
//! (`softcap_mesh::shell`, thesis eq. 5.1, precomputed basis `B`); fine-scale details are learned
//! in a pose space of feature-edge strain and added at run time.
//!
//! | module | what | thesis |
//! |---|---|---|
//! | [`graph`] | handles (farthest points), feature graph, relative-stretch features, WPSD edge weights | §5.4.1, eq. 5.4 |
//! | [`animate`] | stage MCAP: handle trajectory (`/capture/markers`) in, `/face/mesh` + `/psd/large_scale` out | §5.5.2 |
//! | [`frames`] | topology, normals, per-vertex local frames (f32, parallel kernels) | §5.4.2, §5.5.2 |
//! | [`rig`] | [`FaceRig`] (shell basis + graph on a rest face), training examples, run-time [`Animator`] | §5.3, §5.5.2 |
//! | [`runtime`] | vertex-major f32 run-time layout: block low-rank basis, one-ring fans, batched detail kernel, three parallel passes | §5.5.2 |
//! | [`detail`] | PSD / WPSD fits (interpolation, least squares), greedy pose selection, evaluation | eq. 5.2, 5.3, 5.5 |
//! | [`blend`] | global and local blend-shape baselines | §5.5.1 |
//! | [`transfer`] | detail transfer by dense correspondence | §5.4.4 |
//! | [`poses`] | `SCPOSE01` pose-delta files, seeded expression mixtures | |
//! | [`experiment`] | the ICT-FaceKit Fig. 5.5 evaluation | §5.5.1 |
//! | [`render`], [`plot`] | software rasterizer and plots for the docs | |
//! | [`transfer_sheet`] | the identity-transfer renders and errors of `evaluate` | §5.4.4 |
//! | [`cli`] | the `softcap-psd` command line ([`cli::Cli::run`]) | |
//!
//! ```
//! use softcap_psd::{EdgeWeightSettings, EdgeWeights, FeatureGraph, farthest_point_handles};
//! use softcap_psd::nalgebra::Vector3;
//! // a 10×10 grid, 12 handles, 20 feature edges, ≤ 16 edges per vertex
//! let rest: Vec<_> = (0..100).map(|k| Vector3::new((k % 10) as f64, (k / 10) as f64, 0.0)).collect();
//! let handles = farthest_point_handles(&rest, 12);
//! let hp: Vec<_> = handles.iter().map(|&v| rest[v]).collect();
//! let graph = FeatureGraph::nearest_neighbours(&hp, 20);
//! let mut f = vec![0.0; graph.len()];
//! let stretched: Vec<_> = hp.iter().map(|p| Vector3::new(1.1 * p.x, p.y, p.z)).collect();
//! graph.features(&stretched, &mut f); // relative stretch per edge (§5.4.1)
//! assert!(f.iter().all(|&x| (-1e-12..=0.1 + 1e-12).contains(&x)));
//! let w = EdgeWeights::new(&rest, &hp, &graph, &EdgeWeightSettings::default());
//! assert_eq!(w.len(), 100);
//! ```

pub mod animate;
pub mod blend;
pub mod cli;
pub mod detail;
pub mod error;
pub mod experiment;
pub mod frames;
pub mod graph;
pub mod plot;
pub mod poses;
pub mod render;
pub mod rig;
pub mod runtime;
pub mod transfer;
pub mod transfer_sheet;

pub use animate::{
    AnimateSettings, AnimateSummary, HandleFrame, HandleTrajectory, animate_to_mcap,
    read_handle_csv, read_handle_trajectory, write_handle_trajectory,
};
pub use blend::{global_blend, local_blend, project_simplex, simplex_least_squares};
pub use detail::{
    DetailModel, Examples, FitMode, GreedyStep, Method, Metric, fit_psd, fit_wpsd, greedy_selection,
};
pub use error::{PsdError, Result};
pub use experiment::{Curve, EvaluationReport, EvaluationSettings, IctData, evaluate, pose_sets};
pub use frames::Topology;
pub use graph::{EdgeWeightSettings, EdgeWeights, FeatureGraph, farthest_point_handles};
pub use nalgebra;
pub use poses::{PoseDeltas, PoseRecipe, random_combinations};
pub use rig::{
    Animator, FaceRig, RigSettings, large_scale_kernel, permute_rig, reference_frame,
    shell_for_mesh, subdivide_midpoint, subdivide_rig,
};
pub use runtime::{Fans, LowRankBasis, RuntimeLayout, RuntimeSettings};
pub use softcap_mesh::{LinearShell, ShellBasis, ShellSettings};
pub use transfer::{Correspondence, identity_correspondence, transfer_details};
