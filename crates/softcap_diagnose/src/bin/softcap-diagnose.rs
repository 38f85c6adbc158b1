//! `softcap-diagnose capture.mcap material.mcap -o diagnosis.mcap …`: the diagnose stage's
//! binary ([`softcap_diagnose::cli`]).

fn main() -> std::process::ExitCode {
    softcap_app::main(softcap_diagnose::cli::Cli::run)
}
