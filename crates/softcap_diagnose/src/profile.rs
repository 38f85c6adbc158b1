//! Where the diagnosis's time goes (a measuring aid, off unless asked for): with the environment
//! variable `SOFTCAP_DIAGNOSE_PROFILE` set, every phase of [`crate::diagnose()`] and every
//! confirmation prints one `PROFILE` line to stderr — its CPU seconds (user + system of the
//! process, every thread: the re-simulations run in parallel), wall seconds, and what the
//! simulator did meanwhile: sequences re-simulated, frames solved, equilibrium iterations (an
//! assembly and factorization each under `Refactorization::EveryIteration`, the baseline's; a
//! force pass and a back-substitution each, with a factorization only when the factor went
//! stale, under `WhenStale`, the re-simulated sequences') and iterations × tets; and one
//! `PROFILE-SEQ` line per re-simulated sequence with the CPU seconds of the thread that ran it;
//! for a verdict named on the force channel, one `LOOKALIKE` line per other force-qualifying
//! hypothesis: the mean and spread of the paired fold-gain differences (verdict − it) on every
//! contact frame and after the ramp corners, the margins `separable` and `outexplains` decide on.
//!
//! ```sh
//! SOFTCAP_DIAGNOSE_PROFILE=1 softcap diagnose capture.mcap material.mcap -o /tmp/d.mcap
//! ```
//!
//! Unset, a span costs one relaxed atomic load and the counters are not touched.

use std::sync::OnceLock;
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::time::Instant;

/// Sequences re-simulated (force-driven or rigid-tip replays).
static SEQUENCES: AtomicU64 = AtomicU64::new(0);
/// Frames solved to equilibrium.
static SOLVES: AtomicU64 = AtomicU64::new(0);
/// Equilibrium iterations.
static ITERATIONS: AtomicU64 = AtomicU64::new(0);
/// Equilibrium iterations × tets of the mesh they ran on.
static TET_ITERATIONS: AtomicU64 = AtomicU64::new(0);

/// True when `SOFTCAP_DIAGNOSE_PROFILE` is set (read once).
pub fn enabled() -> bool {
    static ON: OnceLock<bool> = OnceLock::new();
    *ON.get_or_init(|| std::env::var_os("SOFTCAP_DIAGNOSE_PROFILE").is_some())
}

thread_local! {
    /// (solves, iterations) on this thread so far.
    static THREAD: std::cell::Cell<(u64, u64)> = const { std::cell::Cell::new((0, 0)) };
}

/// One re-simulated sequence (run on one thread); prints its `PROFILE-SEQ` line when dropped.
pub(crate) struct Sequence {
    kind: &'static str,
    tets: usize,
    frames: usize,
    cpu_s: f64,
    thread: (u64, u64),
}

/// Counts one re-simulated sequence of `frames` frames, `kind` (force-driven, rigid-tip replay)
/// on a mesh of `tets` tets; its line reports the solves and iterations of this thread until it
/// is dropped.
pub(crate) fn sequence(kind: &'static str, tets: usize, frames: usize) -> Option<Sequence> {
    enabled().then(|| {
        SEQUENCES.fetch_add(1, Relaxed);
        Sequence {
            kind,
            tets,
            frames,
            cpu_s: softcap_app::process::thread_cpu_seconds().unwrap_or(f64::NAN),
            thread: THREAD.with(|t| t.get()),
        }
    })
}

impl Drop for Sequence {
    fn drop(&mut self) {
        let cpu = softcap_app::process::thread_cpu_seconds().unwrap_or(f64::NAN) - self.cpu_s;
        let (s, i) = THREAD.with(|t| t.get());
        eprintln!(
            "PROFILE-SEQ | {} | {} tets | {} frames | solves {} | iterations {} | {cpu:.2} thread CPU-s",
            self.kind,
            self.tets,
            self.frames,
            s - self.thread.0,
            i - self.thread.1
        );
    }
}

/// This thread's CPU seconds when profiling (0 otherwise).
pub(crate) fn thread_cpu() -> f64 {
    if enabled() {
        softcap_app::process::thread_cpu_seconds().unwrap_or(f64::NAN)
    } else {
        0.0
    }
}

