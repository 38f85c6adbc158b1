//! Pinhole camera with OpenCV Brown–Conrady distortion, exactly as in `docs/session-format.md`
//! (pure math, no I/O: reading `rig/cameras.toml` is its readers' job — [`CameraTable`] is one
//! `[[camera]]` table as deserialized — writing it [`cameras_toml`]'s):
//!
//! `Xc = R·X + t`, `x = Xc.x/Xc.z`, `y = Xc.y/Xc.z`, `r² = x²+y²`,
//! `xd = x(1+k1 r²+k2 r⁴+k3 r⁶) + 2 p1 x y + p2 (r²+2x²)`,
//! `yd = y(1+k1 r²+k2 r⁴+k3 r⁶) + p1 (r²+2y²) + 2 p2 x y`, `u = fx·xd + cx`, `v = fy·yd + cy`.

use nalgebra::{Matrix2, Matrix2x3, Matrix3, Point3, SMatrix, Vector2, Vector3};

use crate::error::{CoreError, Result};

/// One `[[camera]]` table of `rig/cameras.toml` as written in the file (SESSION_FORMAT.md):
/// intrinsics in pixels, distortion defaulting to 0, rotation world→camera row-major, translation
/// in the session's length unit. Deserialized by the stages that read camera rigs.
#[derive(Clone, Debug, PartialEq, serde::Deserialize)]
pub struct CameraTable {
    /// Camera id.
    pub id: String,
    /// Image width, px.
    pub width: u32,
    /// Image height, px.
    pub height: u32,
    /// Focal length x, px.
    pub fx: f64,
    /// Focal length y, px.
    pub fy: f64,
    /// Principal point x, px.
    pub cx: f64,
    /// Principal point y, px.
    pub cy: f64,
    /// Radial k1.
    #[serde(default)]
    pub k1: f64,
    /// Radial k2.
    #[serde(default)]
    pub k2: f64,
    /// Tangential p1.
    #[serde(default)]
    pub p1: f64,
    /// Tangential p2.
    #[serde(default)]
    pub p2: f64,
    /// Radial k3.
    #[serde(default)]
    pub k3: f64,
    /// Rotation world→camera, row-major 3×3.
    pub rotation: [f64; 9],
    /// Translation world→camera, length unit.
    pub translation: [f64; 3],
}

impl CameraTable {
    /// The validated camera, the translation converted to metres (`metres_per_unit` metres per
    /// length unit).
    pub fn to_camera(&self, metres_per_unit: f64) -> Result<Camera> {
        Camera::new(
            self.id.clone(),
            self.width,
            self.height,
            [self.fx, self.fy, self.cx, self.cy],
            [self.k1, self.k2, self.p1, self.p2, self.k3],
            Matrix3::from_row_slice(&self.rotation),
            Vector3::from(self.translation) * metres_per_unit,
        )
    }
}

/// A calibrated camera. Extrinsics are world→camera (`camera_from_world`), translation in metres.
#[derive(Debug, Clone, PartialEq)]
pub struct Camera {
    /// Camera id.
    pub id: String,
    /// Image width, px.
    pub width: u32,
    /// Image height, px.
    pub height: u32,
    /// Focal lengths and principal point `[fx, fy, cx, cy]`, px.
    pub intrinsics: [f64; 4],
    /// Distortion `[k1, k2, p1, p2, k3]` (OpenCV order).
    pub distortion: [f64; 5],
    /// Rotation world→camera.
    pub rotation: Matrix3<f64>,
    /// Translation world→camera, m.
    pub translation_m: Vector3<f64>,
}

/// [`Camera::project_camera_point`]: pixel position and its derivatives.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraPointProjection {
    /// Pixel position `(u, v)`.
    pub uv: Vector2<f64>,
    /// `∂(u,v)/∂Xc`, the camera-frame point.
    pub d_camera_point: Matrix2x3<f64>,
    /// `∂(u,v)/∂(fx, fy, cx, cy, k1, k2, p1, p2, k3)` (the order of [`INTRINSIC_NAMES`]).
    pub d_intrinsics: SMatrix<f64, 2, 9>,
}

/// Names of the intrinsic parameters in the column order of
/// [`CameraPointProjection::d_intrinsics`].
pub const INTRINSIC_NAMES: [&str; 9] = ["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"];

