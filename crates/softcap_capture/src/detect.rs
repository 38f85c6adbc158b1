//! Marker detection in colour images (thesis §6.2.2): per-colour thresholding in CIELab,
//! morphological clean-up (opening then closing, 3×3), connected components (8-connected) and
//! sub-pixel centroids weighted by colour strength.

use std::path::Path;

use image::RgbImage;
use nalgebra::Vector2;
use serde::{Deserialize, Serialize};

use crate::camera::Camera;
use crate::correspond::Blob;
use crate::error::{CaptureError, Result};
use crate::session::MarkerColor;

/// Settings of [`detect_markers`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DetectionSettings {
    /// Minimum colour strength (CIELab chroma projected on the colour's hue) of a marker pixel.
    pub chroma_threshold: f64,
    /// Colour strength below which a pixel gets no centroid weight.
    pub chroma_floor: f64,
    /// Half-width of the accepted hue sector around each colour's reference hue, degrees.
    pub hue_tolerance_deg: f64,
    /// Smallest blob area after clean-up, px.
    pub min_area_px: usize,
    /// Largest blob area, px.
    pub max_area_px: usize,
    /// Apply the morphological opening/closing.
    pub morphology: bool,
    /// L* above which a low-chroma pixel is `white`, below which it is `black` (only when the
    /// session uses those colours).
    pub white_l: f64,
    /// See `white_l`.
    pub black_l: f64,
}

impl Default for DetectionSettings {
    fn default() -> Self {
        DetectionSettings {
            chroma_threshold: 25.0,
            chroma_floor: 6.0,
            hue_tolerance_deg: 30.0,
            min_area_px: 5,
            max_area_px: 20_000,
            morphology: true,
            white_l: 95.0,
            black_l: 15.0,
        }
    }
}

/// CIELab reference hue angle `atan2(b*, a*)` of each chromatic marker colour, degrees.
pub fn reference_hue_deg(c: MarkerColor) -> Option<f64> {
    match c {
        MarkerColor::Red => Some(40.0),
        MarkerColor::Yellow => Some(95.0),
        MarkerColor::Green => Some(136.0),
        MarkerColor::Cyan => Some(196.0),
        MarkerColor::Blue => Some(295.0),
        MarkerColor::Magenta => Some(328.0),
        MarkerColor::White | MarkerColor::Black => None,
    }
}

fn srgb_to_linear_lut() -> [f64; 256] {
    let mut lut = [0.0; 256];
    for (i, v) in lut.iter_mut().enumerate() {
        let c = i as f64 / 255.0;
        *v = if c <= 0.04045 {
            c / 12.92
        } else {
            ((c + 0.055) / 1.055).powf(2.4)
        };
    }
    lut
}

/// sRGB (D65) → CIELab, `lut` the sRGB → linear table.
fn lab(lut: &[f64; 256], p: [u8; 3]) -> [f64; 3] {
    let (r, g, b) = (lut[p[0] as usize], lut[p[1] as usize], lut[p[2] as usize]);
    let x = (0.4124564 * r + 0.3575761 * g + 0.1804375 * b) / 0.95047;
    let y = 0.2126729 * r + 0.7151522 * g + 0.0721750 * b;
    let z = (0.0193339 * r + 0.1191920 * g + 0.9503041 * b) / 1.08883;
    let f = |t: f64| {
        if t > 216.0 / 24389.0 {
            t.cbrt()
        } else {
            (24389.0 / 27.0 * t + 16.0) / 116.0
        }
    };
    let (fx, fy, fz) = (f(x), f(y), f(z));
    [116.0 * fy - 16.0, 500.0 * (fx - fy), 200.0 * (fy - fz)]
}

fn erode(m: &[bool], w: usize, h: usize) -> Vec<bool> {
    let mut o = vec![false; m.len()];
    for y in 1..h.saturating_sub(1) {
        for x in 1..w - 1 {
            let i = y * w + x;
            o[i] = m[i - w - 1]
                && m[i - w]
                && m[i - w + 1]
                && m[i - 1]
                && m[i]
                && m[i + 1]
                && m[i + w - 1]
                && m[i + w]
                && m[i + w + 1];
        }
    }
    o
}

