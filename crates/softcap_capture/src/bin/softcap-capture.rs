//! `softcap-capture DIR -o capture.mcap`: the capture stage's thin binary.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;
use softcap_capture::{
    CaptureError, CaptureSettings, FsrConversion, MarkerSource, Session, capture,
    write_capture_mcap,
};

/// Raw session folder → markers, probe pose and force, clock sync (capture.mcap).
#[derive(Debug, Parser)]
#[command(name = "softcap-capture", version)]
struct Args {
    /// Session folder (contains session.toml).
    session: PathBuf,
    /// Output MCAP file.
    #[arg(short, long, default_value = "capture.mcap")]
    output: PathBuf,
    /// 2D source: auto (images when present), images or detections.
    #[arg(long, value_parser = ["auto", "images", "detections"], default_value = "auto")]
    source: String,
    /// FSR voltage → force: power-law fit or monotone interpolation of the calibration table.
    #[arg(long, value_parser = ["power-law", "interpolation"])]
    fsr: Option<String>,
    /// Align clocks from the data even when a trigger line is present.
    #[arg(long)]
    data_sync: bool,
    /// Settings file (TOML, `CaptureSettings`); flags override it.
    #[arg(long)]
    settings: Option<PathBuf>,
}

fn run(args: &Args, argv: &[String]) -> Result<(), CaptureError> {
    let mut settings: CaptureSettings = match &args.settings {
        Some(p) => softcap_capture::session::parse_settings_toml(p)?,
        None => CaptureSettings::default(),
    };
    settings.source = match args.source.as_str() {
        "images" => MarkerSource::Images,
        "detections" => MarkerSource::Detections,
        _ => settings.source,
    };
    match args.fsr.as_deref() {
        Some("interpolation") => settings.fsr_conversion = FsrConversion::MonotoneInterpolation,
        Some("power-law") => settings.fsr_conversion = FsrConversion::PowerLaw,
        _ => {}
    }
    settings.force_data_sync |= args.data_sync;
    let session = Session::load(&args.session)?;
    let result = capture(&session, &settings)?;
    let path = write_capture_mcap(&args.output, &session, &result, &settings, argv)?;
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
        count(softcap_capture::MarkerState::Visible),
        count(softcap_capture::MarkerState::Filled),
        count(softcap_capture::MarkerState::Missing)
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
    eprintln!("wrote {}", path.display());
    Ok(())
}

fn main() -> ExitCode {
    let argv: Vec<String> = std::env::args().collect();
    let args = match Args::try_parse_from(&argv) {
        Ok(a) => a,
        Err(e) => {
            let _ = e.print();
            return if e.use_stderr() {
                ExitCode::from(2)
            } else {
                ExitCode::SUCCESS
            };
        }
    };
    match run(&args, &argv) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(if e.is_bad_input() { 2 } else { 1 })
        }
    }
}
