//! Experiment helper: simulates one scenario's truth and prints per-frame figures.
//! `cargo run -p softcap_synth --example effect_probe -- fixtures/scenarios/suite/probe-friction.toml`
use softcap_synth::{Scenario, simulate, truth::stream};
fn main() {
    let path = std::env::args().nth(1).expect("scenario path");
    let s = Scenario::load(std::path::Path::new(&path)).expect("scenario");
    let t0 = std::time::Instant::now();
    match simulate(&s, &mut stream(s.seed, 1)) {
        Ok(t) => {
            for f in &t.frames {
                let disp = f
                    .markers_m
                    .iter()
                    .zip(&t.template_markers_m)
                    .map(|(a, b)| (a - b).xy().norm())
                    .fold(0.0, f64::max);
                println!(
                    "frame {:3} loc {} {:9} depth {:6.3} mm F {:7.3} {:7.3} {:7.3} N axial {:6.3} friction {:6.3} N  max tangential marker disp {:6.3} mm it {}",
                    f.spec.frame,
                    f.spec.location,
                    f.spec.phase.name(),
                    f.spec.depth_m * 1e3,
                    f.force_n.x,
                    f.force_n.y,
                    f.force_n.z,
                    f.axial_force_n,
                    f.friction_force_n.norm(),
                    disp * 1e3,
                    f.iterations
                );
            }
            println!(
                "simulated in {:.1} s; friction lag mismatch {:.3e}",
                t0.elapsed().as_secs_f64(),
                t.friction_lag_mismatch
            );
        }
        Err(e) => println!("error after {:.1} s: {e}", t0.elapsed().as_secs_f64()),
    }
}