impl Camera {
    /// Builds a camera, rejecting singular intrinsics, non-finite values and improper rotations.
    pub fn new(
        id: String,
        width: u32,
        height: u32,
        intrinsics: [f64; 4],
        distortion: [f64; 5],
        rotation: Matrix3<f64>,
        translation_m: Vector3<f64>,
    ) -> Result<Self> {
        let invalid = |reason: String| CoreError::InvalidCamera { reason };
        let [fx, fy, cx, cy] = intrinsics;
        if width == 0 || height == 0 {
            return Err(invalid("width and height must be positive".into()));
        }
        if !(fx.is_finite() && fy.is_finite() && fx.abs() > 1e-9 && fy.abs() > 1e-9)
            || fx < 0.0
            || fy < 0.0
        {
            return Err(invalid(format!(
                "singular intrinsic matrix: fx = {fx}, fy = {fy} (must be positive)"
            )));
        }
        if !(cx.is_finite() && cy.is_finite()) || distortion.iter().any(|d| !d.is_finite()) {
            return Err(invalid("non-finite principal point or distortion".into()));
        }
        if rotation.iter().any(|v| !v.is_finite()) || translation_m.iter().any(|v| !v.is_finite()) {
            return Err(invalid("non-finite rotation or translation".into()));
        }
        let orth = (rotation.transpose() * rotation - Matrix3::identity())
            .abs()
            .max();
        let det = rotation.determinant();
        if orth > 1e-5 || (det - 1.0).abs() > 1e-5 {
            return Err(invalid(format!(
                "rotation is not a proper rotation (|RᵀR−I|max = {orth:.2e}, det = {det:.6})"
            )));
        }
        Ok(Camera {
            id,
            width,
            height,
            intrinsics,
            distortion,
            rotation,
            translation_m,
        })
    }

    /// World point → camera frame.
    pub fn to_camera(&self, x_world: &Point3<f64>) -> Vector3<f64> {
        self.rotation * x_world.coords + self.translation_m
    }

    /// Camera frame → world point: X = Rᵀ (X_c − t).
    pub fn to_world(&self, x_camera: &Vector3<f64>) -> Point3<f64> {
        Point3::from(self.rotation.transpose() * (x_camera - self.translation_m))
    }

    /// World point seen at pixel `(u, v)` at depth `z_m` along the camera's +z axis (the depth
    /// camera convention of SESSION_FORMAT.md, "Dynamic sessions": depth is z, not the distance
    /// along the ray): X_c = z (x, y, 1) with (x, y) = [`Camera::undistort`]`(u, v)`,
    /// X = Rᵀ (X_c − t). The inverse of [`Camera::project`] for points in front of the camera.
    pub fn back_project(&self, u: f64, v: f64, z_m: f64) -> Point3<f64> {
        let n = self.undistort(u, v);
        self.to_world(&(Vector3::new(n.x, n.y, 1.0) * z_m))
    }

    /// Camera centre in the world frame, m.
    pub fn centre_world(&self) -> Point3<f64> {
        Point3::from(-(self.rotation.transpose() * self.translation_m))
    }

    /// Applies the Brown–Conrady distortion to normalized coordinates.
    pub fn distort(&self, x: f64, y: f64) -> (f64, f64) {
        let [k1, k2, p1, p2, k3] = self.distortion;
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        (
            x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
        )
    }

