//! Ground-truth wrinkle "video": Monte-Carlo ambient occlusion on a 3D height field.
//!
//! This renderer is deliberately *not* the estimator's 2.5D model (thesis eq. 4.4): it casts
//! cosine-distributed rays from every pixel's surface point over the full 3D height field of a
//! curved, finite, tapered wrinkle and counts the unoccluded ones (uniform ambient light,
//! Lambertian paint). The wrinkle valley follows a circular arc so the valley position is known
//! exactly for the tracking tests.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::cross_section::wrinkle_profile;
use crate::image::RgbImage;

/// A painted wrinkle whose valley is the arc ‖q − center‖ = radius, all lengths in pixels
/// (orthographic camera looking down −z, one pixel = one length unit, heights in pixels).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct WrinkleScene {
    /// Image columns.
    pub width_px: usize,
    /// Image rows.
    pub height_px: usize,
    /// Centre of the valley arc.
    pub arc_center_px: [f64; 2],
    /// Radius of the valley arc.
    pub arc_radius_px: f64,
    /// Angular extent of the wrinkle on the arc, radians (atan2 convention).
    pub arc_angles_rad: [f64; 2],
    /// Length over which the depth ramps from 0 to full at both ends.
    pub taper_px: f64,
    /// Cross-section width w.
    pub width_w_px: f64,
    /// Cross-section depth d.
    pub depth_d_px: f64,
    /// Half width of the painted band around the valley.
    pub paint_half_width_px: f64,
    /// Albedo of the wrinkle paint.
    pub paint_rgb: [f64; 3],
    /// Albedo of the skin.
    pub skin_rgb: [f64; 3],
    /// Uniform ambient radiance.
    pub ambient: f64,
}

impl Default for WrinkleScene {
    fn default() -> Self {
        // A 100 px long, gently curved wrinkle across a 140 × 64 image.
        let r = 400.0;
        let half = 55.0 / r;
        Self {
            width_px: 140,
            height_px: 64,
            arc_center_px: [70.0, 32.0 + r],
            arc_radius_px: r,
            arc_angles_rad: [
                -std::f64::consts::FRAC_PI_2 - half,
                -std::f64::consts::FRAC_PI_2 + half,
            ],
            taper_px: 12.0,
            width_w_px: 4.0,
            depth_d_px: 3.0,
            paint_half_width_px: 14.0,
            paint_rgb: [0.15, 0.35, 0.8],
            skin_rgb: [0.85, 0.62, 0.5],
            ambient: 0.9,
        }
    }
}

impl WrinkleScene {
    /// Signed distance p to the valley arc and arc length s from the arc start.
    pub fn valley_coordinates(&self, x: f64, y: f64) -> (f64, f64) {
        let (dx, dy) = (x - self.arc_center_px[0], y - self.arc_center_px[1]);
        let rho = (dx * dx + dy * dy).sqrt();
        let angle = dy.atan2(dx);
        (
            rho - self.arc_radius_px,
            (angle - self.arc_angles_rad[0]) * self.arc_radius_px,
        )
    }

    /// Arc length of the wrinkle.
    pub fn length_px(&self) -> f64 {
        (self.arc_angles_rad[1] - self.arc_angles_rad[0]) * self.arc_radius_px
    }

    /// Depth multiplier in [0, 1] at arc length s (smoothstep ramps at both ends).
    pub fn taper(&self, s: f64) -> f64 {
        let ramp = |t: f64| {
            let t = t.clamp(0.0, 1.0);
            t * t * (3.0 - 2.0 * t)
        };
        ramp(s / self.taper_px) * ramp((self.length_px() - s) / self.taper_px)
    }

    /// Height H(x, y) = S(w, d·taper(s), p) of the surface.
    pub fn height(&self, x: f64, y: f64) -> f64 {
        let (p, s) = self.valley_coordinates(x, y);
        wrinkle_profile(self.width_w_px, self.depth_d_px * self.taper(s), p)
    }

    /// Whether (x, y) lies on the painted band.
    pub fn painted(&self, x: f64, y: f64) -> bool {
        let (p, s) = self.valley_coordinates(x, y);
        p.abs() <= self.paint_half_width_px && s >= 0.0 && s <= self.length_px()
    }

    /// Closest point on the (untruncated) valley arc to (x, y).
    pub fn closest_valley_point(&self, x: f64, y: f64) -> [f64; 2] {
        let (dx, dy) = (x - self.arc_center_px[0], y - self.arc_center_px[1]);
        let rho = (dx * dx + dy * dy).sqrt();
        let k = self.arc_radius_px / rho;
        [
            self.arc_center_px[0] + k * dx,
            self.arc_center_px[1] + k * dy,
        ]
    }
}

/// Settings of [`render_ambient_occlusion`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AoRenderSettings {
    /// Stratified cosine-weighted rays per pixel = n².
    pub rays_per_axis: usize,
    /// Gaussian sensor noise (standard deviation, linear intensity units).
    pub noise_sigma: f64,
    /// RNG seed (each pixel derives its own stream from it).
    pub seed: u64,
}

