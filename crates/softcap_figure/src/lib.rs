//! What every softcap figure shares: the font it is drawn with, its atomic PNG output
//! ([`draw_png`], [`write_png`]) and labelled colour scales ([`ColorScale`], [`draw_colorbar`]).
//!
//! softcap's stages write PNG figures with [plotters] (fit reports, residual maps, force–displacement
//! loops, `softcap inspect plot`). plotters' default text backend (`ttf`) finds fonts through the
//! system's fontconfig and rasterizes them with FreeType, which makes every build need the
//! fontconfig/FreeType development packages and makes a figure depend on whichever fonts the
//! machine happens to have installed. softcap instead enables plotters' pure-Rust `ab_glyph`
//! backend and embeds one font, DejaVu Sans (Bitstream Vera license, `fonts/LICENSE-DejaVu.txt`):
//! nothing to install, and the same pixels on every machine.
//!
//! With the `ab_glyph` backend plotters knows no font until one is registered, so every function
//! that draws text calls [`register_fonts`] first (it is cheap and idempotent). All figures use
//! the family [`FONT_FAMILY`].
//!
//! ```
//! use plotters::prelude::*;
//!
//! softcap_figure::register_fonts();
//! let mut pixels = vec![255u8; 200 * 60 * 3];
//! {
//!     let root = BitMapBackend::with_buffer(&mut pixels, (200, 60)).into_drawing_area();
//!     root.draw(&Text::new("1.5 mm", (10, 20), (softcap_figure::FONT_FAMILY, 20)))
//!         .expect("the embedded font draws text");
//!     root.present().expect("a buffer backend cannot fail to present");
//! }
//! assert!(pixels.iter().any(|&p| p < 128), "the text left dark pixels");
//! ```

mod png;
mod scale;

use std::sync::OnceLock;

pub use png::{FigureError, draw_png, write_png};
pub use scale::{ColorScale, diverging, draw_colorbar, sequential};

/// The font family name every softcap figure uses (plotters' conventional `"sans-serif"`).
pub const FONT_FAMILY: &str = "sans-serif";

/// DejaVu Sans Book, embedded (Bitstream Vera license; DejaVu changes are public domain).
pub const DEJAVU_SANS_TTF: &[u8] = include_bytes!("../fonts/DejaVuSans.ttf");

/// Register the embedded font with plotters as [`FONT_FAMILY`] (all styles fall back to it).
///
/// Idempotent and thread-safe; returns whether the font is registered. It can only return
/// `false` if the embedded bytes were not a valid font, which the crate's tests rule out; text
/// drawn after a `false` would fail with plotters' `FontUnavailable` error, which every caller
/// already reports as a figure error.
pub fn register_fonts() -> bool {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    *REGISTERED.get_or_init(|| {
        plotters::style::register_font(
            FONT_FAMILY,
            plotters::style::FontStyle::Normal,
            DEJAVU_SANS_TTF,
        )
        .is_ok()
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use plotters::prelude::*;

    /// Text laid out with the embedded font has the width DejaVu Sans gives it: "MMMM" at 20 px is
    /// wider than "iiii" (a proportional font, so not plotters' fixed-width fallback).
    #[test]
    fn embedded_font_lays_out_proportional_text() {
        assert!(register_fonts());
        assert!(register_fonts(), "a second call is a no-op");
        let font: FontDesc<'_> = (FONT_FAMILY, 20.0).into();
        let (wide, _) = font
            .box_size("MMMM")
            .expect("layout with the embedded font");
        let (narrow, _) = font
            .box_size("iiii")
            .expect("layout with the embedded font");
        assert!(wide > 2 * narrow, "MMMM {wide} px vs iiii {narrow} px");
        // Bold and italic fall back to the one registered face.
        let bold = FontDesc::new(FontFamily::SansSerif, 20.0, FontStyle::Bold);
        assert!(bold.box_size("axis").is_ok());
    }

    /// A chart with a caption and axis labels renders into a bitmap (the path every stage takes).
    #[test]
    fn chart_with_caption_and_labels_renders() {
        register_fonts();
        let (w, h) = (320u32, 200u32);
        let mut pixels = vec![255u8; (w * h * 3) as usize];
        {
            let root = BitMapBackend::with_buffer(&mut pixels, (w, h)).into_drawing_area();
            let mut chart = ChartBuilder::on(&root)
                .caption("force (N)", (FONT_FAMILY, 18))
                .x_label_area_size(30)
                .y_label_area_size(40)
                .build_cartesian_2d(0.0..1.0, 0.0..2.0)
                .expect("chart");
            chart
                .configure_mesh()
                .x_desc("depth (mm)")
                .draw()
                .expect("mesh with labels");
            root.present().expect("present");
        }
        // The caption band (top 20 rows) holds dark text pixels.
        let caption_dark = pixels[..(20 * w * 3) as usize]
            .iter()
            .filter(|&&p| p < 100)
            .count();
        assert!(caption_dark > 20, "caption pixels: {caption_dark}");
    }
}
