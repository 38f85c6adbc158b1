//! The one way a softcap binary turns its result into an exit code.
//!
//! | outcome | printed | exit code |
//! |---|---|---|
//! | success, `--help`, `--version` | the command's own output, help or version on stdout | 0 |
//! | a failure while running ([`ErrorClass::Failure`](crate::ErrorClass::Failure)) | `PROGRAM: error: MESSAGE` on stderr | 1 |
//! | bad usage (clap) | clap's usage message on stderr | 2 |
//! | bad input ([`ErrorClass::BadInput`](crate::ErrorClass::BadInput)) | `PROGRAM: error: MESSAGE` on stderr | 2 |
//!
//! `MESSAGE` is [`Error::message`]: every cause once, outermost first.

use std::ffi::OsString;
use std::process::ExitCode;

use clap::Parser;

use crate::error::Error;

/// The degree of faer's parallel kernels (dense products and solves, sparse Cholesky) in every
/// softcap binary. faer's default, `Par::rayon(0)`, takes the rayon pool's thread count and cuts
/// a product into that many parts summed in order, so the last bits of a result depended on
/// `RAYON_NUM_THREADS` (the least-squares normal equations of softcap_core, the face shell).
/// With a fixed degree the cut is the same for every thread count and the work still runs on
/// whatever threads the pool has: outputs are identical with 1 and 2 threads
/// (docs/reliability.md, `make verify-threads`). 2 is faer's own choice on a 2-core machine.
pub const FAER_PARALLEL_DEGREE: usize = 2;

/// Exit code of a failure while running.
pub const EXIT_FAILURE: u8 = 1;
/// Exit code of bad usage or bad input.
pub const EXIT_BAD_INPUT: u8 = 2;

/// The whole `main` of a softcap binary: parses the process arguments into `C`, runs `run` and
/// maps the outcome to the exit code (see the module table).
pub fn main<C: Parser, T: Outcome>(run: impl FnOnce(C) -> Result<T, Error>) -> ExitCode {
    main_from(std::env::args_os(), run)
}

/// What a successful run exits with: `()` is 0; an [`ExitCode`] as it is (the umbrella `softcap`
/// passing on the exit code of the stage binary it ran).
pub trait Outcome {
    /// The exit code of this outcome.
    fn exit_code(self) -> ExitCode;
}

impl Outcome for () {
    fn exit_code(self) -> ExitCode {
        ExitCode::SUCCESS
    }
}

impl Outcome for ExitCode {
    fn exit_code(self) -> ExitCode {
        self
    }
}

/// [`main`] over explicit arguments (the first is the program name).
pub fn main_from<C, O, I, T>(args: I, run: impl FnOnce(C) -> Result<O, Error>) -> ExitCode
where
    C: Parser,
    O: Outcome,
    I: IntoIterator<Item = T>,
    T: Into<OsString> + Clone,
{
    faer::set_global_parallelism(faer::Par::rayon(FAER_PARALLEL_DEGREE));
    let cli = match C::try_parse_from(args) {
        Ok(cli) => cli,
        Err(e) => {
            // --help / --version print to stdout and are not errors; usage errors go to stderr.
            let _ = e.print();
            return ExitCode::from(if e.use_stderr() { EXIT_BAD_INPUT } else { 0 });
        }
    };
    match run(cli) {
        Ok(outcome) => outcome.exit_code(),
        Err(e) => {
            report(C::command().get_name(), &e);
            ExitCode::from(e.exit_code())
        }
    }
}

/// Prints `PROGRAM: error: MESSAGE` on stderr, each cause once.
pub fn report(program: &str, error: &Error) {
    eprintln!("{program}: error: {}", error.message());
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, Parser)]
    #[command(name = "softcap-test", version)]
    struct Cli {
        input: String,
    }

    fn run(cli: Cli) -> Result<(), Error> {
        match cli.input.as_str() {
            "ok" => Ok(()),
            "bad" => Err(Error::bad_input("bad: line 1: not a number")),
            _ => Err(Error::failure("solver broke")),
        }
    }

    #[test]
    fn exit_codes_of_help_version_usage_bad_input_and_failure() {
        let code = |args: &[&str]| main_from(args.iter().copied(), run);
        let ok = ExitCode::SUCCESS;
        assert_eq!(code(&["softcap-test", "--help"]), ok);
        assert_eq!(code(&["softcap-test", "--version"]), ok);
        assert_eq!(code(&["softcap-test", "ok"]), ok);
        assert_eq!(code(&["softcap-test"]), ExitCode::from(EXIT_BAD_INPUT));
        assert_eq!(
            code(&["softcap-test", "a", "b"]),
            ExitCode::from(EXIT_BAD_INPUT)
        );
        assert_eq!(
            code(&["softcap-test", "bad"]),
            ExitCode::from(EXIT_BAD_INPUT)
        );
        assert_eq!(code(&["softcap-test", "x"]), ExitCode::from(EXIT_FAILURE));
    }
}
