//! The calibration report: `report.md` (errors before/after, gauge, status, rounds, per-camera
//! parameter changes and rejected outliers) and one reprojection-error histogram per camera.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use plotters::prelude::*;

use super::{Calibration, CalibrationInput};
use crate::error::{CaptureError, Result};
use crate::pipeline::median_sorted;

/// Writes `report.md` and `reprojection_<camera>.png` into `dir` (created if missing); returns
/// the files written, each atomically ([`softcap_app::write_atomic`]).
pub fn write_report(
    dir: &Path,
    input: &CalibrationInput,
    cal: &Calibration,
) -> Result<Vec<PathBuf>> {
    std::fs::create_dir_all(dir).map_err(|e| CaptureError::Output {
        path: dir.to_path_buf(),
        message: e.to_string(),
    })?;
    let mut written = Vec::new();
    for (c, cam) in cal.refined.iter().enumerate() {
        let path = dir.join(format!("reprojection_{}.png", file_safe(&cam.id)));
        histogram(
            &path,
            &cam.id,
            &cal.before.per_camera_px[c],
            &cal.after.per_camera_px[c],
        )?;
        written.push(path);
    }
    let path = dir.join("report.md");
    super::write_atomic(&path, markdown(input, cal, &written).as_bytes())?;
    written.push(path);
    Ok(written)
}

fn file_safe(id: &str) -> String {
    id.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect()
}

fn sorted(v: &[f64]) -> Vec<f64> {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    s
}

fn markdown(input: &CalibrationInput, cal: &Calibration, figures: &[PathBuf]) -> String {
    let mut t = String::new();
    let s = &cal.settings;
    let _ = writeln!(t, "# Calibration report\n");
    let _ = writeln!(t, "- input: `{}`", input.source.display());
    let _ = writeln!(t, "- initial rig: `{}`", input.cameras_path.display());
    let _ = writeln!(
        t,
        "- refined: extrinsics + {}; loss {:?} with scale {} σ̂; outliers beyond {} σ̂ rejected",
        s.bundle.refine.describe(),
        s.bundle.loss,
        s.loss_scale,
        s.outlier_threshold
    );
    let _ = writeln!(t, "- gauge: {}", cal.gauge_description());
    let _ = writeln!(t, "- status: {}", cal.status_description());
    for w in cal.warnings() {
        let _ = writeln!(t, "- warning: {w}");
    }
    let _ = writeln!(t);
    let _ = writeln!(
        t,
        "| all points, each triangulated from all its views | before | after |"
    );
    let _ = writeln!(t, "|---|---|---|");
    let _ = writeln!(
        t,
        "| median per-point reprojection error (mean over its views) | {:.3} px | {:.3} px |",
        cal.before.median_point_error_px, cal.after.median_point_error_px
    );
    let _ = writeln!(
        t,
        "| median per-observation reprojection error | {:.3} px | {:.3} px |",
        cal.before.median_observation_error_px, cal.after.median_observation_error_px
    );
    let _ = writeln!(
        t,
        "| points not triangulable in front of all their cameras (of {}) | {} | {} |\n",
        cal.before.points, cal.before.failed_points, cal.after.failed_points
    );
    let _ = writeln!(t, "## Rounds\n");
    let _ = writeln!(
        t,
        "| round | σ̂ (px) | loss scale (px) | inlier observations | points | LM iterations | robust cost before → after | status |"
    );
    let _ = writeln!(t, "|---|---|---|---|---|---|---|---|");
    for (k, r) in cal.rounds.iter().enumerate() {
        let _ = writeln!(
            t,
            "| {} | {:.3} | {:.3} | {} | {} | {} | {:.6e} → {:.6e} | {:?} |",
            k + 1,
            r.sigma_px,
            r.loss_scale_px,
            r.inliers,
            r.points,
            r.iterations,
            r.initial_cost,
            r.final_cost,
            r.status
        );
    }
    let _ = writeln!(t, "\n## Cameras\n");
    let _ = writeln!(
        t,
        "| camera | observations | rejected (last round) | median error before (px) | after (px) | Δ rotation (°) | Δ centre (mm) | Δ focal (%) | Δ cx, cy (px) | Δ k1 | Δ k2 | Δ p1 | Δ p2 | Δ k3 |"
    );
    let _ = writeln!(
        t,
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"
    );
    for (c, ch) in cal.changes().iter().enumerate() {
        let med = |v: &[f64]| median_sorted(&sorted(v));
        let _ = writeln!(
            t,
            "| {} | {} | {} | {:.3} | {:.3} | {:.4} | {:.3} | {:+.3} | {:+.2}, {:+.2} | {:+.2e} | {:+.2e} | {:+.2e} | {:+.2e} | {:+.2e} |",
            ch.id,
            cal.observations_per_camera[c],
            cal.rejected_per_camera[c],
            med(&cal.before.per_camera_px[c]),
            med(&cal.after.per_camera_px[c]),
            ch.rotation_deg,
            ch.centre_m * 1e3,
            ch.focal_relative * 100.0,
            ch.principal_px[0],
            ch.principal_px[1],
            ch.distortion[0],
            ch.distortion[1],
            ch.distortion[2],
            ch.distortion[3],
            ch.distortion[4]
        );
    }
    let _ = writeln!(t, "\n## Figures\n");
    for f in figures {
        if let Some(name) = f.file_name().and_then(|n| n.to_str()) {
            let _ = writeln!(t, "![{name}]({name})");
        }
    }
    t
}

