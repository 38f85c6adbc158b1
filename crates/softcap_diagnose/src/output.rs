//! Outputs of a diagnosis: the JSON document (`--json`), the report folder (`--report`: report.md
//! with a residual map on the surface, residual against time, measured vs simulated
//! force–displacement loops and a before/after table) and `diagnosis.mcap`.

use crate::diagnose::DiagnosisRun;
use crate::evidence::Diagnosis;
use crate::hypotheses::Effect;
use crate::recording::Recording;
use crate::residual::Residuals;
use crate::segment::Phase;
use crate::{DiagnoseError, Result};
use nalgebra::Vector3;
use plotters::prelude::*;
use softcap_mcap::{Provenance, Writer, proto, topics};
use std::fmt::Write as _;
use std::path::Path;

fn out_err(path: &Path, e: impl std::fmt::Display) -> DiagnoseError {
    DiagnoseError::Output {
        path: path.to_path_buf(),
        reason: e.to_string(),
    }
}

/// Writes `bytes` atomically ([`softcap_app::write_atomic`]: `NAME.PID-N.tmp`, fsync, rename).
fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    softcap_app::write_atomic(path, bytes).map_err(|e| out_err(path, e))
}

/// Writes the diagnosis JSON (issue 8 schema).
pub fn write_json(path: &Path, d: &Diagnosis) -> Result<()> {
    let s = serde_json::to_string_pretty(d).map_err(|e| out_err(path, e))?;
    write_atomic(path, s.as_bytes())
}

fn key_value(key: &str, v: f64) -> proto::KeyValue {
    let unit = if key.ends_with("_s") {
        "s"
    } else if key.ends_with("_s2") {
        "s^2"
    } else if key.ends_with("_n") {
        "N"
    } else if key.ends_with("_m_per_n") {
        "m/N"
    } else {
        ""
    };
    proto::KeyValue {
        key: key.into(),
        value: Some(proto::key_value::Value::Number(v)),
        unit: unit.into(),
    }
}

/// The `unexplained` verdict's location and the outlier markers left out, as report sections.
fn write_unexplained(s: &mut String, d: &Diagnosis) {
    if let Some(u) = &d.unexplained {
        let markers: Vec<String> = u
            .markers
            .iter()
            .map(|(id, r)| format!("{id} {:.4} mm", 1e3 * r))
            .collect();
        let _ = writeln!(
            s,
            "No catalog entry explains the mismatch: held-out RMS {:.4} mm, the best any \
             hypothesis or the stiffness scale reaches {:.4} mm, noise RMS {:.4} mm. It lives in \
             `{}` ({:.4} mm){}; markers {}.\n",
            1e3 * u.heldout_rmse_m,
            1e3 * u.best_explained_rmse_m,
            1e3 * u.noise_floor_m,
            u.cell,
            1e3 * u.cell_rmse_m,
            u.location
                .map(|l| format!(", largest at probe location {l}"))
                .unwrap_or_default(),
            markers.join(", ")
        );
    }
    if !d.outliers.is_empty() {
        let _ = writeln!(
            s,
            "## Outlier markers (left out)\n\n| marker | frames | time (s) | step (mm) | observations |\n|---|---|---|---|---|"
        );
        for o in &d.outliers {
            let _ = writeln!(
                s,
                "| {} | {}–{} | {:.2}–{:.2} | {:.3} | {} |",
                o.marker,
                o.frames[0],
                o.frames[1],
                o.time_s[0],
                o.time_s[1],
                1e3 * o.step_m,
                o.observations
            );
        }
        let _ = writeln!(s);
    }
}

