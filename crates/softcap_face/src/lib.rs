//! softcap face stage (thesis ch. 3–4, bickel2007): a static face scan animated by mocap markers,
//! with medium-scale expression wrinkles measured from video and synthesized onto the animation.
//!
//! | module | what | thesis |
//! |---|---|---|
//! | [`cross_section`] | wrinkle profile S(w,d,p), visible-wedge ambient integral with exact ∂/∂d, ∂/∂w | §4.3.2 eq. 4.3–4.4 |
//! | [`render`] | ground-truth wrinkle video: Monte-Carlo ambient occlusion on a 3D height field | test renderer |
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

pub mod classify;
pub mod cross_section;
pub mod error;
pub mod image;
pub mod morphology;
pub mod render;

pub use classify::{SvmSettings, classify_frames};
pub use cross_section::{
    HorizonSettings, Shading, UnitHorizons, ambient_ratio, wedge_shading, wrinkle_profile,
    wrinkle_profile_slope,
};
pub use error::{FaceError, Result};
pub use image::RgbImage;
pub use nalgebra;
pub use render::{AoRenderSettings, RenderedFrame, WrinkleScene, render_ambient_occlusion};
