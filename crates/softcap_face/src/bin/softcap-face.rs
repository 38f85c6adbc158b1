//! `softcap-face landmarks|run|animate …`: the face stage's binary ([`softcap_face::cli`]).

fn main() -> std::process::ExitCode {
    softcap_app::main(softcap_face::cli::Cli::run)
}
