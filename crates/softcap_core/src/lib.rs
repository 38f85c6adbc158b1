//! Math with no I/O that every softcap stage stands on.
//!
//! | module | what |
//! |---|---|
//! | [`polar`] | robust 3×3 polar decomposition F = R S (near-inverted elements included) |
//!
//! ```
//! use softcap_core::{nalgebra::Matrix3, polar_decomposition};
//! let f = Matrix3::new(2.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0);
//! let p = polar_decomposition(&f);
//! assert!((p.rotation - Matrix3::identity()).norm() < 1e-12);
//! ```

pub mod polar;

pub use nalgebra;
pub use polar::{Polar, polar_decomposition};
