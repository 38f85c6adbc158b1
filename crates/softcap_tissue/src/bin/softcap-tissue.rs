//! `softcap-tissue fit capture.mcap --mesh volume.msh -o material.mcap [--settings S.toml]`:
//! bickel2009 material capture; `softcap-tissue simulate material.mcap --probe-shape sphere
//! --radius R --tip x,y,z --axis x,y,z --force N -o sim.mcap`: novel-probe synthesis. Exit codes: 0 success, 1 failure while running, 2 bad usage or
//! bad input.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context as _;
use clap::{Parser, Subcommand};
use softcap_tissue::{
    FitConfig, FitSettings, ProbeShape, ProbeSpec, SimulateConfig, SimulateSettings,
};

/// Soft-tissue material capture and synthesis (bickel2009).
#[derive(Debug, Parser)]
#[command(name = "softcap-tissue", version)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Fit a heterogeneous non-linear material to a capture.
    Fit(FitArgs),
    /// Synthesize a novel probe deformation with a fitted material (SI units).
    Simulate(SimulateArgs),
}

#[derive(Debug, clap::Args)]
struct SimulateArgs {
    /// material.mcap written by `softcap tissue fit`.
    material: PathBuf,
    /// Tip shape.
    #[arg(long, value_enum)]
    probe_shape: ProbeShape,
    /// Tip radius, m.
    #[arg(long)]
    radius: f64,
    /// A point on the approach line, m: x,y,z.
    #[arg(
        long,
        value_delimiter = ',',
        num_args = 3,
        allow_negative_numbers = true
    )]
    tip: Vec<f64>,
    /// Approach direction (handle → tip): x,y,z.
    #[arg(
        long,
        value_delimiter = ',',
        num_args = 3,
        allow_negative_numbers = true,
        default_value = "0,0,-1"
    )]
    axis: Vec<f64>,
    /// Axial force on the object, N.
    #[arg(long)]
    force: f64,
    /// Disk thickness, m.
    #[arg(long, default_value_t = 0.002)]
    thickness: f64,
    /// Cylinder half length, m (default 2 × radius).
    #[arg(long, default_value_t = 0.0)]
    half_length: f64,
    /// sim.mcap to write.
    #[arg(short, long)]
    output: PathBuf,
    /// Settings TOML (softcap_tissue::SimulateSettings).
    #[arg(long)]
    settings: Option<PathBuf>,
}

impl SimulateArgs {
    fn run(&self, arguments: Vec<String>) -> Result<(), Failure> {
        let settings: SimulateSettings = load_settings(&self.settings)?;
        let three = |v: &[f64], what: &str| -> Result<[f64; 3], Failure> {
            <[f64; 3]>::try_from(v).map_err(|_| {
                Failure::BadInput(anyhow::anyhow!(
                    "--{what} needs three comma-separated numbers"
                ))
            })
        };
        let cfg = SimulateConfig {
            material: self.material.clone(),
            output: self.output.clone(),
            probe: ProbeSpec {
                shape: self.probe_shape,
                radius_m: self.radius,
                tip_m: three(&self.tip, "tip")?,
                axis: three(&self.axis, "axis")?,
                force_n: self.force,
                disk_thickness_m: self.thickness,
                half_length_m: self.half_length,
            },
            settings,
            arguments,
        };
        let o = softcap_tissue::simulate::run(&cfg).map_err(classify)?;
        println!(
            "depth {:.4} mm, axial force {:.4} N, {} load steps, max marker displacement {:.4} mm",
            1e3 * o.depth_m,
            o.axial_force_n,
            o.load_steps,
            1e3 * o.max_marker_displacement_m
        );
        Ok(())
    }
}

#[derive(Debug, clap::Args)]
struct FitArgs {
    /// capture.mcap (markers, probe, /capture/session).
    capture: PathBuf,
    /// Tet mesh (Gmsh 4.1 .msh) in the session's length unit, e.g. SESSION/template/volume.msh.
    #[arg(long)]
    mesh: Option<PathBuf>,
    /// material.mcap to write.
    #[arg(short, long)]
    output: PathBuf,
    /// Settings TOML (softcap_tissue::FitSettings).
    #[arg(long)]
    settings: Option<PathBuf>,
    /// Also write report.md and PNG figures (per-example error, error vs basis size) here.
    #[arg(long)]
    report: Option<PathBuf>,
    /// Examples per probe location (overrides the settings).
    #[arg(long)]
    examples_per_location: Option<usize>,
    /// No progress bars.
    #[arg(long)]
    quiet: bool,
}

enum Failure {
    BadInput(anyhow::Error),
    Run(anyhow::Error),
}

fn load_settings<T: serde::de::DeserializeOwned + Default>(
    path: &Option<PathBuf>,
) -> Result<T, Failure> {
    match path {
        None => Ok(T::default()),
        Some(p) => {
            let text = std::fs::read_to_string(p)
                .with_context(|| format!("reading {}", p.display()))
                .map_err(Failure::BadInput)?;
            toml::from_str(&text)
                .with_context(|| format!("{}: bad settings", p.display()))
                .map_err(Failure::BadInput)
        }
    }
}

fn classify(e: softcap_tissue::TissueError) -> Failure {
    if e.is_bad_input() {
        Failure::BadInput(e.into())
    } else {
        Failure::Run(e.into())
    }
}

impl FitArgs {
    fn run(&self, arguments: Vec<String>) -> Result<(), Failure> {
        let mut settings: FitSettings = load_settings(&self.settings)?;
        if let Some(n) = self.examples_per_location {
            settings.examples.examples_per_location = n;
        }
        if self.quiet {
            settings.progress = false;
        }
        let cfg = FitConfig {
            capture: self.capture.clone(),
            mesh: self.mesh.clone(),
            output: self.output.clone(),
            report: self.report.clone(),
            settings,
            arguments,
        };
        let o = softcap_tissue::fit::run(&cfg).map_err(classify)?;
        println!(
            "{} examples, {} tets: marker RMS homogeneous {:.4} mm, per-example {:.4} mm, strain-space material {:.4} mm ({:.1} centres/tet)",
            o.examples.len(),
            o.tets,
            1e3 * o.homogeneous_rms_m,
            1e3 * o.example_rms_m,
            1e3 * o.material_rms_m,
            o.mean_centers
        );
        Ok(())
    }
}

fn main_inner() -> Result<(), Failure> {
    let args: Vec<String> = std::env::args().collect();
    let cli = Cli::try_parse_from(&args).map_err(|e| {
        let _ = e.print();
        if e.use_stderr() {
            Failure::BadInput(anyhow::anyhow!("bad usage"))
        } else {
            Failure::Run(anyhow::anyhow!(""))
        }
    });
    let cli = match cli {
        Ok(c) => c,
        Err(Failure::Run(_)) => return Ok(()), // --help / --version
        Err(f) => return Err(f),
    };
    match &cli.command {
        Command::Fit(a) => a.run(args),
        Command::Simulate(a) => a.run(args),
    }
}

fn main() -> ExitCode {
    match main_inner() {
        Ok(()) => ExitCode::SUCCESS,
        Err(Failure::BadInput(e)) => {
            eprintln!("softcap-tissue: {e:#}");
            ExitCode::from(2)
        }
        Err(Failure::Run(e)) => {
            eprintln!("softcap-tissue: {e:#}");
            ExitCode::from(1)
        }
    }
}
