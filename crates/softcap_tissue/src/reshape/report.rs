//! The reshape report: `report.md` and three PNG figures (plotters) — the histogram of constraint
//! errors (saito-barbic Fig. 16), the convergence of the objective (Fig. 9), and before/after
//! renders of the surface (flat-shaded triangles in depth order, orthographic view along the
//! direction in which the reshaped surface is thinnest).

use std::fmt::Write as _;
use std::path::Path;

use nalgebra::{Matrix3, SymmetricEigen, Vector3};
use plotters::prelude::*;
use softcap_mesh::TetMesh;

use super::cv::{CvRule, HoldOut};
use super::output::error_stats;
use super::problem::ConstraintKind;
use super::run::ReshapeRun;
use crate::error::{Result, TissueError};

fn draw_err(path: &Path) -> impl Fn(String) -> TissueError + '_ {
    move |reason| TissueError::Output {
        path: path.to_path_buf(),
        reason,
    }
}

/// Writes `dir/report.md`, `constraint_errors.png`, `convergence.png` and `before_after.png`.
pub fn write_report(dir: &Path, template: &TetMesh, run: &ReshapeRun) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| TissueError::Output {
        path: dir.to_path_buf(),
        reason: e.to_string(),
    })?;
    draw_error_histogram(&dir.join("constraint_errors.png"), run)?;
    draw_convergence(&dir.join("convergence.png"), run)?;
    draw_before_after(&dir.join("before_after.png"), template, run)?;
    let md = report_markdown(run);
    let path = dir.join("report.md");
    std::fs::write(&path, md).map_err(|e| TissueError::Output {
        path,
        reason: e.to_string(),
    })
}

fn report_markdown(run: &ReshapeRun) -> String {
    let o = &run.outcome;
    let mut s = String::new();
    let _ = writeln!(s, "# softcap tissue reshape\n");
    let _ = writeln!(
        s,
        "Status **{}**; {} tets, {} nodes, {}.\n",
        run.status_name(),
        o.plastic.len(),
        o.positions_m.len(),
        if run.free_flying {
            "free-flying (rigid gauge, saito-barbic §3.6)"
        } else {
            "attached"
        }
    );
    match &o.cross_validation {
        None => {
            let _ = writeln!(s, "Smoothness α̂ = {:e}.\n", o.smoothness);
        }
        Some(cv) => {
            let held = match cv.hold_out {
                HoldOut::IcpMarkers => "the ICP markers (distance to the reshaped surface)",
                HoldOut::Correspondence => {
                    "the attachments and landmarks (distance of the template point from its target)"
                }
            };
            let rule = match cv.rule {
                CvRule::Minimum => "the lowest held-out error",
                CvRule::OneStandardError => {
                    "the largest α̂ within one standard error of the lowest (one-standard-error rule)"
                }
            };
            let _ = writeln!(
                s,
                "Smoothness α̂ = {:e}, chosen by {}-fold cross-validation holding out {held}: {rule}.\n",
                o.smoothness, cv.folds
            );
            let _ = writeln!(
                s,
                "| α̂ | held-out error, RMS (mm) | standard error of its square (mm²) |\n|---|---|---|"
            );
            for score in &cv.scores {
                let _ = writeln!(
                    s,
                    "| {:e} | {:.4} | {:.4} |",
                    score.smoothness,
                    score.rms_m * 1e3,
                    super::cv::standard_error(&score.fold_rms_m) * 1e6
                );
            }
            let _ = writeln!(s);
        }
    }
    let _ = writeln!(
        s,
        "| stage | iterations | stop | objective start → end (m²) | max error (mm) |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|");
    for st in &o.stages {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {:.3e} → {:.3e} | {:.3} |",
            st.name,
            st.iterations,
            st.stop.name(),
            st.objective_start,
            st.objective_end,
            st.max_error_m * 1e3
        );
    }
    let _ = writeln!(
        s,
        "\n| constraints | count | mean (mm) | 95th pct (mm) | max (mm) |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|");
    for kind in [
        ConstraintKind::Attachment,
        ConstraintKind::Landmark,
        ConstraintKind::Icp,
    ] {
        let e = o.errors_of(kind);
        if e.is_empty() {
            continue;
        }
        let (mean, p95, max) = error_stats(&e);
        let _ = writeln!(
            s,
            "| {} | {} | {:.3} | {:.3} | {:.3} |",
            kind.name(),
            e.len(),
            mean * 1e3,
            p95 * 1e3,
            max * 1e3
        );
    }
    if let Some((mean, p95, max)) = run.surface_distance {
        let _ = writeln!(
            s,
            "\nTARGET/surface.obj to the reshaped surface: mean {:.3} mm, 95th pct {:.3} mm, max {:.3} mm.",
            mean * 1e3,
            p95 * 1e3,
            max * 1e3
        );
    }
    let q = [
        ("template", &o.template_quality),
        ("reshaped", &o.reshaped_quality),
    ];
    let _ = writeln!(
        s,
        "\n| mesh | min dihedral (°) | max dihedral (°) | inverted tets | max aspect | mean aspect |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|");
    for (name, q) in q {
        let _ = writeln!(
            s,
            "| {name} | {:.2} | {:.2} | {} | {:.2} | {:.3} |",
            q.min_dihedral_deg,
            q.max_dihedral_deg,
            q.inverted_tets,
            q.max_aspect_ratio,
            q.mean_aspect_ratio
        );
    }
    let _ = writeln!(
        s,
        "\n![constraint errors](constraint_errors.png)\n\n![convergence](convergence.png)\n\n![before and after](before_after.png)"
    );
    s
}