/// The diagnosis as its protobuf message.
pub fn diagnosis_message(d: &Diagnosis) -> proto::Diagnosis {
    proto::Diagnosis {
        verdict: d.verdict.clone(),
        ranked: d
            .ranked
            .iter()
            .map(|r| proto::HypothesisScore {
                hypothesis: r.hypothesis.clone(),
                score: r.score,
                heldout_rmse_before_m: r.heldout_rmse_before_m,
                heldout_rmse_after_m: r.heldout_rmse_after_m,
                params: r.params.iter().map(|(k, v)| key_value(k, *v)).collect(),
                evidence_json: r.evidence.to_json().to_string(),
            })
            .collect(),
        located: d
            .located
            .iter()
            .map(|l| proto::LocatedResidual {
                region: l.region.clone(),
                phase: l.phase.clone(),
                component: l.component.clone(),
                rmse_m: l.rmse_m,
            })
            .collect(),
        unexplained: d.unexplained.as_ref().map(|u| proto::Unexplained {
            heldout_rmse_m: u.heldout_rmse_m,
            best_explained_rmse_m: u.best_explained_rmse_m,
            noise_floor_m: u.noise_floor_m,
            cell: u.cell.clone(),
            cell_rmse_m: u.cell_rmse_m,
            location: u.location.map(|l| l as u32),
            markers: u
                .markers
                .iter()
                .map(|(id, rmse_m)| proto::KeyValue {
                    key: id.clone(),
                    value: Some(proto::key_value::Value::Number(*rmse_m)),
                    unit: "m".into(),
                })
                .collect(),
        }),
        outliers: d
            .outliers
            .iter()
            .map(|o| proto::OutlierRun {
                marker: o.marker.clone(),
                marker_index: o.marker_index as u32,
                first_frame: o.frames[0] as u32,
                last_frame: o.frames[1] as u32,
                first_time_s: o.time_s[0],
                last_time_s: o.time_s[1],
                step_m: o.step_m,
                observations: o.observations as u32,
            })
            .collect(),
    }
}

/// The extended model (the verdict's term and parameters).
pub fn extended_model_message(d: &Diagnosis, base_material_sha256: &str) -> proto::ExtendedModel {
    let top = d.ranked.iter().find(|r| r.hypothesis == d.verdict);
    proto::ExtendedModel {
        hypothesis: d.verdict.clone(),
        term: Effect::from_name(&d.verdict)
            .and_then(crate::hypotheses::of)
            .map(|h| h.term().to_string())
            .unwrap_or_else(|| {
                format!(
                    "{}: the default elastostatic model (bickel2009)",
                    if d.verdict == "unexplained" {
                        "unexplained (no catalog entry explains the mismatch)"
                    } else {
                        "none"
                    }
                )
            }),
        params: top
            .map(|r| r.params.iter().map(|(k, v)| key_value(k, *v)).collect())
            .unwrap_or_default(),
        base_material_sha256: base_material_sha256.into(),
    }
}

fn sim_markers(rec: &Recording, k: usize, x: &[Vector3<f64>]) -> proto::SimulatedMarkers {
    let v = |p: &Vector3<f64>| proto::Vec3 {
        x: p.x,
        y: p.y,
        z: p.z,
    };
    proto::SimulatedMarkers {
        frame: rec.frames[k].frame,
        example: 0,
        load_step: 0,
        ids: (0..x.len() as u32).collect(),
        positions_m: x.iter().map(v).collect(),
        measured_m: rec.frames[k]
            .markers_m
            .iter()
            .zip(x)
            .map(|(m, s)| v(&m.unwrap_or(*s)))
            .collect(),
    }
}

