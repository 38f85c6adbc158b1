//! Levenberg–Marquardt on standard test problems (Moré, Garbow & Hillstrom 1981).

use softcap_core::faer::Mat;
use softcap_core::nalgebra::DMatrix;
use softcap_core::{
    Bounds, ConvergenceReason, DampingScaling, FiniteDifference, LeastSquaresProblem,
    LevenbergMarquardtSettings, SolverStatus, levenberg_marquardt,
};

/// Rosenbrock: r = (10 (y − x²), 1 − x), minimum 0 at (1, 1).
struct Rosenbrock {
    analytic: bool,
}

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
        if !self.analytic {
            return false;
        }
        j[(0, 0)] = -20.0 * p[0];
        j[(0, 1)] = 10.0;
        j[(1, 0)] = -1.0;
        j[(1, 1)] = 0.0;
        true
    }
}

/// Powell's singular function: minimum 0 at the origin, where J is singular (so convergence
/// is only linear).
struct PowellSingular;

impl LeastSquaresProblem for PowellSingular {
    fn num_params(&self) -> usize {
        4
    }
    fn num_residuals(&self) -> usize {
        4
    }
    fn residuals(&mut self, x: &[f64], r: &mut [f64]) {
        r[0] = x[0] + 10.0 * x[1];
        r[1] = 5f64.sqrt() * (x[2] - x[3]);
        r[2] = (x[1] - 2.0 * x[2]).powi(2);
        r[3] = 10f64.sqrt() * (x[0] - x[3]).powi(2);
    }
    fn jacobian(&mut self, x: &[f64], j: &mut DMatrix<f64>) -> bool {
        j.fill(0.0);
        j[(0, 0)] = 1.0;
        j[(0, 1)] = 10.0;
        j[(1, 2)] = 5f64.sqrt();
        j[(1, 3)] = -5f64.sqrt();
        let a = x[1] - 2.0 * x[2];
        j[(2, 1)] = 2.0 * a;
        j[(2, 2)] = -4.0 * a;
        let b = x[0] - x[3];
        j[(3, 0)] = 2.0 * 10f64.sqrt() * b;
        j[(3, 3)] = -2.0 * 10f64.sqrt() * b;
        true
    }
}

/// Exponential fit y = a e^{−b t} + c to noiseless data; with a box that excludes the true b
/// the optimum sits on the bound.
struct ExpFit {
    t: Vec<f64>,
    y: Vec<f64>,
}

impl ExpFit {
    fn new() -> Self {
        let t: Vec<f64> = (0..30).map(|i| i as f64 * 0.2).collect();
        let y = t.iter().map(|t| 2.0 * (-1.3 * t).exp() + 0.5).collect();
        Self { t, y }
    }
}

impl LeastSquaresProblem for ExpFit {
    fn num_params(&self) -> usize {
        3
    }
    fn num_residuals(&self) -> usize {
        self.t.len()
    }
    fn residuals(&mut self, p: &[f64], r: &mut [f64]) {
        for (k, (t, y)) in self.t.iter().zip(&self.y).enumerate() {
            r[k] = p[0] * (-p[1] * t).exp() + p[2] - y;
        }
    }
}

#[test]
fn rosenbrock_converges_to_one_one() {
    for scaling in [DampingScaling::Diagonal, DampingScaling::Identity] {
        for analytic in [true, false] {
            let settings = LevenbergMarquardtSettings {
                scaling,
                ..Default::default()
            };
            let rep =
                levenberg_marquardt(&mut Rosenbrock { analytic }, &[-1.2, 1.0], None, &settings)
                    .unwrap();
            let err = ((rep.params[0] - 1.0).powi(2) + (rep.params[1] - 1.0).powi(2)).sqrt();
            println!(
                "Rosenbrock {scaling:?} analytic={analytic}: {:?} after {} iterations, |p − p*| = {err:.2e}, F = {:.2e}",
                rep.status, rep.iterations, rep.cost
            );
            assert!(rep.status.is_converged(), "{:?}", rep.status);
            assert!(err < 1e-8, "{err}");
        }
    }
}

