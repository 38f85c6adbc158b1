//! Gauss–Newton and Nelder–Mead on standard test functions (Moré, Garbow & Hillstrom 1981).

use softcap_core::nalgebra::DMatrix;
use softcap_core::{
    Bounds, ConvergenceReason, GaussNewtonSettings, LeastSquaresProblem, NelderMeadSettings,
    SolverStatus, gauss_newton, nelder_mead,
};

struct Rosenbrock;
impl LeastSquaresProblem for Rosenbrock {
    fn num_params(&self) -> usize {
        2
    }
    fn num_residuals(&self) -> usize {
        2
    }
    fn residuals(&mut self, p: &[f64], r: &mut [f64]) {
        r[0] = 10.0 * (p[1] - p[0] * p[0]);
        r[1] = 1.0 - p[0];
    }
    fn jacobian(&mut self, p: &[f64], j: &mut DMatrix<f64>) -> bool {
        j[(0, 0)] = -20.0 * p[0];
        j[(0, 1)] = 10.0;
        j[(1, 0)] = -1.0;
        j[(1, 1)] = 0.0;
        true
    }
}

/// Meyer-like but well-scaled exponential decay with noise-free data: zero-residual problem.
struct Decay {
    t: Vec<f64>,
    y: Vec<f64>,
}
impl Decay {
    fn new() -> Self {
        let t: Vec<f64> = (0..40).map(|i| i as f64 * 0.1).collect();
        let y = t
            .iter()
            .map(|t| 3.0 * (-0.7 * t).exp() * (2.0 * t).cos())
            .collect();
        Self { t, y }
    }
}
impl LeastSquaresProblem for Decay {
    fn num_params(&self) -> usize {
        3
    }
    fn num_residuals(&self) -> usize {
        self.t.len()
    }
    fn residuals(&mut self, p: &[f64], r: &mut [f64]) {
        for k in 0..self.t.len() {
            r[k] = p[0] * (-p[1] * self.t[k]).exp() * (p[2] * self.t[k]).cos() - self.y[k];
        }
    }
}

/// Box 3-D function (Moré et al. #12), zero residual at (1, 10, 1).
struct Box3d;
impl LeastSquaresProblem for Box3d {
    fn num_params(&self) -> usize {
        3
    }
    fn num_residuals(&self) -> usize {
        10
    }
    fn residuals(&mut self, x: &[f64], r: &mut [f64]) {
        for i in 0..10 {
            let t = 0.1 * (i + 1) as f64;
            r[i] = (-t * x[0]).exp() - (-t * x[1]).exp() - x[2] * ((-t).exp() - (-10.0 * t).exp());
        }
    }
}

#[test]
fn gauss_newton_solves_rosenbrock_with_step_halving() {
    let rep = gauss_newton(&mut Rosenbrock, &[-1.2, 1.0], None, &Default::default()).unwrap();
    let err = ((rep.params[0] - 1.0).powi(2) + (rep.params[1] - 1.0).powi(2)).sqrt();
    println!(
        "GN Rosenbrock: {:?}, {} iterations, |p − p*| = {err:.2e}",
        rep.status, rep.iterations
    );
    assert!(rep.status.is_converged(), "{:?}", rep.status);
    assert!(err < 1e-8, "{err}");
}

#[test]
fn gauss_newton_fits_zero_residual_problems_with_finite_differences() {
    let rep = gauss_newton(
        &mut Decay::new(),
        &[2.0, 0.5, 1.8],
        None,
        &Default::default(),
    )
    .unwrap();
    let err = (rep.params[0] - 3.0)
        .abs()
        .max((rep.params[1] - 0.7).abs())
        .max((rep.params[2] - 2.0).abs());
    println!(
        "GN decay: {:?}, {} iterations, max param error {err:.2e}",
        rep.status, rep.iterations
    );
    assert!(rep.status.is_converged(), "{:?}", rep.status);
    assert!(err < 1e-8, "{err}");
    let rep = gauss_newton(&mut Box3d, &[0.0, 10.0, 20.0], None, &Default::default()).unwrap();
    println!(
        "GN box3d: {:?}, {} iterations, F = {:.2e}, p = {:?}",
        rep.status, rep.iterations, rep.cost, rep.params
    );
    assert!(rep.status.is_converged(), "{:?}", rep.status);
    assert!(rep.cost < 1e-20, "{}", rep.cost);
}