impl Default for AoRenderSettings {
    fn default() -> Self {
        Self {
            rays_per_axis: 24,
            noise_sigma: 0.002,
            seed: 7,
        }
    }
}

/// A rendered frame with its ground truth.
#[derive(Clone, Debug)]
pub struct RenderedFrame {
    /// The image.
    pub image: RgbImage,
    /// True paint mask.
    pub paint_mask: Vec<bool>,
    /// Ambient-occlusion fraction per pixel (before albedo and noise).
    pub occlusion: Vec<f64>,
}

/// A surface the ambient-occlusion renderer can draw: a height field H(x, y) over the image
/// plane (orthographic camera looking down −z, lengths in pixels) with painted and skin albedo,
/// and optionally occluders in front of it.
pub trait AoSurface: Sync {
    /// Image columns and rows.
    fn image_size(&self) -> (usize, usize);
    /// Height H(x, y).
    fn height(&self, x: f64, y: f64) -> f64;
    /// A Lipschitz bound of H (safe ray-marching steps) and an upper bound of H.
    fn height_bounds(&self) -> (f64, f64);
    /// Whether (x, y) lies on wrinkle paint.
    fn painted(&self, x: f64, y: f64) -> bool;
    /// Albedo of the paint and of the skin.
    fn albedo(&self) -> ([f64; 3], [f64; 3]);
    /// Uniform ambient radiance.
    fn ambient(&self) -> f64;
    /// Albedo of an occluder in front of the surface at (x, y), if any (lit by the full sky).
    fn occluder(&self, _x: f64, _y: f64) -> Option<[f64; 3]> {
        None
    }
}

impl AoSurface for WrinkleScene {
    fn image_size(&self) -> (usize, usize) {
        (self.width_px, self.height_px)
    }
    fn height(&self, x: f64, y: f64) -> f64 {
        WrinkleScene::height(self, x, y)
    }
    fn height_bounds(&self) -> (f64, f64) {
        (
            2.0 * self.depth_d_px / self.width_w_px + 2.0 * self.depth_d_px / self.taper_px + 0.05,
            self.depth_d_px * (-2.0f64).exp() + 1e-9,
        )
    }
    fn painted(&self, x: f64, y: f64) -> bool {
        WrinkleScene::painted(self, x, y)
    }
    fn albedo(&self) -> ([f64; 3], [f64; 3]) {
        (self.paint_rgb, self.skin_rgb)
    }
    fn ambient(&self) -> f64 {
        self.ambient
    }
}

/// An axis-aligned occluder in front of the face (a strand of hair, a finger), pixels.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Occluder {
    /// Columns covered, [from, to].
    pub x_px: [f64; 2],
    /// Rows covered, [from, to].
    pub y_px: [f64; 2],
    /// Its albedo.
    pub rgb: [f64; 3],
}

/// Several painted wrinkles on one skin patch (heights add up) with occluders in front: one
/// camera's view of a face take. Image size, paint, skin and ambient are this struct's; of each
/// wrinkle only the geometry (arc, taper, w, d, paint band) is used.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CompositeScene {
    /// Image columns.
    pub width_px: usize,
    /// Image rows.
    pub height_px: usize,
    /// The wrinkles.
    pub wrinkles: Vec<WrinkleScene>,
    /// Occluders in front of the skin.
    pub occluders: Vec<Occluder>,
    /// Albedo of the wrinkle paint.
    pub paint_rgb: [f64; 3],
    /// Albedo of the skin.
    pub skin_rgb: [f64; 3],
    /// Uniform ambient radiance.
    pub ambient: f64,
}

impl AoSurface for CompositeScene {
    fn image_size(&self) -> (usize, usize) {
        (self.width_px, self.height_px)
    }
    fn height(&self, x: f64, y: f64) -> f64 {
        self.wrinkles.iter().map(|w| w.height(x, y)).sum()
    }
    fn height_bounds(&self) -> (f64, f64) {
        self.wrinkles
            .iter()
            .map(AoSurface::height_bounds)
            .fold((0.05, 1e-9), |(l, h), (a, b)| (l + a, h + b))
    }
    fn painted(&self, x: f64, y: f64) -> bool {
        self.wrinkles.iter().any(|w| w.painted(x, y))
    }
    fn albedo(&self) -> ([f64; 3], [f64; 3]) {
        (self.paint_rgb, self.skin_rgb)
    }
    fn ambient(&self) -> f64 {
        self.ambient
    }
    fn occluder(&self, x: f64, y: f64) -> Option<[f64; 3]> {
        self.occluders
            .iter()
            .find(|o| x >= o.x_px[0] && x <= o.x_px[1] && y >= o.y_px[0] && y <= o.y_px[1])
            .map(|o| o.rgb)
    }
}

