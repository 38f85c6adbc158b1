//! Depth cameras of the virtual rig: placement around the object, depth images ray cast from
//! the truth surface (`softcap_mesh::SurfaceRayCaster`, parry3d), and a structured-light sensor
//! model (Kinect v1, as in wang2015 §7):
//!
//! - axial noise σ_z = c z² (Khoshelham & Elberink 2012, c ≈ 1.425e-3 /m),
//! - disparity quantisation: d = f b / z rounded to `disparity_step_px`, z = f b / d,
//! - holes where the viewing ray grazes the surface (angle to the normal > `grazing_deg`),
//!   independent dropouts, and "flying pixels" 1–5 cm behind the surface at silhouettes,
//! - self-occlusion (the first hit of every pixel's ray).
//!
//! Depth is z along the camera's +z axis (SESSION_FORMAT.md "Dynamic sessions"); every pixel
//! (u, v) looks along the ray of its undistorted normalized coordinates (`softcap_core::Camera`).

use nalgebra::{Matrix3, Point3, Vector3};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use rayon::prelude::*;
use softcap_core::Camera;
use softcap_mesh::SurfaceRayCaster;

use super::settings::{DepthSensorSettings, DynamicSettings};
use crate::error::Result;

const MM: f64 = 1e-3;

/// A depth camera: the calibrated pinhole + distortion model and the rays of its pixels.
pub struct DepthCamera {
    /// The camera (world→camera extrinsics in metres).
    pub camera: Camera,
    /// Per pixel (row-major), the world direction of its ray scaled to unit camera-frame z (a hit
    /// at ray parameter t is at depth z = t).
    rays: Vec<Vector3<f64>>,
}

impl DepthCamera {
    /// Camera centre, world frame.
    pub fn centre(&self) -> Vector3<f64> {
        self.camera.centre_world().coords
    }
}

/// Places the cameras of `d.cameras` looking at `aim_m` and precomputes their pixel rays.
pub fn rig(d: &DynamicSettings, aim_m: &Vector3<f64>) -> Result<Vec<DepthCamera>> {
    let s = &d.sensor;
    let mut out = Vec::with_capacity(d.cameras.len());
    for (k, c) in d.cameras.iter().enumerate() {
        let (az, el) = (c.azimuth_deg.to_radians(), c.elevation_deg.to_radians());
        let dir_to_cam = Vector3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin());
        let centre = aim_m + dir_to_cam * (c.distance_mm * MM);
        let zc = (aim_m - centre).normalize();
        let xc = zc.cross(&Vector3::z()).normalize();
        let yc = zc.cross(&xc);
        let rot = Matrix3::from_rows(&[xc.transpose(), yc.transpose(), zc.transpose()]);
        // slightly different intrinsics per camera, like a calibrated rig
        let fx = s.focal_px * (1.0 + 0.002 * k as f64);
        let fy = fx * (1.0 - 0.0005 * (k as f64 + 1.0));
        let cx = 0.5 * (s.width as f64 - 1.0) + 0.7 * k as f64 - 0.4;
        let cy = 0.5 * (s.height as f64 - 1.0) - 0.4 * k as f64 + 0.2;
        let camera = Camera::new(
            format!("depth{k}"),
            s.width,
            s.height,
            [fx, fy, cx, cy],
            s.distortion,
            rot,
            -(rot * centre),
        )?;
        let rt = rot.transpose();
        let rays = (0..s.height)
            .flat_map(|v| (0..s.width).map(move |u| (u, v)))
            .map(|(u, v)| {
                let n = camera.undistort(u as f64, v as f64);
                rt * Vector3::new(n.x, n.y, 1.0)
            })
            .collect();
        out.push(DepthCamera { camera, rays });
    }
    Ok(out)
}

/// One rendered depth image: depth in metres per pixel (row-major), 0 = no reading.
pub struct DepthImage {
    /// Width, px.
    pub width: u32,
    /// Height, px.
    pub height: u32,
    /// Depth z per pixel, m (0 = no reading).
    pub depth_m: Vec<f64>,
}

impl DepthImage {
    /// 16-bit counts of `depth_scale_mm`, 0 where there is no reading or it is out of range.
    pub fn counts(&self, s: &DepthSensorSettings) -> Vec<u16> {
        self.depth_m
            .iter()
            .map(|&z| {
                let mm = z / MM;
                if z > 0.0 && mm >= s.min_depth_mm && mm <= s.max_depth_mm {
                    (mm / s.depth_scale_mm).round().clamp(1.0, 65535.0) as u16
                } else {
                    0
                }
            })
            .collect()
    }
}

