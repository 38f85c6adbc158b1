//! Bridge to `softcap_core`'s Levenberg–Marquardt (pending).
use nalgebra::Point3;

use crate::camera::Camera;
use crate::triangulate::PixelObservation;

pub(crate) fn refine_point(_cameras: &[Camera], _obs: &[PixelObservation], x0: Point3<f64>, _max_iterations: usize) -> Point3<f64> {
    x0
}
