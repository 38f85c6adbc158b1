//! Thesis §8.6 validation with *fitted* base materials as the design library: each of the nine
//! reference materials (seven isotropic, two transversely isotropic) is probed on a
//! 4 × 5 × 2.5 cm block (four examples of 5–8 N, two oblique; simulated with the true material,
//! all top nodes observed) and fitted by §8.3 (`fit_isotropic` / `fit_transverse`, 2 centres).
//! Targets are random designs of the *true* materials with jittered layer thicknesses; the search
//! (exact B&B, margins certified on the fitted library's exhaustive table) runs on the fitted
//! library. Reports the fit errors, whether the search finds the exhaustive optimum of the fitted
//! library, and how often that optimum is the target's own material sequence.
//!
//! ```sh
//! cargo run --profile test -p softcap_design --example fitted_library -- [LAYERS]
//! ```

use softcap_design::*;
use std::sync::Arc;

/// The four probe loads on the top face (centre x, y [m]; force on the object [N]); two oblique.
const LOADS: [([f64; 2], [f64; 3]); 4] = [
    ([0.02, 0.025], [0.0, 0.0, -8.0]),
    ([0.01, 0.0125], [1.5, 0.0, -6.0]),
    ([0.03, 0.0375], [0.0, -1.5, -6.0]),
    ([0.02, 0.0125], [1.2, 1.2, -5.0]),
];

fn measurements(truth: &BaseMaterial, settings: &BaseFitSettings) -> Result<BaseMeasurements> {
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [0.04, 0.05, 0.025], [4, 5, 2]);
    simulate_block_probes(&mesh, truth, &LOADS, 0.011, settings)
}

fn main() -> std::result::Result<(), Box<dyn std::error::Error>> {
    use rayon::prelude::*;
    let layers: usize = std::env::args().nth(1).map_or(Ok(3), |a| a.parse())?;
    let truth = Arc::new(reference_library());
    let fit_settings = BaseFitSettings {
        centres: 2,
        tangential: false,
        lm: softcap_core::LevenbergMarquardtSettings {
            max_iterations: 8,
            finite_difference: softcap_core::FiniteDifference::Forward,
            ..softcap_core::LevenbergMarquardtSettings::default()
        },
        ..BaseFitSettings::default()
    };
    let fits: Vec<(BaseFitReport, f64)> = truth
        .par_iter()
        .map(|m| -> Result<(BaseFitReport, f64)> {
            let meas = measurements(m, &fit_settings)?;
            let max_u = meas
                .examples
                .iter()
                .flat_map(|e| e.displacements_m.iter())
                .map(|d| (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt())
                .fold(0.0, f64::max);
            let rep = match m {
                BaseMaterial::Isotropic(_) => fit_isotropic(&meas, 3.0e5, &fit_settings)?,
                BaseMaterial::Transverse(_) => fit_transverse(
                    &meas,
                    TransverseParams::isotropic(1.5e5, 1.0e5),
                    &fit_settings,
                )?,
            };
            Ok((rep, max_u))
        })
        .collect::<Result<_>>()?;
    println!(
        "| material | kind | max marker displacement [mm] | linear pre-fit RMS [mm] | fit RMS [mm] |"
    );
    println!("|---|---|---|---|---|");
    for (i, (rep, max_u)) in fits.iter().enumerate() {
        let kind = match truth[i] {
            BaseMaterial::Isotropic(_) => "isotropic",
            BaseMaterial::Transverse(_) => "transversely isotropic",
        };
        println!(
            "| {i} | {kind} | {:.3} | {:.4} | {:.4} |",
            max_u * 1e3,
            rep.linear_rms_m * 1e3,
            rep.rms_m * 1e3
        );
    }
    let fitted = Arc::new(fits.into_iter().map(|f| f.0.material).collect::<Vec<_>>());
    let settings = ExperimentSettings {
        composite: CompositeSettings {
            layers,
            ..CompositeSettings::default()
        },
        ..ExperimentSettings::default()
    };
    let m = fitted.len();
    let targets = random_targets(&truth, &settings)?;
    let mut ev = ParallelEvaluator::new(fitted.clone(), &settings.composite)?;
    let table = exhaustive_table(layers, m, &mut ev, 4096);
    let order = settings.search.cell_order;
    let search = SearchSettings {
        margin: BoundMargin::relative(&box_excess(&table, layers, m, order), 1.0),
        additive: Some(AdditiveMargin::relative(
            &additive_residual(&table, layers, m, order),
            1.0,
        )),
        ..settings.search.clone()
    };
    let (mut matches, mut own, mut rms_sum) = (0, 0, 0.0);
    for t in &targets {
        let mut tev = TableEvaluator {
            table: &table,
            materials: m,
        };
        let rep = branch_and_bound(layers, m, &t.response, &mut tev, &search)?;
        let (opt, _) = exhaustive_optimum(&table, &t.response).ok_or("empty table")?;
        let rms = rep.error_m / ((t.response.len() / 3) as f64).sqrt();
        rms_sum += rms;
        matches += usize::from(design_index(&rep.design, m) == opt);
        own += usize::from(rep.design == t.design);
        println!(
            "target {:?} → found {:?} (RMS {:.4} mm, {} designs), exhaustive optimum {:?}",
            t.design,
            rep.design,
            rms * 1e3,
            rep.evaluations,
            design_from_index(opt, layers, m)
        );
    }
    println!(
        "{layers} layers, fitted library: found = exhaustive optimum {matches}/{}; found = target's own materials {own}/{}; mean RMS {:.4} mm (bickel2010: 0.067 mm); table failures {}",
        targets.len(),
        targets.len(),
        rms_sum / targets.len() as f64 * 1e3,
        table.iter().filter(|r| r.is_none()).count()
    );
    Ok(())
}