/// Writes `diagnosis.mcap`: diagnosis, extended model, baseline/extended simulations per frame,
/// a key-value report.
pub fn write_mcap(
    path: &Path,
    provenance: &Provenance,
    rec: &Recording,
    run: &DiagnosisRun,
    base_material_sha256: &str,
) -> Result<()> {
    let e = |source: softcap_mcap::Error| DiagnoseError::Mcap {
        path: path.to_path_buf(),
        source: Box::new(source),
    };
    let d = &run.diagnosis;
    let mut w = Writer::create(path, provenance).map_err(e)?;
    w.write_static(&topics::DIAGNOSIS, &diagnosis_message(d))
        .map_err(e)?;
    w.write_static(
        &topics::EXTENDED_MODEL,
        &extended_model_message(d, base_material_sha256),
    )
    .map_err(e)?;
    let t0 = rec.frames.first().map(|f| f.time_s).unwrap_or(0.0);
    for k in 0..rec.frames.len() {
        let t_ns = ((rec.frames[k].time_s - t0).max(0.0) * 1e9).round() as u64;
        w.write(
            &topics::BASELINE_MARKERS,
            t_ns,
            &sim_markers(rec, k, &run.baseline_m[k]),
        )
        .map_err(e)?;
        if let Some(x) = &run.extended_m {
            w.write(&topics::EXTENDED_MARKERS, t_ns, &sim_markers(rec, k, &x[k]))
                .map_err(e)?;
        }
    }
    let top = d.ranked.first();
    let report = proto::Report {
        title: "softcap diagnose".into(),
        entries: vec![
            proto::KeyValue {
                key: "verdict".into(),
                value: Some(proto::key_value::Value::Text(d.verdict.clone())),
                unit: String::new(),
            },
            proto::KeyValue {
                key: "heldout_rmse_before".into(),
                value: top.map(|r| proto::key_value::Value::Number(r.heldout_rmse_before_m)),
                unit: "m".into(),
            },
            proto::KeyValue {
                key: "heldout_rmse_after".into(),
                value: top.map(|r| proto::key_value::Value::Number(r.heldout_rmse_after_m)),
                unit: "m".into(),
            },
            proto::KeyValue {
                key: "locations".into(),
                value: Some(proto::key_value::Value::Integer(
                    run.segmentation.num_folds() as i64,
                )),
                unit: String::new(),
            },
            proto::KeyValue {
                key: "noise_sigma".into(),
                value: Some(proto::key_value::Value::Number(
                    run.signatures.noise_sigma_m,
                )),
                unit: "m".into(),
            },
        ],
    };
    w.write_static(&topics::DIAGNOSE_REPORT, &report)
        .map_err(e)?;
    w.finish().map_err(e)?;
    Ok(())
}

fn per_marker_rms(res: &Residuals, m: usize) -> f64 {
    let (mut a, mut n) = (0.0, 0);
    for row in res {
        if let Some(r) = row[m] {
            a += r.norm_squared();
            n += 1;
        }
    }
    if n > 0 { (a / n as f64).sqrt() } else { 0.0 }
}

fn per_frame_rms(row: &[Option<Vector3<f64>>]) -> f64 {
    let (mut a, mut n) = (0.0, 0);
    for r in row.iter().flatten() {
        a += r.norm_squared();
        n += 1;
    }
    if n > 0 { (a / n as f64).sqrt() } else { 0.0 }
}

type DrawResult<T> = std::result::Result<T, String>;

/// The drawing area a report figure is drawn on (in memory; [`softcap_figure::draw_png`] writes
/// it atomically).
type Root<'a> = DrawingArea<BitMapBackend<'a>, plotters::coord::Shift>;

