//! The integration tests of softcap_core in one test binary, `core_tests`: every file under tests/ is a
//! module of it (`autotests = false` in Cargo.toml), so the generics the files share are compiled
//! and the binary is linked once instead of once per file. One file's tests:
//! `cargo test --workspace --test core_tests -- gauss_newton_nelder_mead::` (a module path prefix filters).
//! A new file under tests/ needs its two lines below (`#[path]` and `mod`):
//! `every_test_file_of_every_crate_is_compiled` (below) fails for a file that is in no binary, in this
//! crate and in every other crate with `autotests = false`.

#[path = "gauss_newton_nelder_mead.rs"]
mod gauss_newton_nelder_mead;
#[path = "kmeans_bspline.rs"]
mod kmeans_bspline;
#[path = "levenberg_marquardt.rs"]
mod levenberg_marquardt;
#[path = "properties.rs"]
mod properties;
#[path = "rbf.rs"]
mod rbf;

/// Every crate under crates/ whose Cargo.toml says `autotests = false` compiles only the test
/// binaries it names, so a file under its tests/ that is neither a `#[path = "<file>"]` module of its
/// tests/main.rs nor a `path = "tests/<file>"` `[[test]]` of its Cargo.toml would never be compiled
/// or run. One guard for the whole workspace, read from the files at run time
/// (`CARGO_MANIFEST_DIR/..`). It must see this crate (itself `autotests = false`), so a wrong
/// directory cannot make it pass on nothing. Checked to fail: with the line
/// `#[path = "refine_local.rs"]` of crates/softcap_mesh/tests/main.rs renamed to `"refine_localX.rs"`
/// it fails naming crates/softcap_mesh/tests/refine_local.rs.
#[test]
fn every_test_file_of_every_crate_is_compiled() {
    use std::fs;
    use std::path::Path;

    let crates = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let mut checked = Vec::new();
    let mut missing = Vec::new();
    let mut crate_dirs: Vec<_> = fs::read_dir(&crates)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    crate_dirs.sort();
    for dir in crate_dirs {
        let Ok(manifest) = fs::read_to_string(dir.join("Cargo.toml")) else {
            continue;
        };
        if !manifest
            .lines()
            .any(|line| line.trim() == "autotests = false")
        {
            continue;
        }
        let name = dir.file_name().unwrap().to_string_lossy().into_owned();
        let main = fs::read_to_string(dir.join("tests/main.rs")).unwrap_or_default();
        let mut files: Vec<String> = fs::read_dir(dir.join("tests"))
            .map(|entries| {
                entries
                    .map(|e| e.unwrap().file_name().into_string().unwrap())
                    .collect()
            })
            .unwrap_or_default();
        files.sort();
        for file in files {
            if file.ends_with(".rs") && file != "main.rs" {
                let module = format!("#[path = \"{file}\"]");
                let target = format!("path = \"tests/{file}\"");
                if !(main.contains(&module) || manifest.contains(&target)) {
                    missing.push(format!("crates/{name}/tests/{file}"));
                }
            }
        }
        checked.push(name);
    }
    assert!(
        checked.iter().any(|name| name == "softcap_core"),
        "no crate with `autotests = false` found under {}: {checked:?}",
        crates.display()
    );
    assert!(
        missing.is_empty(),
        "neither a module of the crate's tests/main.rs nor a [[test]] of its Cargo.toml: {missing:?}"
    );
}
