//! The fuzz findings as regression tests: every input under `fuzz/regressions/TARGET/` (an input
//! that once crashed, hung or exhausted memory in a reader) must now be a clean bad-input error
//! (exit code 2), and every input of the committed minimized corpora `fuzz/corpus/TARGET/` must
//! read without a panic. The readers are the fuzz harness's own table (`fuzz/src/readers.rs`),
//! so the test drives exactly what the fuzzers drove. docs/reliability.md has the fuzz table.

use std::path::{Path, PathBuf};

use softcap_app::ErrorClass;

#[path = "../../../fuzz/src/readers.rs"]
#[allow(dead_code)]
mod readers;

fn fuzz_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fuzz")
}

/// `(target, input file)` for every file under `fuzz/KIND/TARGET/`.
fn inputs(kind: &str) -> Vec<(String, PathBuf)> {
    let mut out = Vec::new();
    let Ok(targets) = std::fs::read_dir(fuzz_dir().join(kind)) else {
        return out;
    };
    for target in targets.flatten() {
        let name = target.file_name().to_string_lossy().into_owned();
        let mut files: Vec<PathBuf> = std::fs::read_dir(target.path())
            .unwrap()
            .flatten()
            .map(|e| e.path())
            .filter(|p| p.is_file())
            .collect();
        files.sort();
        out.extend(files.into_iter().map(|f| (name.clone(), f)));
    }
    out.sort();
    out
}

/// Reads `file` as `target`'s input in `scratch`, the target's own folder (as under the fuzzer,
/// where one process reads every input of one target: fixed companion files are written once).
fn read(target: &str, file: &Path, scratch: &Path) -> softcap_app::Result<()> {
    let t = readers::target(target)
        .unwrap_or_else(|| panic!("{}: no fuzz target `{target}`", file.display()));
    let bytes = std::fs::read(file).unwrap();
    let dir = scratch.join(target);
    std::fs::create_dir_all(&dir).unwrap();
    (t.read)(&dir, &bytes)
}

#[test]
fn every_fuzz_crash_input_is_a_clean_bad_input_error() {
    let scratch = tempfile::tempdir().unwrap();
    for (target, file) in inputs("regressions") {
        match read(&target, &file, scratch.path()) {
            Ok(()) => {}
            Err(e) => assert_eq!(
                e.class(),
                ErrorClass::BadInput,
                "{target} {}: {:#}",
                file.display(),
                e
            ),
        }
    }
}

#[test]
fn the_minimized_fuzz_corpora_read_without_a_panic() {
    let inputs = inputs("corpus");
    let scratch = tempfile::tempdir().unwrap();
    for (target, file) in &inputs {
        let _ = read(target, file, scratch.path());
    }
    for t in readers::TARGETS {
        assert!(
            inputs.iter().any(|(name, _)| name == t.name),
            "fuzz/corpus/{} is empty: seed it with scripts/fuzz",
            t.name
        );
    }
}
