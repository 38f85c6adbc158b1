//! Colour scales a reader can read: every colour-coded figure names its quantity and unit on a
//! colour bar, and before/after panels share one [`ColorScale`] (one range, one bar).

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

/// Maps values in `[min, max]` to colours through `map` (`t = 0` at `min`, `1` at `max`),
/// labelled with the quantity and unit it shows (e.g. `"RMS marker residual [mm]"`).
#[derive(Clone, Debug)]
pub struct ColorScale {
    /// Quantity and unit, printed under the bar.
    pub label: String,
    /// Value at the low end.
    pub min: f64,
    /// Value at the high end.
    pub max: f64,
    /// Colour of `t ∈ [0, 1]`.
    pub map: fn(f64) -> RGBColor,
}

impl ColorScale {
    /// A scale over `[min, max]`.
    pub fn new(label: impl Into<String>, min: f64, max: f64, map: fn(f64) -> RGBColor) -> Self {
        Self {
            label: label.into(),
            min,
            max,
            map,
        }
    }

    /// One scale for several panels: `[0, max]` over every finite value of all of them (a
    /// zero-based magnitude scale; `max` is at least `1e-12` so the scale is never empty).
    pub fn shared_magnitude(
        label: impl Into<String>,
        values: impl IntoIterator<Item = f64>,
        map: fn(f64) -> RGBColor,
    ) -> Self {
        let max = values
            .into_iter()
            .filter(|v| v.is_finite())
            .fold(1e-12, f64::max);
        Self::new(label, 0.0, max, map)
    }

    /// A symmetric scale `[-limit, limit]` for signed values (with [`diverging`]).
    pub fn symmetric(label: impl Into<String>, limit: f64, map: fn(f64) -> RGBColor) -> Self {
        Self::new(label, -limit, limit, map)
    }

    /// Position of `value` on the scale, clamped to `[0, 1]` (NaN maps to 0).
    pub fn t(&self, value: f64) -> f64 {
        let span = self.max - self.min;
        if span > 0.0 && value.is_finite() {
            ((value - self.min) / span).clamp(0.0, 1.0)
        } else {
            0.0
        }
    }

    /// The colour of `value`.
    pub fn color(&self, value: f64) -> RGBColor {
        (self.map)(self.t(value))
    }
}

/// Blue–white–red for signed quantities: `t = 0` blue, `0.5` white, `1` red.
pub fn diverging(t: f64) -> RGBColor {
    let x = (2.0 * t.clamp(0.0, 1.0) - 1.0) as f32;
    let c = if x >= 0.0 {
        [1.0, 1.0 - x, 1.0 - x]
    } else {
        [1.0 + x, 1.0 + x, 1.0]
    };
    RGBColor(
        (255.0 * c[0]).round() as u8,
        (255.0 * c[1]).round() as u8,
        (255.0 * c[2]).round() as u8,
    )
}

/// A perceptually ordered dark-blue → green → yellow ramp (viridis' end points and midpoint,
/// linearly interpolated) for magnitudes.
pub fn sequential(t: f64) -> RGBColor {
    const STOPS: [(f64, [f64; 3]); 5] = [
        (0.0, [68.0, 1.0, 84.0]),
        (0.25, [59.0, 82.0, 139.0]),
        (0.5, [33.0, 145.0, 140.0]),
        (0.75, [94.0, 201.0, 98.0]),
        (1.0, [253.0, 231.0, 37.0]),
    ];
    let t = t.clamp(0.0, 1.0);
    let k = STOPS
        .windows(2)
        .position(|w| t <= w[1].0)
        .unwrap_or(STOPS.len() - 2);
    let ((t0, a), (t1, b)) = (STOPS[k], STOPS[k + 1]);
    let s = (t - t0) / (t1 - t0);
    let c = |i: usize| (a[i] + s * (b[i] - a[i])).round() as u8;
    RGBColor(c(0), c(1), c(2))
}

