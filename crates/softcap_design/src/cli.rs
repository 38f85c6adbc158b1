//! The `softcap-design` command line: base-material library, targets, goal-based design search
//! (thesis ch. 8).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use clap::{Parser, Subcommand};
use softcap_app::indicatif::ProgressBar;
use softcap_app::{Context, IntoError, Progress, Result, load_toml_or_default};
use softcap_mcap::Provenance;

use crate::*;

#[derive(Parser, Debug)]
#[command(
    name = "softcap-design",
    version,
    about = "Materials with desired deformation behaviour (thesis ch. 8)"
)]
pub struct Cli {
    /// The subcommand.
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Write the reference library of nine known non-linear base materials (JSON).
    Library {
        /// Output JSON.
        #[arg(short, long)]
        output: PathBuf,
    },
    /// Fit the invariant material to uniaxial + biaxial rubber tables at once.
    FitRubber {
        /// Treloar-style CSV: stretch,nominal_stress_mpa.
        #[arg(long)]
        uniaxial: PathBuf,
        /// Kawabata-style CSV: stretch1,stretch2,nominal_stress1_mpa,nominal_stress2_mpa.
        #[arg(long)]
        biaxial: PathBuf,
        /// Output material JSON.
        #[arg(short, long)]
        output: PathBuf,
    },
    /// Fit one base material (isotropic eq. 8.1–8.3, or `--transverse` eq. 8.5) per
    /// capture.mcap of a probed block and
    /// write them as a library JSON (input of `target` / `search`).
    FitBase {
        /// capture.mcap files, one per base material (probe sessions on 4 × 5 × 2.5 cm blocks).
        #[arg(required = true)]
        captures: Vec<PathBuf>,
        /// Starting Young's modulus of the linear pre-fit, in Pa.
        #[arg(long, default_value_t = 2.0e5)]
        young_guess: f64,
        /// RBF centres per material (thesis: 6 isotropic, up to 12 printed materials).
        #[arg(long, default_value_t = 6)]
        centres: usize,
        /// Fit transversely isotropic materials (tubes along z; eq. 8.5, five parameters)
        /// instead of isotropic ones.
        #[arg(long)]
        transverse: bool,
        /// Optional TOML with `CaptureMappingSettings` (block size, mesh cells, snapping).
        #[arg(long)]
        mapping: Option<PathBuf>,
        /// Output library JSON.
        #[arg(short, long)]
        output: PathBuf,
    },
    /// Simulate a layered design and write it as a target (force–displacement examples).
    Target {
        /// Base-material library JSON.
        #[arg(long)]
        materials: PathBuf,
        /// Material per layer, bottom first, e.g. 0,3,5,1,2.
        #[arg(long, value_delimiter = ',')]
        design: Vec<usize>,
        /// Output target JSON.
        #[arg(short, long)]
        output: PathBuf,
    },
    /// Branch-and-bound search for the design matching a target (thesis §8.4); exact mode
    /// (K orders the work; see docs/design.md).
    Search {
        /// Base-material library JSON.
        #[arg(long)]
        materials: PathBuf,
        /// Target JSON (from `target` or hand-made).
        #[arg(long)]
        target: PathBuf,
        /// Output folder: design.mcap (`/design/report`, provenance), design.json, curves.png,
        /// design.3mf (one object per material).
        #[arg(short, long)]
        output: PathBuf,
        /// Clusters K.
        #[arg(long, default_value_t = 20)]
        clusters: usize,
    },
}

fn settings_for(forces: &[f64], layers: usize) -> CompositeSettings {
    CompositeSettings {
        layers,
        forces_n: forces.to_vec(),
        ..CompositeSettings::default()
    }
}

impl Cli {
    /// Runs the subcommand.
    pub fn run(self) -> Result<()> {
        self.command.run()
    }
}