/// Residual map on the surface: markers at their rest positions projected onto the plane
/// perpendicular to the mean probe axis, coloured by per-marker RMS residual (before | after),
/// one colour scale shared by both panels and drawn as a labelled bar under them; probe locations
/// as crosses.
fn draw_residual_map(root: &Root<'_>, rec: &Recording, run: &DiagnosisRun) -> DrawResult<()> {
    let axis: Vector3<f64> = run.segmentation.locations.iter().map(|l| l.axis).sum();
    let n = axis.try_normalize(1e-12).unwrap_or_else(|| -Vector3::z());
    let u = n
        .cross(&Vector3::x())
        .try_normalize(1e-6)
        .unwrap_or_else(|| n.cross(&Vector3::y()).normalize());
    let v = n.cross(&u);
    let pts: Vec<(f64, f64)> = rec
        .rest_markers_m
        .iter()
        .map(|p| (1e3 * p.dot(&u), 1e3 * p.dot(&v)))
        .collect();
    let before: Vec<f64> = (0..rec.num_markers())
        .map(|m| 1e3 * per_marker_rms(&run.residuals_before, m))
        .collect();
    let after: Vec<f64> = (0..rec.num_markers())
        .map(|m| 1e3 * per_marker_rms(&run.residuals_after, m))
        .collect();
    let scale = softcap_figure::ColorScale::shared_magnitude(
        "RMS marker residual [mm]",
        before.iter().chain(&after).copied(),
        softcap_figure::sequential,
    );
    let (x0, x1, y0, y1) = pts.iter().fold(
        (
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ),
        |a, p| (a.0.min(p.0), a.1.max(p.0), a.2.min(p.1), a.3.max(p.1)),
    );
    let pad = 0.08 * (x1 - x0).max(y1 - y0).max(1.0);
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    let (panels, bar) = root.split_vertically(RESIDUAL_MAP_SIZE.1 - 70);
    let halves = panels.split_evenly((1, 2));
    for (area, (title, vals)) in halves.iter().zip([("before", &before), ("after", &after)]) {
        let mut chart = ChartBuilder::on(area)
            .caption(
                format!(
                    "RMS marker residual {title} (max {:.3} mm)",
                    vals.iter().cloned().fold(0.0, f64::max)
                ),
                (softcap_figure::FONT_FAMILY, 18),
            )
            .margin(10)
            .x_label_area_size(35)
            .y_label_area_size(45)
            .build_cartesian_2d((x0 - pad)..(x1 + pad), (y0 - pad)..(y1 + pad))
            .map_err(|e| e.to_string())?;
        chart
            .configure_mesh()
            .x_desc("surface u, mm")
            .y_desc("surface v, mm")
            .draw()
            .map_err(|e| e.to_string())?;
        chart
            .draw_series(
                pts.iter()
                    .zip(vals.iter())
                    .map(|(p, &r)| Circle::new(*p, 7, scale.color(r).filled())),
            )
            .map_err(|e| e.to_string())?;
        chart
            .draw_series(run.segmentation.locations.iter().map(|l| {
                let p = l.contact_tip_m;
                Cross::new((1e3 * p.dot(&u), 1e3 * p.dot(&v)), 6, BLACK.stroke_width(2))
            }))
            .map_err(|e| e.to_string())?;
    }
    softcap_figure::draw_colorbar(&bar.margin(0, 0, 300, 300), &scale).map_err(|e| e.to_string())
}

/// Fold gains as text: `0.91 0.88 …`.
fn gains_text(g: &[f64]) -> String {
    g.iter()
        .map(|x| format!("{x:.2}"))
        .collect::<Vec<_>>()
        .join(" ")
}

