//! The integration tests of softcap_fem in one test binary, `fem_tests`: every file under tests/ is a
//! module of it (`autotests = false` in Cargo.toml), so the generics the files share are compiled
//! and the binary is linked once instead of once per file. One file's tests:
//! `cargo test --workspace --test fem_tests -- anisotropy::` (a module path prefix filters).
//! A new file under tests/ needs its two lines below (`#[path]` and `mod`): `core_tests`'
//! `every_test_file_of_every_crate_is_compiled` fails for a file that is in no binary.

#[path = "anisotropy.rs"]
mod anisotropy;
#[path = "cantilever.rs"]
mod cantilever;
/// The helpers several files share (tests/common/): one module, which the files `use crate::common`.
mod common;
#[path = "contact.rs"]
mod contact;
#[path = "contact_quadrature.rs"]
mod contact_quadrature;
#[path = "cook.rs"]
mod cook;
#[path = "derivatives.rs"]
mod derivatives;
#[path = "dynamics.rs"]
mod dynamics;
#[path = "friction.rs"]
mod friction;
#[path = "gradients.rs"]
mod gradients;
#[path = "gravity.rs"]
mod gravity;
#[path = "hertz.rs"]
mod hertz;
#[path = "modal.rs"]
mod modal;
#[path = "patch.rs"]
mod patch;
#[path = "path_independence.rs"]
mod path_independence;
#[path = "plasticity.rs"]
mod plasticity;
#[path = "properties.rs"]
mod properties;
#[path = "quadratic.rs"]
mod quadratic;
#[path = "refactorization.rs"]
mod refactorization;
#[path = "support.rs"]
mod support;
#[path = "viscoelastic.rs"]
mod viscoelastic;
