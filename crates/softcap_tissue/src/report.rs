//! The fit report: `report.md` and two PNG figures (plotters) — marker error per example for
//! the homogeneous model, the per-example fits (eq. 9) and the strain-space material (eq. 8),
//! and the strain-space error against basis size (bickel2009 Fig. 5).

use std::fmt::Write as _;
use std::path::Path;

use plotters::prelude::*;

use crate::error::{Result, TissueError};
use crate::fit::FitOutcome;

fn figure_err(path: &Path) -> impl Fn(softcap_figure::FigureError) -> TissueError + '_ {
    move |e| TissueError::Output {
        path: path.to_path_buf(),
        reason: e.to_string(),
    }
}

/// Bars of the RMS marker error per example (mm): homogeneous, per-example fit, material.
pub fn draw_example_errors(path: &Path, o: &FitOutcome) -> Result<()> {
    let n = o.examples.len().max(1);
    let ymax = o
        .examples
        .iter()
        .flat_map(|e| [e.homogeneous_rms_m, e.example_rms_m, e.material_rms_m])
        .filter(|v| v.is_finite())
        .fold(1e-9, f64::max)
        * 1e3
        * 1.15;
    softcap_figure::draw_png(path, (1100, 520), |root| {
        root.fill(&WHITE)?;
        let mut chart = ChartBuilder::on(root)
            .caption(
                "RMS marker error per example (bickel2009 eq. 9 / eq. 8)",
                (softcap_figure::FONT_FAMILY, 18),
            )
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(0.0..n as f64, 0.0..ymax)?;
        chart
            .configure_mesh()
            .x_desc("example")
            .y_desc("RMS marker error, mm")
            .disable_x_mesh()
            .draw()?;
        let series: [(&str, RGBColor, fn(&crate::ExampleSummary) -> f64, f64); 3] = [
            ("homogeneous", RED, |e| e.homogeneous_rms_m, 0.05),
            ("per-example fit", GREEN, |e| e.example_rms_m, 0.35),
            ("strain-space material", BLUE, |e| e.material_rms_m, 0.65),
        ];
        for (label, color, value, offset) in series {
            chart
                .draw_series(o.examples.iter().enumerate().map(|(k, e)| {
                    let v = value(e);
                    let v = if v.is_finite() { 1e3 * v } else { 0.0 };
                    let x0 = k as f64 + offset;
                    Rectangle::new([(x0, 0.0), (x0 + 0.28, v)], color.filled())
                }))?
                .label(label)
                .legend(move |(x, y)| {
                    Rectangle::new([(x, y - 5), (x + 14, y + 5)], color.filled())
                });
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()?;
        Ok(())
    })
    .map_err(figure_err(path))
}

/// The relative RMS parameter error of the strain-space material against basis size M.
pub fn draw_basis_curve(path: &Path, o: &FitOutcome) -> Result<()> {
    let pts: Vec<(f64, f64)> = o
        .basis_curve
        .iter()
        .map(|s| (s.num_centers as f64, 100.0 * s.relative_rms_error))
        .collect();
    let xmax = pts.last().map_or(2.0, |p| p.0.max(2.0)) + 0.5;
    let ymax = pts.iter().map(|p| p.1).fold(1e-9, f64::max) * 1.15;
    softcap_figure::draw_png(path, (800, 520), |root| {
        root.fill(&WHITE)?;
        let mut chart = ChartBuilder::on(root)
            .caption(
                "strain-space fitting error vs basis size (bickel2009 §4.2, Fig. 5)",
                (softcap_figure::FONT_FAMILY, 18),
            )
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(0.5..xmax, 0.0..ymax)?;
        chart
            .configure_mesh()
            .x_desc("basis size M (centres per tet)")
            .y_desc("RMS parameter error, % of mean λ")
            .draw()?;
        chart.draw_series(LineSeries::new(pts.clone(), BLUE.stroke_width(2)))?;
        chart.draw_series(pts.iter().map(|p| Circle::new(*p, 4, BLUE.filled())))?;
        Ok(())
    })
    .map_err(figure_err(path))
}

/// Writes `dir/report.md`, `dir/example-errors.png`, `dir/basis-error.png`.
pub fn write_report(dir: &Path, o: &FitOutcome) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| TissueError::Output {
        path: dir.to_path_buf(),
        reason: e.to_string(),
    })?;
    draw_example_errors(&dir.join("example-errors.png"), o)?;
    if !o.homogeneous_only {
        draw_basis_curve(&dir.join("basis-error.png"), o)?;
    }
    let mut md = String::new();
    let _ = writeln!(md, "# softcap tissue fit\n");
    let _ = writeln!(
        md,
        "{} tets, {} probe locations, {} examples. Homogeneous baseline E = {:.0} Pa, ν = {:.3}.\n",
        o.tets,
        o.locations,
        o.examples.len(),
        o.homogeneous_young_pa,
        o.homogeneous_nu
    );
    let _ = writeln!(
        md,
        "| model | RMS marker error (mm) | mean marker error (mm) |\n|---|---|---|"
    );
    let _ = writeln!(
        md,
        "| homogeneous linear corotational (bickel2009 Fig. 8) | {:.4} | {:.4} |",
        1e3 * o.homogeneous_rms_m,
        1e3 * o.homogeneous_mean_error_m
    );
    if o.homogeneous_only {
        let _ = writeln!(
            md,
            "\nHomogeneous baseline only (`homogeneous_only = true`): no per-example fits, no strain-space material.\n\n![per-example error](example-errors.png)\n\n| example | frame | location | force (N) | RMS displacement (mm) | homogeneous (mm) |\n|---|---|---|---|---|---|"
        );
        for (k, e) in o.examples.iter().enumerate() {
            let _ = writeln!(
                md,
                "| {k} | {} | {} | {:.3} | {:.4} | {:.4} |",
                e.frame,
                e.location,
                e.force_n,
                1e3 * e.displacement_rms_m,
                1e3 * e.homogeneous_rms_m
            );
        }
        return softcap_app::write_atomic(dir.join("report.md"), md.as_bytes()).map_err(|e| {
            TissueError::Output {
                path: dir.join("report.md"),
                reason: e.to_string(),
            }
        });
    }
    let _ = writeln!(
        md,
        "| per-example fits (eq. 9) | {:.4} | |",
        1e3 * o.example_rms_m
    );
    let _ = writeln!(
        md,
        "| strain-space material (eq. 8, {:.2} centres/tet; {} examples not converged) | {:.4} | {:.4} |\n",
        o.mean_centers,
        o.material_failures,
        1e3 * o.material_rms_m,
        1e3 * o.material_mean_error_m
    );
    if o.gamma_prior_scores.is_empty() {
        let _ = writeln!(
            md,
            "Shrinkage of the per-example fits γ_p = {} (given).\n",
            o.gamma_prior
        );
    } else {
        let _ = writeln!(
            md,
            "Shrinkage of the per-example fits γ_p = {} (leave-one-location-out):\n\n| γ_p | held-out RMS (mm) | held-out not converged | per-example fit RMS (mm) |\n|---|---|---|---|",
            o.gamma_prior
        );
        for g in &o.gamma_prior_scores {
            let _ = writeln!(
                md,
                "| {} | {:.4} | {} | {:.4} |",
                g.gamma_prior,
                1e3 * g.heldout_rms_m,
                g.heldout_failures,
                1e3 * g.example_rms_m
            );
        }
        let _ = writeln!(md);
    }
    let _ = writeln!(md, "![per-example error](example-errors.png)\n");
    let _ = writeln!(md, "![error vs basis size](basis-error.png)\n");
    let _ = writeln!(
        md,
        "| example | frame | location | force (N) | RMS displacement (mm) | homogeneous (mm) | per-example (mm) | material (mm) |\n|---|---|---|---|---|---|---|---|"
    );
    for (k, e) in o.examples.iter().enumerate() {
        let _ = writeln!(
            md,
            "| {k} | {} | {} | {:.3} | {:.4} | {:.4} | {:.4} | {:.4} |",
            e.frame,
            e.location,
            e.force_n,
            1e3 * e.displacement_rms_m,
            1e3 * e.homogeneous_rms_m,
            1e3 * e.example_rms_m,
            1e3 * e.material_rms_m
        );
    }
    softcap_app::write_atomic(dir.join("report.md"), md.as_bytes()).map_err(|e| {
        TissueError::Output {
            path: dir.join("report.md"),
            reason: e.to_string(),
        }
    })
}