/// The named effects (joint model against each one alone), or the candidates of an
/// `inconclusive` verdict and the experiment that would separate them.
fn write_effects(s: &mut String, d: &Diagnosis) {
    let mm = |x: f64| 1e3 * x;
    let params = |p: &std::collections::BTreeMap<String, f64>| {
        p.iter()
            .map(|(k, v)| format!("{k} = {v:.4e}"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    if !d.effects.is_empty() {
        let _ = writeln!(
            s,
            "## Named effects\n\nEach effect on its scored cells, held-out RMS in mm: the default \
             model, the effects named before it, the effect alone, the joint model (fold gains: \
             1 − joint/without of the held-out MSE per probe location).\n"
        );
        let _ = writeln!(
            s,
            "| effect | confidence | default | without it | alone | joint | fold gains | params |\n|---|---|---|---|---|---|---|---|"
        );
        for e in &d.effects {
            let _ = writeln!(
                s,
                "| {} | {:.3} | {:.4} | {:.4} | {:.4} | {:.4} | {} | {} |",
                e.hypothesis,
                e.confidence,
                mm(e.heldout_rmse_before_m),
                mm(e.heldout_rmse_without_m),
                mm(e.heldout_rmse_single_m),
                mm(e.heldout_rmse_after_m),
                gains_text(&e.fold_gains),
                params(&e.params)
            );
        }
        let _ = writeln!(s);
    }
    if !d.candidates.is_empty() {
        let _ = writeln!(
            s,
            "## Inconclusive: look-alikes the data cannot separate\n\nTheir held-out gains per \
             probe location differ by less than their fold-to-fold spread.\n"
        );
        let _ = writeln!(
            s,
            "| candidate | confidence | held-out after (mm) | fold gains | params |\n|---|---|---|---|---|"
        );
        for c in &d.candidates {
            let _ = writeln!(
                s,
                "| {} | {:.3} | {:.4} | {} | {} |",
                c.hypothesis,
                c.confidence,
                mm(c.heldout_rmse_after_m),
                gains_text(&c.fold_gains),
                params(&c.params)
            );
        }
        let _ = writeln!(s);
    }
    if let Some(n) = &d.next_experiment {
        let _ = writeln!(
            s,
            "## Next experiment: `{}`\n\n{}\n\nPredicted RMS marker difference between the \
             two leading candidates: {:.4} mm under it, {:.4} mm under the recorded protocol.\n",
            n.protocol,
            n.description,
            mm(n.predicted_difference_m),
            mm(n.recorded_difference_m)
        );
        let _ = writeln!(s, "| protocol | predicted difference (mm) |\n|---|---|");
        for p in &n.protocols {
            let _ = writeln!(
                s,
                "| {} | {:.4} |",
                p.protocol,
                mm(p.predicted_difference_m)
            );
        }
        let _ = writeln!(s);
    }
}

/// Residual against time: RMS over markers per frame, before and after; force on a second panel.
fn draw_residual_time(root: &Root<'_>, rec: &Recording, run: &DiagnosisRun) -> DrawResult<()> {
    let t: Vec<f64> = rec.times_s();
    let b: Vec<f64> = run
        .residuals_before
        .iter()
        .map(|r| 1e3 * per_frame_rms(r))
        .collect();
    let a: Vec<f64> = run
        .residuals_after
        .iter()
        .map(|r| 1e3 * per_frame_rms(r))
        .collect();
    let f: Vec<f64> = rec.frames.iter().map(|f| f.force_n.norm()).collect();
    let tmax = t.last().copied().unwrap_or(1.0).max(t[0] + 1e-6);
    let ymax = b.iter().chain(&a).cloned().fold(1e-9, f64::max) * 1.1;
    let fmax = f.iter().cloned().fold(1e-9, f64::max) * 1.1;
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    let (top, bottom) = root.split_vertically(460);
    let mut chart = ChartBuilder::on(&top)
        .caption(
            "RMS marker residual per frame",
            (softcap_figure::FONT_FAMILY, 18),
        )
        .margin(10)
        .x_label_area_size(30)
        .y_label_area_size(60)
        .build_cartesian_2d(t[0]..tmax, 0.0..ymax)
        .map_err(|e| e.to_string())?;
    chart
        .configure_mesh()
        .y_desc("residual, mm")
        .draw()
        .map_err(|e| e.to_string())?;
    // hold phases shaded
    for (k, p) in run.segmentation.phases.iter().enumerate() {
        if *p == Phase::Hold && k + 1 < t.len() {
            chart
                .draw_series(std::iter::once(Rectangle::new(
                    [(t[k], 0.0), (t[k + 1], ymax)],
                    RGBColor(230, 230, 230).filled(),
                )))
                .map_err(|e| e.to_string())?;
        }
    }
    chart
        .draw_series(LineSeries::new(
            t.iter().cloned().zip(b.iter().cloned()),
            RED.stroke_width(2),
        ))
        .map_err(|e| e.to_string())?
        .label("default model")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], RED));
    chart
        .draw_series(LineSeries::new(
            t.iter().cloned().zip(a.iter().cloned()),
            BLUE.stroke_width(2),
        ))
        .map_err(|e| e.to_string())?
        .label(format!("extended ({})", run.diagnosis.verdict))
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], BLUE));
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(|e| e.to_string())?;
    let mut fc = ChartBuilder::on(&bottom)
        .margin(10)
        .x_label_area_size(35)
        .y_label_area_size(60)
        .build_cartesian_2d(t[0]..tmax, 0.0..fmax)
        .map_err(|e| e.to_string())?;
    fc.configure_mesh()
        .x_desc("time, s")
        .y_desc("|force|, N")
        .draw()
        .map_err(|e| e.to_string())?;
    fc.draw_series(LineSeries::new(
        t.iter().cloned().zip(f.iter().cloned()),
        BLACK.stroke_width(2),
    ))
    .map_err(|e| e.to_string())?;
    Ok(())
}

