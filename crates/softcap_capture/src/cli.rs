//! `softcap-capture DIR -o capture.mcap [--cameras refined.toml]`: the command line of the capture
//! stage; `softcap-capture calibrate POINTS_OR_SESSION --cameras rig.toml -o refined.toml
//! [--report DIR]`: bundle adjustment of the rig.

use std::path::PathBuf;

use clap::{Parser, Subcommand};
use softcap_app::{Error, Progress, Result};

use crate::bundle::Refine;
use crate::calibrate::{self, CalibrateSettings};
use crate::{
    CaptureError, CaptureResult, CaptureSettings, FsrConversion, MarkerSource, MarkerState,
    Session, capture, write_capture_mcap,
};

/// Raw session folder → markers, probe pose and force, clock sync (capture.mcap).
#[derive(Debug, Parser)]
#[command(
    name = "softcap-capture",
    version,
    args_conflicts_with_subcommands = true,
    subcommand_negates_reqs = true
)]
pub struct Cli {
    /// `calibrate`; without it, capture a session.
    #[command(subcommand)]
    pub command: Option<Command>,
    /// Session folder (contains session.toml).
    #[arg(required = true)]
    pub session: Option<PathBuf>,
    /// Use this rig (rig/cameras.toml format, the session's length unit) instead of the
    /// session's, e.g. one refined by `softcap capture calibrate`.
    #[arg(long)]
    pub cameras: Option<PathBuf>,
    /// Output MCAP file.
    #[arg(short, long, default_value = "capture.mcap")]
    pub output: PathBuf,
    /// 2D source: auto (images when present), images or detections.
    #[arg(long, value_parser = ["auto", "images", "detections"], default_value = "auto")]
    pub source: String,
    /// FSR voltage → force: power-law fit or monotone interpolation of the calibration table.
    #[arg(long, value_parser = ["power-law", "interpolation"])]
    pub fsr: Option<String>,
    /// Align clocks from the data even when a trigger line is present.
    #[arg(long)]
    pub data_sync: bool,
    /// Settings file (TOML, `CaptureSettings`); flags override it.
    #[arg(long)]
    pub settings: Option<PathBuf>,
    /// Dynamic sessions: voxel size of the cloud downsampling, m (0 = keep every point).
    #[arg(long)]
    pub voxel_size: Option<f64>,
}

/// Subcommands of `softcap-capture`.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Refine a rig by bundle adjustment from labeled 2D points (.npz p2d, CSV or a session).
    Calibrate(CalibrateArgs),
}

/// `softcap capture calibrate`.
#[derive(Debug, clap::Args)]
pub struct CalibrateArgs {
    /// Session folder, aniposelib `.npz` (array `p2d`: cameras × points × 2, NaN = unseen) or CSV
    /// `point,camera,u,v`.
    pub input: PathBuf,
    /// Initial rig: rig/cameras.toml or aniposelib calibration TOML (required for points files;
    /// replaces a session's rig).
    #[arg(long)]
    pub cameras: Option<PathBuf>,
    /// Refined rig to write (rig/cameras.toml format).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Folder for report.md and per-camera reprojection histograms.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Intrinsics refined besides the extrinsics: comma list of focal, principal, k1, k2, p1, p2,
    /// k3 (or radial, tangential, distortion, none).
    #[arg(long, default_value = "focal,k1")]
    pub refine: String,
    /// Robust loss.
    #[arg(long, value_parser = ["huber", "cauchy", "squared"], default_value = "huber")]
    pub loss: String,
    /// Camera whose pose is held (default: the first).
    #[arg(long)]
    pub fix_camera: Option<String>,
    /// Camera whose distance to the fixed one sets the scale (default: the farthest).
    #[arg(long)]
    pub scale_camera: Option<String>,
    /// That distance in metres (default: its value in the initial rig).
    #[arg(long)]
    pub scale_distance: Option<f64>,
    /// Rounds of outlier rejection + bundle adjustment.
    #[arg(long, default_value_t = 5)]
    pub max_rounds: usize,
    /// Outlier threshold on the residual norm, in robust noise scales σ̂.
    #[arg(long, default_value_t = 3.0)]
    pub outlier_threshold: f64,
    /// Levenberg–Marquardt iteration cap per round.
    #[arg(long, default_value_t = 100)]
    pub max_iterations: usize,
}

impl CalibrateArgs {
    /// The calibration settings the flags describe; an unknown `--refine` or `--loss` is bad
    /// input naming the flag.
    pub fn settings(&self) -> Result<CalibrateSettings> {
        let bad = |field: &str, message: String| CaptureError::Format {
            path: PathBuf::from(format!("--{field}")),
            message,
        };
        let mut settings = CalibrateSettings::default();
        settings.bundle.refine = Refine::parse(&self.refine).map_err(|m| bad("refine", m))?;
        settings.bundle.loss = calibrate::parse_loss(&self.loss)
            .ok_or_else(|| bad("loss", format!("unknown loss `{}`", self.loss)))?;
        settings.fixed_camera.clone_from(&self.fix_camera);
        settings.scale_camera.clone_from(&self.scale_camera);
        settings.scale_distance_m = self.scale_distance;
        settings.max_rounds = self.max_rounds;
        settings.outlier_threshold = self.outlier_threshold;
        settings.bundle.max_iterations = self.max_iterations;
        Ok(settings)
    }

