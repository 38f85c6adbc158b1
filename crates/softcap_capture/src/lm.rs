//! Point refinement by `softcap_core`'s Levenberg–Marquardt on the pixel reprojection error.
use nalgebra::{DMatrix, Point3};
use softcap_core::{LeastSquaresProblem, LevenbergMarquardtSettings, levenberg_marquardt};

use crate::camera::Camera;
use crate::triangulate::PixelObservation;

struct Reprojection<'a> {
    cameras: &'a [Camera],
    obs: &'a [PixelObservation],
}

impl LeastSquaresProblem for Reprojection<'_> {
    fn num_params(&self) -> usize {
        3
    }
    fn num_residuals(&self) -> usize {
        2 * self.obs.len()
    }
    fn residuals(&mut self, p: &[f64], r: &mut [f64]) {
        let x = Point3::new(p[0], p[1], p[2]);
        for (i, o) in self.obs.iter().enumerate() {
            // Behind a camera: a large finite residual so LM rejects the step.
            let uv = self.cameras[o.camera]
                .project(&x)
                .unwrap_or(o.uv.add_scalar(1e6));
            r[2 * i] = uv.x - o.uv.x;
            r[2 * i + 1] = uv.y - o.uv.y;
        }
    }
    fn jacobian(&mut self, p: &[f64], j: &mut DMatrix<f64>) -> bool {
        let x = Point3::new(p[0], p[1], p[2]);
        for (i, o) in self.obs.iter().enumerate() {
            match self.cameras[o.camera].project_with_jacobian(&x) {
                Some((_, jac)) => j.view_mut((2 * i, 0), (2, 3)).copy_from(&jac),
                None => j.view_mut((2 * i, 0), (2, 3)).fill(0.0),
            }
        }
        true
    }
}

/// Minimises `Σ_c |π_c(X) − u_c|²` from `x0`; returns `x0` unchanged if the solver fails on input.
pub(crate) fn refine_point(
    cameras: &[Camera],
    obs: &[PixelObservation],
    x0: Point3<f64>,
    max_iterations: usize,
) -> Point3<f64> {
    let mut problem = Reprojection { cameras, obs };
    let settings = LevenbergMarquardtSettings {
        max_iterations,
        ..Default::default()
    };
    match levenberg_marquardt(&mut problem, x0.coords.as_slice(), None, &settings) {
        Ok(rep) if rep.params.iter().all(|v| v.is_finite()) => {
            Point3::new(rep.params[0], rep.params[1], rep.params[2])
        }
        _ => x0,
    }
}
