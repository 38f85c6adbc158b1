//! The fit-dynamic report: `report.md` (parameters with uncertainty, trajectory RMS before and
//! after, modal frequencies measured vs fitted) and `trajectories.png` (a few nodes' tracked and
//! simulated displacement over the free-motion segments).

use std::fmt::Write as _;
use std::path::Path;

use plotters::prelude::*;
use softcap_mesh::TetMesh;

use super::fit::{DynamicFit, FitDynamicSettings};
use super::sequence::TrackedSequence;
use crate::error::{Result, TissueError};

/// Up to three unsupported nodes spread along the body: the farthest from the support, and the
/// ones a third and two thirds of the way.
fn plotted_nodes(mesh: &TetMesh, seq: &TrackedSequence) -> Vec<usize> {
    let held: std::collections::BTreeSet<usize> = seq.support_nodes.iter().copied().collect();
    let anchor = if held.is_empty() {
        mesh.vertices.iter().sum::<nalgebra::Vector3<f64>>() / mesh.vertices.len().max(1) as f64
    } else {
        held.iter()
            .map(|&i| mesh.vertices[i])
            .sum::<nalgebra::Vector3<f64>>()
            / held.len() as f64
    };
    let mut by_distance: Vec<(f64, usize)> = (0..mesh.vertices.len())
        .filter(|i| !held.contains(i))
        .map(|i| ((mesh.vertices[i] - anchor).norm(), i))
        .collect();
    by_distance.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    let Some(&(far, _)) = by_distance.last() else {
        return Vec::new();
    };
    [1.0, 2.0 / 3.0, 1.0 / 3.0]
        .iter()
        .filter_map(|f| {
            by_distance
                .iter()
                .min_by(|a, b| (a.0 - f * far).abs().total_cmp(&(b.0 - f * far).abs()))
                .map(|p| p.1)
        })
        .collect()
}

