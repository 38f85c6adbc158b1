//! `softcap-psd evaluate|markers|animate …`: pose-space details ([`softcap_psd::cli`]).

fn main() -> std::process::ExitCode {
    softcap_app::main(softcap_psd::cli::Cli::run)
}
