//! Crash safety of `softcap-tissue` (docs/reliability.md): `fit`, `simulate` and `reshape`
//! SIGKILLed at random moments leave nothing or a complete MCAP under the output name, and two
//! processes writing one output at once leave one complete file. `make test` runs a few trials
//! per command; `scripts/kill-test` runs 50 (`SOFTCAP_KILL_TRIALS`).

use crate::common;

use std::path::Path;
use std::process::Command;

use common::{SessionSpec, quiet_fit, write_session};
use softcap_app::testing::{kill_trial_count, kill_trials, race_trials};
use softcap_tissue::reshape::known_truth::problem;
use softcap_tissue::reshape::write_target;

const BIN: &str = env!("CARGO_BIN_EXE_softcap-tissue");

/// What `softcap inspect summary` checks: the file opens as a complete, valid MCAP.
fn complete(path: &Path) -> Result<(), String> {
    softcap_mcap::Recording::open(path)
        .map(|_| ())
        .map_err(|e| e.to_string())
}

/// `kills` and `races` trials in `make test` (scripts/kill-test: 50 each).
fn trials(command: &dyn Fn() -> Command, out: &Path, seed: u64, kills: usize, races: usize) {
    let tally = kill_trials(command, out, kill_trial_count(kills), seed, &complete);
    let raced = race_trials(command, out, kill_trial_count(races), &complete);
    eprintln!("{}: {tally:?}, {raced} race trials", out.display());
}

#[test]
fn fit_and_simulate_killed_at_random_moments_leave_nothing_or_a_complete_file() {
    let dir = tempfile::tempdir().unwrap();
    let s = write_session(
        dir.path(),
        &SessionSpec {
            locations: vec![[0.015, 0.015]],
            forces_n: vec![1.0],
            ..SessionSpec::default()
        },
    );
    let material = dir.path().join("material.mcap");
    let fit = || {
        let mut c = Command::new(BIN);
        c.arg("fit").arg(&s.capture).arg("--mesh").arg(&s.mesh);
        c.arg("-o").arg(&material);
        c.args(["--examples-per-location", "1", "--quiet"]);
        c
    };
    trials(&fit, &material, 311, 2, 0);
    quiet_fit(&s.capture, &s.mesh, &material);
    let sim = dir.path().join("sim.mcap");
    let simulate = || {
        let mut c = Command::new(BIN);
        c.arg("simulate").arg(&material);
        c.args(["--probe-shape", "sphere", "--radius", "0.005"]);
        c.args(["--tip", "0.015", "0.015", "0.03", "--axis", "0", "0", "-1"]);
        c.args(["--force", "0.4", "-o"]).arg(&sim);
        c
    };
    trials(&simulate, &sim, 312, 2, 1);
}

#[test]
fn reshape_killed_at_random_moments_leaves_nothing_or_a_complete_file() {
    let (p, _) = problem(false);
    let dir = tempfile::tempdir().unwrap();
    write_target(dir.path(), &p, "mm").unwrap();
    let settings = dir.path().join("reshape.toml");
    std::fs::write(&settings, "max_iterations = 2\nconstant_iterations = 2\n").unwrap();
    let out = dir.path().join("reshaped.mcap");
    let reshape = || {
        let mut c = Command::new(BIN);
        c.arg("reshape")
            .arg("--template")
            .arg(dir.path().join("template.msh"));
        c.arg("--target").arg(dir.path().join("target"));
        c.arg("-o")
            .arg(&out)
            .arg("--settings")
            .arg(&settings)
            .arg("--quiet");
        c
    };
    trials(&reshape, &out, 313, 3, 1);
}
