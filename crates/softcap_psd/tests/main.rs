//! The integration tests of softcap_psd in one test binary, `psd_tests`: every file under tests/ is a
//! module of it (`autotests = false` in Cargo.toml), so the generics the files share are compiled
//! and the binary is linked once instead of once per file. One file's tests:
//! `cargo test --workspace --test psd_tests -- animate::` (a module path prefix filters).
//! A new file under tests/ needs its two lines below (`#[path]` and `mod`): `core_tests`'
//! `every_test_file_of_every_crate_is_compiled` fails for a file that is in no binary.

#[path = "animate.rs"]
mod animate;
#[path = "ict.rs"]
mod ict;
#[path = "runtime.rs"]
mod runtime;
