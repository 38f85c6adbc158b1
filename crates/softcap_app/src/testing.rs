//! Helpers for the exit-code tests every binary has (`tests/exit_codes.rs` of each stage):
//! run the binary, and check that an error message names a file exactly once; and the
//! crash-safety trials of every stage binary ([`kill_trials`], [`race_trials`]: SIGKILL at a
//! random moment, two writers of one output at once).

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

/// What [`kill_trials`] saw.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct KillTally {
    /// Trials run.
    pub trials: usize,
    /// Killed with no file under the output name.
    pub absent: usize,
    /// Killed, and the output name held a complete file (an earlier run's or this run's).
    pub complete: usize,
    /// The process exited by itself before its kill time.
    pub finished: usize,
}

/// The number of crash-safety trials: `SOFTCAP_KILL_TRIALS` if set (scripts/kill-test sets 50),
/// else `default` (a few, to keep `make test` cheap).
pub fn kill_trial_count(default: usize) -> usize {
    std::env::var("SOFTCAP_KILL_TRIALS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// Crash safety of one command writing `output` (docs/reliability.md): runs `command` once to
/// completion (its wall time `T` sets the kill window), then `trials` times SIGKILLs it after a
/// random delay in `[0, 1.2 T)` — even trials start with no output, odd trials with whatever the
/// trial before left (nothing or a complete file) — and checks that `output` then holds nothing or a file `complete` accepts, never a truncated
/// one. Temporary files a killed writer leaves (`*.tmp`) are removed between trials. Panics
/// with the trial and the problem on the first failure.
pub fn kill_trials(
    command: &dyn Fn() -> Command,
    output: &Path,
    trials: usize,
    seed: u64,
    complete: &dyn Fn(&Path) -> Result<(), String>,
) -> KillTally {
    let start = std::time::Instant::now();
    let status = command().status().expect("starting the command");
    let window = start.elapsed().mul_f64(1.2);
    assert!(status.success(), "the clean run failed: {status}");
    complete(output).unwrap_or_else(|e| panic!("the clean run's output: {e}"));
    let mut rng = seed | 1;
    let mut tally = KillTally {
        trials,
        ..KillTally::default()
    };
    for trial in 0..trials {
        if trial % 2 == 0 {
            let _ = std::fs::remove_file(output);
        }
        // xorshift64: a seeded uniform delay.
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        let delay = window.mul_f64((rng >> 11) as f64 / (1u64 << 53) as f64);
        let mut child = command()
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .expect("starting the command");
        std::thread::sleep(delay);
        if child.try_wait().expect("polling the command").is_some() {
            tally.finished += 1;
        } else {
            child.kill().expect("SIGKILL");
        }
        child.wait().expect("reaping the command");
        if output.exists() {
            complete(output).unwrap_or_else(|e| {
                panic!("trial {trial}: killed after {delay:?}, the output is not complete: {e}")
            });
            tally.complete += 1;
        } else {
            tally.absent += 1;
        }
        remove_tmp_files(output);
    }
    tally
}

/// Two processes writing `output` at once, `trials` times: both must succeed and leave one
/// complete file (the last rename wins whole). Returns the trials run.
pub fn race_trials(
    command: &dyn Fn() -> Command,
    output: &Path,
    trials: usize,
    complete: &dyn Fn(&Path) -> Result<(), String>,
) -> usize {
    for trial in 0..trials {
        let _ = std::fs::remove_file(output);
        let quiet = || {
            let mut c = command();
            c.stdout(std::process::Stdio::null());
            c
        };
        let (mut a, mut b) = (
            quiet().spawn().expect("starting the first writer"),
            quiet().spawn().expect("starting the second writer"),
        );
        let (sa, sb) = (
            a.wait().expect("reaping the first writer"),
            b.wait().expect("reaping the second writer"),
        );
        assert!(sa.success() && sb.success(), "trial {trial}: {sa}, {sb}");
        complete(output).unwrap_or_else(|e| panic!("trial {trial}: racing writers: {e}"));
        let left = std::fs::read_dir(output.parent().unwrap_or(Path::new(".")))
            .expect("listing the output folder")
            .flatten()
            .filter(|e| crate::fs::is_tmp_of(output, &e.path()))
            .count();
        assert_eq!(left, 0, "trial {trial}: temporary files left behind");
    }
    trials
}

/// Removes the temporary files of atomic writes of `output` (see [`crate::fs::tmp_path`]).
fn remove_tmp_files(output: &Path) {
    let dir = output.parent().unwrap_or(Path::new("."));
    if let Ok(entries) = std::fs::read_dir(dir) {
        for e in entries.flatten() {
            if crate::fs::is_tmp_of(output, &e.path()) {
                let _ = std::fs::remove_file(e.path());
            }
        }
    }
}
