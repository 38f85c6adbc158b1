//! Per-design cost of the composite simulator and its agreement with a stored exhaustive table:
//! simulates `COUNT` designs spread over the 5 × 9 design space (every 59,049 / COUNT-th index)
//! on one thread and compares each response with TABLE.bin (written by `--example validation`,
//! possibly by an older simulator).
//!
//! ```sh
//! /usr/bin/time cargo run --profile test -p softcap_design --example simulator_check -- COUNT [TABLE.bin]
//! ```
//! Run it under `/usr/bin/time`: user + sys / COUNT is the CPU cost per design.

use softcap_design::*;
use std::sync::Arc;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let count: usize = args.get(1).map_or(Ok(500), |a| a.parse())?;
    let table = match args.get(2) {
        Some(p) => Some(read_table(std::path::Path::new(p))?),
        None => None,
    };
    let settings = CompositeSettings::default();
    let block = Arc::new(LayeredBlock::uniform(&settings)?);
    let mut sim = CompositeSimulator::new(block, Arc::new(reference_library()), &settings)?;
    let total = 9usize.pow(5);
    let step = (total / count.max(1)).max(1);
    let (mut iterations, mut failures, mut max_diff, mut max_u) = (0usize, 0usize, 0.0f64, 0.0f64);
    let t = std::time::Instant::now();
    let mut n = 0;
    for index in (0..total).step_by(step).take(count) {
        let design = design_from_index(index, 5, 9);
        n += 1;
        match sim.simulate(&design) {
            Ok(r) => {
                iterations += r.iterations;
                max_u = r.displacements_m.iter().fold(max_u, |m, v| m.max(v.abs()));
                if let Some(Some(old)) = table.as_ref().map(|t| &t.responses[index]) {
                    for (a, b) in r.displacements_m.iter().zip(old.iter()) {
                        max_diff = max_diff.max((a - b).abs());
                    }
                }
            }
            Err(_) => failures += 1,
        }
    }
    println!(
        "{n} designs, {failures} failures, mean {:.2} Newton steps, {:.2} ms wall per design; max |u| {:.4} mm; max |x_new − x_table| {:.3e} m",
        iterations as f64 / n as f64,
        t.elapsed().as_secs_f64() * 1e3 / n as f64,
        max_u * 1e3,
        max_diff
    );
    Ok(())
}
