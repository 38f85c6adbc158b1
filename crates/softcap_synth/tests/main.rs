//! The integration tests of softcap_synth in one test binary, `synth_tests`: every file under tests/ is a
//! module of it (`autotests = false` in Cargo.toml), so the generics the files share are compiled
//! and the binary is linked once instead of once per file. One file's tests:
//! `cargo test --workspace --test synth_tests -- cli::` (a module path prefix filters).
//! A new file under tests/ needs its two lines below (`#[path]` and `mod`): `core_tests`'
//! `every_test_file_of_every_crate_is_compiled` fails for a file that is in no binary.

#[path = "cli.rs"]
mod cli;
#[path = "dynamic.rs"]
mod dynamic;
#[path = "effects.rs"]
mod effects;
#[path = "render.rs"]
mod render;
#[path = "sensors.rs"]
mod sensors;
#[path = "session.rs"]
mod session;
#[path = "truth_refine.rs"]
mod truth_refine;
