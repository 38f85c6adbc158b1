//! Times a whole reshape of the known-truth case ([`softcap_tissue::reshape::known_truth`],
//! saito-barbic Fig. 21) in process: wall time and CPU-s (user + system, all threads) after every
//! Gauss–Newton iteration, so the cost of each stage shows. The row "whole reshape at Table 1
//! size" of docs/reshape.md:
//!
//! ```sh
//! cargo build --workspace --profile test --example reshape_timing
//! target/debug/examples/reshape_timing 22,20,15            # 39,600 tets
//! SOFTCAP_RESHAPE_SETTINGS='step_solver = "woodbury"' target/debug/examples/reshape_timing 22,20,15
//! ```
//!
//! The argument is the box cells X,Y,Z (6 tets each; default 8,5,3: 720 tets); the optional
//! `SOFTCAP_RESHAPE_SETTINGS` is `ReshapeSettings` as TOML (default: the defaults).

use std::process::ExitCode;
use std::time::Instant;

use softcap_tissue::reshape::{ReshapeSettings, known_truth, reshape};

/// CPU seconds of this process (user + system, every thread) from /proc/self/stat; NaN elsewhere.
fn cpu_seconds() -> f64 {
    softcap_app::process::cpu_seconds().unwrap_or(f64::NAN)
}

fn main() -> ExitCode {
    let arg = std::env::args().nth(1).unwrap_or_else(|| "8,5,3".into());
    let cells: Vec<usize> = arg.split(',').filter_map(|v| v.parse().ok()).collect();
    let [x, y, z] = match cells[..] {
        [x, y, z] if x > 0 && y > 0 && z > 0 => [x, y, z],
        _ => {
            eprintln!("reshape_timing: expected X,Y,Z (three positive integers), got {arg:?}");
            return ExitCode::from(2);
        }
    };
    let settings: ReshapeSettings = match std::env::var("SOFTCAP_RESHAPE_SETTINGS") {
        Ok(text) => match toml::from_str(&text) {
            Ok(s) => s,
            Err(e) => {
                eprintln!("reshape_timing: SOFTCAP_RESHAPE_SETTINGS: {e}");
                return ExitCode::from(2);
            }
        },
        Err(_) => ReshapeSettings::default(),
    };
    let (problem, _) = known_truth::problem_with_cells(false, [x, y, z]);
    let start = Instant::now();
    let cpu0 = cpu_seconds();
    let mut last = cpu0;
    eprintln!(
        "{} tets, step_solver {:?}, {} threads",
        problem.template.tets.len(),
        settings.step_solver,
        rayon::current_num_threads()
    );
    let outcome = reshape(
        &problem,
        &settings,
        &mut |stage, it, objective, max_error| {
            let cpu = cpu_seconds();
            eprintln!(
                "{:8.1} s wall {:7.1} CPU-s (+{:5.1})  {stage} {it}: E {objective:.3e} m², max error \
             {:.3} mm",
                start.elapsed().as_secs_f64(),
                cpu - cpu0,
                cpu - last,
                max_error * 1e3
            );
            last = cpu;
        },
    );
    match outcome {
        Ok(out) => {
            let stages: Vec<String> = out
                .stages
                .iter()
                .map(|s| format!("{} {} {}", s.name, s.iterations, s.stop.name()))
                .collect();
            println!(
                "{:?}: {} ({}); {:.1} s wall, {:.1} CPU-s",
                out.status,
                stages.join(", "),
                out.history.len(),
                start.elapsed().as_secs_f64(),
                cpu_seconds() - cpu0
            );
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("reshape_timing: {e}");
            ExitCode::FAILURE
        }
    }
}
