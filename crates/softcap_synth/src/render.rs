//! Camera images: a neutral textured background and block, the grey probe, and anti-aliased
//! marker discs.
//!
//! Object markers are painted circles on the deformed surface (centre and normal from the truth):
//! every pixel near a marker is supersampled S×S; each sub-sample's ray (exact undistortion at the
//! pixel corners, bilinear inside the pixel) is intersected with the marker's plane and counted when
//! it lands within the painted radius and in front of the probe. Shaft markers are spheres. The
//! pixel colour is the background blended with the paint by the covered fraction, so the rendered
//! disc is the exact perspective + distortion image of the painted circle up to S⁻² quantisation.

use image::{Rgb, RgbImage};
use nalgebra::{Isometry3, Point3, Vector2, Vector3};
use softcap_core::Camera;

use crate::rig::{ray_probe, ray_sphere};
use crate::truth::{FrameTruth, Truth};

/// sRGB paint colour of a session-format colour name.
pub fn paint(color: &str) -> [u8; 3] {
    match color {
        "red" => [215, 35, 35],
        "yellow" => [235, 215, 25],
        "green" => [30, 170, 60],
        "cyan" => [30, 190, 210],
        "magenta" => [200, 40, 190],
        "white" => [250, 250, 250],
        "black" => [15, 15, 15],
        _ => [25, 45, 225],
    }
}

/// Precomputed per-camera data: world-frame ray directions of every pixel centre.
pub struct CameraRays {
    cam: Camera,
    centre: Vector3<f64>,
    dirs: Vec<Vector3<f64>>,
}

impl CameraRays {
    /// Rays of every pixel centre of `cam`.
    pub fn new(cam: &Camera) -> Self {
        let (w, h) = (cam.width as usize, cam.height as usize);
        let mut dirs = Vec::with_capacity(w * h);
        for v in 0..h {
            for u in 0..w {
                dirs.push(cam.ray(u as f64, v as f64).1);
            }
        }
        Self {
            cam: cam.clone(),
            centre: cam.centre_world().coords,
            dirs,
        }
    }

    /// World ray direction (not normalised) through sub-pixel `(u, v)` given the normalised
    /// undistorted coordinates at the four corners of its pixel.
    fn ray_dir(&self, n: &Vector2<f64>) -> Vector3<f64> {
        self.cam.rotation.transpose() * Vector3::new(n.x, n.y, 1.0)
    }
}