/// Tracked (dots) and simulated (lines) displacement from the static shape of a few nodes.
pub fn draw_trajectories(
    path: &Path,
    mesh: &TetMesh,
    seq: &TrackedSequence,
    fit: &DynamicFit,
) -> Result<()> {
    let nodes = plotted_nodes(mesh, seq);
    let disp = |x: &nalgebra::Vector3<f64>, i: usize| 1e3 * (x - mesh.vertices[i]).norm();
    let mut tracked: Vec<Vec<(f64, f64)>> = vec![Vec::new(); nodes.len()];
    let mut simulated: Vec<Vec<Vec<(f64, f64)>>> = vec![Vec::new(); nodes.len()];
    for (k, &i) in nodes.iter().enumerate() {
        for (t, x) in seq.times_s.iter().zip(&seq.positions_m) {
            tracked[k].push((*t, disp(&x[i], i)));
        }
        for run in &fit.runs {
            let s = &run.segment;
            let mut line = vec![(seq.times_s[s.start], disp(&seq.positions_m[s.start][i], i))];
            for (o, x) in run.positions_m.iter().enumerate() {
                line.push((seq.times_s[s.start + 1 + o], disp(&x[i], i)));
            }
            simulated[k].push(line);
        }
    }
    let t0 = seq.times_s.first().copied().unwrap_or(0.0);
    let t1 = seq.times_s.last().copied().unwrap_or(1.0).max(t0 + 1e-6);
    let ymax = tracked.iter().flatten().map(|p| p.1).fold(1e-6, f64::max) * 1.1;
    let colors = [RED, BLUE, GREEN];
    softcap_figure::draw_png(path, (1100, 520), |root| {
        root.fill(&WHITE)?;
        let mut chart = ChartBuilder::on(root)
            .caption(
                "tracked (dots) vs simulated with the fitted parameters (lines), per segment",
                (softcap_figure::FONT_FAMILY, 18),
            )
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(t0..t1, 0.0..ymax)?;
        chart
            .configure_mesh()
            .x_desc("time, s")
            .y_desc("displacement from the static shape, mm")
            .draw()?;
        for (k, &node) in nodes.iter().enumerate() {
            let c = colors[k % 3];
            chart
                .draw_series(tracked[k].iter().map(|p| Circle::new(*p, 3, c.filled())))?
                .label(format!("node {node}"))
                .legend(move |(x, y)| Circle::new((x + 7, y), 4, c.filled()));
            for line in &simulated[k] {
                chart.draw_series(LineSeries::new(line.clone(), c.stroke_width(2)))?;
            }
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()?;
        Ok(())
    })
    .map_err(|e| TissueError::Output {
        path: path.to_path_buf(),
        reason: e.to_string(),
    })
}

/// Writes `dir/report.md` and `dir/trajectories.png`.
pub fn write_report(
    dir: &Path,
    mesh: &TetMesh,
    seq: &TrackedSequence,
    fit: &DynamicFit,
    settings: &FitDynamicSettings,
) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| TissueError::Output {
        path: dir.to_path_buf(),
        reason: e.to_string(),
    })?;
    draw_trajectories(&dir.join("trajectories.png"), mesh, seq, fit)?;
    let mut md = String::new();
    let _ = writeln!(md, "# softcap tissue fit-dynamic\n");
    let _ = writeln!(
        md,
        "Status: {}. {} segments, {} frames simulated per evaluation, {} simulations and {} one-segment simulations (start states of {} modes fitted); fit mesh {} nodes, {} tets ({} refinement levels, {:?} optimizer).\n",
        fit.status,
        fit.segments,
        fit.frames,
        fit.simulations,
        fit.segment_simulations,
        fit.start_state_modes,
        fit.fit_mesh_size.0,
        fit.fit_mesh_size.1,
        settings.refine,
        settings.optimizer
    );
    // The relative 1-σ of parameter k: s²(JᵀJ)⁻¹, and the sandwich ones per segment and per
    // frame (`DynamicFit::segment_robust_sigma`; "—" where the data do not bound it).
    let sigmas = |k: usize| {
        [
            &fit.relative_sigma,
            &fit.segment_robust_sigma,
            &fit.frame_robust_sigma,
        ]
        .iter()
        .map(|v| match v.get(k) {
            Some(x) if x.is_finite() => format!("{x:.2e}"),
            _ => "—".into(),
        })
        .collect::<Vec<_>>()
        .join(" | ")
    };
    let _ = writeln!(
        md,
        "| parameter | value | 1-σ (relative) | sandwich 1-σ per segment | sandwich 1-σ per frame |\n|---|---|---|---|---|"
    );
    let nc = fit.young_pa.len();
    for (c, e) in fit.young_pa.iter().enumerate() {
        let p = fit.control_points.positions_m[c];
        let _ = writeln!(
            md,
            "| E at control point {c} ({:.3}, {:.3}, {:.3}) m | {:.4e} Pa | {} |",
            p.x,
            p.y,
            p.z,
            e,
            sigmas(c)
        );
    }
    let _ = writeln!(md, "| ν (held) | {:.3} | — | — | — |", fit.poisson);
    let _ = writeln!(
        md,
        "| Rayleigh α | {:.4e} 1/s | {} |",
        fit.damping.alpha_per_s,
        sigmas(nc)
    );
    let _ = writeln!(
        md,
        "| Rayleigh β | {:.4e} s | {} |\n",
        fit.damping.beta_s,
        sigmas(nc + 1)
    );
    let _ = writeln!(
        md,
        "The s²(JᵀJ)⁻¹ 1-σ takes the residuals as independent; the sandwich (cluster-robust) 1-σ count their correlation within a segment (correlated tracking noise, a start state's error) or a frame, and are rough with few segments.\n"
    );
    let _ = writeln!(
        md,
        "Trajectory RMS: {:.3} mm at the starting material, {:.3} mm after the modal warm start{} (E = {:.4e} Pa, α = {:.3e}, β = {:.3e}), {:.3} mm fitted.\n",
        1e3 * fit.rms_initial_m,
        1e3 * fit.rms_warm_m,
        fit.warm_rms_scope(),
        fit.warm_young_pa,
        fit.warm_damping.alpha_per_s,
        fit.warm_damping.beta_s,
        1e3 * fit.rms_m
    );
    if let Some(coarse) = &fit.coarse_young_pa {
        let list: Vec<String> = coarse.iter().map(|e| format!("{e:.4e}")).collect();
        let _ = writeln!(
            md,
            "Coarse to fine: E fitted on the given mesh first: [{}] Pa; the refined mesh's is above.\n",
            list.join(", ")
        );
    }
    let _ = writeln!(
        md,
        "| mode | measured Hz | damping ratio | variance explained | fitted Hz |\n|---|---|---|---|---|"
    );
    for m in &fit.measured_modes {
        let fitted = fit
            .fitted_frequencies_hz
            .get(m.mode)
            .map_or("—".to_string(), |f| format!("{f:.3}"));
        let _ = writeln!(
            md,
            "| {} | {:.3} | {:.4} | {:.3} | {fitted} |",
            m.mode,
            m.omega_rad_s / std::f64::consts::TAU,
            m.zeta,
            m.explained
        );
    }
    let _ = writeln!(
        md,
        "\nRest shape: {}.\n\n![trajectories](trajectories.png)",
        fit.rest_status
    );
    softcap_app::write_atomic(dir.join("report.md"), md.as_bytes()).map_err(|e| {
        TissueError::Output {
            path: dir.join("report.md"),
            reason: e.to_string(),
        }
    })
}
