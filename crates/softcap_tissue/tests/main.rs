//! The integration tests of softcap_tissue in one test binary, `tissue_tests`: every file under tests/ is a
//! module of it (`autotests = false` in Cargo.toml), so the generics the files share are compiled
//! and the binary is linked once instead of once per file. One file's tests:
//! `cargo test --workspace --test tissue_tests -- fit_dynamic::` (a module path prefix filters).
//! A new file under tests/ needs its two lines below (`#[path]` and `mod`): `core_tests`'
//! `every_test_file_of_every_crate_is_compiled` fails for a file that is in no binary.

/// The helpers several files share (tests/common/): one module, which the files `use crate::common`.
mod common;
#[path = "fit.rs"]
mod fit;
#[path = "fit_convergence.rs"]
mod fit_convergence;
#[path = "fit_dynamic.rs"]
mod fit_dynamic;
#[path = "heldout.rs"]
mod heldout;
#[path = "jacobian.rs"]
mod jacobian;
#[path = "kill.rs"]
mod kill;
#[path = "noise.rs"]
mod noise;
#[path = "properties.rs"]
mod properties;
#[path = "reshape.rs"]
mod reshape;
#[path = "session_min.rs"]
mod session_min;
#[path = "simulate.rs"]
mod simulate;
#[path = "track.rs"]
mod track;
