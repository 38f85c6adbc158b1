//! `softcap tissue reshape --template T.msh --target TARGET/ -o reshaped.mcap [--report DIR]`.

use std::path::PathBuf;

use super::output::{error_stats, write_reshaped};
use super::problem::SurfaceProjector;
use super::solve::{ReshapeOutcome, ReshapeSettings, ReshapeStatus, reshape};
use super::target::load_target;
use crate::error::Result;
use softcap_app::Progress;

/// What `softcap tissue reshape` was asked to do.
#[derive(Clone, Debug)]
pub struct ReshapeConfig {
    /// Template tet mesh (Gmsh 4.1).
    pub template: PathBuf,
    /// TARGET folder (target.toml, landmarks.csv, icp_markers.csv, …).
    pub target: PathBuf,
    /// reshaped.mcap to write.
    pub output: PathBuf,
    /// Report folder (report.md + PNG figures), if wanted.
    pub report: Option<PathBuf>,
    /// Solver settings.
    pub settings: ReshapeSettings,
    /// Command line, for the provenance record.
    pub arguments: Vec<String>,
}

/// A finished reshape.
#[derive(Clone, Debug)]
pub struct ReshapeRun {
    /// The solver's result.
    pub outcome: ReshapeOutcome,
    /// The object had no attachments.
    pub free_flying: bool,
    /// Distance from every vertex of TARGET/surface.obj to the reshaped surface (mean, 95th
    /// percentile, max; m), when the surface was given.
    pub surface_distance: Option<(f64, f64, f64)>,
    /// Files read.
    pub inputs: Vec<PathBuf>,
}

impl ReshapeRun {
    /// "converged" or "max-iterations".
    pub fn status_name(&self) -> &'static str {
        match self.outcome.status {
            ReshapeStatus::Converged => "converged",
            ReshapeStatus::MaxIterations => "max-iterations",
        }
    }
}

/// Reads the template and TARGET, reshapes, writes reshaped.mcap (and the report).
pub fn run(cfg: &ReshapeConfig, progress: &Progress) -> Result<ReshapeRun> {
    let loaded = load_target(&cfg.template, &cfg.target)?;
    let problem = &loaded.problem;
    let bar = progress.bar(
        "reshape",
        (cfg.settings.constant_iterations + 3 * cfg.settings.max_iterations) as u64,
    );
    let outcome = reshape(
        problem,
        &cfg.settings,
        &mut |stage, it, objective, max_error| {
            bar.inc(1);
            bar.set_message(format!(
                "{stage} {it}: E {objective:.3e} m², max error {:.3} mm",
                max_error * 1e3
            ));
        },
    )?;
    bar.finish_and_clear();
    let surface_distance = loaded.surface.as_ref().map(|s| {
        let faces = problem.template.boundary_faces();
        let projector = SurfaceProjector::new(&faces, &outcome.positions_m);
        let d: Vec<f64> = s
            .vertices
            .iter()
            .filter_map(|v| projector.project(v).map(|(_, d)| d))
            .collect();
        error_stats(&d)
    });
    let mut inputs = vec![cfg.template.clone(), cfg.target.join("target.toml")];
    inputs.extend(loaded.files.iter().cloned());
    let run = ReshapeRun {
        outcome,
        free_flying: problem.free_flying,
        surface_distance,
        inputs,
    };
    write_reshaped(cfg, &problem.template, &run)?;
    if let Some(dir) = &cfg.report {
        super::report::write_report(dir, &problem.template, &run)?;
    }
    Ok(run)
}

/// One line for the terminal: status, stages, errors, quality.
pub fn summary_line(run: &ReshapeRun) -> String {
    let o = &run.outcome;
    let stat = |kind| error_stats(&o.errors_of(kind));
    let (_, _, lmax) = stat(super::problem::ConstraintKind::Landmark);
    let (imean, _, imax) = stat(super::problem::ConstraintKind::Icp);
    let iterations: usize = o.stages.iter().map(|s| s.iterations).sum();
    format!(
        "{}: {} Gauss-Newton iterations ({}); ICP error mean {:.3} / max {:.3} mm, landmarks max {:.3} mm; \
         {} inverted tets, dihedral {:.1}..{:.1} deg",
        run.status_name(),
        iterations,
        o.stages
            .iter()
            .map(|s| format!("{} {} {}", s.name, s.iterations, s.stop.name()))
            .collect::<Vec<_>>()
            .join(", "),
        imean * 1e3,
        imax * 1e3,
        lmax * 1e3,
        o.reshaped_quality.inverted_tets,
        o.reshaped_quality.min_dihedral_deg,
        o.reshaped_quality.max_dihedral_deg
    )
}