impl Command {
    /// Runs the subcommand.
    pub fn run(&self) -> Result<()> {
        match self {
            Command::Library { output } => {
                write_json(output, &reference_library())?;
                eprintln!(
                    "wrote {} base materials to {}",
                    reference_library().len(),
                    output.display()
                );
            }
            Command::FitRubber {
                uniaxial,
                biaxial,
                output,
            } => {
                let u = read_uniaxial(uniaxial)?;
                let b = read_biaxial(biaxial)?;
                let rep = fit_rubber(
                    &[("uniaxial", u.as_slice()), ("biaxial", b.as_slice())],
                    &RubberFitSettings::default(),
                )?;
                for e in &rep.errors {
                    println!(
                        "{}: {} values, RMS {:.4} MPa ({:.2} % of max)",
                        e.name,
                        e.count,
                        e.rms_mpa,
                        100.0 * e.relative
                    );
                }
                write_json(output, &rep)?;
            }
            Command::FitBase {
                captures,
                young_guess,
                centres,
                transverse,
                mapping,
                output,
            } => {
                let mapping: CaptureMappingSettings = load_toml_or_default(mapping.as_deref())?;
                let settings = BaseFitSettings {
                    centres: *centres,
                    ..BaseFitSettings::default()
                };
                let mut library = Vec::new();
                for path in captures {
                    let capture = softcap_mcap::capture::CaptureData::read(path)?;
                    let meas = measurements_from_capture(&capture, &mapping)?;
                    let rep = if *transverse {
                        let iso = InvariantMaterial::from_young_poisson(*young_guess, 0.3);
                        let (l, mu) = (iso.rbf.constant[0], iso.rbf.constant[1]);
                        fit_transverse(&meas, TransverseParams::isotropic(l, mu), &settings)?
                    } else {
                        fit_isotropic(&meas, *young_guess, &settings)?
                    };
                    println!(
                        "{}: {} examples, linear pre-fit RMS {:.4} mm, fit RMS {:.4} mm ({})",
                        path.display(),
                        meas.examples.len(),
                        rep.linear_rms_m * 1e3,
                        rep.rms_m * 1e3,
                        rep.status
                    );
                    library.push(rep.material);
                }
                write_json(output, &library)?;
            }
            Command::Target {
                materials,
                design,
                output,
            } => {
                let mats: Vec<BaseMaterial> = read_json(materials)?;
                if let Some(&m) = design.iter().find(|&&m| m >= mats.len()) {
                    return Err(DesignError::Invalid {
                        field: "--design",
                        reason: format!("material {m} but the library has {}", mats.len()),
                    }
                    .into());
                }
                let settings = settings_for(&CompositeSettings::default().forces_n, design.len());
                let block = Arc::new(LayeredBlock::uniform(&settings)?);
                let mut sim = CompositeSimulator::new(block, Arc::new(mats), &settings)?;
                let r = sim.simulate(design)?;
                write_json(
                    output,
                    &DesignTarget {
                        layers: design.len(),
                        forces_n: settings.forces_n.clone(),
                        displacements_m: r.displacements_m,
                        probe_displacement_m: r.probe_displacement_m,
                    },
                )?;
            }
            Command::Search {
                materials,
                target,
                output,
                clusters,
            } => search(materials, target, output, *clusters)?,
        }
        Ok(())
    }
}