#[test]
fn finite_differences_agree_with_analytic_jacobian() {
    let settings = LevenbergMarquardtSettings {
        max_iterations: 8,
        ..Default::default()
    };
    let exact = levenberg_marquardt(
        &mut Rosenbrock { analytic: true },
        &[-1.2, 1.0],
        None,
        &settings,
    )
    .unwrap();
    for fd in [FiniteDifference::Central, FiniteDifference::Forward] {
        let s = LevenbergMarquardtSettings {
            finite_difference: fd,
            ..settings
        };
        let approx =
            levenberg_marquardt(&mut Rosenbrock { analytic: false }, &[-1.2, 1.0], None, &s)
                .unwrap();
        let diff = exact
            .params
            .iter()
            .zip(&approx.params)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        println!("{fd:?}: iterate after 8 iterations differs by {diff:.2e}");
        assert!(diff < 1e-5, "{fd:?}: {diff}");
        assert_eq!(exact.iterations, approx.iterations);
    }
}

#[test]
fn powell_singular_reaches_zero_despite_singular_jacobian() {
    // Default settings stop on the gradient test (‖Jᵀr‖∞ ≤ 1e-12); F ~ |x|⁴ there.
    let rep = levenberg_marquardt(
        &mut PowellSingular,
        &[3.0, -1.0, 0.0, 1.0],
        None,
        &Default::default(),
    )
    .unwrap();
    let xnorm = rep.params.iter().map(|v| v * v).sum::<f64>().sqrt();
    println!(
        "Powell singular (defaults): {:?} after {} iterations, F = {:.2e}, |x| = {xnorm:.2e}",
        rep.status, rep.iterations, rep.cost
    );
    assert!(rep.status.is_converged(), "{:?}", rep.status);
    assert!(rep.cost < 1e-16, "{}", rep.cost);
    assert!(xnorm < 1e-3, "{xnorm}");
    // Slow (linear) convergence continues when the default tests are switched off.
    let settings = LevenbergMarquardtSettings {
        gradient_tolerance: 0.0,
        step_tolerance: 0.0,
        relative_cost_tolerance: 0.0,
        cost_tolerance: 1e-40,
        max_iterations: 500,
        ..Default::default()
    };
    let rep =
        levenberg_marquardt(&mut PowellSingular, &[3.0, -1.0, 0.0, 1.0], None, &settings).unwrap();
    let xnorm = rep.params.iter().map(|v| v * v).sum::<f64>().sqrt();
    println!(
        "Powell singular (cost ≤ 1e-40): {:?} after {} iterations, F = {:.2e}, |x| = {xnorm:.2e}",
        rep.status, rep.iterations, rep.cost
    );
    // It stops either on F ≤ 1e-40 or when Jᵀr underflows to exactly 0 (gradient test with 0).
    assert!(rep.status.is_converged(), "{:?}", rep.status);
    assert!(rep.cost < 1e-30, "{}", rep.cost);
    assert!(xnorm < 1e-8, "{xnorm}");
}