/// Force–displacement loops: |f| against the mean displacement of the probed markers near each
/// location along the probe axis, measured vs default-model vs extended-model simulation.
fn draw_loops(root: &Root<'_>, rec: &Recording, run: &DiagnosisRun) -> DrawResult<()> {
    let seg = &run.segmentation;
    let nloc = seg.locations.len().min(LOOP_PANELS);
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    let cells = root.split_evenly((nloc.div_ceil(3), 3));
    for (li, area) in seg.locations.iter().take(nloc).zip(cells.iter()) {
        let near = seg.near_markers(rec, li);
        if near.is_empty() {
            continue;
        }
        // The frames of this location: its contact frames plus the frame before and the
        // released frame after each contact run, split into runs of consecutive frames — only
        // consecutive samples of one location are connected (a location visited twice gives two
        // polylines, never a jump between them).
        let mut frames: Vec<usize> = li.contact_frames.clone();
        for &k in &li.contact_frames {
            if k > 0 && !li.contact_frames.contains(&(k - 1)) {
                frames.push(k - 1);
            }
            if k + 1 < rec.frames.len()
                && !li.contact_frames.contains(&(k + 1))
                && seg.phases[k + 1] == crate::segment::Phase::Released
            {
                frames.push(k + 1);
            }
        }
        frames.sort_unstable();
        frames.dedup();
        let disp = |x: &dyn Fn(usize, usize) -> Option<Vector3<f64>>, k: usize| {
            let (mut s, mut n) = (0.0, 0);
            for &m in &near {
                if let Some(p) = x(k, m) {
                    s += (p - rec.rest_markers_m[m]).dot(&li.axis);
                    n += 1;
                }
            }
            (n > 0).then(|| 1e3 * s / n as f64)
        };
        // polylines: a new one starts at a frame gap or where no near marker is observed
        let polylines = |x: &dyn Fn(usize, usize) -> Option<Vector3<f64>>| -> Vec<Vec<(f64, f64)>> {
            let mut out: Vec<Vec<(f64, f64)>> = Vec::new();
            let mut prev: Option<usize> = None;
            for &k in &frames {
                let Some(d) = disp(x, k) else {
                    prev = None;
                    continue;
                };
                let p = (d, rec.frames[k].force_n.norm());
                match (prev, out.last_mut()) {
                    (Some(j), Some(line)) if j + 1 == k => line.push(p),
                    _ => out.push(vec![p]),
                }
                prev = Some(k);
            }
            out
        };
        let meas = polylines(&|k, m| rec.frames[k].markers_m[m]);
        let base = polylines(&|k, m| Some(run.baseline_m[k][m]));
        let ext: Option<Vec<Vec<(f64, f64)>>> = run
            .extended_m
            .as_ref()
            .map(|x| polylines(&|k, m| Some(x[k][m])));
        let all = meas
            .iter()
            .chain(&base)
            .chain(ext.iter().flatten())
            .flatten()
            .copied();
        let (x0, x1, y1) = all.fold((f64::INFINITY, f64::NEG_INFINITY, 1e-9f64), |a, p| {
            (a.0.min(p.0), a.1.max(p.0), a.2.max(p.1))
        });
        let px = 0.05 * (x1 - x0).max(1e-3);
        let mut chart = ChartBuilder::on(area)
            .caption(
                format!("location {}", li.index),
                (softcap_figure::FONT_FAMILY, 16),
            )
            .margin(8)
            .x_label_area_size(35)
            .y_label_area_size(50)
            .build_cartesian_2d((x0 - px)..(x1 + px), 0.0..(1.1 * y1))
            .map_err(|e| e.to_string())?;
        chart
            .configure_mesh()
            .x_desc("displacement along probe axis, mm")
            .y_desc("|force|, N")
            .draw()
            .map_err(|e| e.to_string())?;
        let styles: [(&str, RGBColor, Vec<Vec<(f64, f64)>>); 3] = [
            ("measured", BLACK, meas),
            ("default model", RED, base),
            ("extended", BLUE, ext.unwrap_or_default()),
        ];
        for (label, color, lines) in styles {
            for (i, line) in lines.into_iter().enumerate() {
                let series = chart
                    .draw_series(LineSeries::new(line, color.stroke_width(2)))
                    .map_err(|e| e.to_string())?;
                if i == 0 {
                    series
                        .label(label)
                        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], color));
                }
            }
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(|e| e.to_string())?;
    }
    Ok(())
}

/// Pixel size of the residual map (two panels over a colour bar).
const RESIDUAL_MAP_SIZE: (u32, u32) = (1200, 630);
/// At most this many locations get a force–displacement panel (three per row).
const LOOP_PANELS: usize = 6;

