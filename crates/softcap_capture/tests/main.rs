//! The integration tests of softcap_capture in one test binary, `capture_tests`: every file under tests/ is a
//! module of it (`autotests = false` in Cargo.toml), so the generics the files share are compiled
//! and the binary is linked once instead of once per file. One file's tests:
//! `cargo test --workspace --test capture_tests -- aniposelib::` (a module path prefix filters).
//! A new file under tests/ needs its two lines below (`#[path]` and `mod`): `core_tests`'
//! `every_test_file_of_every_crate_is_compiled` fails for a file that is in no binary.

#[path = "aniposelib.rs"]
mod aniposelib;
#[path = "bounds.rs"]
mod bounds;
#[path = "c3d.rs"]
mod c3d;
#[path = "calibrate.rs"]
mod calibrate;
#[path = "cli.rs"]
mod cli;
/// The helpers several files share (tests/common/): one module, which the files `use crate::common`.
mod common;
#[path = "dynamic.rs"]
mod dynamic;
#[path = "robot.rs"]
mod robot;
#[path = "session_min.rs"]
mod session_min;
#[path = "thirdparty.rs"]
mod thirdparty;