/// One `PROFILE-FRAMES` line for a rigid-tip replay: frames stepped of `frames`, their thread
/// CPU-s, the 5 costliest (frame: CPU-s) and the failure (`failed`: the last frame's status).
pub(crate) fn replay_frames(
    mu: Option<f64>,
    tets: usize,
    cpu: &[(usize, f64)],
    frames: usize,
    failed: Option<&str>,
) {
    if !enabled() {
        return;
    }
    let total: f64 = cpu.iter().map(|c| c.1).sum();
    let mut top = cpu.to_vec();
    top.sort_by(|a, b| b.1.total_cmp(&a.1));
    top.truncate(5);
    let top: Vec<String> = top.iter().map(|(k, c)| format!("{k}: {c:.1}")).collect();
    eprintln!(
        "PROFILE-FRAMES | mu {mu:?} | {tets} tets | stepped {} of {frames} | {total:.1} thread CPU-s | costliest {} | {}",
        cpu.len(),
        top.join(", "),
        failed.map_or("converged".to_string(), |s| format!(
            "FAILED at frame {}: {s}",
            cpu.last().map_or(0, |c| c.0)
        ))
    );
}

/// One `PROFILE-RANK` line for a coarse-first ranking (`Replays::run_coarse_first`): the ranking
/// mesh's tets as a multiple of the fit mesh's, the candidates (index: parameters) and what each fold (then the full data) kept,
/// and the points chosen for the refined replays.
pub(crate) fn ranking(
    tet_factor: usize,
    params: &[&[(String, f64)]],
    kept: &[Vec<usize>],
    chosen: &[usize],
) {
    if !enabled() {
        return;
    }
    let points: Vec<String> = params
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let p: Vec<String> = p.iter().map(|(k, v)| format!("{k} {v:.6e}")).collect();
            format!("{i}: {}", p.join(" "))
        })
        .collect();
    eprintln!(
        "PROFILE-RANK | {tet_factor} x the fit mesh's tets | kept per fold {kept:?} | chosen {chosen:?} | {}",
        points.join("; ")
    );
}

/// One `PROFILE-ATTEMPT` line for a rigid-tip replay's solve that did not converge (`status`)
/// and its thread CPU-s.
pub(crate) fn failed_attempt(status: &str, cpu_s: f64) {
    if enabled() {
        eprintln!("PROFILE-ATTEMPT | {cpu_s:.1} thread CPU-s | {status}");
    }
}

/// Counts one equilibrium solve of `iterations` iterations on a mesh of `tets` tets.
pub(crate) fn solve(iterations: usize, tets: usize) {
    if enabled() {
        SOLVES.fetch_add(1, Relaxed);
        ITERATIONS.fetch_add(iterations as u64, Relaxed);
        TET_ITERATIONS.fetch_add((iterations * tets) as u64, Relaxed);
        THREAD.with(|t| {
            let (s, i) = t.get();
            t.set((s + 1, i + iterations as u64));
        });
    }
}

fn counters() -> [u64; 4] {
    [&SEQUENCES, &SOLVES, &ITERATIONS, &TET_ITERATIONS].map(|c| c.load(Relaxed))
}

/// A timed stretch of the diagnosis; prints its `PROFILE` line when dropped.
pub struct Span {
    name: String,
    cpu_s: f64,
    wall: Instant,
    counters: [u64; 4],
}

/// Starts a span named `name()` (evaluated only when profiling is on).
pub fn span(name: impl FnOnce() -> String) -> Option<Span> {
    enabled().then(|| Span {
        name: name(),
        cpu_s: softcap_app::process::cpu_seconds().unwrap_or(f64::NAN),
        wall: Instant::now(),
        counters: counters(),
    })
}

impl Drop for Span {
    fn drop(&mut self) {
        let cpu = softcap_app::process::cpu_seconds().unwrap_or(f64::NAN) - self.cpu_s;
        let now = counters();
        let [seq, solves, it, tet_it] = [0, 1, 2, 3].map(|i| now[i] - self.counters[i]);
        eprintln!(
            "PROFILE | {} | {cpu:.2} CPU-s | {:.2} s wall | sequences {seq} | solves {solves} | iterations {it} | iterations x tets {tet_it}",
            self.name,
            self.wall.elapsed().as_secs_f64()
        );
    }
}