/// Writes `DIR/report.md` and its figures (`residual_map.png`, `residual_time.png`,
/// `loops.png`).
pub fn write_report(dir: &Path, rec: &Recording, run: &DiagnosisRun) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| out_err(dir, e))?;
    let loop_rows = run
        .segmentation
        .locations
        .len()
        .clamp(1, LOOP_PANELS)
        .div_ceil(3) as u32;
    type Draw = fn(&Root<'_>, &Recording, &DiagnosisRun) -> DrawResult<()>;
    let figs: [(&str, (u32, u32), Draw); 3] = [
        ("residual_map.png", RESIDUAL_MAP_SIZE, draw_residual_map),
        ("residual_time.png", (1100, 700), draw_residual_time),
        ("loops.png", (1200, 420 * loop_rows), draw_loops),
    ];
    for (name, size, draw) in figs {
        let p = dir.join(name);
        softcap_figure::draw_png(&p, size, |root| Ok(draw(root, rec, run)?))
            .map_err(|e| out_err(&p, e))?;
    }
    let d = &run.diagnosis;
    let mut s = String::new();
    let mm = |x: f64| 1e3 * x;
    let _ = writeln!(s, "# softcap diagnose report\n");
    let _ = writeln!(s, "**Verdict: `{}`**\n", d.verdict);
    if let Some(top) = d.ranked.first() {
        let _ = writeln!(
            s,
            "Held-out marker RMS (leave one probe location out): {:.4} mm before, {:.4} mm after \
             ({:.1}× lower).\n",
            mm(top.heldout_rmse_before_m),
            mm(top.heldout_rmse_after_m),
            top.heldout_rmse_before_m / top.heldout_rmse_after_m.max(1e-300)
        );
    }
    let _ = writeln!(s, "Confidence of the verdict: {:.3}.\n", d.confidence);
    write_unexplained(&mut s, d);
    write_effects(&mut s, d);
    let _ = writeln!(
        s,
        "{} frames, {} markers, {} probe locations, marker noise σ ≈ {:.4} mm.\n",
        rec.frames.len(),
        rec.num_markers(),
        run.segmentation.num_folds(),
        mm(run.signatures.noise_sigma_m)
    );
    let _ = writeln!(s, "## Ranked hypotheses\n");
    let _ = writeln!(
        s,
        "| hypothesis | score | held-out before (mm) | held-out after (mm) | params |\n|---|---|---|---|---|"
    );
    for r in &d.ranked {
        let params: Vec<String> = r
            .params
            .iter()
            .map(|(k, v)| format!("{k} = {v:.4e}"))
            .collect();
        let _ = writeln!(
            s,
            "| {} | {:.3} | {:.4} | {:.4} | {} |",
            r.hypothesis,
            r.score,
            mm(r.heldout_rmse_before_m),
            mm(r.heldout_rmse_after_m),
            params.join(", ")
        );
    }
    let _ = writeln!(s, "\n## Where the error lives (default model)\n");
    let _ = writeln!(
        s,
        "| region | phase | component | RMS (mm) |\n|---|---|---|---|"
    );
    for l in d.located.iter().take(15) {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {:.4} |",
            l.region,
            l.phase,
            l.component,
            mm(l.rmse_m)
        );
    }
    let _ = writeln!(
        s,
        "\n## Before / after by region and phase (in-sample, full fit)\n"
    );
    let _ = writeln!(
        s,
        "| region | phase | before (mm) | after (mm) |\n|---|---|---|---|"
    );
    for (region, phase, b, a) in &run.table {
        let _ = writeln!(s, "| {region} | {phase} | {:.4} | {:.4} |", mm(*b), mm(*a));
    }
    let _ = writeln!(s, "\n## Signatures\n\n```\n{:#?}\n```\n", run.signatures);
    let _ = writeln!(s, "## Figures\n");
    let _ = writeln!(s, "![residual map](residual_map.png)\n");
    let _ = writeln!(s, "![residual against time](residual_time.png)\n");
    let _ = writeln!(s, "![force-displacement loops](loops.png)");
    write_atomic(&dir.join("report.md"), s.as_bytes())
}