#[test]
fn bounded_optimum_on_the_bound() {
    // Unconstrained optimum b = 1.3; box b ≤ 1.0 forces the fit onto the bound.
    let bounds = Bounds::new(vec![0.0, 0.1, -10.0], vec![10.0, 1.0, 10.0]).unwrap();
    let rep = levenberg_marquardt(
        &mut ExpFit::new(),
        &[1.0, 0.5, 0.0],
        Some(&bounds),
        &Default::default(),
    )
    .unwrap();
    println!(
        "bounded: {:?} p = {:?} after {} iterations",
        rep.status, rep.params, rep.iterations
    );
    assert!(rep.status.is_converged(), "{:?}", rep.status);
    assert_eq!(rep.params[1], 1.0);
    // KKT check: with b fixed at 1.0 the remaining (a, c) are a linear least-squares fit;
    // compare with the normal-equation solution, and the gradient in b points out of the box.
    let mut prob = ExpFit::new();
    let (mut saa, mut sac, mut scc, mut say, mut scy) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for (t, y) in prob.t.iter().zip(&prob.y) {
        let e = (-t).exp();
        saa += e * e;
        sac += e;
        scc += 1.0;
        say += e * y;
        scy += y;
    }
    let det = saa * scc - sac * sac;
    let a = (say * scc - sac * scy) / det;
    let c = (saa * scy - sac * say) / det;
    assert!(
        (rep.params[0] - a).abs() < 1e-8 && (rep.params[2] - c).abs() < 1e-8,
        "{:?} vs {a} {c}",
        rep.params
    );
    let mut r = vec![0.0; 30];
    prob.residuals(&rep.params, &mut r);
    let dfdb: f64 = prob
        .t
        .iter()
        .zip(&r)
        .map(|(t, r)| r * (-rep.params[0] * t * (-rep.params[1] * t).exp()))
        .sum();
    assert!(
        dfdb < 0.0,
        "descent direction −∂F/∂b must point above the upper bound: {dfdb}"
    );
    // Unbounded, the true parameters are recovered.
    let free = levenberg_marquardt(
        &mut ExpFit::new(),
        &[1.0, 0.5, 0.0],
        None,
        &Default::default(),
    )
    .unwrap();
    let err = (free.params[0] - 2.0)
        .abs()
        .max((free.params[1] - 1.3).abs())
        .max((free.params[2] - 0.5).abs());
    assert!(err < 1e-8, "{:?}", free.params);
}

#[test]
fn capped_run_reports_max_iterations() {
    let settings = LevenbergMarquardtSettings {
        max_iterations: 3,
        ..Default::default()
    };
    let rep = levenberg_marquardt(
        &mut Rosenbrock { analytic: true },
        &[-1.2, 1.0],
        None,
        &settings,
    )
    .unwrap();
    assert_eq!(rep.status, SolverStatus::MaxIterations);
    assert_eq!(rep.iterations, 3);
    assert_eq!(rep.cost_history.len(), 4);
    assert!(rep.cost < rep.cost_history[0]);
}

#[test]
fn cost_tolerance_is_reported_as_reason() {
    let settings = LevenbergMarquardtSettings {
        cost_tolerance: 1e-6,
        ..Default::default()
    };
    let rep =
        levenberg_marquardt(&mut PowellSingular, &[3.0, -1.0, 0.0, 1.0], None, &settings).unwrap();
    assert_eq!(
        rep.status,
        SolverStatus::Converged {
            reason: ConvergenceReason::Cost
        }
    );
    assert!(rep.cost <= 1e-6);
}

struct NanAtStart;
impl LeastSquaresProblem for NanAtStart {
    fn num_params(&self) -> usize {
        1
    }
    fn num_residuals(&self) -> usize {
        1
    }
    fn residuals(&mut self, p: &[f64], r: &mut [f64]) {
        r[0] = if p[0] > 0.0 { p[0].ln() } else { f64::NAN };
    }
}

#[test]
fn non_finite_start_and_trial_points_are_reported_not_panics() {
    let rep = levenberg_marquardt(&mut NanAtStart, &[-1.0], None, &Default::default()).unwrap();
    assert_eq!(rep.status, SolverStatus::NonFinite);
    // From p = 3 the Gauss–Newton step of ln p overshoots below 0 (NaN): LM must reject it,
    // damp, and still converge to p = 1.
    let rep = levenberg_marquardt(&mut NanAtStart, &[30.0], None, &Default::default()).unwrap();
    assert!(rep.status.is_converged(), "{:?}", rep.status);
    assert!((rep.params[0] - 1.0).abs() < 1e-10, "{:?}", rep.params);
}

