//! # softcap_app — what every softcap binary and output writer shares
//!
//! The process-level layer under the stages: it knows nothing about tissue, faces or MCAP, only
//! about files, errors and terminals, so every crate that writes a file or runs as a binary can
//! use it without a stage importing another stage.
//!
//! | module | what |
//! |---|---|
//! | [`fs`] | [`write_atomic`] and [`AtomicFile`]: write `NAME.PID-N.tmp` in the same folder, fsync it, rename it over `NAME`, fsync the folder; [`path_inside`] for file names read from input files |
//! | [`error`] | [`Error`]: an error that knows whether the user's input (exit code 2) or the run (exit code 1) is at fault; [`Classify`] for stage error enums |
//! | [`cli`] | [`main`]: parse with clap, run, print an error once with its causes, map it to the exit code |
//! | [`settings`] | [`load_toml`]: a stage's `…Settings` from a TOML file, errors naming file, line and field; [`non_finite`]: `nan` / `inf` in any TOML input |
//! | [`testing`] | running a binary in its exit-code tests; an error that names a file once |
//! | [`progress`] | [`Progress`]: indicatif bars and per-step status on stderr, drawn only on a terminal |
//! | [`process`] | [`process::cpu_seconds`]: CPU time this process has used (benches' and examples' timing lines) |
//!
//! A stage binary is three lines over its library's `run()`:
//!
//! ```no_run
//! # mod my_stage { #[derive(clap::Parser)] pub struct Cli; impl Cli { pub fn run(self) -> softcap_app::Result<()> { Ok(()) } } }
//! fn main() -> std::process::ExitCode {
//!     softcap_app::main(my_stage::Cli::run)
//! }
//! ```
//!
//! Exit codes: 0 success (also `--help` and `--version`), 1 failure while running, 2 bad usage
//! or bad input (a missing or malformed file, an out-of-range argument).

pub mod cli;
pub mod error;
pub mod fs;
pub mod process;
pub mod progress;
pub mod settings;
pub mod testing;

pub use cli::{EXIT_BAD_INPUT, EXIT_FAILURE, Outcome, main, main_from, report};
pub use error::{Classify, Context, Error, ErrorClass, IntoError, Result};
pub use fs::{AtomicFile, is_tmp_of, path_inside, tmp_path, write_atomic, write_atomic_with};
pub use progress::Progress;
pub use settings::{NonFinite, load_toml, load_toml_or_default, non_finite};

/// Re-exported so binaries and tests name one clap.
pub use clap;
pub use indicatif;
