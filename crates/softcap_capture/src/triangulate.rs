//! Multi-view triangulation: linear DLT on undistorted normalized coordinates (Hartley & Zisserman
//! §12.2), then Levenberg–Marquardt refinement of the pixel reprojection error through the full
//! distortion model.

use nalgebra::{DMatrix, Matrix4, Point3, Vector2, Vector4};
use serde::{Deserialize, Serialize};

use crate::camera::Camera;

/// One 2D observation of a point: camera index and pixel position.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PixelObservation {
    /// Index into the camera list.
    pub camera: usize,
    /// Pixel position `(u, v)`.
    pub uv: Vector2<f64>,
}

/// Settings of [`triangulate`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TriangulationSettings {
    /// Refine the DLT estimate by Levenberg–Marquardt on the reprojection error.
    pub refine: bool,
    /// Maximum LM iterations.
    pub max_iterations: usize,
}

impl Default for TriangulationSettings {
    fn default() -> Self {
        TriangulationSettings {
            refine: true,
            max_iterations: 20,
        }
    }
}

/// A triangulated point.
#[derive(Debug, Clone, PartialEq)]
pub struct Triangulated {
    /// Position, world frame, m.
    pub position_m: Point3<f64>,
    /// Number of views used.
    pub views: usize,
    /// RMS reprojection error over the views, px.
    pub reprojection_rms_px: f64,
    /// Largest reprojection error over the views, px.
    pub reprojection_max_px: f64,
}

/// Linear triangulation (DLT): for each view with normalized projection `P = [R|t]` and undistorted
/// normalized point `(x, y)`, the rows `x·P₃ − P₁` and `y·P₃ − P₂`; the point is the right singular
/// vector of the smallest singular value. Returns `None` with fewer than two views or a degenerate
/// configuration (point at infinity).
pub fn triangulate_dlt(cameras: &[Camera], obs: &[PixelObservation]) -> Option<Point3<f64>> {
    if obs.len() < 2 {
        return None;
    }
    // Accumulate AᵀA (4×4) to avoid a tall SVD; the eigenvector of the smallest eigenvalue is the solution.
    let mut ata = Matrix4::<f64>::zeros();
    for o in obs {
        let cam = &cameras[o.camera];
        let n = cam.undistort(o.uv.x, o.uv.y);
        let p = cam.normalized_projection();
        let r1: Vector4<f64> = (p.row(2) * n.x - p.row(0)).transpose();
        let r2: Vector4<f64> = (p.row(2) * n.y - p.row(1)).transpose();
        ata += r1 * r1.transpose() + r2 * r2.transpose();
    }
    let eig = ata.symmetric_eigen();
    let k = eig.eigenvalues.imin();
    let h = eig.eigenvectors.column(k);
    if h[3].abs() < 1e-12 {
        return None;
    }
    let p = Point3::new(h[0] / h[3], h[1] / h[3], h[2] / h[3]);
    p.coords.iter().all(|v| v.is_finite()).then_some(p)
}

/// Stacked pixel residuals `π_c(X) − u_c` and their Jacobian (2n × 3). `None` if the point is behind a camera.
pub fn reprojection_residuals(
    cameras: &[Camera],
    obs: &[PixelObservation],
    x: &Point3<f64>,
) -> Option<(Vec<f64>, DMatrix<f64>)> {
    let mut r = Vec::with_capacity(2 * obs.len());
    let mut j = DMatrix::zeros(2 * obs.len(), 3);
    for (i, o) in obs.iter().enumerate() {
        let (uv, jac) = cameras[o.camera].project_with_jacobian(x)?;
        r.push(uv.x - o.uv.x);
        r.push(uv.y - o.uv.y);
        j.view_mut((2 * i, 0), (2, 3)).copy_from(&jac);
    }
    Some((r, j))
}

fn error_stats(cameras: &[Camera], obs: &[PixelObservation], x: &Point3<f64>) -> (f64, f64) {
    let mut sum = 0.0;
    let mut max: f64 = 0.0;
    for o in obs {
        let e = cameras[o.camera]
            .project(x)
            .map(|uv| (uv - o.uv).norm())
            .unwrap_or(f64::INFINITY);
        sum += e * e;
        max = max.max(e);
    }
    ((sum / obs.len() as f64).sqrt(), max)
}

