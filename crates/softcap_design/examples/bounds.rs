//! How valid are the §8.4.2 uniform-fill bounds, and what slack makes them valid? Over the
//! exhaustive table (cached in TABLE.bin) of the §8.6 validation: the box excess per level for
//! both cell orders, then table-backed searches of the 20 targets with each margin.
//!
//! ```sh
//! cargo run --profile test -p softcap_design --example bounds -- TABLE.bin [LAYERS] [SAMPLE]
//! ```
//! SAMPLE (default 0): also calibrate the margin on a random sample of that many prefixes per
//! level (all their completions) instead of the whole table.

use softcap_design::*;
use std::sync::Arc;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let layers: usize = args.get(2).map_or(Ok(5), |a| a.parse())?;
    let settings = ExperimentSettings {
        table_path: args.get(1).map(Into::into),
        composite: CompositeSettings {
            layers,
            ..CompositeSettings::default()
        },
        ..ExperimentSettings::default()
    };
    let lib = Arc::new(reference_library());
    let m = lib.len();
    let t = std::time::Instant::now();
    let mut ev = ParallelEvaluator::new(lib.clone(), &settings.composite)?;
    let table = load_or_compute_table(&mut ev, &settings)?;
    println!(
        "table: {} designs, {} failed, {:.1} s",
        table.len(),
        table.iter().filter(|r| r.is_none()).count(),
        t.elapsed().as_secs_f64()
    );
    let targets = random_targets(&lib, &settings)?;
    let xs: Vec<Vec<f64>> = targets.iter().map(|t| t.response.clone()).collect();
    let optima: Vec<usize> = xs
        .iter()
        .map(|x| exhaustive_optimum(&table, x).map_or(usize::MAX, |o| o.0))
        .collect();
    for order in [CellOrder::BottomFirst, CellOrder::TopFirst] {
        let excess = box_excess(&table, layers, m, order);
        println!(
            "\n{order:?}: level | designs outside | max excess [mm] | max excess/diag | mean diag [mm]"
        );
        for e in &excess {
            println!(
                "  {} | {} | {:.5} | {:.4} | {:.4}",
                e.level,
                e.designs_outside,
                e.max_excess_m * 1e3,
                e.max_relative,
                e.mean_diagonal_m * 1e3
            );
        }
        let add = additive_residual(&table, layers, m, order);
        println!("  additive residual: level | max r [mm] | max r/s | mean s [mm]");
        for e in &add {
            println!(
                "  {} | {:.5} | {:.4} | {:.4}",
                e.level,
                e.max_residual_m * 1e3,
                e.max_relative,
                e.mean_scale_m * 1e3
            );
            println!(
                "    per reference r [mm]: {:?}",
                e.per_reference_max_m
                    .iter()
                    .map(|v| (v * 1e6).round() / 1e3)
                    .collect::<Vec<_>>()
            );
            println!(
                "    per reference r/s: {:?}",
                e.per_reference_relative
                    .iter()
                    .map(|v| (v * 1e3).round() / 1e3)
                    .collect::<Vec<_>>()
            );
        }
        // Calibration from a sample: SAMPLE random designs (seeded), their prefixes' fills
        // and additive variations looked up; compared with the full-table maxima.
        let sample_n: usize = args.get(3).map_or(Ok(0), |a| a.parse())?;
        if sample_n > 0 {
            let mut state = 0x9e37_79b9_7f4a_7c15u64;
            let mut sample: Vec<usize> = (0..sample_n)
                .map(|_| {
                    state ^= state << 13;
                    state ^= state >> 7;
                    state ^= state << 17;
                    (state % table.len() as u64) as usize
                })
                .collect();
            sample.sort_unstable();
            sample.dedup();
            let se = box_excess_of(&table, layers, m, order, &sample);
            let sa = additive_residual_of(&table, layers, m, order, &sample);
            println!(
                "  sample of {} designs: level | κ sample / full | additive r/s sample / full (max over b)",
                sample.len()
            );
            for (l, e) in se.iter().enumerate() {
                let a = sa.get(l).map_or((0.0, 0.0), |a| {
                    (a.max_relative, add.get(l).map_or(0.0, |f| f.max_relative))
                });
                println!(
                    "  {} | {:.4} / {:.4} | {:.4} / {:.4}",
                    e.level, e.max_relative, excess[l].max_relative, a.0, a.1
                );
            }
            for factor in [1.0, 1.5, 2.0] {
                let s = SearchSettings {
                    cell_order: order,
                    margin: BoundMargin::relative(&se, factor),
                    additive: Some(AdditiveMargin::relative(&sa, factor)),
                    ..SearchSettings::default()
                };
                let mut matches = 0;
                let mut evals = 0;
                for (x, &opt) in xs.iter().zip(&optima) {
                    let mut tev = TableEvaluator {
                        table: &table,
                        materials: m,
                    };
                    let rep = branch_and_bound(layers, m, x, &mut tev, &s)?;
                    matches += usize::from(design_index(&rep.design, m) == opt);
                    evals += rep.evaluations;
                }
                println!(
                    "  sampled margins × {factor}: matches {matches}/{}, mean evaluations {:.0}",
                    xs.len(),
                    evals as f64 / xs.len() as f64
                );
            }
        }
        let rel = BoundMargin::relative(&excess, 1.0);
        let margins = [
            ("none", BoundMargin::default(), None),
            ("relative ×1", rel.clone(), None),
            (
                "relative ×1 + additive abs ×1",
                rel.clone(),
                Some(AdditiveMargin::absolute(&add, 1.0)),
            ),
            (
                "relative ×1 + additive rel ×1",
                rel.clone(),
                Some(AdditiveMargin::relative(&add, 1.0)),
            ),
        ];
        for (name, margin, additive) in margins {
            let sweeps = 3;
            let s = SearchSettings {
                cell_order: order,
                margin: margin.clone(),
                additive,
                incumbent_sweeps: sweeps,
                ..SearchSettings::default()
            };
            let mut matches = 0;
            let mut evals = 0;
            let mut rms = 0.0;
            for (x, &opt) in xs.iter().zip(&optima) {
                let mut tev = TableEvaluator {
                    table: &table,
                    materials: m,
                };
                let rep = branch_and_bound(layers, m, x, &mut tev, &s)?;
                matches += usize::from(design_index(&rep.design, m) == opt);
                evals += rep.evaluations;
                rms += table[design_index(&rep.design, m)]
                    .as_deref()
                    .map_or(f64::NAN, |r| rms_displacement_error(r, x));
            }
            let checks = bound_violations(&table, layers, m, &xs, order, &margin);
            let failures: usize = checks.iter().map(|c| c.bound_failures).sum();
            println!(
                "  margin {name}, {sweeps} sweeps: matches {matches}/{}, mean evaluations {:.0}, mean RMS {:.4} mm, bound failures {failures}",
                xs.len(),
                evals as f64 / xs.len() as f64,
                rms / xs.len() as f64 * 1e3
            );
        }
    }
    Ok(())
}
