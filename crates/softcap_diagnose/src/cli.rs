//! `softcap-diagnose capture.mcap material.mcap -o diagnosis.mcap [--json FILE] [--report DIR]`:
//! locate the model/recording mismatch, name the missing physics, write the extended model.

use std::path::PathBuf;

use clap::Parser;
use softcap_app::{Result, load_toml_or_default};

use crate::{RunConfig, StageSettings, run};

/// Diagnose missing physics: recording (capture.mcap) vs model (material.mcap).
#[derive(Debug, Parser)]
#[command(name = "softcap-diagnose", version)]
pub struct Cli {
    /// capture.mcap (markers, probe, /capture/session).
    pub capture: PathBuf,
    /// material.mcap (/mesh/volume, /tissue/basis or /tissue/element_material).
    pub material: PathBuf,
    /// diagnosis.mcap to write.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Also write the diagnosis as JSON.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Also write report.md and figures into this folder.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Settings TOML (`[diagnose]`, `[simulator]`).
    #[arg(long)]
    pub settings: Option<PathBuf>,
}

impl Cli {
    /// Diagnoses, writes the outputs and prints the verdict.
    pub fn run(self) -> Result<()> {
        let settings: StageSettings = load_toml_or_default(self.settings.as_deref())?;
        let cfg = RunConfig {
            capture: self.capture,
            material: self.material,
            output: self.output,
            json: self.json,
            report: self.report,
            settings,
            arguments: std::env::args().collect(),
            progress: true,
        };
        let d = run(&cfg)?;
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
}
