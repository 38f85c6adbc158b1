//! `softcap-tissue fit capture.mcap --mesh volume.msh -o material.mcap [--settings S.toml]`:
//! bickel2009 material capture; `softcap-tissue simulate material.mcap --probe-shape sphere
//! --radius R --tip x,y,z --axis x,y,z --force N -o sim.mcap`: novel-probe synthesis;
//! `softcap-tissue reshape --template T.msh --target TARGET/ -o reshaped.mcap [--report DIR]`:
//! saito-barbic template reshaping (a reshape that hits its iteration cap says so and still
//! writes its result); `softcap-tissue track capture.mcap --mesh volume.msh -o track.mcap`: wang2015 §5 tracking;
//! `softcap-tissue fit-dynamic track.mcap --mesh volume.msh -o dynamic.mcap`: wang2015 §6 parameter
//! estimation; `softcap-tissue simulate-dynamic dynamic.mcap --initial track.mcap --frames a..b -o sim.mcap`.

use std::path::PathBuf;

use clap::{Parser, Subcommand};
use softcap_app::{Error, Result, load_toml_or_default};

use crate::{FitConfig, FitSettings, ProbeShape, ProbeSpec, SimulateConfig, SimulateSettings};

/// Soft-tissue material capture and synthesis (bickel2009).
#[derive(Debug, Parser)]
#[command(name = "softcap-tissue", version)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Fit a heterogeneous non-linear material to a capture.
    Fit(FitArgs),
    /// Synthesize a novel probe deformation with a fitted material (SI units).
    Simulate(SimulateArgs),
    /// Reshape a template tet mesh to a subject's landmarks and ICP markers (saito-barbic).
    Reshape(ReshapeArgs),
    /// Track the template mesh through the point clouds of a dynamic capture (wang2015 §5).
    Track(TrackArgs),
    /// Fit E at control points, Rayleigh α/β and the rest shape to tracked trajectories (wang2015 §6).
    FitDynamic(FitDynamicArgs),
    /// Simulate a fitted dynamic material from a tracked frame over a frame range.
    SimulateDynamic(SimulateDynamicArgs),
}

#[derive(Debug, clap::Args)]
pub struct FitDynamicArgs {
    /// track.mcap (`softcap tissue track`); several: recorded motions of the same body (same
    /// template and support), fitted jointly.
    #[arg(required = true, num_args = 1..)]
    pub track: Vec<PathBuf>,
    /// Template tet mesh (Gmsh 4.1, session length unit) the track was made with: the frame-0 shape.
    #[arg(long)]
    pub mesh: PathBuf,
    /// dynamic.mcap to write.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Also write report.md and trajectories.png here.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Also write the fitted parameters as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Also write the material for the next `tissue track --material` pass here: the fit's, with
    /// control points at an E bound given their nearest free neighbour's E, rest shape solved by
    /// the tracker.
    #[arg(long)]
    pub next_material: Option<PathBuf>,
    /// With --next-material: the --json of this loop's earlier passes, oldest first (the last
    /// one's next material is what these tracks were tracked with); the next material is then
    /// Anderson-accelerated over the last two of them and this pass.
    #[arg(long, num_args = 1.., requires = "next_material")]
    pub previous_passes: Vec<PathBuf>,
    /// Settings TOML (softcap_tissue::fit_dynamic::FitDynamicSettings).
    #[arg(long)]
    pub settings: Option<PathBuf>,
    /// Material control points (overrides the settings).
    #[arg(long)]
    pub control_points: Option<usize>,
    /// Uniform refinement levels of the fit mesh (overrides the settings).
    #[arg(long)]
    pub refine: Option<usize>,
    /// Elements of the fit: linear tets, or quadratic (10-node) tets converged in bending
    /// (overrides the settings).
    #[arg(long, value_enum)]
    pub elements: Option<crate::fit_dynamic::Elements>,
    /// No progress display.
    #[arg(long)]
    pub quiet: bool,
}

