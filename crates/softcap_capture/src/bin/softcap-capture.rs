//! `softcap-capture`: the capture stage's binary ([`softcap_capture::cli`]: capture, calibrate).

fn main() -> std::process::ExitCode {
    softcap_app::main(softcap_capture::cli::Cli::run)
}