/// Render a wrinkle frame: per pixel, I = ambient · albedo · (fraction of cosine-weighted rays
/// that escape the 3D height field) + noise; an occluder's pixels are ambient · its albedo +
/// noise (it is far enough in front not to shadow the skin).
pub fn render_ambient_occlusion<S: AoSurface>(
    scene: &S,
    settings: &AoRenderSettings,
) -> RenderedFrame {
    let (w, h) = scene.image_size();
    let (lip, h_max) = scene.height_bounds();
    let occlusion: Vec<f64> = (0..w * h)
        .into_par_iter()
        .map(|i| {
            let (x, y) = ((i % w) as f64, (i / w) as f64);
            if scene.occluder(x, y).is_some() {
                return 1.0;
            }
            let mut rng = ChaCha8Rng::seed_from_u64(
                settings.seed ^ (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15),
            );
            pixel_occlusion(scene, x, y, settings.rays_per_axis, lip, h_max, &mut rng)
        })
        .collect();
    let mut image = RgbImage::new(w, h);
    let mut paint_mask = vec![false; w * h];
    let mut rng = ChaCha8Rng::seed_from_u64(settings.seed.wrapping_add(1));
    let (paint, skin) = scene.albedo();
    for i in 0..w * h {
        let (x, y) = ((i % w) as f64, (i / w) as f64);
        let occluder = scene.occluder(x, y);
        paint_mask[i] = occluder.is_none() && scene.painted(x, y);
        let albedo = match occluder {
            Some(rgb) => rgb,
            None if paint_mask[i] => paint,
            None => skin,
        };
        for c in 0..3 {
            image.data[i][c] = scene.ambient() * albedo[c] * occlusion[i]
                + settings.noise_sigma * gaussian(&mut rng);
        }
    }
    RenderedFrame {
        image,
        paint_mask,
        occlusion,
    }
}

fn gaussian(rng: &mut ChaCha8Rng) -> f64 {
    let u1: f64 = rng.random::<f64>().max(1e-300);
    let u2: f64 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

fn pixel_occlusion<S: AoSurface>(
    scene: &S,
    x: f64,
    y: f64,
    n: usize,
    lip: f64,
    h_max: f64,
    rng: &mut ChaCha8Rng,
) -> f64 {
    let z0 = scene.height(x, y);
    let e = 1e-5;
    let hx = (scene.height(x + e, y) - scene.height(x - e, y)) / (2.0 * e);
    let hy = (scene.height(x, y + e) - scene.height(x, y - e)) / (2.0 * e);
    let nrm = {
        let l = (hx * hx + hy * hy + 1.0).sqrt();
        [-hx / l, -hy / l, 1.0 / l]
    };
    // Orthonormal frame (t, b, n).
    let t = {
        let a = if nrm[0].abs() < 0.9 {
            [1.0, 0.0, 0.0]
        } else {
            [0.0, 1.0, 0.0]
        };
        let d = a[0] * nrm[0] + a[1] * nrm[1] + a[2] * nrm[2];
        let v = [a[0] - d * nrm[0], a[1] - d * nrm[1], a[2] - d * nrm[2]];
        let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        [v[0] / l, v[1] / l, v[2] / l]
    };
    let b = [
        nrm[1] * t[2] - nrm[2] * t[1],
        nrm[2] * t[0] - nrm[0] * t[2],
        nrm[0] * t[1] - nrm[1] * t[0],
    ];
    let origin = [x + 1e-3 * nrm[0], y + 1e-3 * nrm[1], z0 + 1e-3 * nrm[2]];
    let mut visible = 0usize;
    for i in 0..n {
        for j in 0..n {
            let u1 = (i as f64 + rng.random::<f64>()) / n as f64;
            let u2 = (j as f64 + rng.random::<f64>()) / n as f64;
            let r = u1.sqrt();
            let phi = std::f64::consts::TAU * u2;
            let (lx, ly, lz) = (r * phi.cos(), r * phi.sin(), (1.0 - u1).max(0.0).sqrt());
            let d = [
                lx * t[0] + ly * b[0] + lz * nrm[0],
                lx * t[1] + ly * b[1] + lz * nrm[1],
                lx * t[2] + ly * b[2] + lz * nrm[2],
            ];
            if ray_escapes(scene, origin, d, lip, h_max) {
                visible += 1;
            }
        }
    }
    visible as f64 / (n * n) as f64
}

/// March a ray over the height field with conservative steps gap / (L·|d_xy| + max(−d_z, 0)).
fn ray_escapes<S: AoSurface>(scene: &S, o: [f64; 3], d: [f64; 3], lip: f64, h_max: f64) -> bool {
    let dxy = (d[0] * d[0] + d[1] * d[1]).sqrt();
    let rate = lip * dxy + (-d[2]).max(0.0);
    let mut t = 0.0;
    for _ in 0..20_000 {
        let p = [o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]];
        if p[2] > h_max && d[2] >= 0.0 {
            return true;
        }
        let gap = p[2] - scene.height(p[0], p[1]);
        if gap < 0.0 {
            return false;
        }
        if rate <= 0.0 || t > 1e5 {
            return true;
        }
        t += (gap / rate).max(1e-2);
    }
    true
}