impl FitDynamicArgs {
    fn run(&self, arguments: Vec<String>) -> Result<()> {
        let mut settings: crate::fit_dynamic::FitDynamicSettings =
            load_toml_or_default(self.settings.as_deref())?;
        if let Some(n) = self.control_points {
            settings.control_points = n;
        }
        if let Some(n) = self.refine {
            settings.refine = n;
        }
        if let Some(e) = self.elements {
            settings.elements = e;
        }
        if self.quiet {
            settings.progress = false;
        }
        let cfg = crate::fit_dynamic::FitDynamicConfig {
            track: self.track[0].clone(),
            more_tracks: self.track[1..].to_vec(),
            mesh: self.mesh.clone(),
            output: self.output.clone(),
            report: self.report.clone(),
            json: self.json.clone(),
            next_material: self.next_material.clone(),
            previous_passes: self.previous_passes.clone(),
            settings,
            arguments,
        };
        let progress = softcap_app::Progress::new(cfg.settings.progress);
        let f = crate::fit_dynamic::run::run(&cfg, &progress)?;
        let young: Vec<String> = f.young_pa.iter().map(|e| format!("{e:.4e}")).collect();
        println!(
            "{}: E [{}] Pa, nu {:.3}, alpha {:.4e} 1/s, beta {:.4e} s; trajectory RMS {:.3} mm (start {:.3} mm, warm start {:.3} mm{}), {} simulations",
            f.status,
            young.join(", "),
            f.poisson,
            f.damping.alpha_per_s,
            f.damping.beta_s,
            1e3 * f.rms_m,
            1e3 * f.rms_initial_m,
            1e3 * f.rms_warm_m,
            f.warm_rms_scope(),
            f.simulations
        );
        Ok(())
    }
}

#[derive(Debug, clap::Args)]
pub struct SimulateDynamicArgs {
    /// dynamic.mcap (`softcap tissue fit-dynamic`).
    pub material: PathBuf,
    /// track.mcap whose frame `a` is the initial state (support and gravity from it too).
    #[arg(long)]
    pub initial: PathBuf,
    /// Frame range `a..b` (frame numbers of the track, inclusive).
    #[arg(long)]
    pub frames: String,
    /// sim.mcap to write.
    #[arg(short, long)]
    pub output: PathBuf,
}

impl SimulateDynamicArgs {
    fn run(&self, arguments: Vec<String>) -> Result<()> {
        let range = self
            .frames
            .split_once("..")
            .and_then(|(a, b)| Some((a.trim().parse().ok()?, b.trim().parse().ok()?)))
            .ok_or_else(|| {
                Error::bad_input(format!(
                    "--frames `{}`: expected a..b (two frame numbers)",
                    self.frames
                ))
            })?;
        let cfg = crate::fit_dynamic::SimulateDynamicConfig {
            material: self.material.clone(),
            initial: self.initial.clone(),
            frames: range,
            output: self.output.clone(),
            forward: crate::fit_dynamic::ForwardSettings::default(),
            arguments,
        };
        let o = crate::fit_dynamic::simulate(&cfg)?;
        println!(
            "{} frames simulated, RMS {:.3} mm to the track, {} steps at the Newton limit",
            o.frames,
            1e3 * o.rms_m,
            o.max_iteration_steps
        );
        Ok(())
    }
}

#[derive(Debug, clap::Args)]
pub struct ReshapeArgs {
    /// Template tet mesh (Gmsh 4.1 .msh), coordinates in TARGET/target.toml's length unit.
    #[arg(long)]
    pub template: PathBuf,
    /// TARGET folder: target.toml, landmarks.csv, icp_markers.csv [, attachments.csv, surface.obj].
    #[arg(long)]
    pub target: PathBuf,
    /// reshaped.mcap to write.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Also write report.md and PNG figures (error histogram, convergence, before/after) here.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Settings TOML (softcap_tissue::reshape::ReshapeSettings).
    #[arg(long)]
    pub settings: Option<PathBuf>,
    /// No progress display.
    #[arg(long)]
    pub quiet: bool,
}

impl ReshapeArgs {
    fn run(&self, arguments: Vec<String>) -> Result<()> {
        let cfg = crate::reshape::ReshapeConfig {
            template: self.template.clone(),
            target: self.target.clone(),
            output: self.output.clone(),
            report: self.report.clone(),
            settings: load_toml_or_default(self.settings.as_deref())?,
            arguments,
        };
        let r = crate::reshape::run(&cfg, &softcap_app::Progress::new(!self.quiet))?;
        println!("{}", crate::reshape::summary_line(&r));
        Ok(())
    }
}

#[derive(Debug, clap::Args)]
pub struct TrackArgs {
    /// capture.mcap of a dynamic session (`softcap capture` on kind = "dynamic").
    pub capture: PathBuf,
    /// Template tet mesh (Gmsh 4.1, session length unit), e.g. SESSION/template/volume.msh.
    #[arg(long)]
    pub mesh: PathBuf,
    /// Dynamic material (`/tissue/dynamic_material`); default: a soft corotational material
    /// (settings).
    #[arg(long)]
    pub material: Option<PathBuf>,
    /// Extra attachment nodes: CSV with a `node` column (0-based node indices of the mesh).
    #[arg(long)]
    pub attach: Option<PathBuf>,
    /// track.mcap to write.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Settings TOML (softcap_tissue::TrackSettings).
    #[arg(long)]
    pub settings: Option<PathBuf>,
    /// Young's modulus of the default material, Pa (overrides the settings).
    #[arg(long)]
    pub young_pa: Option<f64>,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
}

