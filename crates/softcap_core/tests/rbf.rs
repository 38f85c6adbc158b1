//! RBF interpolation, least-squares fitting and greedy centre selection (thesis eq. 4.1,
//! bickel2009 eq. 8 and §4.2).

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use softcap_core::{
    CoreError, GreedyErrorMeasure, GreedyRbfSettings, GreedyStatus, PolynomialTail, Rbf, RbfKernel,
    RbfSettings, ScatteredData, greedy_rbf,
};

fn random_points(n: usize, d: usize, seed: u64, scale: f64) -> Vec<f64> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n * d)
        .map(|_| rng.random_range(-1.0..1.0) * scale)
        .collect()
}

fn affine(x: &[f64]) -> [f64; 3] {
    [
        0.5 + 1.2 * x[0] - 0.3 * x[1] + 0.1 * x[2],
        -2.0 + 0.2 * x[0] + 0.9 * x[1] - 0.4 * x[2],
        1.0 - 0.7 * x[0] + 0.05 * x[1] + 1.1 * x[2],
    ]
}

fn quadratic(x: &[f64]) -> [f64; 2] {
    [
        1.0 + x[0] - 2.0 * x[2] + 0.5 * x[0] * x[0] - x[1] * x[2] + 0.25 * x[2] * x[2],
        -0.3 * x[1] + 2.0 * x[0] * x[1] - x[1] * x[1],
    ]
}

fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

/// thesis §4.2.1: r³ + quadratic tail reproduces affine motions exactly (here to 1e-10,
/// evaluated away from the centres, with coordinates in millimetres-sized magnitudes).
#[test]
fn cubic_with_quadratic_tail_reproduces_affine_map() {
    let pts = random_points(60, 3, 1, 100.0);
    let vals: Vec<f64> = pts.chunks(3).flat_map(affine).collect();
    let data = ScatteredData::new(&pts, 3, &vals, 3).unwrap();
    let rbf = Rbf::interpolate(&data, &RbfSettings::default()).unwrap();
    let test = random_points(200, 3, 2, 120.0);
    let got = rbf.evaluate_batch(&test).unwrap();
    let want: Vec<f64> = test.chunks(3).flat_map(affine).collect();
    let err = max_abs_diff(&got, &want);
    let ymax = want.iter().fold(0.0f64, |a, v| a.max(v.abs()));
    println!("affine reproduction: max error {err:.3e} (|y| up to {ymax:.1})");
    assert!(err < 1e-10 * ymax.max(1.0), "{err}");
    // The RBF weights vanish for a polynomial in the tail space.
    let wmax = rbf.weights().iter().fold(0.0f64, |a, v| a.max(v.abs()));
    assert!(wmax < 1e-12, "{wmax}");
}

#[test]
fn cubic_with_quadratic_tail_reproduces_quadratic_in_any_dimension() {
    for (kernel, d) in [
        (RbfKernel::Cubic, 3),
        (RbfKernel::Linear, 3),
        (RbfKernel::Cubic, 5),
    ] {
        let pts = random_points(80, d, 3, 1.0);
        let f = |x: &[f64]| quadratic(&[x[0], x[1], x[d - 1]]);
        let vals: Vec<f64> = pts.chunks(d).flat_map(f).collect();
        let data = ScatteredData::new(&pts, d, &vals, 2).unwrap();
        let settings = RbfSettings {
            kernel,
            tail: PolynomialTail::Quadratic,
            ..Default::default()
        };
        let rbf = Rbf::interpolate(&data, &settings).unwrap();
        let test = random_points(100, d, 4, 1.0);
        let got = rbf.evaluate_batch(&test).unwrap();
        let want: Vec<f64> = test.chunks(d).flat_map(f).collect();
        let err = max_abs_diff(&got, &want);
        println!("{kernel:?} d={d}: quadratic reproduction max error {err:.3e}");
        assert!(err < 1e-10, "{kernel:?} d={d}: {err}");
    }
}

