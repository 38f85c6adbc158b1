//! The integration tests of softcap_face in one test binary, `face_tests`: every file under tests/ is a
//! module of it (`autotests = false` in Cargo.toml), so the generics the files share are compiled
//! and the binary is linked once instead of once per file. One file's tests:
//! `cargo test --workspace --test face_tests -- correspondence::` (a module path prefix filters).
//! A new file under tests/ needs its two lines below (`#[path]` and `mod`): `core_tests`'
//! `every_test_file_of_every_crate_is_compiled` fails for a file that is in no binary.

#[path = "correspondence.rs"]
mod correspondence;
#[path = "ict_face.rs"]
mod ict_face;
#[path = "output.rs"]
mod output;
#[path = "pooled.rs"]
mod pooled;
#[path = "removal.rs"]
mod removal;
#[path = "render_vs_model.rs"]
mod render_vs_model;
#[path = "synthesis.rs"]
mod synthesis;
#[path = "synthesis_face.rs"]
mod synthesis_face;
#[path = "take.rs"]
mod take;
#[path = "tracking.rs"]
mod tracking;