/// Renders camera `cam` looking at the surface (`caster` built over `vertices`): exact first hits
/// in the pixels of the surface's projected bounding box, then the sensor model with `rng`.
pub fn render(
    cam: &DepthCamera,
    caster: &SurfaceRayCaster,
    vertices: &[Vector3<f64>],
    s: &DepthSensorSettings,
    rng: &mut ChaCha8Rng,
) -> DepthImage {
    let (w, h) = (s.width as usize, s.height as usize);
    let mut depth = vec![0.0; w * h];
    let Some((u0, u1, v0, v1)) = pixel_box(&cam.camera, vertices, w, h) else {
        return DepthImage {
            width: s.width,
            height: s.height,
            depth_m: depth,
        };
    };
    let origin = cam.centre();
    let cos_grazing = s.grazing_deg.to_radians().cos();
    let max_t = 2.0 * s.max_depth_mm * MM;
    // exact depth of every pixel in the box (parallel over rows; no randomness here)
    let rows: Vec<Vec<f64>> = (v0..=v1)
        .into_par_iter()
        .map(|v| {
            (u0..=u1)
                .map(|u| {
                    let d = &cam.rays[v * w + u];
                    match caster.cast(&origin, d, max_t) {
                        Some(hit) => {
                            let cos = (hit.normal.dot(d) / d.norm()).abs();
                            if cos < cos_grazing { 0.0 } else { hit.t }
                        }
                        None => 0.0,
                    }
                })
                .collect()
        })
        .collect();
    for (r, row) in rows.iter().enumerate() {
        let v = v0 + r;
        depth[v * w + u0..=v * w + u1].copy_from_slice(row);
    }
    apply_sensor_noise(&mut depth, w, h, cam.camera.intrinsics[0], s, rng);
    DepthImage {
        width: s.width,
        height: s.height,
        depth_m: depth,
    }
}

/// Pixel bounding box (inclusive) of the projected vertices, 2 px margin, clipped to the image.
fn pixel_box(
    camera: &Camera,
    vertices: &[Vector3<f64>],
    w: usize,
    h: usize,
) -> Option<(usize, usize, usize, usize)> {
    let (mut umin, mut umax, mut vmin, mut vmax) = (
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    );
    for p in vertices {
        let uv = camera.project(&Point3::from(*p))?;
        umin = umin.min(uv.x);
        umax = umax.max(uv.x);
        vmin = vmin.min(uv.y);
        vmax = vmax.max(uv.y);
    }
    let clip = |a: f64, n: usize| (a.max(0.0) as usize).min(n - 1);
    let (u0, u1) = (clip(umin - 2.0, w), clip(umax + 3.0, w));
    let (v0, v1) = (clip(vmin - 2.0, h), clip(vmax + 3.0, h));
    (umax >= 0.0 && vmax >= 0.0 && umin < w as f64 && vmin < h as f64).then_some((u0, u1, v0, v1))
}

/// The structured-light sensor model on exact depths (in place): flying pixels at silhouettes,
/// dropouts, axial noise σ = c z², disparity quantisation. Pixels are visited in row-major order
/// so the result depends only on the seed.
fn apply_sensor_noise(
    depth: &mut [f64],
    w: usize,
    h: usize,
    focal_px: f64,
    s: &DepthSensorSettings,
    rng: &mut ChaCha8Rng,
) {
    let exact = depth.to_vec();
    let fb = focal_px * s.baseline_mm * MM;
    let unit = Normal::new(0.0, 1.0).expect("unit normal");
    for v in 0..h {
        for u in 0..w {
            let i = v * w + u;
            let z = exact[i];
            if z <= 0.0 {
                continue;
            }
            if rng.random::<f64>() < s.dropout_probability {
                depth[i] = 0.0;
                continue;
            }
            let silhouette = [(0i64, -1i64), (0, 1), (-1, 0), (1, 0)]
                .iter()
                .any(|(du, dv)| {
                    let (uu, vv) = (u as i64 + du, v as i64 + dv);
                    uu < 0
                        || vv < 0
                        || uu >= w as i64
                        || vv >= h as i64
                        || exact[vv as usize * w + uu as usize] <= 0.0
                });
            let mut zn = z + unit.sample(rng) * s.sigma_z_per_m * z * z;
            if silhouette && rng.random::<f64>() < s.edge_outlier_probability {
                zn += rng.random_range(0.01..0.05);
            }
            if s.disparity_step_px > 0.0 {
                let disparity = (fb / zn / s.disparity_step_px).round() * s.disparity_step_px;
                zn = if disparity > 0.0 { fb / disparity } else { 0.0 };
            }
            depth[i] = zn;
        }
    }
}

/// Whether a surface point with unit outward normal `n` is seen by some camera: inside its image,
/// in the depth range, facing it within the grazing angle, and not hidden by the surface.
pub fn seen_by_any(
    cams: &[DepthCamera],
    caster: &SurfaceRayCaster,
    p: &Vector3<f64>,
    n: &Vector3<f64>,
    s: &DepthSensorSettings,
) -> bool {
    let cos_grazing = s.grazing_deg.to_radians().cos();
    cams.iter().any(|c| {
        let Some(uv) = c.camera.project(&Point3::from(*p)) else {
            return false;
        };
        let inside = uv.x >= -0.5
            && uv.y >= -0.5
            && uv.x < s.width as f64 - 0.5
            && uv.y < s.height as f64 - 0.5;
        let z_mm = c.camera.to_camera(&Point3::from(*p)).z / MM;
        let to_cam = c.centre() - p;
        let facing = n.dot(&to_cam) >= cos_grazing * to_cam.norm();
        inside
            && facing
            && z_mm >= s.min_depth_mm
            && z_mm <= s.max_depth_mm
            && !caster.occluded(&c.centre(), p, 0.5 * MM)
    })
}
