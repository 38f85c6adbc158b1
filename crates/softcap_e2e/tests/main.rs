//! The integration tests of softcap_e2e in one test binary, `e2e_tests`: every file under tests/ is a
//! module of it (`autotests = false` in Cargo.toml), so the generics the files share are compiled
//! and the binary is linked once instead of once per file — except the two suites `diagnose_suite`
//! and `thirdparty_diagnose`, each its own [[test]] (run case by case from the built binaries:
//! `target/debug/deps/diagnose_suite-<hash> <case> --exact`). One file's tests:
//! `cargo test --workspace --test e2e_tests -- track_accuracy::` (a module path prefix filters).
//! A new file under tests/ needs its two lines below (`#[path]` and `mod`): `core_tests`'
//! `every_test_file_of_every_crate_is_compiled` fails for a file that is in no binary.

#[path = "capture_reads_synth.rs"]
mod capture_reads_synth;
/// The helpers several files share (tests/common/): one module, which the files `use crate::common`.
mod common;
#[path = "export_markers.rs"]
mod export_markers;
#[path = "fit_dynamic_depth.rs"]
mod fit_dynamic_depth;
#[path = "fuzz_regressions.rs"]
mod fuzz_regressions;
#[path = "track_accuracy.rs"]
mod track_accuracy;
