//! The integration tests of softcap_mesh in one test binary, `mesh_tests`: every file under tests/ is a
//! module of it (`autotests = false` in Cargo.toml), so the generics the files share are compiled
//! and the binary is linked once instead of once per file. One file's tests:
//! `cargo test --workspace --test mesh_tests -- bounds::` (a module path prefix filters).
//! A new file under tests/ needs its two lines below (`#[path]` and `mod`): `core_tests`'
//! `every_test_file_of_every_crate_is_compiled` fails for a file that is in no binary.

#[path = "bounds.rs"]
mod bounds;
#[path = "embed.rs"]
mod embed;
#[path = "io.rs"]
mod io;
#[path = "laplacian.rs"]
mod laplacian;
#[path = "refine_local.rs"]
mod refine_local;
