//! The integration tests of softcap_fem in one test binary, `fem_tests`: every file under tests/ is a
//! module of it (`autotests = false` in Cargo.toml), so the generics the files share are compiled
//! and the binary is linked once instead of once per file. One file's tests:
//! `cargo test --workspace --test fem_tests -- anisotropy::` (a module path prefix filters).

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

/// A file under tests/ that is neither a module above nor its own `[[test]]` in Cargo.toml would
/// never be compiled or run (`autotests = false`).
#[test]
fn every_test_file_is_compiled() {
    let main = include_str!("main.rs");
    let manifest = include_str!("../Cargo.toml");
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests");
    for entry in std::fs::read_dir(&dir).unwrap() {
        let file = entry.unwrap().file_name().into_string().unwrap();
        if file.ends_with(".rs") && file != "main.rs" {
            let module = format!("#[path = \"{file}\"]");
            let target = format!("path = \"tests/{file}\"");
            assert!(
                main.contains(&module) || manifest.contains(&target),
                "tests/{file} is neither a module of tests/main.rs nor a [[test]] of Cargo.toml"
            );
        }
    }
}
