//! Writes the known-truth case of saito-barbic Fig. 21 ([`softcap_tissue::reshape::known_truth`])
//! as a template and a TARGET folder in mm, the input of the worked example in docs/reshape.md:
//!
//! ```sh
//! cargo run --release -p softcap_tissue --example reshape_box -- /tmp/box [--free-flying] [--cells X,Y,Z]
//! softcap tissue reshape --template /tmp/box/template.msh --target /tmp/box/target -o /tmp/box/reshaped.mcap
//! ```
//!
//! `--cells X,Y,Z`: a finer template of X × Y × Z box cells, 6 tets each (default 8,5,3: 720 tets;
//! `--cells 22,20,15`: 39,600 tets, the size of saito-barbic Table 1, to time a whole reshape).

use std::path::PathBuf;
use std::process::ExitCode;

use softcap_tissue::reshape::{known_truth, write_target};

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(dir) = args
        .iter()
        .enumerate()
        .find(|(i, a)| !a.starts_with("--") && (*i == 0 || args[i - 1] != "--cells"))
        .map(|(_, a)| PathBuf::from(a))
    else {
        eprintln!("usage: reshape_box DIR [--free-flying] [--cells X,Y,Z]");
        return ExitCode::from(2);
    };
    let free_flying = args.iter().any(|a| a == "--free-flying");
    let cells = match args.iter().position(|a| a == "--cells") {
        None => [8, 5, 3],
        Some(i) => {
            let c: Vec<usize> = args
                .get(i + 1)
                .map(|v| v.split(',').filter_map(|n| n.parse().ok()).collect())
                .unwrap_or_default();
            match c[..] {
                [x, y, z] if x > 0 && y > 0 && z > 0 => [x, y, z],
                _ => {
                    eprintln!("reshape_box: --cells expects X,Y,Z (three positive integers)");
                    return ExitCode::from(2);
                }
            }
        }
    };
    let (problem, _) = known_truth::problem_with_cells(free_flying, cells);
    match write_target(&dir, &problem, "mm") {
        Ok(()) => {
            println!(
                "{}: template.msh ({} tets), target/ ({} landmarks, {} ICP markers, {} attachments)",
                dir.display(),
                problem.template.tets.len(),
                problem.landmarks.len(),
                problem.icp_markers.len(),
                problem.attachments.len()
            );
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("reshape_box: {e}");
            ExitCode::FAILURE
        }
    }
}
