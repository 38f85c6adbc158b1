//! `softcap-synth --scenario FILE --out DIR`: writes one synthetic session.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::Parser;
use softcap_synth::{Scenario, SynthError, synthesize};

/// The virtual rig: simulate a scenario and write a raw session folder (docs/session-format.md).
#[derive(Parser, Debug)]
#[command(name = "softcap-synth", version)]
struct Args {
    /// Scenario TOML (see docs/synth.md and fixtures/scenarios/).
    #[arg(long)]
    scenario: PathBuf,
    /// Output session folder (must not exist or be empty).
    #[arg(long)]
    out: PathBuf,
    /// Override the scenario's seed.
    #[arg(long)]
    seed: Option<u64>,
}

fn run(args: &Args) -> anyhow::Result<()> {
    let mut scenario = Scenario::load(&args.scenario)?;
    if let Some(seed) = args.seed {
        scenario.seed = seed;
    }
    let r = synthesize(&scenario, &args.out)
        .with_context(|| format!("synthesizing {}", args.scenario.display()))?;
    eprintln!(
        "wrote {}: {} frames, {} locations, truth {} tets / template {} tets, max force {:.3} N, max marker displacement {:.3} mm, {} detections, {} images",
        r.path.display(),
        r.frames,
        r.locations,
        r.truth_tets,
        r.fit_tets,
        r.max_axial_force_n,
        r.max_marker_displacement_m * 1e3,
        r.detections,
        r.images
    );
    Ok(())
}

fn main() -> ExitCode {
    let args = match Args::try_parse() {
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
    match run(&args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            let bad_input = e.chain().any(|c| {
                matches!(
                    c.downcast_ref::<SynthError>(),
                    Some(
                        SynthError::Scenario { .. }
                            | SynthError::Unsupported { .. }
                            | SynthError::OutputExists { .. }
                    )
                ) || c.downcast_ref::<std::io::Error>().is_some()
            });
            if bad_input {
                ExitCode::from(2)
            } else {
                ExitCode::from(1)
            }
        }
    }
}
