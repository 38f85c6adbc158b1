//! The integration tests of softcap_mcap in one test binary, `mcap_tests`: every file under tests/ is a
//! module of it (`autotests = false` in Cargo.toml), so the generics the files share are compiled
//! and the binary is linked once instead of once per file. One file's tests:
//! `cargo test --workspace --test mcap_tests -- capture_data::` (a module path prefix filters).
//! A new file under tests/ needs its two lines below (`#[path]` and `mod`): `core_tests`'
//! `every_test_file_of_every_crate_is_compiled` fails for a file that is in no binary.

#[path = "capture_data.rs"]
mod capture_data;
#[path = "catalog.rs"]
mod catalog;
#[path = "material_data.rs"]
mod material_data;
#[path = "round_trip.rs"]
mod round_trip;
#[path = "track_data.rs"]
mod track_data;