/// Value noise in [−1, 1] on a lattice of `cell` pixels (deterministic hash, bilinear).
fn value_noise(u: f64, v: f64, cell: f64, salt: u64) -> f64 {
    let hash = |i: i64, j: i64| {
        let mut x = (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
            ^ (j as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
            ^ salt.wrapping_mul(0x1656_67B1_9E37_79F9);
        x ^= x >> 31;
        x = x.wrapping_mul(0xBF58_476D_1CE4_E5B9);
        x ^= x >> 27;
        (x >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    };
    let (x, y) = (u / cell, v / cell);
    let (i, j) = (x.floor() as i64, y.floor() as i64);
    let (fx, fy) = (x - i as f64, y - j as f64);
    let (sx, sy) = (fx * fx * (3.0 - 2.0 * fx), fy * fy * (3.0 - 2.0 * fy));
    let a = hash(i, j) + sx * (hash(i + 1, j) - hash(i, j));
    let b = hash(i, j + 1) + sx * (hash(i + 1, j + 1) - hash(i, j + 1));
    a + sy * (b - a)
}

/// Ray / axis-aligned box [0, size] entry: (t, outward normal of the entry face).
fn ray_box(o: &Vector3<f64>, d: &Vector3<f64>, size: &Vector3<f64>) -> Option<(f64, usize)> {
    let (mut t0, mut t1, mut axis) = (f64::NEG_INFINITY, f64::INFINITY, 0);
    for k in 0..3 {
        if d[k].abs() < 1e-300 {
            if o[k] < 0.0 || o[k] > size[k] {
                return None;
            }
            continue;
        }
        let (a, b) = ((0.0 - o[k]) / d[k], (size[k] - o[k]) / d[k]);
        let (lo, hi) = if a < b { (a, b) } else { (b, a) };
        if lo > t0 {
            t0 = lo;
            axis = k;
        }
        t1 = t1.min(hi);
    }
    (t0 <= t1 && t0 > 0.0).then_some((t0, axis))
}

/// The static part of a camera's image: textured table and the block at rest.
pub fn background(
    rays: &CameraRays,
    block_size_m: &Vector3<f64>,
    texture: f64,
    salt: u64,
) -> RgbImage {
    let (w, h) = (rays.cam.width, rays.cam.height);
    let mut img = RgbImage::new(w, h);
    for v in 0..h {
        for u in 0..w {
            let d = rays.dirs[(v * w + u) as usize];
            let (uf, vf) = (u as f64, v as f64);
            let tex = texture
                * (0.6 * value_noise(uf, vf, 9.0, salt) + 0.4 * value_noise(uf, vf, 3.0, salt + 1));
            let base = match ray_box(&rays.centre, &d, block_size_m) {
                Some((_, 2)) => 214.0,
                Some((_, 0)) => 186.0,
                Some(_) => 176.0,
                None => 198.0,
            };
            let g = (base + tex).round().clamp(0.0, 255.0) as u8;
            img.put_pixel(u, v, Rgb([g, g, g]));
        }
    }
    img
}

/// Pixel bounding box (clipped) of projected world points, expanded by `pad` px.
fn bbox(cam: &Camera, pts: &[Vector3<f64>], pad: f64) -> Option<(u32, u32, u32, u32)> {
    let (mut lo, mut hi) = (
        Vector2::repeat(f64::INFINITY),
        Vector2::repeat(f64::NEG_INFINITY),
    );
    for p in pts {
        let uv = cam.project(&Point3::from(*p))?;
        lo = lo.inf(&uv);
        hi = hi.sup(&uv);
    }
    let (w, h) = (cam.width as f64, cam.height as f64);
    if hi.x < -pad || hi.y < -pad || lo.x > w + pad || lo.y > h + pad {
        return None;
    }
    let u0 = (lo.x - pad).floor().max(0.0) as u32;
    let v0 = (lo.y - pad).floor().max(0.0) as u32;
    let u1 = ((hi.x + pad).ceil().min(w - 1.0)).max(0.0) as u32;
    let v1 = ((hi.y + pad).ceil().min(h - 1.0)).max(0.0) as u32;
    Some((u0, v0, u1, v1))
}

/// What a marker looks like to the renderer.
#[derive(Clone, Debug)]
pub enum MarkerShape {
    /// Painted disc: centre, unit normal, radius (m).
    Disc(Vector3<f64>, Vector3<f64>, f64),
    /// Sphere: centre, radius (m).
    Sphere(Vector3<f64>, f64),
}

impl MarkerShape {
    fn hit(&self, o: &Vector3<f64>, d: &Vector3<f64>) -> Option<f64> {
        match self {
            MarkerShape::Disc(c, n, r) => {
                let dn = d.dot(n);
                if dn.abs() < 1e-300 {
                    return None;
                }
                let t = (c - o).dot(n) / dn;
                (t > 0.0 && (o + d * t - c).norm_squared() <= r * r).then_some(t)
            }
            MarkerShape::Sphere(c, r) => ray_sphere(o, d, c, *r, 0.0),
        }
    }

    fn outline(&self) -> Vec<Vector3<f64>> {
        match self {
            MarkerShape::Disc(c, n, r) => {
                let a = if n.x.abs() < 0.9 {
                    Vector3::x()
                } else {
                    Vector3::y()
                };
                let e1 = n.cross(&a).normalize();
                let e2 = n.cross(&e1);
                (0..24)
                    .map(|k| {
                        let t = std::f64::consts::TAU * k as f64 / 24.0;
                        c + (e1 * t.cos() + e2 * t.sin()) * *r
                    })
                    .collect()
            }
            MarkerShape::Sphere(c, r) => {
                let mut v = vec![];
                for a in [-1.0, 0.0, 1.0] {
                    for b in [-1.0, 0.0, 1.0] {
                        for cc in [-1.0, 0.0, 1.0] {
                            v.push(c + Vector3::new(a, b, cc) * *r);
                        }
                    }
                }
                v
            }
        }
    }
}

/// Draws one marker with S×S supersampling, hidden where the probe (if given) is in front.
pub fn draw_marker(
    img: &mut RgbImage,
    rays: &CameraRays,
    shape: &MarkerShape,
    color: [u8; 3],
    probe: Option<(&crate::truth::ProbeGeometry, &Isometry3<f64>)>,
    supersample: usize,
) {
    let cam = &rays.cam;
    let Some((u0, v0, u1, v1)) = bbox(cam, &shape.outline(), 1.5) else {
        return;
    };
    let s = supersample.max(1);
    let nu = (u1 - u0 + 2) as usize;
    let nv = (v1 - v0 + 2) as usize;
    // Exact undistorted coordinates at pixel corners (u − ½, v − ½).
    let corner: Vec<Vector2<f64>> = (0..nv)
        .flat_map(|j| (0..nu).map(move |i| (i, j)))
        .map(|(i, j)| cam.undistort(u0 as f64 + i as f64 - 0.5, v0 as f64 + j as f64 - 0.5))
        .collect();
    let o = rays.centre;
    for v in v0..=v1 {
        for u in u0..=u1 {
            let (i, j) = ((u - u0) as usize, (v - v0) as usize);
            let c00 = corner[j * nu + i];
            let c10 = corner[j * nu + i + 1];
            let c01 = corner[(j + 1) * nu + i];
            let c11 = corner[(j + 1) * nu + i + 1];
            let mut hits = 0usize;
            for b in 0..s {
                let fy = (b as f64 + 0.5) / s as f64;
                for a in 0..s {
                    let fx = (a as f64 + 0.5) / s as f64;
                    let n = c00 * ((1.0 - fx) * (1.0 - fy))
                        + c10 * (fx * (1.0 - fy))
                        + c01 * ((1.0 - fx) * fy)
                        + c11 * (fx * fy);
                    let d = rays.ray_dir(&n);
                    if let Some(t) = shape.hit(&o, &d) {
                        let blocked = probe.is_some_and(|(pg, pose)| {
                            ray_probe(pg, pose, &o, &d, 1e-12).is_some_and(|tp| tp < t - 1e-9)
                        });
                        if !blocked {
                            hits += 1;
                        }
                    }
                }
            }
            if hits > 0 {
                let alpha = hits as f64 / (s * s) as f64;
                let p = img.get_pixel_mut(u, v);
                for k in 0..3 {
                    p.0[k] = (p.0[k] as f64 * (1.0 - alpha) + color[k] as f64 * alpha)
                        .round()
                        .clamp(0.0, 255.0) as u8;
                }
            }
        }
    }
}

/// Draws the probe (tip and shaft, flat grey, one sample per pixel).
pub fn draw_probe(
    img: &mut RgbImage,
    rays: &CameraRays,
    probe: &crate::truth::ProbeGeometry,
    pose: &Isometry3<f64>,
) {
    let cam = &rays.cam;
    let up = -(pose.rotation * Vector3::z());
    let tip = pose.translation.vector;
    let a = if up.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let e1 = up.cross(&a).normalize();
    let e2 = up.cross(&e1);
    let mut pts = Vec::new();
    for (h, r) in [
        (0.0, probe.radius_m),
        (probe.thickness_m.max(probe.radius_m), probe.radius_m),
        (probe.shaft_length_m, probe.shaft_radius_m),
    ] {
        for k in 0..16 {
            let t = std::f64::consts::TAU * k as f64 / 16.0;
            pts.push(tip + up * h + (e1 * t.cos() + e2 * t.sin()) * r);
        }
    }
    let Some((u0, v0, u1, v1)) = bbox(cam, &pts, 2.0) else {
        return;
    };
    let w = cam.width;
    for v in v0..=v1 {
        for u in u0..=u1 {
            let d = rays.dirs[(v * w + u) as usize];
            if ray_probe(probe, pose, &rays.centre, &d, 1e-9).is_some() {
                img.put_pixel(u, v, Rgb([92, 92, 92]));
            }
        }
    }
}

/// Renders one frame of one camera: background, probe, object markers (painted discs), shaft
/// markers (spheres). `draw_markers = false` gives the marker-free image (used by tests).
pub fn render_frame(
    base: &RgbImage,
    rays: &CameraRays,
    truth: &Truth,
    f: &FrameTruth,
    marker_color: &str,
    marker_radius_m: f64,
    supersample: usize,
    draw_markers: bool,
) -> RgbImage {
    let mut img = base.clone();
    let pose = &f.spec.world_from_probe;
    draw_probe(&mut img, rays, &truth.probe, pose);
    if !draw_markers {
        return img;
    }
    let col = paint(marker_color);
    for (p, n) in f.markers_m.iter().zip(&f.marker_normals) {
        if n.dot(&(rays.centre - p)) <= 0.0 {
            continue;
        }
        draw_marker(
            &mut img,
            rays,
            &MarkerShape::Disc(*p, *n, marker_radius_m),
            col,
            Some((&truth.probe, pose)),
            supersample,
        );
    }
    for ((_, _, color), c) in truth
        .probe
        .shaft_markers
        .iter()
        .zip(truth.probe.shaft_marker_positions(pose))
    {
        draw_marker(
            &mut img,
            rays,
            &MarkerShape::Sphere(c, truth.probe.shaft_marker_radius_m),
            paint(color),
            None,
            supersample,
        );
    }
    img
}
