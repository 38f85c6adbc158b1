//! A small linear-RGB float image, the pixel format between the renderers and the tracker.

use std::path::Path;

use crate::error::{FaceError, Result};

/// Row-major linear RGB image, pixel (x, y) at `data[y * width + x]`, pixel centres at
/// integer coordinates.
#[derive(Clone, Debug, PartialEq)]
pub struct RgbImage {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Pixels, row-major.
    pub data: Vec<[f64; 3]>,
}

impl RgbImage {
    /// A black image.
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            data: vec![[0.0; 3]; width * height],
        }
    }

    /// Gray value (mean of the channels) of pixel `i`.
    pub fn gray(&self, i: usize) -> f64 {
        let [r, g, b] = self.data[i];
        (r + g + b) / 3.0
    }

    /// Write as an 8-bit sRGB PNG (values clamped to [0, 1]), atomically.
    pub fn write_png(&self, path: &Path) -> Result<()> {
        let mut buf = Vec::with_capacity(self.data.len() * 3);
        for px in &self.data {
            for c in px {
                let v = c.clamp(0.0, 1.0);
                let s = if v <= 0.003_130_8 {
                    12.92 * v
                } else {
                    1.055 * v.powf(1.0 / 2.4) - 0.055
                };
                buf.push((s * 255.0 + 0.5) as u8);
            }
        }
        softcap_figure::write_png(path, &buf, self.width as u32, self.height as u32).map_err(|e| {
            FaceError::Image {
                path: path.to_path_buf(),
                reason: e.to_string(),
            }
        })
    }
}
