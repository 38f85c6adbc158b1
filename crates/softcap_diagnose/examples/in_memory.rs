//! Harnesses over the in-memory recordings of `tests/in_memory.rs` (its helpers are shared):
//!
//! - `timing`: ten simulations and one diagnosis of a sensor-lag session;
//! - `ten-locations`: the full catalog on a 10-location sensor-lag session;
//! - `docs-report`: regenerates the example report in `docs/diagnose/` (report.md, figures,
//!   diagnosis.json) from a creep session.
//!
//! `cargo run --release -p softcap_diagnose --example in_memory -- timing|ten-locations|docs-report`

#[path = "../tests/in_memory.rs"]
#[allow(dead_code, unused_imports)]
mod cases;

fn main() -> std::process::ExitCode {
    match cases::harness(std::env::args().nth(1).as_deref()) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("in_memory: {e}");
            std::process::ExitCode::from(2)
        }
    }
}
