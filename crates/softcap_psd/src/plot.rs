//! Fig. 5.5-style plot: held-out L² error against basis size.

use crate::error::{PsdError, Result};
use crate::experiment::EvaluationReport;
use plotters::prelude::*;
use std::path::Path;

/// Draw every curve of `report` (log-scale error) into a PNG at `path`.
pub fn plot_error_vs_basis(report: &EvaluationReport, path: &Path) -> Result<()> {
    softcap_figure::draw_png(path, (900, 600), |root| {
        root.fill(&WHITE)?;
        let pmax = report
            .curves
            .iter()
            .flat_map(|c| c.basis_sizes.iter().copied())
            .max()
            .unwrap_or(1);
        let values = report
            .curves
            .iter()
            .flat_map(|c| c.heldout_rms_mm.iter().copied());
        let (lo, hi) = values.fold((f64::INFINITY, 0.0f64), |(a, b), x| (a.min(x), b.max(x)));
        let lo = lo.min(report.large_scale_only_rms_mm).max(1e-4);
        let hi = hi.max(report.large_scale_only_rms_mm);
        let mut chart = ChartBuilder::on(root)
            .caption(
                format!(
                    "L2 error vs. basis size (ICT face, {} held-out poses, H = {}, F = {})",
                    report.heldout_poses, report.handles, report.feature_edges
                ),
                (softcap_figure::FONT_FAMILY, 22),
            )
            .margin(12)
            .x_label_area_size(45)
            .y_label_area_size(70)
            .build_cartesian_2d(1f64..pmax as f64, (lo * 0.8..hi * 1.25).log_scale())?;
        chart
            .configure_mesh()
            .x_desc("size of the basis P (poses, incl. rest)")
            .y_desc("RMS vertex error on held-out poses [mm]")
            .draw()?;
        let styles: [(RGBColor, bool); 6] = [
            (BLUE, false),
            (BLUE, true),
            (RED, false),
            (RED, true),
            (BLACK, false),
            (GREEN, false),
        ];
        for (k, c) in report.curves.iter().enumerate() {
            let (color, dashed) = styles[k % styles.len()];
            let pts: Vec<(f64, f64)> = c
                .basis_sizes
                .iter()
                .zip(&c.heldout_rms_mm)
                .map(|(&p, &e)| (p as f64, e))
                .collect();
            let style = ShapeStyle {
                color: color.to_rgba(),
                filled: true,
                stroke_width: if dashed { 1 } else { 2 },
            };
            chart
                .draw_series(LineSeries::new(pts.clone(), style))?
                .label(c.method.clone())
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style));
            if dashed {
                chart.draw_series(pts.iter().map(|&p| Cross::new(p, 4, style)))?;
            } else {
                chart.draw_series(pts.iter().map(|&p| Circle::new(p, 3, style)))?;
            }
        }
        let ls = report.large_scale_only_rms_mm;
        chart
            .draw_series(LineSeries::new(
                vec![(1.0, ls), (pmax as f64, ls)],
                ShapeStyle::from(&RGBColor(128, 128, 128)),
            ))?
            .label("large-scale shell only")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], RGBColor(128, 128, 128)));
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .position(SeriesLabelPosition::UpperRight)
            .draw()?;
        Ok(())
    })
    .map_err(|e| PsdError::Render {
        path: path.into(),
        reason: e.to_string(),
    })
}
