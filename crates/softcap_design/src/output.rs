//! Outputs of a design run: the design as MCAP (`/design/report`, with provenance) and JSON, and
//! the predicted force–displacement curves (PNG).

use crate::error::{DesignError, Result};
use crate::search::SearchReport;
use plotters::prelude::*;
use serde::{Deserialize, Serialize};
use softcap_mcap::proto::{KeyValue, Report};
use softcap_mcap::{Provenance, Writer, topics};
use std::path::Path;

/// A goal: forces of the examples and the desired surface displacements (thesis §8.4.1).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DesignTarget {
    /// Number of layers (cells) of the block.
    pub layers: usize,
    /// Probe forces of the examples \[N\].
    pub forces_n: Vec<f64>,
    /// Desired top-surface displacements x̄ \[m\], example-major (as [`crate::CompositeResponse`]).
    pub displacements_m: Vec<f64>,
    /// Desired probe indentation per example \[m\] (for the curve plot).
    pub probe_displacement_m: Vec<f64>,
}

/// Writes `value` as pretty JSON atomically ([`softcap_app::write_atomic`]).
pub fn write_json<T: Serialize>(path: &Path, value: &T) -> Result<()> {
    let text = serde_json::to_string_pretty(value).map_err(|e| DesignError::File {
        path: path.into(),
        reason: e.to_string(),
    })?;
    softcap_app::write_atomic(path, text.as_bytes()).map_err(|source| DesignError::Io {
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

/// Force–displacement curves (probe indentation \[mm\] against force \[N\]) into a PNG at `path`.
pub fn plot_force_displacement(
    path: &Path,
    title: &str,
    forces_n: &[f64],
    curves: &[(String, Vec<f64>)],
) -> Result<()> {
    softcap_figure::draw_png(path, (800, 560), |root| {
        root.fill(&WHITE)?;
        let dmax = curves
            .iter()
            .flat_map(|c| c.1.iter().copied())
            .fold(0.0f64, f64::max)
            * 1e3;
        let fmax = forces_n.iter().copied().fold(0.0f64, f64::max);
        let mut chart = ChartBuilder::on(root)
            .caption(title, (softcap_figure::FONT_FAMILY, 20))
            .margin(12)
            .x_label_area_size(45)
            .y_label_area_size(60)
            .build_cartesian_2d(0.0..dmax.max(1e-6) * 1.1, 0.0..fmax.max(1e-6) * 1.1)?;
        chart
            .configure_mesh()
            .x_desc("probe displacement [mm]")
            .y_desc("force [N]")
            .draw()?;
        let colors = [BLACK, RED, BLUE, GREEN, MAGENTA, CYAN];
        for (k, (label, d)) in curves.iter().enumerate() {
            let color = colors[k % colors.len()];
            let pts: Vec<(f64, f64)> = std::iter::once((0.0, 0.0))
                .chain(d.iter().zip(forces_n).map(|(&u, &f)| (u * 1e3, f)))
                .collect();
            chart
                .draw_series(LineSeries::new(pts.clone(), color.stroke_width(2)))?
                .label(label.clone())
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color));
            chart.draw_series(pts.iter().map(|&p| Circle::new(p, 3, color.filled())))?;
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()?;
        Ok(())
    })
    .map_err(|e| DesignError::Output {
        path: path.into(),
        reason: e.to_string(),
    })
}

/// What `softcap design search` found, as written to `design.mcap` and `design.json`.
#[derive(Clone, Debug, Serialize)]
pub struct DesignRecord {
    /// Material index per layer, bottom first.
    pub design: Vec<usize>,
    /// RMS top-surface displacement error of the found design against the target \[m\].
    pub rms_error_m: f64,
    /// The search's statistics.
    pub search: SearchReport,
    /// Probe forces of the examples \[N\].
    pub forces_n: Vec<f64>,
    /// The target's probe indentation per example \[m\].
    pub target_probe_displacement_m: Vec<f64>,
    /// The found design's predicted probe indentation per example \[m\].
    pub predicted_probe_displacement_m: Vec<f64>,
}

/// The `/design/report` of a search: design, errors, search statistics per level, and per
/// example the force, the target and the predicted probe indentation.
pub fn design_report(record: &DesignRecord, materials: usize, clusters: usize) -> Report {
    let design: Vec<String> = record.design.iter().map(usize::to_string).collect();
    let mut entries = vec![
        KeyValue::text("design", design.join(",")),
        KeyValue::integer("layers", record.design.len() as i64, ""),
        KeyValue::integer("materials", materials as i64, ""),
        KeyValue::integer("clusters", clusters as i64, ""),
        KeyValue::number("rms_error", record.rms_error_m, "m"),
        KeyValue::number("search.error", record.search.error_m, "m"),
        KeyValue::integer("search.evaluations", record.search.evaluations as i64, ""),
    ];
    for l in &record.search.levels {
        let p = format!("search.level.{}", l.level);
        entries.push(KeyValue::integer(format!("{p}.nodes"), l.nodes as i64, ""));
        entries.push(KeyValue::integer(
            format!("{p}.culled"),
            l.culled as i64,
            "",
        ));
        entries.push(KeyValue::integer(
            format!("{p}.representatives"),
            l.representatives as i64,
            "",
        ));
        entries.push(KeyValue::number(format!("{p}.d_min"), l.d_min, "m"));
    }
    let examples = record
        .forces_n
        .iter()
        .zip(&record.target_probe_displacement_m)
        .zip(&record.predicted_probe_displacement_m);
    for (k, ((&f, &target), &predicted)) in examples.enumerate() {
        let p = format!("example.{k}");
        entries.push(KeyValue::number(format!("{p}.force"), f, "N"));
        entries.push(KeyValue::number(
            format!("{p}.target_probe_displacement"),
            target,
            "m",
        ));
        entries.push(KeyValue::number(
            format!("{p}.predicted_probe_displacement"),
            predicted,
            "m",
        ));
    }
    Report {
        title: "softcap design search (thesis §8.4)".into(),
        entries,
    }
}

/// Writes `design.mcap` atomically: the provenance (inputs, arguments, settings) and
/// `/design/report` ([`design_report`]).
pub fn write_design_mcap(
    path: &Path,
    provenance: &Provenance,
    record: &DesignRecord,
    materials: usize,
    clusters: usize,
) -> Result<()> {
    let mcap_err = |e: softcap_mcap::Error| DesignError::Output {
        path: path.into(),
        reason: e.to_string(),
    };
    let mut w = Writer::create(path, provenance).map_err(mcap_err)?;
    w.write_static(
        &topics::DESIGN_REPORT,
        &design_report(record, materials, clusters),
    )
    .map_err(mcap_err)?;
    w.finish().map_err(mcap_err)?;
    Ok(())
}