/// Triangulates one point from two or more views: DLT, then (optionally) Levenberg–Marquardt on the
/// pixel reprojection error `Σ_c |π_c(X) − u_c|²` with the full distortion model.
pub fn triangulate(
    cameras: &[Camera],
    obs: &[PixelObservation],
    settings: &TriangulationSettings,
) -> Option<Triangulated> {
    let mut x = triangulate_dlt(cameras, obs)?;
    if settings.refine {
        x = refine_lm(cameras, obs, x, settings.max_iterations);
    }
    let (rms, max) = error_stats(cameras, obs, &x);
    rms.is_finite().then_some(Triangulated {
        position_m: x,
        views: obs.len(),
        reprojection_rms_px: rms,
        reprojection_max_px: max,
    })
}

fn refine_lm(
    cameras: &[Camera],
    obs: &[PixelObservation],
    x0: Point3<f64>,
    max_iterations: usize,
) -> Point3<f64> {
    crate::lm::refine_point(cameras, obs, x0, max_iterations)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Rotation3, Vector3};

    pub(crate) fn ring(n: usize) -> Vec<Camera> {
        (0..n)
            .map(|i| {
                let a = i as f64 * std::f64::consts::TAU / n as f64;
                let centre = Vector3::new(0.3 * a.cos(), 0.3 * a.sin(), 0.25);
                let z = (-centre).normalize();
                let x = z.cross(&Vector3::z()).normalize();
                let y = z.cross(&x);
                let r = Rotation3::from_matrix_unchecked(nalgebra::Matrix3::from_rows(&[
                    x.transpose(),
                    y.transpose(),
                    z.transpose(),
                ]))
                .into_inner();
                Camera::new(
                    format!("c{i}"),
                    640,
                    480,
                    [700.0, 701.0, 320.0, 240.0],
                    [-0.05, 0.008, 1e-4, -1e-4, 0.0],
                    r,
                    -(r * centre),
                )
                .unwrap()
            })
            .collect()
    }

    #[test]
    fn noise_free_points_are_recovered_exactly() {
        let cams = ring(3);
        let p = Point3::new(0.01, -0.005, 0.02);
        let obs: Vec<_> = (0..3)
            .map(|c| PixelObservation {
                camera: c,
                uv: cams[c].project(&p).unwrap(),
            })
            .collect();
        let dlt = triangulate_dlt(&cams, &obs).unwrap();
        assert!((dlt - p).norm() < 1e-9, "{}", (dlt - p).norm());
        let t = triangulate(&cams, &obs, &TriangulationSettings::default()).unwrap();
        assert!((t.position_m - p).norm() < 1e-10);
        assert!(t.reprojection_rms_px < 1e-6);
    }

    #[test]
    fn lm_reduces_reprojection_error_of_noisy_points() {
        let cams = ring(4);
        let p = Point3::new(-0.01, 0.015, 0.005);
        let noise = [0.4, -0.3, 0.2, 0.5, -0.6, 0.1, 0.3, -0.2];
        let obs: Vec<_> = (0..4)
            .map(|c| PixelObservation {
                camera: c,
                uv: cams[c].project(&p).unwrap() + Vector2::new(noise[2 * c], noise[2 * c + 1]),
            })
            .collect();
        let dlt = triangulate_dlt(&cams, &obs).unwrap();
        let (rms_dlt, _) = error_stats(&cams, &obs, &dlt);
        let t = triangulate(&cams, &obs, &TriangulationSettings::default()).unwrap();
        assert!(
            t.reprojection_rms_px <= rms_dlt + 1e-12,
            "{} > {}",
            t.reprojection_rms_px,
            rms_dlt
        );
        // First-order optimality: Jᵀr = 0 at the refined point.
        let (r, j) = reprojection_residuals(&cams, &obs, &t.position_m).unwrap();
        let g = j.transpose() * nalgebra::DVector::from_vec(r);
        assert!(g.norm() < 1e-3, "gradient {}", g.norm());
        assert!((t.position_m - p).norm() < 1e-3);
    }
}