fn dilate(m: &[bool], w: usize, h: usize) -> Vec<bool> {
    let mut o = vec![false; m.len()];
    for y in 0..h {
        for x in 0..w {
            if !m[y * w + x] {
                continue;
            }
            for yy in y.saturating_sub(1)..(y + 2).min(h) {
                for xx in x.saturating_sub(1)..(x + 2).min(w) {
                    o[yy * w + xx] = true;
                }
            }
        }
    }
    o
}

/// Detects markers of the given colours in an RGB image.
pub fn detect_markers(
    img: &RgbImage,
    colors: &[MarkerColor],
    settings: &DetectionSettings,
) -> Vec<Blob> {
    let (w, h) = (img.width() as usize, img.height() as usize);
    let lut = srgb_to_linear_lut();
    let labs: Vec<[f64; 3]> = img.pixels().map(|p| lab(&lut, p.0)).collect();
    let mut out = Vec::new();
    let mut colors: Vec<MarkerColor> = colors.to_vec();
    colors.sort();
    colors.dedup();
    let cos_tol = settings.hue_tolerance_deg.to_radians().cos();
    for &color in &colors {
        // Colour strength of every pixel.
        let strength: Vec<f64> = match reference_hue_deg(color) {
            Some(hue) => {
                let (ca, cb) = (hue.to_radians().cos(), hue.to_radians().sin());
                labs.iter()
                    .map(|l| {
                        let c = (l[1] * l[1] + l[2] * l[2]).sqrt();
                        let proj = l[1] * ca + l[2] * cb;
                        if c > 0.0 && proj >= c * cos_tol {
                            proj
                        } else {
                            0.0
                        }
                    })
                    .collect()
            }
            None => {
                let white = color == MarkerColor::White;
                labs.iter()
                    .map(|l| {
                        let c = (l[1] * l[1] + l[2] * l[2]).sqrt();
                        if c > settings.chroma_threshold {
                            0.0
                        } else if white {
                            (l[0] - settings.white_l + settings.chroma_threshold).max(0.0)
                        } else {
                            (settings.black_l - l[0] + settings.chroma_threshold).max(0.0)
                        }
                    })
                    .collect()
            }
        };
        let mut mask: Vec<bool> = strength
            .iter()
            .map(|&s| s >= settings.chroma_threshold)
            .collect();
        if settings.morphology && w >= 3 && h >= 3 {
            mask = dilate(&erode(&mask, w, h), w, h); // opening: removes specks
            mask = erode(&dilate(&mask, w, h), w, h); // closing: fills pinholes
        }
        // Connected components (8-connected), iterative flood fill in scan order (deterministic).
        let mut label = vec![u32::MAX; w * h];
        let mut stack = Vec::new();
        for start in 0..w * h {
            if !mask[start] || label[start] != u32::MAX {
                continue;
            }
            let id = start as u32;
            label[start] = id;
            stack.push(start);
            let (mut x0, mut y0, mut x1, mut y1, mut area) = (w, h, 0, 0, 0usize);
            while let Some(i) = stack.pop() {
                let (x, y) = (i % w, i / w);
                area += 1;
                x0 = x0.min(x);
                y0 = y0.min(y);
                x1 = x1.max(x);
                y1 = y1.max(y);
                for yy in y.saturating_sub(1)..(y + 2).min(h) {
                    for xx in x.saturating_sub(1)..(x + 2).min(w) {
                        let j = yy * w + xx;
                        if mask[j] && label[j] == u32::MAX {
                            label[j] = id;
                            stack.push(j);
                        }
                    }
                }
            }
            if area < settings.min_area_px || area > settings.max_area_px {
                continue;
            }
            // Intensity-weighted centroid over the component's box grown by 2 px, so that the
            // anti-aliased rim (below threshold) contributes in proportion to its colour strength.
            let (mut sw, mut su, mut sv) = (0.0, 0.0, 0.0);
            for y in y0.saturating_sub(2)..(y1 + 3).min(h) {
                for x in x0.saturating_sub(2)..(x1 + 3).min(w) {
                    let i = y * w + x;
                    if label[i] != u32::MAX && label[i] != id {
                        continue;
                    }
                    let wt = (strength[i] - settings.chroma_floor).max(0.0);
                    sw += wt;
                    su += wt * x as f64;
                    sv += wt * y as f64;
                }
            }
            if sw > 0.0 {
                out.push(Blob {
                    uv: Vector2::new(su / sw, sv / sw),
                    color,
                    label: None,
                });
            }
        }
    }
    out
}

