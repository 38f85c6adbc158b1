//! Helpers for the exit-code tests every binary has (`tests/exit_codes.rs` of each stage):
//! run the binary, and check that an error message names a file exactly once.

use std::path::Path;
use std::process::Command;

/// What a run of a binary printed and returned.
#[derive(Debug)]
pub struct Run {
    /// The exit code (-1 when killed by a signal).
    pub code: i32,
    /// Standard output.
    pub stdout: String,
    /// Standard error.
    pub stderr: String,
}

/// Runs `bin` with `args` (stdin closed, stderr not a terminal).
pub fn run(bin: impl AsRef<Path>, args: &[&str]) -> Run {
    let out = Command::new(bin.as_ref())
        .args(args)
        .stdin(std::process::Stdio::null())
        .output()
        .unwrap_or_else(|e| panic!("running {}: {e}", bin.as_ref().display()));
    Run {
        code: out.status.code().unwrap_or(-1),
        stdout: String::from_utf8_lossy(&out.stdout).into(),
        stderr: String::from_utf8_lossy(&out.stderr).into(),
    }
}

/// `--help` and `--version` exit 0 and print to stdout; no arguments is a usage error (2).
pub fn assert_help_version_usage(bin: impl AsRef<Path>) {
    let bin = bin.as_ref();
    for flag in ["--help", "--version"] {
        let r = run(bin, &[flag]);
        assert_eq!(r.code, 0, "{} {flag}: {r:?}", bin.display());
        assert!(!r.stdout.is_empty() && r.stderr.is_empty(), "{flag}: {r:?}");
    }
    let r = run(bin, &[]);
    assert_eq!(r.code, 2, "{} without arguments: {r:?}", bin.display());
}

/// The run failed with exit code `code` and one `PROGRAM: error: …` line on stderr that names
/// `file` exactly once (the path or, if it is long, its file name).
pub fn assert_error_names_once(r: &Run, code: i32, file: &Path) {
    assert_eq!(r.code, code, "{r:?}");
    let lines: Vec<&str> = r
        .stderr
        .lines()
        .filter(|l| l.contains(": error: "))
        .collect();
    assert_eq!(lines.len(), 1, "one error line: {r:?}");
    let name = file.file_name().map_or_else(
        || file.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    );
    assert_eq!(
        lines[0].matches(name.as_str()).count(),
        1,
        "`{name}` named once: {}",
        lines[0]
    );
}
