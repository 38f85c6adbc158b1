//! `softcap`: the umbrella binary.

fn main() -> std::process::ExitCode {
    softcap_app::main(softcap_cli::run)
}