/// bickel2009 eq. 8: φ(r) = r without tail interpolates exactly at the centres.
#[test]
fn linear_kernel_interpolates_exactly_at_centres() {
    let d = 6; // strain space ℝ⁶ → (λ, α) ∈ ℝ² as in bickel2009
    let pts = random_points(40, d, 5, 0.2);
    let mut rng = ChaCha8Rng::seed_from_u64(6);
    let vals: Vec<f64> = (0..80).map(|_| rng.random_range(1e3..1e5)).collect();
    let data = ScatteredData::new(&pts, d, &vals, 2).unwrap();
    for tail in [PolynomialTail::None, PolynomialTail::Linear] {
        let settings = RbfSettings {
            kernel: RbfKernel::Linear,
            tail,
            ..Default::default()
        };
        let rbf = Rbf::interpolate(&data, &settings).unwrap();
        let got = rbf.evaluate_batch(&pts).unwrap();
        let rel = max_abs_diff(&got, &vals) / 1e5;
        println!("φ=r tail {tail:?}: relative error at centres {rel:.3e}");
        assert!(rel < 1e-11, "{tail:?}: {rel}");
    }
}

#[test]
fn jacobian_matches_finite_differences() {
    let pts = random_points(30, 3, 7, 1.0);
    let vals: Vec<f64> = pts
        .chunks(3)
        .flat_map(|x| [x[0].sin() + x[1] * x[2], (x[1] - x[0]).cos()])
        .collect();
    let data = ScatteredData::new(&pts, 3, &vals, 2).unwrap();
    for kernel in [RbfKernel::Linear, RbfKernel::Cubic] {
        let rbf = Rbf::interpolate(
            &data,
            &RbfSettings {
                kernel,
                ..Default::default()
            },
        )
        .unwrap();
        let x = [0.13, -0.21, 0.37];
        let mut jac = [0.0; 6];
        rbf.jacobian_into(&x, &mut jac).unwrap();
        let h = 1e-6;
        for i in 0..3 {
            let mut xp = x;
            let mut xm = x;
            xp[i] += h;
            xm[i] -= h;
            let (fp, fm) = (rbf.evaluate(&xp).unwrap(), rbf.evaluate(&xm).unwrap());
            for k in 0..2 {
                let fd = (fp[k] - fm[k]) / (2.0 * h);
                assert!(
                    (fd - jac[k * 3 + i]).abs() < 1e-6 * (1.0 + fd.abs()),
                    "{kernel:?} ∂f{k}/∂x{i}: {fd} vs {}",
                    jac[k * 3 + i]
                );
            }
        }
    }
}

#[test]
fn least_squares_with_all_samples_as_centres_is_interpolation() {
    let pts = random_points(25, 2, 8, 1.0);
    let vals: Vec<f64> = pts
        .chunks(2)
        .map(|x| (3.0 * x[0]).sin() * x[1].exp())
        .collect();
    let data = ScatteredData::new(&pts, 2, &vals, 1).unwrap();
    let interp = Rbf::interpolate(&data, &RbfSettings::default()).unwrap();
    let ls = Rbf::fit_least_squares(&data, &pts, &RbfSettings::default()).unwrap();
    let test = random_points(50, 2, 9, 1.0);
    let err = max_abs_diff(
        &interp.evaluate_batch(&test).unwrap(),
        &ls.evaluate_batch(&test).unwrap(),
    );
    println!("least squares (M = N) vs interpolation: {err:.3e}");
    assert!(err < 1e-9, "{err}");
}

#[test]
fn least_squares_with_few_centres_reproduces_tail_polynomials() {
    let pts = random_points(200, 3, 10, 2.0);
    let vals: Vec<f64> = pts.chunks(3).flat_map(quadratic).collect();
    let data = ScatteredData::new(&pts, 3, &vals, 2).unwrap();
    let centers = random_points(15, 3, 11, 2.0);
    let rbf = Rbf::fit_least_squares(&data, &centers, &RbfSettings::default()).unwrap();
    let err = max_abs_diff(&rbf.evaluate_batch(&pts).unwrap(), &vals);
    assert!(err < 1e-10, "{err}");
}

