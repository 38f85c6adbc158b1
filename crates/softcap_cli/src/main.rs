//! `softcap`: the umbrella binary. Thin: parse, run, map errors to exit codes.

use std::process::ExitCode;

use clap::Parser;
use softcap_cli::{Cli, run};

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => {
            let code = if e.use_stderr() { 2 } else { 0 };
            let _ = e.print();
            return ExitCode::from(code);
        }
    };
    match run(&cli) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("softcap: error: {e:#}");
            ExitCode::from(softcap_cli::exit_code(&e))
        }
    }
}
