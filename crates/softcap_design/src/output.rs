//! Outputs of a design run: the design as JSON and the predicted force–displacement curves (PNG).

use crate::error::{DesignError, Result};
use plotters::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// A goal: forces of the examples and the desired surface displacements (thesis §8.4.1).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DesignTarget {
    /// Number of layers (cells) of the block.
    pub layers: usize,
    /// Probe forces of the examples [N].
    pub forces_n: Vec<f64>,
    /// Desired top-surface displacements x̄ [m], example-major (as [`crate::CompositeResponse`]).
    pub displacements_m: Vec<f64>,
    /// Desired probe indentation per example [m] (for the curve plot).
    pub probe_displacement_m: Vec<f64>,
}

/// Writes `value` as pretty JSON atomically (tmp + rename).
pub fn write_json<T: Serialize>(path: &Path, value: &T) -> Result<()> {
    let text = serde_json::to_string_pretty(value).map_err(|e| DesignError::File {
        path: path.into(),
        reason: e.to_string(),
    })?;
    let tmp = path.with_extension("json.tmp");
    std::fs::write(&tmp, text).map_err(|source| DesignError::Io {
        path: tmp.clone(),
        source,
    })?;
    std::fs::rename(&tmp, path).map_err(|source| DesignError::Io {
        path: path.into(),
        source,
    })
}

/// Reads JSON, naming the file (and serde's line/column) on error.
pub fn read_json<T: for<'de> Deserialize<'de>>(path: &Path) -> Result<T> {
    let text = std::fs::read_to_string(path).map_err(|source| DesignError::Io {
        path: path.into(),
        source,
    })?;
    serde_json::from_str(&text).map_err(|e| DesignError::File {
        path: path.into(),
        reason: e.to_string(),
    })
}

/// Force–displacement curves (probe indentation [mm] against force [N]) into a PNG at `path`.
pub fn plot_force_displacement(
    path: &Path,
    title: &str,
    forces_n: &[f64],
    curves: &[(String, Vec<f64>)],
) -> Result<()> {
    let err = |e: &dyn std::fmt::Display| DesignError::File {
        path: path.into(),
        reason: e.to_string(),
    };
    let tmp = path.with_extension("tmp.png");
    {
        softcap_figure::register_fonts();
        let root = BitMapBackend::new(&tmp, (800, 560)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| err(&e))?;
        let dmax = curves
            .iter()
            .flat_map(|c| c.1.iter().copied())
            .fold(0.0f64, f64::max)
            * 1e3;
        let fmax = forces_n.iter().copied().fold(0.0f64, f64::max);
        let mut chart = ChartBuilder::on(&root)
            .caption(title, (softcap_figure::FONT_FAMILY, 20))
            .margin(12)
            .x_label_area_size(45)
            .y_label_area_size(60)
            .build_cartesian_2d(0.0..dmax.max(1e-6) * 1.1, 0.0..fmax.max(1e-6) * 1.1)
            .map_err(|e| err(&e))?;
        chart
            .configure_mesh()
            .x_desc("probe displacement [mm]")
            .y_desc("force [N]")
            .draw()
            .map_err(|e| err(&e))?;
        let colors = [BLACK, RED, BLUE, GREEN, MAGENTA, CYAN];
        for (k, (label, d)) in curves.iter().enumerate() {
            let color = colors[k % colors.len()];
            let pts: Vec<(f64, f64)> = std::iter::once((0.0, 0.0))
                .chain(d.iter().zip(forces_n).map(|(&u, &f)| (u * 1e3, f)))
                .collect();
            chart
                .draw_series(LineSeries::new(pts.clone(), color.stroke_width(2)))
                .map_err(|e| err(&e))?
                .label(label.clone())
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color));
            chart
                .draw_series(pts.iter().map(|&p| Circle::new(p, 3, color.filled())))
                .map_err(|e| err(&e))?;
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(|e| err(&e))?;
        root.present().map_err(|e| err(&e))?;
    }
    std::fs::rename(&tmp, path).map_err(|source| DesignError::Io {
        path: path.into(),
        source,
    })
}