#[test]
fn invalid_input_is_an_error() {
    assert!(
        levenberg_marquardt(&mut PowellSingular, &[1.0, 2.0], None, &Default::default()).is_err()
    );
    assert!(Bounds::new(vec![1.0], vec![0.0]).is_err());
    let bounds = Bounds::unbounded(3);
    assert!(
        levenberg_marquardt(
            &mut PowellSingular,
            &[1.0; 4],
            Some(&bounds),
            &Default::default()
        )
        .is_err()
    );
}

/// A large linear-in-parameters problem supplied through the normal-equations path
/// (JᵀJ and Jᵀr directly, as an adjoint fitter would): a smoothing problem with n = 1500
/// parameters whose exact solution is known.
struct Smoothing {
    n: usize,
    target: Vec<f64>,
    normal_path_calls: usize,
}

impl LeastSquaresProblem for Smoothing {
    fn num_params(&self) -> usize {
        self.n
    }
    fn num_residuals(&self) -> usize {
        2 * self.n - 1
    }
    fn residuals(&mut self, p: &[f64], r: &mut [f64]) {
        // data term p_i − t_i, smoothness term 3 (p_{i+1} − p_i)
        for i in 0..self.n {
            r[i] = p[i] - self.target[i];
        }
        for i in 0..self.n - 1 {
            r[self.n + i] = 3.0 * (p[i + 1] - p[i]);
        }
    }
    fn normal_equations(
        &mut self,
        _p: &[f64],
        r: &[f64],
        jtj: &mut Mat<f64>,
        jtr: &mut [f64],
    ) -> bool {
        self.normal_path_calls += 1;
        let n = self.n;
        for j in 0..n {
            for i in 0..n {
                jtj[(i, j)] = 0.0;
            }
        }
        jtr[..n].copy_from_slice(&r[..n]);
        for i in 0..n {
            jtj[(i, i)] += 1.0;
        }
        for i in 0..n - 1 {
            // residual 3 (p_{i+1} − p_i): row has −3 at i and +3 at i+1
            jtj[(i, i)] += 9.0;
            jtj[(i + 1, i + 1)] += 9.0;
            jtj[(i, i + 1)] -= 9.0;
            jtj[(i + 1, i)] -= 9.0;
            jtr[i] -= 3.0 * r[n + i];
            jtr[i + 1] += 3.0 * r[n + i];
        }
        true
    }
}

#[test]
fn large_problem_through_normal_equations_path() {
    let n = 1500;
    let target: Vec<f64> = (0..n)
        .map(|i| ((i as f64) * 0.01).sin() + if i % 7 == 0 { 0.5 } else { 0.0 })
        .collect();
    let mut prob = Smoothing {
        n,
        target,
        normal_path_calls: 0,
    };
    let rep = levenberg_marquardt(&mut prob, &vec![0.0; n], None, &Default::default()).unwrap();
    assert!(rep.status.is_converged(), "{:?}", rep.status);
    assert!(prob.normal_path_calls >= 1);
    // The optimum satisfies (I + 9 L) p = t; check the gradient directly.
    let mut r = vec![0.0; 2 * n - 1];
    prob.residuals(&rep.params, &mut r);
    let mut jtj = Mat::<f64>::zeros(n, n);
    let mut g = vec![0.0; n];
    prob.normal_equations(&rep.params, &r, &mut jtj, &mut g);
    let gmax = g.iter().fold(0.0f64, |a, v| a.max(v.abs()));
    println!(
        "n = {n}: {:?} after {} iterations, max |Jᵀr| = {gmax:.2e}",
        rep.status, rep.iterations
    );
    assert!(gmax < 1e-9, "{gmax}");
}

/// y = a e^{−b t} + c + noise (a fixed pseudo-random draw of σ = 0.01), analytic Jacobian.
struct NoisyExp {
    t: Vec<f64>,
    y: Vec<f64>,
    evaluations: usize,
}

