//! Thesis §8.6 validation at full size: 20 random targets (5 layers, 9 base materials, 5
//! force–displacement examples, layer thicknesses jittered ±15 %), branch-and-bound (exact
//! mode, K = 20) and the thesis' heuristic against the exhaustive optimum over all
//! 9⁵ = 59,049 designs, plus the bound check over the whole table.
//!
//! ```sh
//! cargo run --profile test -p softcap_design --example validation -- [TABLE.bin] [REPORT.json] [LAYERS] [SETTINGS.json]
//! ```
//! TABLE.bin caches the exhaustive table (≈ 85 MB at 5 layers; computed and written if
//! missing). LAYERS (default 5) runs the same experiment with fewer cells (9^LAYERS designs).
//! SETTINGS.json receives the search settings with the margins certified on the table
//! (committed as fixtures/design/search-5x9-certified.json for the live bench).
//! Prints the markdown table of docs/design.md.

use softcap_design::*;
use std::sync::Arc;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let layers: usize = match args.get(3) {
        Some(a) => a.parse()?,
        None => 5,
    };
    let settings = ExperimentSettings {
        table_path: args.get(1).map(Into::into),
        composite: CompositeSettings {
            layers,
            ..CompositeSettings::default()
        },
        ..ExperimentSettings::default()
    };
    let t = std::time::Instant::now();
    let rep = run_experiment(Arc::new(reference_library()), &settings)?;
    let mm = |v: f64| v * 1e3;
    println!(
        "| target | thicknesses [mm] | found (exact B&B) | RMS [mm] | evaluations | heuristic (K reps only) | exhaustive optimum | RMS [mm] | found = optimum |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    for o in &rep.outcomes {
        let th: Vec<String> = o
            .target_thickness_m
            .iter()
            .map(|t| format!("{:.2}", t * 1e3))
            .collect();
        let (od, oe) = o.exhaustive.clone().unwrap_or_default();
        println!(
            "| {:?} | {} | {:?} | {:.4} | {} | {:?} ({}) | {:?} | {:.4} | {} |",
            o.target_design,
            th.join("/"),
            o.found_design,
            mm(o.found_rms_m),
            o.evaluations,
            o.heuristic_design.clone().unwrap_or_default(),
            o.heuristic_evaluations.unwrap_or(0),
            od,
            mm(oe),
            if o.matches_exhaustive == Some(true) {
                "yes"
            } else {
                "no"
            }
        );
    }
    let max_rms = rep
        .outcomes
        .iter()
        .map(|o| o.found_rms_m)
        .fold(0.0, f64::max);
    let mean_eval = rep
        .outcomes
        .iter()
        .map(|o| o.evaluations as f64)
        .sum::<f64>()
        / rep.outcomes.len().max(1) as f64;
    let mean_search_s = rep.outcomes.iter().map(|o| o.search_seconds).sum::<f64>()
        / rep.outcomes.len().max(1) as f64;
    println!();
    println!(
        "found = exhaustive optimum: {}/{} (heuristic: {}/{}); mean RMS {:.4} mm (max {:.4} mm; bickel2010: 0.067 mm); mean evaluations {:.0} of {}; mean table-backed search {:.3} s",
        rep.matches,
        rep.outcomes.len(),
        rep.heuristic_matches,
        rep.outcomes.len(),
        mm(rep.mean_found_rms_m),
        mm(max_rms),
        mean_eval,
        9usize.pow(layers as u32),
        mean_search_s
    );
    println!(
        "exhaustive table: {:.1} s, {} failures; total {:.1} s",
        rep.exhaustive_seconds,
        rep.exhaustive_failures,
        t.elapsed().as_secs_f64()
    );
    println!();
    println!(
        "| level | prefixes | with a completion outside the box | max excess [mm] | (prefix, target) bound > subtree best | max bound excess [mm] |"
    );
    println!("|---|---|---|---|---|---|");
    for c in &rep.bound_checks {
        println!(
            "| {} | {} | {} | {:.5} | {} | {:.5} |",
            c.level,
            c.prefixes,
            c.violating_prefixes,
            mm(c.max_component_excess_m),
            c.bound_failures,
            mm(c.max_bound_excess_m)
        );
    }
    println!();
    println!(
        "| level | box excess max [mm] | excess / diag | additive residual max [mm] | residual / s |"
    );
    println!("|---|---|---|---|---|");
    for e in &rep.box_excess {
        let a = rep.additive_residual.iter().find(|a| a.level == e.level);
        println!(
            "| {} | {:.5} | {:.4} | {} | {} |",
            e.level,
            mm(e.max_excess_m),
            e.max_relative,
            a.map_or("exact".into(), |a| format!("{:.5}", mm(a.max_residual_m))),
            a.map_or("exact".into(), |a| format!("{:.4}", a.max_relative)),
        );
    }
    println!(
        "margins: {}",
        serde_json::to_string(&(&rep.margin, &rep.additive_margin))?
    );
    if let Some(p) = args.get(4) {
        // The certified search settings (fixtures/design/search-5x9-certified.json).
        let certified = SearchSettings {
            margin: rep.margin.clone(),
            additive: rep.additive_margin.clone(),
            ..settings.search.clone()
        };
        write_json(std::path::Path::new(p), &certified)?;
    }
    if let Some(p) = args.get(2) {
        write_json(std::path::Path::new(p), &rep)?;
    }
    Ok(())
}
