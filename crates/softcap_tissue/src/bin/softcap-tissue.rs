//! `softcap-tissue fit|simulate …`: the tissue stage's binary ([`softcap_tissue::cli`]).

fn main() -> std::process::ExitCode {
    softcap_app::main(softcap_tissue::cli::Cli::run)
}
