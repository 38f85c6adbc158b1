//! The invariant material (thesis eq. 8.1–8.2) fits Treloar's uniaxial and Kawabata's general
//! biaxial rubber data at once (fixtures/rubber/).

use softcap_design::*;
use std::path::PathBuf;

fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../fixtures/rubber")
        .join(name)
}

#[test]
fn invariant_model_fits_treloar_and_kawabata_at_once() {
    let uni = read_uniaxial(&fixture("treloar1944_uniaxial.csv")).unwrap();
    let bi = read_biaxial(&fixture("kawabata1981_biaxial.csv")).unwrap();
    assert_eq!((uni.len(), bi.len()), (21, 117));
    let sets = [
        ("treloar1944 uniaxial", uni.as_slice()),
        ("kawabata1981 biaxial", bi.as_slice()),
    ];
    let rep = fit_rubber(&sets, &RubberFitSettings::default()).unwrap();
    for e in &rep.errors {
        println!(
            "{}: {} values, RMS {:.4} MPa, {:.2} % of max stress",
            e.name,
            e.count,
            e.rms_mpa,
            100.0 * e.relative
        );
    }
    println!("status {} after {} iterations", rep.status, rep.iterations);
    // For reference: the constant part alone, without the strain-dependent RBF terms.
    let mut linear = rep.material.clone();
    linear.rbf.centres.clear();
    linear.rbf.weights.clear();
    let base = rubber_errors(&linear, &sets);
    for e in &base {
        println!(
            "p₀ alone (RBF terms dropped): {}: RMS {:.4} MPa",
            e.name, e.rms_mpa
        );
    }
    assert!(
        rep.errors[0].relative < 0.05,
        "uniaxial {:?}",
        rep.errors[0]
    );
    assert!(rep.errors[1].relative < 0.05, "biaxial {:?}", rep.errors[1]);
}

#[test]
fn bad_rubber_file_names_line_and_column() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("bad.csv");
    std::fs::write(&p, "stretch,nominal_stress_mpa\n1.0,0.0\n1.5,abc\n").unwrap();
    let e = read_uniaxial(&p).unwrap_err().to_string();
    assert!(e.contains("line 3") && e.contains("column 2"), "{e}");
}
