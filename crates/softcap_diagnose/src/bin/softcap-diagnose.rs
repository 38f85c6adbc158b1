//! `softcap-diagnose capture.mcap material.mcap -o diagnosis.mcap [--json FILE] [--report DIR]`:
//! locate the model/recording mismatch, name the missing physics, write the extended model.
//! Exit codes: 0 success, 1 failure while running, 2 bad usage or bad input.

use anyhow::Context as _;
use clap::Parser;
use softcap_diagnose::{DiagnoseError, RunConfig, StageSettings, run};
use std::path::PathBuf;
use std::process::ExitCode;

/// Diagnose missing physics: recording (capture.mcap) vs model (material.mcap).
#[derive(Debug, Parser)]
#[command(name = "softcap-diagnose", version)]
struct Cli {
    /// capture.mcap (markers, probe, /capture/session).
    capture: PathBuf,
    /// material.mcap (/mesh/volume, /tissue/basis or /tissue/element_material).
    material: PathBuf,
    /// diagnosis.mcap to write.
    #[arg(short, long)]
    output: PathBuf,
    /// Also write the diagnosis as JSON.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Also write report.md and figures into this folder.
    #[arg(long)]
    report: Option<PathBuf>,
    /// Settings TOML (`[diagnose]`, `[simulator]`).
    #[arg(long)]
    settings: Option<PathBuf>,
}

enum Failure {
    BadInput(anyhow::Error),
    Run(anyhow::Error),
}

fn main_inner() -> Result<(), Failure> {
    let args: Vec<String> = std::env::args().collect();
    let cli = Cli::try_parse_from(&args).map_err(|e| {
        let _ = e.print();
        Failure::BadInput(anyhow::anyhow!("bad usage"))
    })?;
    let settings: StageSettings = match &cli.settings {
        Some(p) => {
            let text = std::fs::read_to_string(p)
                .with_context(|| format!("reading {}", p.display()))
                .map_err(Failure::BadInput)?;
            toml::from_str(&text)
                .with_context(|| format!("{}: bad settings", p.display()))
                .map_err(Failure::BadInput)?
        }
        None => StageSettings::default(),
    };
    let cfg = RunConfig {
        capture: cli.capture,
        material: cli.material,
        output: cli.output,
        json: cli.json,
        report: cli.report,
        settings,
        arguments: args,
        progress: true,
    };
    match run(&cfg) {
        Ok(d) => {
            println!("verdict: {}", d.verdict);
            if let Some(top) = d.ranked.first() {
                println!(
                    "held-out rmse: {:.4} mm → {:.4} mm",
                    1e3 * top.heldout_rmse_before_m,
                    1e3 * top.heldout_rmse_after_m
                );
            }
            Ok(())
        }
        Err(
            e @ (DiagnoseError::BadInput { .. }
            | DiagnoseError::Mcap { .. }
            | DiagnoseError::BadRecording { .. }
            | DiagnoseError::NonFinite { .. }
            | DiagnoseError::Mesh(_)),
        ) => Err(Failure::BadInput(e.into())),
        Err(e) => Err(Failure::Run(e.into())),
    }
}

fn main() -> ExitCode {
    match main_inner() {
        Ok(()) => ExitCode::SUCCESS,
        Err(Failure::BadInput(e)) => {
            eprintln!("softcap-diagnose: {e:#}");
            ExitCode::from(2)
        }
        Err(Failure::Run(e)) => {
            eprintln!("softcap-diagnose: {e:#}");
            ExitCode::from(1)
        }
    }
}