/// `search`: branch-and-bound for the design matching `target_path`, then design.mcap,
/// design.json, design.3mf and curves.png in `output`.
fn search(materials: &Path, target_path: &Path, output: &Path, clusters: usize) -> Result<()> {
    let mats: Arc<Vec<BaseMaterial>> = Arc::new(read_json(materials)?);
    let target: DesignTarget = read_json(target_path)?;
    let settings = settings_for(&target.forces_n, target.layers);
    let mut ev = ParallelEvaluator::new(mats.clone(), &settings)?;
    let per_example = ev.block.top_nodes.len() * 3;
    if target.displacements_m.len() != per_example * target.forces_n.len() {
        return Err(DesignError::File {
            path: target_path.into(),
            reason: format!(
                "displacements_m has {} values, expected {} ({} examples × {} top-node components)",
                target.displacements_m.len(),
                per_example * target.forces_n.len(),
                target.forces_n.len(),
                per_example
            ),
        }
        .into());
    }
    let search = SearchSettings {
        clusters,
        ..SearchSettings::default()
    };
    let mut provenance = Provenance::new("design", env!("CARGO_PKG_VERSION"))
        .with_arguments(std::env::args())
        .with_settings(toml::to_string(&search).failure_with(|| "search settings to TOML")?);
    provenance.add_input(materials)?;
    provenance.add_input(target_path)?;

    let t = std::time::Instant::now();
    let mut counted = Counted {
        bar: Progress::default().counter("branch-and-bound: designs simulated"),
        inner: &mut ev,
    };
    let rep = branch_and_bound(
        settings.layers,
        mats.len(),
        &target.displacements_m,
        &mut counted,
        &search,
    )?;
    counted.bar.finish_and_clear();
    let seconds = t.elapsed().as_secs_f64();
    let mut sim = CompositeSimulator::new(ev.block.clone(), mats.clone(), &settings)?;
    let found = sim.simulate(&rep.design)?;
    let record = DesignRecord {
        design: rep.design.clone(),
        rms_error_m: rms_displacement_error(&found.displacements_m, &target.displacements_m),
        search: rep,
        forces_n: target.forces_n.clone(),
        target_probe_displacement_m: target.probe_displacement_m.clone(),
        predicted_probe_displacement_m: found.probe_displacement_m.clone(),
    };
    println!(
        "design {:?}: RMS displacement error {:.4} mm, {} designs simulated in {:.1} s",
        record.design,
        record.rms_error_m * 1e3,
        record.search.evaluations,
        seconds
    );

    std::fs::create_dir_all(output).with_context(|| format!("creating {}", output.display()))?;
    write_design_mcap(
        &output.join("design.mcap"),
        &provenance,
        &record,
        mats.len(),
        clusters,
    )?;
    #[derive(serde::Serialize)]
    struct Json<'a> {
        design: &'a [usize],
        rms_error_m: f64,
        search: &'a SearchReport,
        predicted_probe_displacement_m: &'a [f64],
        seconds: f64,
    }
    write_json(
        &output.join("design.json"),
        &Json {
            design: &record.design,
            rms_error_m: record.rms_error_m,
            search: &record.search,
            predicted_probe_displacement_m: &record.predicted_probe_displacement_m,
            seconds,
        },
    )?;
    let names: Vec<String> = (0..mats.len())
        .map(|m| format!("base material {m}"))
        .collect();
    write_design_3mf(
        &output.join("design.3mf"),
        &record.design,
        &vec![settings.block_size_m[2] / settings.layers as f64; settings.layers],
        settings.block_size_m,
        &names,
    )?;
    plot_force_displacement(
        &output.join("curves.png"),
        &format!(
            "design {:?}: RMS {:.4} mm",
            record.design,
            record.rms_error_m * 1e3
        ),
        &target.forces_n,
        &[
            ("target".into(), record.target_probe_displacement_m.clone()),
            (
                "found design (predicted)".into(),
                record.predicted_probe_displacement_m.clone(),
            ),
        ],
    )?;
    Ok(())
}

/// Shows the number of designs simulated on a progress counter while a search runs.
struct Counted<'a, E> {
    inner: &'a mut E,
    bar: ProgressBar,
}

impl<E: DesignEvaluator> DesignEvaluator for Counted<'_, E> {
    fn evaluate(&mut self, designs: &[Vec<usize>]) -> Vec<Response> {
        let responses = self.inner.evaluate(designs);
        self.bar.inc(designs.len() as u64);
        responses
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cli_parses_search_and_rejects_missing_args() {
        let c = Cli::try_parse_from([
            "softcap-design",
            "search",
            "--materials",
            "m.json",
            "--target",
            "t.json",
            "-o",
            "out",
        ])
        .unwrap();
        assert!(matches!(c.command, Command::Search { clusters: 20, .. }));
        let c = Cli::try_parse_from([
            "softcap-design",
            "target",
            "--materials",
            "m.json",
            "--design",
            "0,3,5",
            "-o",
            "t.json",
        ])
        .unwrap();
        match c.command {
            Command::Target { design, .. } => assert_eq!(design, vec![0, 3, 5]),
            _ => panic!("wrong subcommand"),
        }
        assert!(
            Cli::try_parse_from(["softcap-design", "search", "--materials", "m.json"]).is_err()
        );
    }
}