/// Loads `path` and detects markers; the image must match the camera's size.
pub fn detect_markers_in_file(
    path: &Path,
    cam: &Camera,
    colors: &[MarkerColor],
    settings: &DetectionSettings,
) -> Result<Vec<Blob>> {
    let img = image::open(path)
        .map_err(|e| match e {
            image::ImageError::IoError(source) => CaptureError::Io {
                path: path.to_path_buf(),
                source,
            },
            e => CaptureError::Image {
                path: path.to_path_buf(),
                message: e.to_string(),
            },
        })?
        .to_rgb8();
    if img.width() != cam.width || img.height() != cam.height {
        return Err(CaptureError::Image {
            path: path.to_path_buf(),
            message: format!(
                "image is {}×{}, camera `{}` is {}×{}",
                img.width(),
                img.height(),
                cam.id,
                cam.width,
                cam.height
            ),
        });
    }
    Ok(detect_markers(&img, colors, settings))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Draws an anti-aliased disc (16×16 supersampling) of `rgb` on a grey background.
    fn disc(w: u32, h: u32, cx: f64, cy: f64, r: f64, rgb: [u8; 3]) -> RgbImage {
        let bg = [205.0, 200.0, 195.0];
        RgbImage::from_fn(w, h, |x, y| {
            let mut cover = 0.0;
            for sy in 0..16 {
                for sx in 0..16 {
                    let (px, py) = (
                        x as f64 - 0.5 + (sx as f64 + 0.5) / 16.0,
                        y as f64 - 0.5 + (sy as f64 + 0.5) / 16.0,
                    );
                    if (px - cx).powi(2) + (py - cy).powi(2) <= r * r {
                        cover += 1.0 / 256.0;
                    }
                }
            }
            image::Rgb(std::array::from_fn(|k| {
                (bg[k] * (1.0 - cover) + rgb[k] as f64 * cover).round() as u8
            }))
        })
    }

    #[test]
    fn subpixel_centroid_of_antialiased_disc() {
        for &(cx, cy) in &[(20.3, 17.8), (31.71, 22.06), (15.5, 25.25)] {
            let img = disc(48, 40, cx, cy, 4.5, [30, 60, 200]);
            let b = detect_markers(
                &img,
                &[MarkerColor::Blue, MarkerColor::Red],
                &DetectionSettings::default(),
            );
            assert_eq!(b.len(), 1, "{b:?}");
            assert_eq!(b[0].color, MarkerColor::Blue);
            let e = (b[0].uv - Vector2::new(cx, cy)).norm();
            assert!(e < 0.05, "centroid error {e} px");
        }
    }

    #[test]
    fn colours_are_separated() {
        let mut img = disc(64, 40, 15.2, 20.1, 4.0, [210, 40, 40]);
        let y = disc(64, 40, 45.7, 19.4, 4.0, [230, 200, 30]);
        for (x, yy, p) in y.enumerate_pixels() {
            if x > 32 {
                img.put_pixel(x, yy, *p);
            }
        }
        let b = detect_markers(
            &img,
            &[MarkerColor::Red, MarkerColor::Yellow, MarkerColor::Blue],
            &DetectionSettings::default(),
        );
        assert_eq!(b.len(), 2);
        assert!(
            b.iter()
                .any(|b| b.color == MarkerColor::Red
                    && (b.uv - Vector2::new(15.2, 20.1)).norm() < 0.1)
        );
        assert!(
            b.iter().any(|b| b.color == MarkerColor::Yellow
                && (b.uv - Vector2::new(45.7, 19.4)).norm() < 0.1)
        );
    }
}
