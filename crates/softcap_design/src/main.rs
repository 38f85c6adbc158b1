//! `softcap-design library|fit-rubber|fit-base|target|search …`: the design stage's binary
//! ([`softcap_design::cli`]).

fn main() -> std::process::ExitCode {
    softcap_app::main(softcap_design::cli::Cli::run)
}