    /// Refines the rig, writes it (and the report) and prints the before/after errors. Each
    /// round's status goes to stderr; the per-iteration `LM` lines only on a terminal.
    pub fn run(&self) -> Result<()> {
        let settings = self.settings()?;
        let verbose = Progress::default().is_visible();
        let start = std::time::Instant::now();
        let (_, cal) = calibrate::run_calibrate(
            &self.input,
            self.cameras.as_deref(),
            &self.output,
            self.report.as_deref(),
            &settings,
            &mut |line| {
                if verbose || !line.starts_with("  LM") {
                    eprintln!("{line}");
                }
            },
        )?;
        println!(
            "median per-point reprojection error: {:.3} px before, {:.3} px after ({} points; {:.1} s)",
            cal.before.median_point_error_px,
            cal.after.median_point_error_px,
            cal.before.points,
            start.elapsed().as_secs_f64()
        );
        println!("gauge: {}", cal.gauge_description());
        println!("status: {}", cal.status_description());
        for w in cal.warnings() {
            println!("warning: {w}");
        }
        println!("wrote {}", self.output.display());
        if let Some(dir) = &self.report {
            println!("report: {}", dir.join("report.md").display());
        }
        Ok(())
    }
}

impl Cli {
    /// The settings file with the flags applied on top.
    pub fn settings(&self) -> Result<CaptureSettings> {
        let mut settings: CaptureSettings = match &self.settings {
            Some(p) => crate::session::parse_settings_toml(p)?,
            None => CaptureSettings::default(),
        };
        settings.source = match self.source.as_str() {
            "images" => MarkerSource::Images,
            "detections" => MarkerSource::Detections,
            _ => settings.source,
        };
        match self.fsr.as_deref() {
            Some("interpolation") => settings.fsr_conversion = FsrConversion::MonotoneInterpolation,
            Some("power-law") => settings.fsr_conversion = FsrConversion::PowerLaw,
            _ => {}
        }
        settings.force_data_sync |= self.data_sync;
        Ok(settings)
    }

    /// `calibrate`, or: reads the session (with `--cameras` in place of its rig), reconstructs
    /// it, writes capture.mcap and prints a summary.
    pub fn run(self) -> Result<()> {
        if let Some(Command::Calibrate(c)) = &self.command {
            return c.run();
        }
        let Some(session_dir) = &self.session else {
            return Err(Error::bad_input("a session folder is required"));
        };
        let mut settings = self.settings()?;
        if let Some(v) = self.voxel_size {
            settings.depth.voxel_size_m = v;
        }
        let argv: Vec<String> = std::env::args().collect();
        let mut session = Session::load(session_dir)?;
        if let Some(path) = &self.cameras {
            session.use_cameras(path)?;
        }
        if session.kind == crate::SessionKind::Dynamic {
            return capture_dynamic_session(&self.output, &session, &settings, &argv);
        }
        let result = capture(&session, &settings)?;
        let path = write_capture_mcap(&self.output, &session, &result, &settings, &argv)?;
        print_summary(&result);
        eprintln!("wrote {}", path.display());
        Ok(())
    }
}

/// A dynamic session: depth images or PLY clouds → capture.mcap, with a one-line summary.
fn capture_dynamic_session(
    output: &std::path::Path,
    session: &Session,
    settings: &CaptureSettings,
    argv: &[String],
) -> Result<()> {
    let result = crate::capture_dynamic(session, &settings.depth)?;
    let path = crate::write_dynamic_capture_mcap(output, session, &result, settings, argv)?;
    let points: usize = result.frames.iter().map(|f| f.points_m.len()).sum();
    eprintln!(
        "{}: {} frames, {} depth cameras, {} points ({:.0} per frame)",
        result.session,
        result.frames.len(),
        result.cameras.len(),
        points,
        points as f64 / result.frames.len().max(1) as f64
    );
    eprintln!("wrote {}", path.display());
    Ok(())
}

/// Markers per state, per-camera reprojection error and the clock fit, on stderr.
fn print_summary(result: &CaptureResult) {
    let count = |s| {
        result
            .frames
            .iter()
            .flat_map(|f| &f.markers)
            .filter(|m| m.state == s)
            .count()
    };
    eprintln!(
        "{}: {} frames, {} markers; samples visible {}, filled {}, missing {}",
        result.session,
        result.frames.len(),
        result.marker_ids.len(),
        count(MarkerState::Visible),
        count(MarkerState::Filled),
        count(MarkerState::Missing)
    );
    for c in &result.cameras {
        eprintln!(
            "  {}: {} blobs, {} used, reprojection median {:.3} px, rms {:.3} px",
            c.id, c.blobs, c.used, c.median_reprojection_px, c.rms_reprojection_px
        );
    }
    if let Some(s) = &result.sync {
        eprintln!(
            "  clock ({:?}): t_daq = {:.6} s + (1 {:+.3e})·t_camera, residual {:.3e}",
            s.method, s.offset_s, s.drift, s.residual
        );
    }
}