/// Draws `scale` as a horizontal colour bar filling `area`: the gradient, ticks at the ends and
/// the middle with their values, and the label (quantity and unit) below.
pub fn draw_colorbar<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    scale: &ColorScale,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    crate::register_fonts();
    let (w, h) = area.dim_in_pixel();
    let (w, h) = (w as i32, h as i32);
    let margin = (w / 10).max(10);
    let bar_w = (w - 2 * margin).max(1);
    let bar_h = (h / 4).clamp(6, 20);
    let top = 4;
    for x in 0..bar_w {
        let t = x as f64 / (bar_w - 1).max(1) as f64;
        let color = (scale.map)(t);
        area.draw(&Rectangle::new(
            [(margin + x, top), (margin + x + 1, top + bar_h)],
            color.filled(),
        ))?;
    }
    area.draw(&Rectangle::new(
        [(margin, top), (margin + bar_w, top + bar_h)],
        BLACK.stroke_width(1),
    ))?;
    let font = (crate::FONT_FAMILY, 14).into_font();
    let tick_style = font.color(&BLACK).pos(Pos::new(HPos::Center, VPos::Top));
    for k in 0..3 {
        let t = k as f64 / 2.0;
        let x = margin + (t * (bar_w - 1) as f64).round() as i32;
        let value = scale.min + t * (scale.max - scale.min);
        area.draw(&PathElement::new(
            vec![(x, top + bar_h), (x, top + bar_h + 4)],
            BLACK,
        ))?;
        area.draw(&Text::new(
            format_tick(value, scale.max - scale.min),
            (x, top + bar_h + 6),
            tick_style.clone(),
        ))?;
    }
    let label_style = (crate::FONT_FAMILY, 15)
        .into_font()
        .color(&BLACK)
        .pos(Pos::new(HPos::Center, VPos::Top));
    area.draw(&Text::new(
        scale.label.clone(),
        (w / 2, top + bar_h + 24),
        label_style,
    ))?;
    Ok(())
}

/// A tick value with as many decimals as the scale's span needs (three significant digits).
fn format_tick(value: f64, span: f64) -> String {
    let decimals = if span > 0.0 && span.is_finite() {
        (2.0 - span.abs().log10().floor()).clamp(0.0, 6.0) as usize
    } else {
        3
    };
    let s = format!("{value:.decimals$}");
    // "-0.00" reads as a sign error on a symmetric scale.
    if s.trim_start_matches('-')
        .chars()
        .all(|c| c == '0' || c == '.')
    {
        s.trim_start_matches('-').to_string()
    } else {
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shared_scale_covers_every_panel_and_clamps() {
        let before = [0.1, 0.4, f64::NAN];
        let after = [0.05, 0.2];
        let s = ColorScale::shared_magnitude(
            "RMS residual [mm]",
            before.iter().chain(&after).copied(),
            sequential,
        );
        assert_eq!((s.min, s.max), (0.0, 0.4));
        assert_eq!(s.t(0.2), 0.5);
        assert_eq!(s.t(9.0), 1.0);
        assert_eq!(s.t(f64::NAN), 0.0);
        assert_eq!(s.color(0.4), sequential(1.0));
    }

    #[test]
    fn diverging_is_white_at_zero_and_saturated_at_the_ends() {
        let s = ColorScale::symmetric("signed detail [mm]", 2.0, diverging);
        assert_eq!(s.color(0.0), RGBColor(255, 255, 255));
        assert_eq!(s.color(2.0), RGBColor(255, 0, 0));
        assert_eq!(s.color(-5.0), RGBColor(0, 0, 255));
    }

    #[test]
    fn ticks_have_the_decimals_the_span_needs() {
        assert_eq!(format_tick(-2.0, 4.0), "-2.00");
        assert_eq!(format_tick(0.0, 4.0), "0.00");
        assert_eq!(format_tick(-0.0001, 4.0), "0.00");
        assert_eq!(format_tick(0.0123, 0.05), "0.0123");
        assert_eq!(format_tick(150.0, 300.0), "150");
    }

    #[test]
    fn colorbar_draws_gradient_and_label() {
        crate::register_fonts();
        let (w, h) = (300u32, 70u32);
        let mut pixels = vec![255u8; (w * h * 3) as usize];
        {
            let root = BitMapBackend::with_buffer(&mut pixels, (w, h)).into_drawing_area();
            let s = ColorScale::symmetric("signed detail [mm]", 2.0, diverging);
            draw_colorbar(&root, &s).unwrap();
            root.present().unwrap();
        }
        // the left end of the bar is blue, the right end red
        let px = |x: u32, y: u32| {
            let i = ((y * w + x) * 3) as usize;
            [pixels[i], pixels[i + 1], pixels[i + 2]]
        };
        let (left, right) = (px(31, 8), px(268, 8));
        assert!(left[2] == 255 && left[0] < 20, "{left:?}");
        assert!(right[0] == 255 && right[2] < 20, "{right:?}");
        // the label rows hold dark text pixels
        let dark = pixels[(45 * w * 3) as usize..]
            .iter()
            .filter(|&&p| p < 100)
            .count();
        assert!(dark > 20, "{dark}");
    }
}
