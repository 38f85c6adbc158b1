//! The integration tests of softcap_diagnose in one test binary, `diagnose_tests`: every file under tests/ is a
//! module of it (`autotests = false` in Cargo.toml), so the generics the files share are compiled
//! and the binary is linked once instead of once per file. One file's tests:
//! `cargo test --workspace --test diagnose_tests -- in_memory::` (a module path prefix filters).
//! A new file under tests/ needs its two lines below (`#[path]` and `mod`): `core_tests`'
//! `every_test_file_of_every_crate_is_compiled` fails for a file that is in no binary.

#[path = "cli.rs"]
mod cli;
#[path = "dynamic_replay.rs"]
mod dynamic_replay;
#[path = "in_memory.rs"]
mod in_memory;
#[path = "persistence.rs"]
mod persistence;
#[path = "rigid_tip.rs"]
mod rigid_tip;