/// Histogram of the landmark and ICP marker errors in mm (saito-barbic Fig. 16).
fn draw_error_histogram(path: &Path, run: &ReshapeRun) -> Result<()> {
    let err = draw_err(path);
    let errors: Vec<(ConstraintKind, f64)> = run
        .outcome
        .errors
        .iter()
        .filter(|e| e.kind != ConstraintKind::Attachment)
        .map(|e| (e.kind, e.error_m * 1e3))
        .collect();
    let max = errors.iter().map(|e| e.1).fold(0.0, f64::max).max(1e-3);
    let bins = 20usize;
    let width = max * 1.0001 / bins as f64;
    let mut counts = [vec![0usize; bins], vec![0usize; bins]];
    for (kind, e) in &errors {
        let b = ((e / width) as usize).min(bins - 1);
        counts[usize::from(*kind == ConstraintKind::Icp)][b] += 1;
    }
    let ymax = counts[0]
        .iter()
        .zip(&counts[1])
        .map(|(a, b)| a + b)
        .max()
        .unwrap_or(1)
        .max(1) as f64
        * 1.1;
    softcap_figure::register_fonts();
    let root = BitMapBackend::new(path, (800, 480)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "constraint errors after reshaping (saito-barbic Fig. 16)",
            (softcap_figure::FONT_FAMILY, 18),
        )
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(50)
        .build_cartesian_2d(0.0..width * bins as f64, 0.0..ymax)
        .map_err(|e| err(e.to_string()))?;
    chart
        .configure_mesh()
        .x_desc("error, mm")
        .y_desc("constraints")
        .draw()
        .map_err(|e| err(e.to_string()))?;
    for (k, (label, color)) in [
        ("landmarks", RGBColor(230, 120, 30)),
        ("ICP markers", RGBColor(40, 90, 200)),
    ]
    .into_iter()
    .enumerate()
    {
        let base: Vec<usize> = if k == 0 {
            vec![0; bins]
        } else {
            counts[0].clone()
        };
        let c = counts[k].clone();
        chart
            .draw_series((0..bins).map(move |b| {
                let x0 = b as f64 * width;
                Rectangle::new(
                    [
                        (x0, base[b] as f64),
                        (x0 + width * 0.95, (base[b] + c[b]) as f64),
                    ],
                    color.filled(),
                )
            }))
            .map_err(|e| err(e.to_string()))?
            .label(label)
            .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 14, y + 5)], color.filled()));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
        .map_err(|e| err(e.to_string()))?;
    root.present().map_err(|e| err(e.to_string()))
}

/// Objective per Gauss–Newton iteration (log scale), all stages in order (saito-barbic Fig. 9).
fn draw_convergence(path: &Path, run: &ReshapeRun) -> Result<()> {
    let err = draw_err(path);
    let h = &run.outcome.history;
    let values: Vec<f64> = h.iter().map(|r| r.objective.max(1e-300)).collect();
    let (lo, hi) = values
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            (a.min(*v), b.max(*v))
        });
    let (lo, hi) = if lo.is_finite() {
        (lo * 0.5, hi * 2.0)
    } else {
        (1e-12, 1.0)
    };
    softcap_figure::register_fonts();
    let root = BitMapBackend::new(path, (800, 480)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "objective per Gauss–Newton iteration (saito-barbic Fig. 9)",
            (softcap_figure::FONT_FAMILY, 18),
        )
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .build_cartesian_2d(0.0..(h.len().max(1) as f64 + 0.5), (lo..hi).log_scale())
        .map_err(|e| err(e.to_string()))?;
    chart
        .configure_mesh()
        .x_desc("iteration")
        .y_desc("objective, m²")
        .draw()
        .map_err(|e| err(e.to_string()))?;
    let colors = [
        ("constant", RGBColor(120, 120, 120)),
        ("attachments", RGBColor(40, 150, 60)),
        ("landmarks", RGBColor(230, 120, 30)),
        ("icp", RGBColor(40, 90, 200)),
    ];
    for (stage, color) in colors {
        let pts: Vec<(f64, f64)> = h
            .iter()
            .enumerate()
            .filter(|(_, r)| r.stage == stage)
            .map(|(k, r)| ((k + 1) as f64, r.objective.max(1e-300)))
            .collect();
        if pts.is_empty() {
            continue;
        }
        chart
            .draw_series(pts.iter().map(|&p| Circle::new(p, 4, color.filled())))
            .map_err(|e| err(e.to_string()))?
            .label(stage)
            .legend(move |(x, y)| Circle::new((x + 7, y), 4, color.filled()));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
        .map_err(|e| err(e.to_string()))?;
    root.present().map_err(|e| err(e.to_string()))
}