#[test]
fn gauss_newton_respects_bounds_and_reports_max_iterations() {
    let bounds = Bounds::new(vec![-2.0, -2.0], vec![0.5, 2.0]).unwrap();
    let rep = gauss_newton(
        &mut Rosenbrock,
        &[-1.2, 1.0],
        Some(&bounds),
        &Default::default(),
    )
    .unwrap();
    // Constrained minimum of Rosenbrock with x ≤ 0.5 is (0.5, 0.25).
    println!("GN bounded Rosenbrock: {:?} {:?}", rep.status, rep.params);
    assert!(rep.status.is_converged(), "{:?}", rep.status);
    assert!(
        (rep.params[0] - 0.5).abs() < 1e-12 && (rep.params[1] - 0.25).abs() < 1e-8,
        "{:?}",
        rep.params
    );
    let capped = GaussNewtonSettings {
        max_iterations: 2,
        ..Default::default()
    };
    let rep = gauss_newton(&mut Rosenbrock, &[-1.2, 1.0], None, &capped).unwrap();
    assert_eq!(rep.status, SolverStatus::MaxIterations);
}

fn rosenbrock(x: &[f64]) -> f64 {
    (0..x.len() - 1)
        .map(|i| 100.0 * (x[i + 1] - x[i] * x[i]).powi(2) + (1.0 - x[i]).powi(2))
        .sum()
}

#[test]
fn nelder_mead_minimizes_rosenbrock_2d_and_4d() {
    for (x0, tol) in [(vec![-1.2, 1.0], 1e-6), (vec![-1.2, 1.0, -1.2, 1.0], 1e-5)] {
        let settings = NelderMeadSettings {
            f_tolerance: 1e-16,
            x_tolerance: 1e-10,
            ..Default::default()
        };
        let rep = nelder_mead(rosenbrock, &x0, None, &settings).unwrap();
        let err = rep
            .params
            .iter()
            .map(|v| (v - 1.0).abs())
            .fold(0.0, f64::max);
        println!(
            "NM Rosenbrock n={}: {:?}, {} iterations, {} evaluations, f = {:.2e}, max |x − 1| = {err:.2e}",
            x0.len(),
            rep.status,
            rep.iterations,
            rep.evaluations,
            rep.value
        );
        assert_eq!(
            rep.status,
            SolverStatus::Converged {
                reason: ConvergenceReason::SimplexSize
            }
        );
        assert!(err < tol, "{err}");
    }
}

#[test]
fn nelder_mead_with_bounds_finds_boundary_optimum_and_reports_caps() {
    // Minimum of (x − 3)² + (y + 1)² within [0, 2] × [0, 2] is (2, 0).
    let f = |x: &[f64]| (x[0] - 3.0).powi(2) + (x[1] + 1.0).powi(2);
    let bounds = Bounds::new(vec![0.0, 0.0], vec![2.0, 2.0]).unwrap();
    let mut outside = 0;
    let rep = nelder_mead(
        |x: &[f64]| {
            if x[0] < 0.0 || x[0] > 2.0 || x[1] < 0.0 || x[1] > 2.0 {
                outside += 1;
            }
            f(x)
        },
        &[1.0, 1.0],
        Some(&bounds),
        &Default::default(),
    )
    .unwrap();
    println!("NM bounded: {:?} {:?}", rep.status, rep.params);
    assert!(rep.status.is_converged(), "{:?}", rep.status);
    assert_eq!(outside, 0, "objective evaluated outside the box");
    assert!(
        (rep.params[0] - 2.0).abs() < 1e-8 && rep.params[1].abs() < 1e-8,
        "{:?}",
        rep.params
    );
    let capped = NelderMeadSettings {
        max_evaluations: 20,
        ..Default::default()
    };
    let rep = nelder_mead(rosenbrock, &[-1.2, 1.0], None, &capped).unwrap();
    assert_eq!(rep.status, SolverStatus::MaxEvaluations);
    let capped = NelderMeadSettings {
        max_iterations: 5,
        ..Default::default()
    };
    let rep = nelder_mead(rosenbrock, &[-1.2, 1.0], None, &capped).unwrap();
    assert_eq!(rep.status, SolverStatus::MaxIterations);
    let rep = nelder_mead(|_: &[f64]| f64::NAN, &[1.0], None, &Default::default()).unwrap();
    assert_eq!(rep.status, SolverStatus::NonFinite);
}

#[test]
fn nelder_mead_is_deterministic() {
    let a = nelder_mead(rosenbrock, &[-1.2, 1.0, 0.3], None, &Default::default()).unwrap();
    let b = nelder_mead(rosenbrock, &[-1.2, 1.0, 0.3], None, &Default::default()).unwrap();
    assert_eq!(a, b);
}
