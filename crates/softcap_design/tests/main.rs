//! The integration tests of softcap_design in one test binary, `design_tests`: every file under tests/ is a
//! module of it (`autotests = false` in Cargo.toml), so the generics the files share are compiled
//! and the binary is linked once instead of once per file. One file's tests:
//! `cargo test --workspace --test design_tests -- capture::` (a module path prefix filters).
//! A new file under tests/ needs its two lines below (`#[path]` and `mod`): `core_tests`'
//! `every_test_file_of_every_crate_is_compiled` fails for a file that is in no binary.

#[path = "capture.rs"]
mod capture;
#[path = "cli.rs"]
mod cli;
#[path = "experiment.rs"]
mod experiment;
#[path = "fit.rs"]
mod fit;
#[path = "fit_transverse.rs"]
mod fit_transverse;
#[path = "newton.rs"]
mod newton;
#[path = "print.rs"]
mod print;
#[path = "quarter.rs"]
mod quarter;
#[path = "rubber.rs"]
mod rubber;
