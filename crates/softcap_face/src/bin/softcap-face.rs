//! `softcap-face`: thin binary over the softcap_face library.
use std::process::ExitCode;

fn main() -> ExitCode {
    ExitCode::SUCCESS
}