/// Histogram of one camera's reprojection errors before and after on a log axis; the last bin
/// collects everything beyond the 99th percentile of the errors before.
fn histogram(path: &Path, camera: &str, before: &[f64], after: &[f64]) -> Result<()> {
    let err = |e: &dyn std::fmt::Display| CaptureError::Output {
        path: path.to_path_buf(),
        message: e.to_string(),
    };
    let (b, a) = (sorted(before), sorted(after));
    let finite = |v: &[f64]| {
        v.iter()
            .copied()
            .filter(|x| x.is_finite())
            .collect::<Vec<_>>()
    };
    let bf = finite(&b);
    let x_max = bf
        .get(((bf.len() as f64 * 0.99) as usize).min(bf.len().saturating_sub(1)))
        .copied()
        .unwrap_or(1.0)
        .max(1.0);
    // Log-spaced bins from 0.01 px: the errors after span sub-pixel to tens of pixels, those
    // before tens to hundreds. The first and last bins collect everything beyond them.
    const BINS: usize = 48;
    let (lo, hi) = (0.01_f64, x_max.max(10.0));
    let edge = |k: usize| lo * (hi / lo).powf(k as f64 / BINS as f64);
    let counts = |v: &[f64]| {
        let mut c = [0usize; BINS];
        for &x in v {
            let t = ((x / lo).ln() / (hi / lo).ln() * BINS as f64).floor();
            let k = if t.is_nan() {
                BINS - 1
            } else {
                t.clamp(0.0, (BINS - 1) as f64) as usize
            };
            c[k] += 1;
        }
        c
    };
    let (cb, ca) = (counts(&b), counts(&a));
    let y_max = cb.iter().chain(&ca).copied().max().unwrap_or(1).max(1) as f64 * 1.1;
    softcap_figure::draw_png(path, (800, 480), |root| {
        root.fill(&WHITE)?;
        let mut chart = ChartBuilder::on(root)
            .caption(
                format!(
                    "{camera}: reprojection error per observation (last bin: ≥ {:.1} px)",
                    edge(BINS - 1)
                ),
                (softcap_figure::FONT_FAMILY, 18),
            )
            .margin(12)
            .x_label_area_size(45)
            .y_label_area_size(60)
            .build_cartesian_2d((lo..hi).log_scale(), 0.0..y_max)?;
        chart
            .configure_mesh()
            .x_desc("reprojection error [px]")
            .y_desc("observations")
            .draw()?;
        let series = [
            ("before", &cb, RGBColor(128, 128, 128), median_sorted(&b)),
            ("after", &ca, RGBColor(31, 119, 180), median_sorted(&a)),
        ];
        for (label, counts, color, median) in series {
            chart
                .draw_series(counts.iter().enumerate().map(|(k, &n)| {
                    Rectangle::new(
                        [(edge(k), 0.0), (edge(k + 1), n as f64)],
                        color.mix(0.45).filled(),
                    )
                }))?
                .label(format!("{label}: median {median:.2} px"))
                .legend(move |(x, y)| {
                    Rectangle::new([(x, y - 5), (x + 14, y + 5)], color.mix(0.45).filled())
                });
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font((softcap_figure::FONT_FAMILY, 15))
            .draw()?;
        Ok(())
    })
    .map_err(|e| err(&e))
}