#[test]
fn duplicate_centres_are_a_singular_system_error() {
    let pts = [0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 1.0, 0.0];
    let vals = [1.0, 2.0, 3.0, 4.0];
    let data = ScatteredData::new(&pts, 2, &vals, 1).unwrap();
    let settings = RbfSettings {
        kernel: RbfKernel::Linear,
        tail: PolynomialTail::None,
        ..Default::default()
    };
    let err = Rbf::interpolate(&data, &settings).unwrap_err();
    assert!(matches!(err, CoreError::SingularSystem { .. }), "{err}");
    assert!(matches!(
        ScatteredData::new(&pts[..3], 2, &vals, 1),
        Err(CoreError::DimensionMismatch { .. })
    ));
    let nan = [0.0, f64::NAN];
    assert!(matches!(
        ScatteredData::new(&nan, 2, &vals[..1], 1),
        Err(CoreError::NonFiniteInput { index: 1, .. })
    ));
}

/// bickel2009 §4.2: greedy basis selection stops at its tolerance; the error history (error
/// against basis size) is reported and decreases.
#[test]
fn greedy_selection_stops_at_tolerance_with_decreasing_history() {
    let pts = random_points(400, 2, 12, 1.0);
    let vals: Vec<f64> = pts
        .chunks(2)
        .map(|x| (2.0 * x[0]).sin() * (1.5 * x[1]).cos() + 0.3 * x[0] * x[1])
        .collect();
    let data = ScatteredData::new(&pts, 2, &vals, 1).unwrap();
    let tolerance = 1e-3;
    let settings = GreedyRbfSettings {
        tolerance,
        measure: GreedyErrorMeasure::Max,
        max_centers: 150,
        initial_centers: vec![0],
        ..Default::default()
    };
    let report = greedy_rbf(&data, &settings).unwrap();
    println!("centres  max error   rms error");
    for s in &report.history {
        println!(
            "{:7}  {:.3e}  {:.3e}",
            s.num_centers, s.max_error, s.rms_error
        );
    }
    assert_eq!(report.status, GreedyStatus::ToleranceReached);
    let last = report.history.last().unwrap();
    assert!(last.max_error <= tolerance);
    assert!(
        report.history[report.history.len() - 2].max_error > tolerance,
        "stopped at the first fit below tolerance"
    );
    assert!(report.centers.len() < 150 && report.centers.len() == last.num_centers);
    assert_eq!(report.rbf.num_centers(), report.centers.len());
    // The returned RBF has exactly the reported error.
    let pred = report.rbf.evaluate_batch(&pts).unwrap();
    let max_err = max_abs_diff(&pred, &vals);
    assert!((max_err - last.max_error).abs() < 1e-12);
    // Monotone-ish: RMS never grows by more than 10% from one step to the next, and the final
    // error is far below the first.
    for w in report.history.windows(2) {
        assert!(w[1].rms_error <= 1.1 * w[0].rms_error, "{:?}", w);
    }
    assert!(last.rms_error < 0.01 * report.history[0].rms_error);
}

#[test]
fn greedy_selection_reports_max_centres() {
    let pts = random_points(100, 1, 13, 3.0);
    let vals: Vec<f64> = pts.iter().map(|x| (4.0 * x).sin()).collect();
    let data = ScatteredData::new(&pts, 1, &vals, 1).unwrap();
    let settings = GreedyRbfSettings {
        tolerance: 1e-12,
        max_centers: 5,
        ..Default::default()
    };
    let report = greedy_rbf(&data, &settings).unwrap();
    assert_eq!(report.status, GreedyStatus::MaxCenters);
    assert_eq!(report.centers.len(), 5);
}
