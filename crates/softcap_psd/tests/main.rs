//! The integration tests of softcap_psd in one test binary, `psd_tests`: every file under tests/ is a
//! module of it (`autotests = false` in Cargo.toml), so the generics the files share are compiled
//! and the binary is linked once instead of once per file. One file's tests:
//! `cargo test --workspace --test psd_tests -- animate::` (a module path prefix filters).

#[path = "animate.rs"]
mod animate;
#[path = "ict.rs"]
mod ict;
#[path = "runtime.rs"]
mod runtime;

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
