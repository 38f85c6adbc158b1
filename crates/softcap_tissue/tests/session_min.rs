//! Issue 7 "done when": on the shared example session (session-min: fixtures/tissue/session-min/capture.mcap and
//! fixtures/session-min/template/volume.msh), the average marker fitting error is < 1 mm and
//! below the homogeneous model's.

use std::path::PathBuf;

use softcap_tissue::{FitConfig, FitSettings};

fn fixture(path: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../fixtures")
        .join(path)
}

/// Measured (docs/tissue.md): 4 examples, 1,642 tets; marker RMS homogeneous 0.0882 mm,
/// per-example 0.0181 mm, strain-space material 0.0326 mm. Tolerances: the issue's < 1 mm on the
/// mean marker error, the material below the homogeneous model (RMS and mean), every
/// re-simulation converged.
#[test]
fn session_min_fit_error_is_below_1_mm_and_below_homogeneous() {
    let dir = tempfile::tempdir().unwrap();
    let o = softcap_tissue::fit::run(&FitConfig {
        capture: fixture("tissue/session-min/capture.mcap"),
        mesh: Some(fixture("session-min/template/volume.msh")),
        output: dir.path().join("material.mcap"),
        report: None,
        settings: FitSettings {
            progress: false,
            ..FitSettings::default()
        },
        arguments: vec![],
    })
    .unwrap();
    eprintln!(
        "session-min: {} examples, {} tets, {} locations; marker RMS homogeneous {:.4} mm, per-example {:.4} mm, material {:.4} mm; mean error homogeneous {:.4} mm, material {:.4} mm",
        o.examples.len(),
        o.tets,
        o.locations,
        1e3 * o.homogeneous_rms_m,
        1e3 * o.example_rms_m,
        1e3 * o.material_rms_m,
        1e3 * o.homogeneous_mean_error_m,
        1e3 * o.material_mean_error_m
    );
    assert_eq!(o.material_failures, 0);
    assert!(
        o.material_mean_error_m < 1e-3,
        "{}",
        o.material_mean_error_m
    );
    assert!(o.material_rms_m < 1e-3, "{}", o.material_rms_m);
    assert!(o.material_rms_m < o.homogeneous_rms_m);
    assert!(o.material_mean_error_m < o.homogeneous_mean_error_m);
}
