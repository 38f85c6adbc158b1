//! A small software rasterizer for the figures: orthographic view along −z, z-buffer,
//! per-pixel interpolated normals with Lambert + ambient shading, PNG output.

use crate::error::{PsdError, Result};
use std::path::Path;

/// View: image size and the world-space window `[x0, x1] × [y0, y1]` mapped onto it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct View {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// World x at the left edge.
    pub x0: f32,
    /// World y at the bottom edge.
    pub y0: f32,
    /// World units per pixel.
    pub scale: f32,
}

impl View {
    /// Fit the x/y bounding box of `positions` into a `width`-pixel-wide image with a margin.
    pub fn fit(positions: &[[f32; 3]], width: u32) -> Self {
        let (mut lo, mut hi) = ([f32::INFINITY; 2], [f32::NEG_INFINITY; 2]);
        for p in positions {
            for k in 0..2 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        let margin = 0.05 * (hi[0] - lo[0]).max(hi[1] - lo[1]);
        let scale = (hi[0] - lo[0] + 2.0 * margin) / width as f32;
        let height = ((hi[1] - lo[1] + 2.0 * margin) / scale).ceil() as u32;
        Self {
            width,
            height,
            x0: lo[0] - margin,
            y0: lo[1] - margin,
            scale,
        }
    }
}

/// Render a shaded mesh (optionally coloured per vertex) into an RGB buffer.
pub fn render(
    view: &View,
    positions: &[[f32; 3]],
    normals: &[[f32; 3]],
    triangles: &[[u32; 3]],
    colors: Option<&[[f32; 3]]>,
) -> image::RgbImage {
    let (w, h) = (view.width as usize, view.height as usize);
    let mut depth = vec![f32::NEG_INFINITY; w * h];
    let mut img = image::RgbImage::from_pixel(view.width, view.height, image::Rgb([255, 255, 255]));
    let light = {
        let l = [0.3f32, 0.4, 1.0];
        let n = (l[0] * l[0] + l[1] * l[1] + l[2] * l[2]).sqrt();
        [l[0] / n, l[1] / n, l[2] / n]
    };
    let to_px = |p: [f32; 3]| {
        [
            (p[0] - view.x0) / view.scale,
            h as f32 - (p[1] - view.y0) / view.scale,
            p[2],
        ]
    };
    for t in triangles {
        let idx = t.map(|v| v as usize);
        let s = idx.map(|v| to_px(positions[v]));
        let area =
            (s[1][0] - s[0][0]) * (s[2][1] - s[0][1]) - (s[2][0] - s[0][0]) * (s[1][1] - s[0][1]);
        if area.abs() < 1e-12 {
            continue;
        }
        let minx = s
            .iter()
            .map(|p| p[0])
            .fold(f32::INFINITY, f32::min)
            .floor()
            .max(0.0) as usize;
        let maxx = s
            .iter()
            .map(|p| p[0])
            .fold(f32::NEG_INFINITY, f32::max)
            .ceil()
            .min(w as f32 - 1.0) as isize;
        let miny = s
            .iter()
            .map(|p| p[1])
            .fold(f32::INFINITY, f32::min)
            .floor()
            .max(0.0) as usize;
        let maxy = s
            .iter()
            .map(|p| p[1])
            .fold(f32::NEG_INFINITY, f32::max)
            .ceil()
            .min(h as f32 - 1.0) as isize;
        if maxx < 0 || maxy < 0 {
            continue;
        }
        for py in miny..=maxy as usize {
            for px in minx..=maxx as usize {
                let (x, y) = (px as f32 + 0.5, py as f32 + 0.5);
                let b0 = ((s[1][0] - x) * (s[2][1] - y) - (s[2][0] - x) * (s[1][1] - y)) / area;
                let b1 = ((s[2][0] - x) * (s[0][1] - y) - (s[0][0] - x) * (s[2][1] - y)) / area;
                let b2 = 1.0 - b0 - b1;
                if b0 < 0.0 || b1 < 0.0 || b2 < 0.0 {
                    continue;
                }
                let z = b0 * s[0][2] + b1 * s[1][2] + b2 * s[2][2];
                let k = py * w + px;
                if z <= depth[k] {
                    continue;
                }
                depth[k] = z;
                let mut n = [0.0f32; 3];
                let mut c = [0.0f32; 3];
                for (b, &v) in [b0, b1, b2].iter().zip(&idx) {
                    for d in 0..3 {
                        n[d] += b * normals[v][d];
                        c[d] += b * colors.map_or([0.85, 0.72, 0.64][d], |cs| cs[v][d]);
                    }
                }
                let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt().max(1e-20);
                let lambert = ((n[0] * light[0] + n[1] * light[1] + n[2] * light[2]) / len).abs();
                let shade = 0.15 + 0.85 * lambert;
                img.put_pixel(
                    px as u32,
                    py as u32,
                    image::Rgb(c.map(|x| (255.0 * (x * shade).clamp(0.0, 1.0)) as u8)),
                );
            }
        }
    }
    img
}

/// Write `img` as PNG atomically ([`softcap_figure::write_png`]).
pub fn save_png(img: &image::RgbImage, path: &Path) -> Result<()> {
    softcap_figure::write_png(path, img.as_raw(), img.width(), img.height()).map_err(|source| {
        PsdError::Io {
            path: path.into(),
            source,
        }
    })
}

/// Blue–white–red colour for a signed value in `[-1, 1]`.
pub fn diverging(x: f32) -> [f32; 3] {
    let x = x.clamp(-1.0, 1.0);
    if x >= 0.0 {
        [1.0, 1.0 - x, 1.0 - x]
    } else {
        [1.0 + x, 1.0 + x, 1.0]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn square_covers_its_pixels_and_nearer_triangle_wins() {
        let pos = [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0],
        ];
        let nrm = [[0.0, 0.0, 1.0]; 4];
        let view = View {
            width: 10,
            height: 10,
            x0: 0.0,
            y0: 0.0,
            scale: 0.1,
        };
        let img = render(&view, &pos, &nrm, &[[0, 1, 2], [0, 2, 3]], None);
        let lit = img.pixels().filter(|p| p.0 != [255, 255, 255]).count();
        assert_eq!(lit, 100);
        // a red triangle in front (z = 1) over a blue one (z = 0)
        let pos2 = [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
            [1.0, 0.0, 1.0],
            [0.0, 1.0, 1.0],
        ];
        let cols = [
            [0.0, 0.0, 1.0],
            [0.0, 0.0, 1.0],
            [0.0, 0.0, 1.0],
            [1.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
        ];
        let img = render(
            &view,
            &pos2,
            &[[0.0, 0.0, 1.0]; 6],
            &[[3, 4, 5], [0, 1, 2]],
            Some(&cols),
        );
        let p = img.get_pixel(2, 7).0;
        assert!(p[0] > 100 && p[2] == 0, "{p:?}");
    }
}
