//! softcap face stage (thesis ch. 3–4, bickel2007): a static face scan animated by mocap markers,
//! with medium-scale expression wrinkles measured from video and synthesized onto the animation.
//!
//! | module | what | thesis |
//! |---|---|---|
//! | [`cross_section`] | wrinkle profile S(w,d,p), visible-wedge ambient integral with exact ∂/∂d, ∂/∂w | §4.3.2 eq. 4.3–4.4 |
//! | [`track`] | PCA + weighted cubic B-spline valley (eq. 4.2), per-cross-section (d, w) by Gauss–Newton on eq. 4.4 | §4.3.1–4.3.2 |
//! | [`pooled`] | one (d, w) profile per wrinkle and frame: eq. 4.4 over all its cross-sections, with its covariance | §4.3.2 eq. 4.3–4.4 |
//! | [`mocap`] | AnimFace CSV reader | §3.2 m_{i,t} |
//! | [`landmarks`] | marker → scan-vertex table (ICP registration + closest vertex) | §4.2.1 f_{i,0} |
//! | [`correspondence`] | space warp c(x) = Σ w_i ‖x − c_i‖³ + q(x), u_{i,t} = c(m_{i,t}) − f_{i,0} | §4.2.1 eq. 4.1 |
//! | [`animate`] | bi-Laplacian linear shell driven by the marker displacements | §3.2.1 eq. 3.3 |
//! | [`raster`] | z-buffer software rasterizer for figures | |
//! | [`render`] | ground-truth wrinkle video: Monte-Carlo ambient occlusion on a 3D height field | test renderer |
//! | [`synth`] | 3D wrinkle synthesis: camera projection, valley offset, discrete-shell energy by Gauss–Newton | §3.3.1 eq. 3.6 |
//! | [`removal`] | wrinkle removal preprocess: detail split, bi-Laplacian patch, details back | §3.3.2 |
//! | [`output`] | stage MCAP: `/face/mesh` per frame, `/face/wrinkles`, `/viz` twins | |
//! | [`take`] | a face take on disk: cameras.toml, `frames/<camera>/<frame>.png`, labels, mocap | |
//! | [`take_report`] | `face track --report`: tracked splines over frames, (d, w) over time (PNG) | |
//! | [`take_track`] | `face track`: a take → wrinkles on the animated face, `wrinkles.mcap` writer and reader | §4.3, §3.3.1 |
//! | [`video`] | wrinkle tracking over a camera's frames: label patches, association, visibility | §4.3 |
//! | [`take_synth`] | a rendered take with known moving, appearing and occluded wrinkles | test data |
//! | [`classify`] | per-colour RBF-kernel SVM pixel classification (smartcore) | §4.3.1 |
//! | [`morphology`] | erosion, dilation, opening, closing, connected components | §4.3.1 |
//! | [`image`] | [`RgbImage`] (linear float RGB, PNG out) | |
//! | [`error`] | [`FaceError`] | |
//!
//! ```
//! use softcap_face::{HorizonSettings, ambient_ratio, wrinkle_profile};
//! // The valley bottom of S(w, d, p) is at −d; the crest at |p| = 2w sees the whole sky.
//! assert!((wrinkle_profile(4.0, 2.0, 0.0) + 2.0).abs() < 1e-12);
//! let crest = ambient_ratio(4.0, 2.0, 8.0, &HorizonSettings::default());
//! assert!((crest.ratio - 1.0).abs() < 1e-9);
//! ```

pub mod animate;
pub mod classify;
pub mod cli;
pub mod correspondence;
pub mod cross_section;
pub mod error;
pub mod image;
pub mod landmarks;
pub mod mocap;
pub mod morphology;
pub mod output;
pub mod pooled;
pub mod raster;
pub mod removal;
pub mod render;
pub mod synth;
pub mod take;
pub mod take_report;
pub mod take_synth;
pub mod take_track;
pub mod track;
pub mod video;

pub use animate::{FaceAnimator, factor_shell, subdivide_midpoint};
pub use classify::{SvmSettings, classify_frames};
pub use correspondence::Correspondence;
pub use cross_section::{
    HorizonSearch, HorizonSettings, Shading, UnitHorizons, ambient_ratio, wedge_shading,
    wrinkle_profile, wrinkle_profile_slope,
};
pub use error::{FaceError, Result};
pub use image::RgbImage;
pub use landmarks::{Landmark, derive_landmarks, landmarks_csv, parse_landmarks_csv};
pub use mocap::{MocapTake, parse_animface_csv, read_animface_csv};
pub use nalgebra;
pub use output::{FaceFrame, FrameWrinkles, WrinkleInput, wrinkles_message, write_face_mcap};
pub use pooled::{
    FrameEstimate, PoolSettings, PooledFit, PooledProfile, SectionSamples, TimeModel,
    estimate_time_noise, fit_pooled, smooth_in_time,
};
pub use raster::{OrthoView, render_mesh, vertex_normals};
pub use removal::{RemovalSettings, remove_wrinkles};
pub use render::{
    AoRenderSettings, AoSurface, CompositeScene, Occluder, RenderedFrame, WrinkleScene,
    render_ambient_occlusion,
};
pub use synth::{
    DiscreteShell, PinholeCamera, ProjectedWrinkle, RegionReport, SynthesisResult,
    SynthesisSettings, WrinkleCurve, WrinkleSample, project_wrinkle, smoothed_normals,
    synthesize_wrinkles, validate_wrinkles,
};
pub use track::{
    CrossSection, TrackSettings, TrackedWrinkle, ValleySpline, fit_cross_section, track_wrinkle,
};