impl NoisyExp {
    fn new() -> Self {
        let t: Vec<f64> = (0..400).map(|i| i as f64 * 0.02).collect();
        let mut state = 12345u64;
        let y = t
            .iter()
            .map(|t| {
                // Sum of 12 uniforms − 6: near-normal, unit variance.
                let g: f64 = (0..12)
                    .map(|_| {
                        state = state
                            .wrapping_mul(6364136223846793005)
                            .wrapping_add(1442695040888963407);
                        (state >> 11) as f64 / (1u64 << 53) as f64
                    })
                    .sum::<f64>()
                    - 6.0;
                2.0 * (-1.3 * t).exp() + 0.5 + 0.01 * g
            })
            .collect();
        Self {
            t,
            y,
            evaluations: 0,
        }
    }
}

impl LeastSquaresProblem for NoisyExp {
    fn num_params(&self) -> usize {
        3
    }
    fn num_residuals(&self) -> usize {
        self.t.len()
    }
    fn residuals(&mut self, p: &[f64], r: &mut [f64]) {
        self.evaluations += 1;
        for (k, (t, y)) in self.t.iter().zip(&self.y).enumerate() {
            r[k] = p[0] * (-p[1] * t).exp() + p[2] - y;
        }
    }
    fn jacobian(&mut self, p: &[f64], j: &mut DMatrix<f64>) -> bool {
        for (k, t) in self.t.iter().enumerate() {
            let e = (-p[1] * t).exp();
            j[(k, 0)] = e;
            j[(k, 1)] = -p[0] * t * e;
            j[(k, 2)] = 1.0;
        }
        true
    }
}

/// `predicted_cost_tolerance` = δ²/(m − n) stops a noisy fit once the Gauss–Newton step left
/// is below δ standard deviations of the parameters (s² (JᵀJ)⁻¹): with fewer residual
/// evaluations than the fit run to its tightest tolerances, and every parameter within δ σ of
/// that fit's optimum (δ = 0.3; the far start takes several steps). Checked to fail: without
/// the criterion the status is `RelativeCost`/`Step` after more evaluations; with ½ gᵀ(JᵀJ)⁻¹g
/// replaced by the damped step's predicted decrease it stops farther away.
#[test]
fn predicted_cost_tolerance_stops_below_the_resolution_of_the_data() {
    let start = [1.0, 0.5, 0.0];
    let mut tight = NoisyExp::new();
    let reference = levenberg_marquardt(
        &mut tight,
        &start,
        None,
        &LevenbergMarquardtSettings::default(),
    )
    .unwrap();
    assert!(reference.status.is_converged(), "{:?}", reference.status);
    let (m, n) = (tight.t.len(), 3);
    let p = &reference.params;
    let mut j = DMatrix::<f64>::zeros(m, n);
    tight.jacobian(p, &mut j);
    let s2 = 2.0 * reference.cost / (m - n) as f64;
    let cov = (j.transpose() * &j).try_inverse().unwrap() * s2;
    let delta = 0.3;
    let mut coarse = NoisyExp::new();
    let r = levenberg_marquardt(
        &mut coarse,
        &start,
        None,
        &LevenbergMarquardtSettings {
            predicted_cost_tolerance: delta * delta / (m - n) as f64,
            ..LevenbergMarquardtSettings::default()
        },
    )
    .unwrap();
    assert_eq!(
        r.status,
        SolverStatus::Converged {
            reason: ConvergenceReason::PredictedCost
        }
    );
    assert!(
        coarse.evaluations < tight.evaluations,
        "{} vs {} evaluations",
        coarse.evaluations,
        tight.evaluations
    );
    for k in 0..n {
        let sigma = cov[(k, k)].sqrt();
        let off = (r.params[k] - p[k]).abs() / sigma;
        eprintln!(
            "parameter {k}: {off:.3} σ off the tight fit ({} vs {} evaluations)",
            coarse.evaluations, tight.evaluations
        );
        assert!(off <= delta, "parameter {k}: {off:.3} σ");
    }
}
