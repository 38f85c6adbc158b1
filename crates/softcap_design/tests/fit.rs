//! Base-material fitting (thesis §8.3) on probe examples generated with softcap_fem (neo-Hookean
//! ground truth, sticky probe: tangential forces that the normal-force sensor misses).

use softcap_design::*;

#[test]
fn base_fit_beats_linear_prefit_and_tangential_forces_help() {
    // 4 × 5 × 2.5 cm block (thesis §8.5), coarse mesh for test speed.
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [0.04, 0.05, 0.025], [4, 5, 2]);
    let truth = softcap_fem::NeoHookeanParams::from_young_poisson(2.0e5, 0.35).unwrap();
    let examples = [
        ([0.02, 0.02], 6.0),
        ([0.02, 0.03], 12.0),
        ([0.01, 0.02], 9.0),
    ];
    let meas = synthesize_measurements(&mesh, truth, &examples, 0.011, true).unwrap();
    let max_u = meas
        .examples
        .iter()
        .flat_map(|e| e.displacements_m.iter())
        .map(|d| (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt())
        .fold(0.0, f64::max);
    println!("max marker displacement {:.3} mm", max_u * 1e3);
    let settings = BaseFitSettings {
        centres: 2,
        lm: softcap_core::LevenbergMarquardtSettings {
            max_iterations: 6,
            finite_difference: softcap_core::FiniteDifference::Forward,
            ..softcap_core::LevenbergMarquardtSettings::default()
        },
        ..BaseFitSettings::default()
    };
    let with_t = fit_isotropic(&meas, 1.0e5, &settings).unwrap();
    let without_t = fit_isotropic(
        &meas,
        1.0e5,
        &BaseFitSettings {
            tangential: false,
            ..settings.clone()
        },
    )
    .unwrap();
    println!(
        "linear pre-fit {:.4} mm, RBF fit {:.4} mm (with tangential forces), {:.4} mm (without); {} / {} simulations; {}",
        with_t.linear_rms_m * 1e3,
        with_t.rms_m * 1e3,
        without_t.rms_m * 1e3,
        with_t.evaluations,
        without_t.evaluations,
        with_t.status
    );
    // Measured: pre-fit 0.233 mm, fit 0.028 mm with the tangential forces, 0.227 mm without,
    // max marker displacement 1.83 mm.
    assert!(with_t.rms_m < 0.7 * with_t.linear_rms_m);
    assert!(with_t.rms_m < 0.8 * without_t.rms_m);
    assert!(with_t.rms_m < 0.1 * max_u);
}
