//! Figures as PNG files, written atomically (`NAME.PID-N.tmp`, fsync, rename: [`softcap_app::fs`]).

use std::fmt;
use std::io;
use std::path::Path;

use image::ImageEncoder;
use image::codecs::png::PngEncoder;
use plotters::coord::Shift;
use plotters::prelude::{BitMapBackend, DrawingArea, IntoDrawingArea};

/// Why a figure was not written.
#[derive(Debug)]
pub enum FigureError {
    /// plotters failed to lay out or draw the figure.
    Draw(String),
    /// Encoding or writing the PNG failed.
    Write(io::Error),
}

impl fmt::Display for FigureError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            FigureError::Draw(reason) => write!(f, "drawing failed: {reason}"),
            FigureError::Write(e) => write!(f, "writing failed: {e}"),
        }
    }
}

impl std::error::Error for FigureError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            FigureError::Draw(_) => None,
            FigureError::Write(e) => Some(e),
        }
    }
}

/// Writes 8-bit RGB pixels (`width × height × 3` bytes, rows top to bottom) as a PNG at `path`,
/// atomically. The bytes are those `image::save_buffer` would write.
pub fn write_png(path: &Path, rgb: &[u8], width: u32, height: u32) -> io::Result<()> {
    softcap_app::write_atomic_with(path, |w| {
        PngEncoder::new(w)
            .write_image(rgb, width, height, image::ColorType::Rgb8)
            .map_err(io::Error::other)
    })
}

/// Draws a `size` (width, height) figure with `draw` into memory and writes it as a PNG at
/// `path` atomically, so a figure that fails half-way leaves no file. Registers the font first.
pub fn draw_png(
    path: &Path,
    size: (u32, u32),
    draw: impl FnOnce(&DrawingArea<BitMapBackend<'_>, Shift>) -> Result<(), Box<dyn std::error::Error>>,
) -> Result<(), FigureError> {
    crate::register_fonts();
    let (w, h) = size;
    let mut pixels = vec![255u8; w as usize * h as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut pixels, size).into_drawing_area();
        draw(&root).map_err(|e| FigureError::Draw(e.to_string()))?;
        root.present()
            .map_err(|e| FigureError::Draw(e.to_string()))?;
    }
    write_png(path, &pixels, w, h).map_err(FigureError::Write)
}

#[cfg(test)]
mod tests {
    use super::*;
    use plotters::prelude::*;

    #[test]
    fn draw_png_writes_a_decodable_png_and_no_tmp() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("f.png");
        draw_png(&p, (64, 32), |root| {
            root.fill(&BLUE)?;
            Ok(())
        })
        .unwrap();
        let img = image::open(&p).unwrap().to_rgb8();
        assert_eq!((img.width(), img.height()), (64, 32));
        assert_eq!(img.get_pixel(5, 5).0, [0, 0, 255]);
        assert!(
            std::fs::read_dir(dir.path()).unwrap().all(|e| !e
                .unwrap()
                .file_name()
                .to_string_lossy()
                .ends_with(".tmp"))
        );
    }

    #[test]
    fn a_failed_drawing_leaves_no_file() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("f.png");
        let e = draw_png(&p, (8, 8), |_| Err("no data".into())).unwrap_err();
        assert_eq!(e.to_string(), "drawing failed: no data");
        assert!(std::fs::read_dir(dir.path()).unwrap().next().is_none());
    }
}
