//! The `softcap` command line: `softcap inspect <verb> FILE …` and `softcap <stage> …`.
//!
//! | command | what |
//! |---|---|
//! | `softcap inspect summary FILE` | profile, message count, time range, channels, provenance |
//! | `softcap inspect channels FILE` | one line per channel: topic, schema, encoding, count |
//! | `softcap inspect dump FILE [--topic T]` | JSON lines, protobuf decoded with the embedded schema |
//! | `softcap inspect digest FILE` | content digest (ignores the provenance timestamp) |
//! | `softcap inspect export FILE --what markers\|probe\|surface\|volume\|nodes\|points\|TOPIC -o OUT` | CSV / OBJ / PLY |
//! | `softcap inspect plot FILE --topic T --field PATH… -o OUT.png` | PNG time series of numeric fields |
//! | `softcap <stage> ARGS…` | runs `softcap-<stage>` found next to `softcap` or on `PATH` |
//!
//! Exit codes: 0 success, 1 failure while running, 2 bad usage or bad input (a corrupt or
//! truncated MCAP, a missing channel).

pub mod export;
mod inspect;
pub mod plot;

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use softcap_app::{Error, IntoError, Result};

pub use inspect::{Inspect, Verb};

/// softcap: soft-tissue and face capture pipeline.
#[derive(Debug, Parser)]
#[command(name = "softcap", version, about)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Look inside any .mcap file.
    Inspect(Inspect),
    /// Run a stage: `softcap capture …` runs `softcap-capture …`.
    #[command(external_subcommand)]
    Stage(Vec<String>),
}

/// Runs the parsed command; a stage's exit code is passed on.
pub fn run(cli: Cli) -> Result<ExitCode> {
    match &cli.command {
        Command::Inspect(i) => {
            i.run()?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Stage(args) => run_stage(args),
    }
}

/// Finds `softcap-<stage>` next to the running binary, else on `PATH`.
pub fn find_stage_binary(stage: &str) -> Option<PathBuf> {
    let name = format!("softcap-{stage}{}", std::env::consts::EXE_SUFFIX);
    if let Some(dir) = std::env::current_exe()
        .ok()
        .and_then(|p| p.parent().map(PathBuf::from))
    {
        let p = dir.join(&name);
        if p.is_file() {
            return Some(p);
        }
    }
    std::env::var_os("PATH").and_then(|paths| {
        std::env::split_paths(&paths)
            .map(|d| d.join(&name))
            .find(|p| p.is_file())
    })
}

fn run_stage(args: &[String]) -> Result<ExitCode> {
    let (stage, rest) = args
        .split_first()
        .ok_or_else(|| Error::bad_input("no stage given"))?;
    let bin = find_stage_binary(stage).ok_or_else(|| {
        Error::bad_input(format!(
            "unknown command `{stage}`: no `softcap-{stage}` next to softcap or on PATH"
        ))
    })?;
    let status = std::process::Command::new(&bin)
        .args(rest)
        .status()
        .failure_with(|| format!("running {}", bin.display()))?;
    Ok(ExitCode::from(
        status.code().unwrap_or(1).clamp(0, 255) as u8
    ))
}
