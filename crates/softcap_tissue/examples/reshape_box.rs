//! Writes the known-truth case of saito-barbic Fig. 21 ([`softcap_tissue::reshape::known_truth`])
//! as a template and a TARGET folder in mm, the input of the worked example in docs/reshape.md:
//!
//! ```sh
//! cargo run --release -p softcap_tissue --example reshape_box -- /tmp/box [--free-flying]
//! softcap tissue reshape --template /tmp/box/template.msh --target /tmp/box/target -o /tmp/box/reshaped.mcap
//! ```

use std::path::PathBuf;
use std::process::ExitCode;

use softcap_tissue::reshape::{known_truth, write_target};

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(dir) = args
        .iter()
        .find(|a| !a.starts_with("--"))
        .map(PathBuf::from)
    else {
        eprintln!("usage: reshape_box DIR [--free-flying]");
        return ExitCode::from(2);
    };
    let free_flying = args.iter().any(|a| a == "--free-flying");
    let (problem, _) = known_truth::problem(free_flying);
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