    /// Jacobian of [`Camera::distort`] with respect to `(x, y)`.
    pub fn distort_jacobian(&self, x: f64, y: f64) -> Matrix2<f64> {
        let [k1, k2, p1, p2, k3] = self.distortion;
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        let dradial_dr2 = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2);
        let (dr2x, dr2y) = (2.0 * x, 2.0 * y);
        Matrix2::new(
            radial + x * dradial_dr2 * dr2x + 2.0 * p1 * y + p2 * (dr2x + 4.0 * x),
            x * dradial_dr2 * dr2y + 2.0 * p1 * x + p2 * dr2y,
            y * dradial_dr2 * dr2x + p1 * dr2x + 2.0 * p2 * y,
            radial + y * dradial_dr2 * dr2y + p1 * (dr2y + 4.0 * y) + 2.0 * p2 * x,
        )
    }

    /// Projects a world point to pixels; `None` behind the camera.
    pub fn project(&self, x_world: &Point3<f64>) -> Option<Vector2<f64>> {
        let xc = self.to_camera(x_world);
        if xc.z <= 1e-12 {
            return None;
        }
        let (xd, yd) = self.distort(xc.x / xc.z, xc.y / xc.z);
        let [fx, fy, cx, cy] = self.intrinsics;
        Some(Vector2::new(fx * xd + cx, fy * yd + cy))
    }

    /// Projection and its Jacobian `∂(u,v)/∂X` (world point); `None` behind the camera.
    pub fn project_with_jacobian(
        &self,
        x_world: &Point3<f64>,
    ) -> Option<(Vector2<f64>, Matrix2x3<f64>)> {
        let p = self.project_camera_point(&self.to_camera(x_world))?;
        Some((p.uv, p.d_camera_point * self.rotation))
    }

    /// Projection of a camera-frame point `Xc` with its Jacobians with respect to `Xc` and to the
    /// intrinsics `(fx, fy, cx, cy, k1, k2, p1, p2, k3)` (bundle adjustment refines them);
    /// `None` behind the camera.
    pub fn project_camera_point(&self, xc: &Vector3<f64>) -> Option<CameraPointProjection> {
        if xc.z <= 1e-12 {
            return None;
        }
        let iz = 1.0 / xc.z;
        let (x, y) = (xc.x * iz, xc.y * iz);
        let (xd, yd) = self.distort(x, y);
        let [fx, fy, cx, cy] = self.intrinsics;
        let dn = Matrix2x3::new(iz, 0.0, -x * iz, 0.0, iz, -y * iz);
        let d_camera_point = Matrix2::new(fx, 0.0, 0.0, fy) * self.distort_jacobian(x, y) * dn;
        // ∂(xd, yd)/∂(k1, k2, p1, p2, k3), scaled by (fx, fy) per row.
        let r2 = x * x + y * y;
        let (r4, xy) = (r2 * r2, x * y);
        let d_distortion = [
            (x * r2, y * r2),
            (x * r4, y * r4),
            (2.0 * xy, r2 + 2.0 * y * y),
            (r2 + 2.0 * x * x, 2.0 * xy),
            (x * r4 * r2, y * r4 * r2),
        ];
        let mut d_intrinsics = SMatrix::<f64, 2, 9>::zeros();
        d_intrinsics[(0, 0)] = xd;
        d_intrinsics[(1, 1)] = yd;
        d_intrinsics[(0, 2)] = 1.0;
        d_intrinsics[(1, 3)] = 1.0;
        for (k, (dx, dy)) in d_distortion.into_iter().enumerate() {
            d_intrinsics[(0, 4 + k)] = fx * dx;
            d_intrinsics[(1, 4 + k)] = fy * dy;
        }
        Some(CameraPointProjection {
            uv: Vector2::new(fx * xd + cx, fy * yd + cy),
            d_camera_point,
            d_intrinsics,
        })
    }

    /// Pixel → undistorted normalized image coordinates, inverting the distortion by fixed-point
    /// iteration `x ← (xd − tangential(x)) / radial(x)` followed by Newton polishing.
    pub fn undistort(&self, u: f64, v: f64) -> Vector2<f64> {
        let [fx, fy, cx, cy] = self.intrinsics;
        let target = Vector2::new((u - cx) / fx, (v - cy) / fy);
        let [k1, k2, p1, p2, k3] = self.distortion;
        let mut p = target;
        for _ in 0..20 {
            let (x, y) = (p.x, p.y);
            let r2 = x * x + y * y;
            let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
            let dx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
            let dy = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
            if radial.abs() < 1e-6 {
                break;
            }
            p = Vector2::new((target.x - dx) / radial, (target.y - dy) / radial);
        }
        for _ in 0..3 {
            let (xd, yd) = self.distort(p.x, p.y);
            let r = Vector2::new(xd, yd) - target;
            if r.norm() < 1e-15 {
                break;
            }
            match self.distort_jacobian(p.x, p.y).try_inverse() {
                Some(ji) => p -= ji * r,
                None => break,
            }
        }
        p
    }

    /// Ray of a pixel: origin (camera centre) and unit direction, world frame.
    pub fn ray(&self, u: f64, v: f64) -> (Point3<f64>, Vector3<f64>) {
        let n = self.undistort(u, v);
        let d = self.rotation.transpose() * Vector3::new(n.x, n.y, 1.0);
        (self.centre_world(), d.normalize())
    }

    /// 3×4 projection matrix `[R | t]` in normalized coordinates.
    pub fn normalized_projection(&self) -> nalgebra::Matrix3x4<f64> {
        let mut p = nalgebra::Matrix3x4::zeros();
        p.fixed_view_mut::<3, 3>(0, 0).copy_from(&self.rotation);
        p.set_column(3, &self.translation_m);
        p
    }

    /// Mean focal length, px (converts normalized distances to pixels).
    pub fn focal_px(&self) -> f64 {
        0.5 * (self.intrinsics[0] + self.intrinsics[1])
    }
}