/// Unit view direction and two screen axes: the reshaped surface's direction of least extent
/// (smallest principal axis), so a layer or a flat object is seen face-on.
fn view_frame(points: &[Vector3<f64>]) -> (Vector3<f64>, Vector3<f64>, Vector3<f64>) {
    let n = points.len().max(1) as f64;
    let c = points.iter().sum::<Vector3<f64>>() / n;
    let cov = points
        .iter()
        .map(|p| (p - c) * (p - c).transpose())
        .sum::<Matrix3<f64>>()
        / n;
    let eig = SymmetricEigen::new(cov);
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    let mut view: Vector3<f64> = eig.eigenvectors.column(order[0]).into_owned();
    let up: Vector3<f64> = eig.eigenvectors.column(order[2]).into_owned();
    // Look from the side the mean outward normal points to (+ the axis with the larger spread).
    if view.sum() < 0.0 {
        view = -view;
    }
    let right = up.cross(&view).normalize();
    (view, right, view.cross(&right))
}

/// Two flat-shaded renders side by side: the template's surface and the reshaped surface with
/// the landmark and ICP targets (dots).
fn draw_before_after(path: &Path, template: &TetMesh, run: &ReshapeRun) -> Result<()> {
    let err = draw_err(path);
    let faces = template.boundary_faces();
    let after = &run.outcome.positions_m;
    let (view, right, up) = view_frame(after);
    let targets: Vec<Vector3<f64>> = run
        .outcome
        .errors
        .iter()
        .filter(|e| e.kind != ConstraintKind::Attachment)
        .map(|e| Vector3::from(e.target_m))
        .collect();
    let all: Vec<Vector3<f64>> = template.vertices.iter().chain(after).copied().collect();
    let project = |p: &Vector3<f64>| (p.dot(&right), p.dot(&up));
    let (mut xmin, mut xmax, mut ymin, mut ymax) = (
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    );
    for p in &all {
        let (x, y) = project(p);
        (xmin, xmax, ymin, ymax) = (xmin.min(x), xmax.max(x), ymin.min(y), ymax.max(y));
    }
    let span = (xmax - xmin).max(ymax - ymin).max(f64::MIN_POSITIVE) * 1.05;
    let (cx, cy) = (0.5 * (xmin + xmax), 0.5 * (ymin + ymax));
    softcap_figure::register_fonts();
    let size = 560u32;
    let root = BitMapBackend::new(path, (2 * size, size + 30)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
    let (left, right_area) = root.split_horizontally(size);
    for (area, title, x, dots) in [
        (&left, "template", &template.vertices, false),
        (&right_area, "reshaped (dots: targets)", after, true),
    ] {
        area.draw(&Text::new(
            title,
            (10, 8),
            (softcap_figure::FONT_FAMILY, 18),
        ))
        .map_err(|e| err(e.to_string()))?;
        let to_px = |p: &Vector3<f64>| {
            let (u, v) = project(p);
            let s = size as f64 / span;
            (
                ((u - cx) * s + size as f64 / 2.0) as i32,
                (-(v - cy) * s + size as f64 / 2.0 + 30.0) as i32,
            )
        };
        let mut order: Vec<(f64, usize)> = faces
            .iter()
            .enumerate()
            .map(|(k, f)| (f.iter().map(|&v| x[v].dot(&view)).sum::<f64>(), k))
            .collect();
        order.sort_by(|a, b| a.0.total_cmp(&b.0));
        for (_, k) in order {
            let [a, b, c] = faces[k].map(|v| x[v]);
            let n = (b - a).cross(&(c - a));
            let len = n.norm();
            if len == 0.0 || n.dot(&view) <= 0.0 {
                continue;
            }
            let shade = 0.25 + 0.75 * (n.dot(&view) / len);
            let g = (200.0 * shade) as u8;
            area.draw(&Polygon::new(
                vec![to_px(&a), to_px(&b), to_px(&c)],
                RGBColor(g, (g as f64 * 0.85) as u8, (g as f64 * 0.75) as u8).filled(),
            ))
            .map_err(|e| err(e.to_string()))?;
        }
        if dots {
            for t in &targets {
                area.draw(&Circle::new(to_px(t), 2, RGBColor(30, 80, 220).filled()))
                    .map_err(|e| err(e.to_string()))?;
            }
        }
    }
    root.present().map_err(|e| err(e.to_string()))
}
