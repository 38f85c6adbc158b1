//! One live branch-and-bound search at full size (5 layers × 9 base materials, simulations
//! included) on a random target, with the search settings of
//! `fixtures/design/search-5x9-certified.json`: prints the found design, its RMS error, the
//! number of designs simulated and the batch statistics. The CPU time quoted in docs/design.md:
//!
//! `cargo build --release -p softcap_design --example live_search &&
//!  /usr/bin/time target/release/examples/live_search`

use softcap_design::*;
use std::sync::Arc;

fn main() {
    // Run under /usr/bin/time: user + sys is the CPU cost (wall time on a loaded machine is not).
    let search: SearchSettings = serde_json::from_str(include_str!(
        "../../../fixtures/design/search-5x9-certified.json"
    ))
    .unwrap();
    let settings = ExperimentSettings {
        targets: 1,
        exhaustive: false,
        ..ExperimentSettings::default()
    };
    let lib = Arc::new(reference_library());
    let target = random_targets(&lib, &settings).unwrap().remove(0);
    let t = std::time::Instant::now();
    let mut ev = ParallelEvaluator::new(lib, &settings.composite).unwrap();
    let rep = branch_and_bound(5, 9, &target.response, &mut ev, &search).unwrap();
    let rms = rep.error_m / ((target.response.len() / 3) as f64).sqrt();
    println!(
        "target {:?} → found {:?}, RMS {:.4} mm, {} designs simulated in {} batches (mean {:.1}, \
         {} of one design); parallel efficiency on 2 workers {:.3}; wall {:.1} s with {} rayon threads",
        target.design,
        rep.design,
        rms * 1e3,
        ev.simulations,
        ev.batch_sizes.len(),
        ev.simulations as f64 / ev.batch_sizes.len().max(1) as f64,
        ev.batch_sizes.iter().filter(|&&b| b == 1).count(),
        ev.parallel_efficiency(2),
        t.elapsed().as_secs_f64(),
        rayon::current_num_threads()
    );
    assert_eq!(ev.simulations, rep.evaluations);
}
