//! `softcap-synth --scenario FILE --out DIR`: the command line of the virtual rig.

use std::path::PathBuf;

use clap::Parser;
use softcap_app::{Context, Progress, Result};

use crate::{Scenario, synthesize_with_progress};

/// The virtual rig: simulate a scenario and write a raw session folder (docs/session-format.md).
#[derive(Parser, Debug)]
#[command(name = "softcap-synth", version)]
pub struct Cli {
    /// Scenario TOML (see docs/synth.md and fixtures/scenarios/).
    #[arg(long)]
    pub scenario: PathBuf,
    /// Output session folder (must not exist or be empty).
    #[arg(long)]
    pub out: PathBuf,
    /// Override the scenario's seed.
    #[arg(long)]
    pub seed: Option<u64>,
    /// No progress bars (they are drawn only when stderr is a terminal).
    #[arg(long)]
    pub quiet: bool,
}

impl Cli {
    /// Loads the scenario, synthesizes the session and prints what was written.
    pub fn run(self) -> Result<()> {
        let mut scenario = Scenario::load(&self.scenario)?;
        if let Some(seed) = self.seed {
            scenario.seed = seed;
        }
        let r = synthesize_with_progress(&scenario, &self.out, &Progress::new(!self.quiet))
            .with_context(|| format!("synthesizing {}", self.scenario.display()))?;
        if scenario.kind == "dynamic" {
            eprintln!(
                "wrote {}: {} frames, truth {} tets / template {} tets, {} depth images, {} depth readings, largest surface displacement {:.1} mm, unseen surface {:.1} %",
                r.path.display(),
                r.frames,
                r.truth_tets,
                r.fit_tets,
                r.images,
                r.depth_readings,
                r.max_marker_displacement_m * 1e3,
                100.0 * r.unseen_fraction
            );
            return Ok(());
        }
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
}
