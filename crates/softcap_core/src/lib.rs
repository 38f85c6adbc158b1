//! Math with no I/O that every softcap stage stands on.
//!
//! | module | what | paper |
//! |---|---|---|
//! | [`camera`] | pinhole camera with OpenCV Brown–Conrady distortion: project, Jacobian, undistort, rays | docs/session-format.md |
//! | [`rbf`] | RBF interpolation / least-squares fit, kernels r and r³, none/linear/quadratic tail, greedy centres | thesis eq. 4.1, bickel2009 eq. 8, §4.2 |
//! | [`least_squares`] | problem trait, bounds, finite differences, solver status and report | |
//! | [`levenberg_marquardt`](mod@levenberg_marquardt) | bounded Levenberg–Marquardt (projected active-set steps) | bickel2009 §4.1 |
//! | [`gauss_newton`](mod@gauss_newton) | dense Gauss–Newton with step-halving (Armijo) line search | |
//! | [`brent`] | Brent's bounded one-dimensional minimization (parabolic + golden section) | Brent 1973; saito-barbic §3.4 line search |
//! | [`rigid`] | weighted absolute orientation (rigid registration) | Horn 1987 |
//! | [`nelder_mead`](mod@nelder_mead) | adaptive Nelder–Mead simplex, bounds by clamping | wang2015 |
//! | [`kmeans`](mod@kmeans) | seeded k-means++ / Lloyd; k-medoids for custom dissimilarities | thesis §8.3 eq. 8.4 |
//! | [`bspline`] | uniform cubic B-spline curves, weighted least-squares fit | thesis §4.3.1 eq. 4.2 |
//! | [`polar`] | robust 3×3 polar decomposition F = R S (near-inverted elements included) | Irving et al. 2004 |
//! | [`error`] | [`CoreError`], the crate's one error type | |
//!
//! ```
//! use softcap_core::{Rbf, RbfSettings, ScatteredData};
//! // Interpolate f(x, y) = (x + 2y, 3 − y) from five samples with φ(r) = r³ + quadratic tail.
//! let points = [0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 1.0, 1.0, 0.5, 0.2, 0.3, 0.9];
//! let values: Vec<f64> = points.chunks(2).flat_map(|p| [p[0] + 2.0 * p[1], 3.0 - p[1]]).collect();
//! let data = ScatteredData::new(&points, 2, &values, 2)?;
//! let rbf = Rbf::interpolate(&data, &RbfSettings::default())?;
//! let y = rbf.evaluate(&[0.25, 0.75])?;
//! assert!((y[0] - 1.75).abs() < 1e-10 && (y[1] - 2.25).abs() < 1e-10);
//! # Ok::<(), softcap_core::CoreError>(())
//! ```

pub mod brent;
pub mod bspline;
pub mod camera;
mod dense;
pub mod error;
pub mod gauss_newton;
pub mod kmeans;
pub mod least_squares;
pub mod levenberg_marquardt;
pub mod nelder_mead;
pub mod polar;
pub mod rbf;
pub mod rigid;

pub use brent::{BrentMinimum, BrentSettings, minimize_bounded};
pub use bspline::{BSplineFitSettings, UniformCubicBSpline, fit_uniform_cubic_bspline};
pub use camera::{Camera, CameraTable};
pub use error::{CoreError, Result};
pub use gauss_newton::{GaussNewtonSettings, gauss_newton};
pub use kmeans::{KMeansResult, KMeansSettings, KMedoidsResult, kmeans, kmedoids};
pub use least_squares::{
    Bounds, ConvergenceReason, FiniteDifference, LeastSquaresProblem, LeastSquaresReport,
    SolverStatus,
};
pub use levenberg_marquardt::{DampingScaling, LevenbergMarquardtSettings, levenberg_marquardt};
pub use nelder_mead::{NelderMeadReport, NelderMeadSettings, nelder_mead};
pub use polar::{Polar, polar_decomposition};
pub use rbf::{
    GreedyErrorMeasure, GreedyRbfReport, GreedyRbfSettings, GreedyStatus, GreedyStep,
    PolynomialTail, Rbf, RbfKernel, RbfSettings, ScatteredData, greedy_rbf,
};
pub use rigid::horn_weighted;

pub use faer;
pub use nalgebra;