/// The cameras as `rig/cameras.toml` tables (`SESSION_FORMAT.md`), translations multiplied by
/// `units_per_metre` (the session's `length_unit`: 1000 for mm, 1 for m). Text formatting only; the
/// virtual rig and `softcap capture calibrate` write it, capture parses it.
pub fn cameras_toml(cameras: &[Camera], units_per_metre: f64) -> String {
    use std::fmt::Write as _;
    let mut t = String::new();
    for c in cameras {
        let [fx, fy, cx, cy] = c.intrinsics;
        let [k1, k2, p1, p2, k3] = c.distortion;
        let r = c.rotation;
        let tr = c.translation_m * units_per_metre;
        let _ = writeln!(t, "[[camera]]");
        let _ = writeln!(t, "id = \"{}\"", c.id);
        let _ = writeln!(t, "width = {}\nheight = {}", c.width, c.height);
        let _ = writeln!(t, "fx = {fx:.6}\nfy = {fy:.6}\ncx = {cx:.6}\ncy = {cy:.6}");
        let _ = writeln!(
            t,
            "k1 = {k1:e}\nk2 = {k2:e}\np1 = {p1:e}\np2 = {p2:e}\nk3 = {k3:e}"
        );
        let rows: Vec<String> = (0..3)
            .flat_map(|i| (0..3).map(move |j| (i, j)))
            .map(|(i, j)| format!("{:.15}", r[(i, j)]))
            .collect();
        let _ = writeln!(t, "rotation = [{}]", rows.join(", "));
        let _ = writeln!(t, "translation = [{:.9}, {:.9}, {:.9}]\n", tr.x, tr.y, tr.z);
    }
    t
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam() -> Camera {
        let r = nalgebra::Rotation3::from_euler_angles(0.3, -0.2, 0.1).into_inner();
        Camera::new(
            "c".into(),
            640,
            480,
            [711.9, 711.5, 319.3, 238.5],
            [-0.051, 0.0086, -4.6e-5, 2.1e-5, 0.001],
            r,
            Vector3::new(0.02, 0.07, 0.27),
        )
        .unwrap()
    }

    #[test]
    fn undistort_inverts_distort() {
        let c = cam();
        for &(x, y) in &[(0.0, 0.0), (0.3, -0.2), (-0.45, 0.33), (0.5, 0.4)] {
            let (xd, yd) = c.distort(x, y);
            let [fx, fy, cx, cy] = c.intrinsics;
            let n = c.undistort(fx * xd + cx, fy * yd + cy);
            assert!((n - Vector2::new(x, y)).norm() < 1e-12, "{x} {y} -> {n}");
        }
    }

    #[test]
    fn back_projection_inverts_projection() {
        let c = cam();
        for p in [
            Point3::new(0.01, -0.02, 0.015),
            Point3::new(-0.05, 0.03, 0.1),
        ] {
            let uv = c.project(&p).unwrap();
            let z = c.to_camera(&p).z;
            let q = c.back_project(uv.x, uv.y, z);
            assert!((q - p).norm() < 1e-12, "{p} -> {q}");
        }
    }

    #[test]
    fn projection_jacobian_matches_finite_differences() {
        let c = cam();
        let p = Point3::new(0.01, -0.02, 0.015);
        let (_, j) = c.project_with_jacobian(&p).unwrap();
        let h = 1e-7;
        for k in 0..3 {
            let mut a = p;
            let mut b = p;
            a[k] += h;
            b[k] -= h;
            let fd = (c.project(&a).unwrap() - c.project(&b).unwrap()) / (2.0 * h);
            assert!(
                (fd - j.column(k)).norm() < 1e-4 * fd.norm().max(1.0),
                "column {k}: {fd} vs {}",
                j.column(k)
            );
        }
    }

    #[test]
    fn intrinsic_jacobian_matches_finite_differences() {
        let c = cam();
        let xc = c.to_camera(&Point3::new(0.03, -0.02, 0.015));
        let p = c.project_camera_point(&xc).unwrap();
        let h = 1e-7;
        let perturbed = |k: usize, d: f64| {
            let mut q = c.clone();
            if k < 4 {
                q.intrinsics[k] += d;
            } else {
                q.distortion[k - 4] += d;
            }
            q.project_camera_point(&xc).unwrap().uv
        };
        for k in 0..9 {
            let fd = (perturbed(k, h) - perturbed(k, -h)) / (2.0 * h);
            let col = p.d_intrinsics.column(k);
            assert!(
                (fd - col).norm() < 1e-6 * fd.norm().max(1.0),
                "{}: {fd} vs {col}",
                INTRINSIC_NAMES[k]
            );
        }
        for k in 0..3 {
            let mut a = xc;
            let mut b = xc;
            a[k] += h;
            b[k] -= h;
            let fd = (c.project_camera_point(&a).unwrap().uv
                - c.project_camera_point(&b).unwrap().uv)
                / (2.0 * h);
            assert!((fd - p.d_camera_point.column(k)).norm() < 1e-4 * fd.norm().max(1.0));
        }
    }

    #[test]
    fn singular_and_improper_cameras_are_rejected() {
        let c = cam();
        let bad = Camera::new(
            "x".into(),
            10,
            10,
            [0.0, 1.0, 0.0, 0.0],
            [0.0; 5],
            c.rotation,
            c.translation_m,
        );
        assert!(bad.unwrap_err().to_string().contains("singular"));
        let refl = Matrix3::new(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -1.0);
        assert!(
            Camera::new(
                "x".into(),
                10,
                10,
                c.intrinsics,
                [0.0; 5],
                refl,
                c.translation_m
            )
            .is_err()
        );
    }
}
