//! `softcap-synth --scenario FILE --out DIR`: writes one synthetic session ([`softcap_synth::cli`]).

fn main() -> std::process::ExitCode {
    softcap_app::main(softcap_synth::cli::Cli::run)
}