#[derive(Debug, clap::Args)]
pub struct SimulateArgs {
    /// material.mcap written by `softcap tissue fit`.
    pub material: PathBuf,
    /// Tip shape.
    #[arg(long, value_enum)]
    pub probe_shape: ProbeShape,
    /// Tip radius, m.
    #[arg(long)]
    pub radius: f64,
    /// A point on the approach line, m: x,y,z.
    #[arg(
        long,
        value_delimiter = ',',
        num_args = 3,
        allow_negative_numbers = true
    )]
    pub tip: Vec<f64>,
    /// Approach direction (handle → tip): x,y,z.
    #[arg(
        long,
        value_delimiter = ',',
        num_args = 3,
        allow_negative_numbers = true,
        default_value = "0,0,-1"
    )]
    pub axis: Vec<f64>,
    /// Axial force on the object, N.
    #[arg(long)]
    pub force: f64,
    /// Disk thickness, m.
    #[arg(long, default_value_t = 0.002)]
    pub thickness: f64,
    /// Cylinder half length, m (default 2 × radius).
    #[arg(long, default_value_t = 0.0)]
    pub half_length: f64,
    /// sim.mcap to write.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Settings TOML (softcap_tissue::SimulateSettings).
    #[arg(long)]
    pub settings: Option<PathBuf>,
}

#[derive(Debug, clap::Args)]
pub struct FitArgs {
    /// capture.mcap (markers, probe, /capture/session).
    pub capture: PathBuf,
    /// Tet mesh (Gmsh 4.1 .msh) in the session's length unit, e.g. SESSION/template/volume.msh.
    #[arg(long)]
    pub mesh: Option<PathBuf>,
    /// material.mcap to write.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Settings TOML (softcap_tissue::FitSettings).
    #[arg(long)]
    pub settings: Option<PathBuf>,
    /// Also write report.md and PNG figures (per-example error, error vs basis size) here.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Examples per probe location (overrides the settings).
    #[arg(long)]
    pub examples_per_location: Option<usize>,
    /// No progress bars.
    #[arg(long)]
    pub quiet: bool,
}

impl Cli {
    /// Runs the subcommand.
    pub fn run(self) -> Result<()> {
        let arguments: Vec<String> = std::env::args().collect();
        match &self.command {
            Command::Fit(a) => a.run(arguments),
            Command::Simulate(a) => a.run(arguments),
            Command::Reshape(a) => a.run(arguments),
            Command::Track(a) => a.run(arguments),
            Command::FitDynamic(a) => a.run(arguments),
            Command::SimulateDynamic(a) => a.run(arguments),
        }
    }
}

impl TrackArgs {
    fn run(&self, arguments: Vec<String>) -> Result<()> {
        let mut settings: crate::TrackSettings = load_toml_or_default(self.settings.as_deref())?;
        if let Some(e) = self.young_pa {
            settings.young_pa = e;
        }
        if self.quiet {
            settings.progress = false;
        }
        let cfg = crate::TrackConfig {
            capture: self.capture.clone(),
            mesh: self.mesh.clone(),
            material: self.material.clone(),
            attach: self.attach.clone(),
            output: self.output.clone(),
            settings,
            arguments,
        };
        let o = crate::track::run(&cfg)?;
        let [c, m, d, n] = o.status_counts();
        println!(
            "{} frames ({c} converged, {m} at the EM limit, {d} diverged, {n} without points), {} nodes, {} surface samples, mean residual {:.3} mm, {:.1} frames/s; rest shape: {}",
            o.frames.len(),
            o.nodes,
            o.samples,
            1e3 * o.mean_residual_m(),
            o.frames.len() as f64 / o.wall_s.max(1e-9),
            o.rest_shape
        );
        Ok(())
    }
}

impl SimulateArgs {
    fn run(&self, arguments: Vec<String>) -> Result<()> {
        let settings: SimulateSettings = load_toml_or_default(self.settings.as_deref())?;
        let three = |v: &[f64], what: &str| -> Result<[f64; 3]> {
            <[f64; 3]>::try_from(v).map_err(|_| {
                Error::bad_input(format!("--{what} needs three comma-separated numbers"))
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
        let o = crate::simulate::run(&cfg)?;
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

impl FitArgs {
    fn run(&self, arguments: Vec<String>) -> Result<()> {
        let mut settings: FitSettings = load_toml_or_default(self.settings.as_deref())?;
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
        let o = crate::fit::run(&cfg)?;
        if o.homogeneous_only {
            println!(
                "{} examples, {} tets: homogeneous baseline only, E {:.1} Pa, nu {:.3}, marker RMS {:.4} mm",
                o.examples.len(),
                o.tets,
                o.homogeneous_young_pa,
                o.homogeneous_nu,
                1e3 * o.homogeneous_rms_m
            );
            return Ok(());
        }
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
