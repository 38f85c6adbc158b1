//! Property tests of the fitting kernels every material fit runs on (docs/reliability.md):
//! Levenberg–Marquardt, Gauss–Newton and Nelder–Mead on random exponential-decay fits
//! y = a e^{−b t} + c with random data, noise, outliers, start points and bounds. Every outcome
//! is a report with a status or an error — never a panic — and a reported fit has finite
//! parameters and cost. Case counts are CI-cheap (`PROPTEST_CASES` raises them).

use proptest::prelude::*;
use softcap_core::{
    Bounds, GaussNewtonSettings, LeastSquaresProblem, LevenbergMarquardtSettings,
    NelderMeadSettings, gauss_newton, levenberg_marquardt, nelder_mead,
};

#[derive(Debug, Clone)]
struct Decay {
    t: Vec<f64>,
    y: Vec<f64>,
}

impl Decay {
    fn cost(&self, p: &[f64]) -> f64 {
        let mut r = vec![0.0; self.t.len()];
        let mut me = Decay {
            t: self.t.clone(),
            y: self.y.clone(),
        };
        me.residuals(p, &mut r);
        0.5 * r.iter().map(|v| v * v).sum::<f64>()
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
        for ((r, t), y) in r.iter_mut().zip(&self.t).zip(&self.y) {
            *r = p[0] * (-p[1] * t).exp() + p[2] - y;
        }
    }
}

fn problem() -> impl Strategy<Value = (Decay, Vec<f64>, Option<Bounds>)> {
    (
        [-10.0f64..10.0, 0.0f64..20.0, -5.0f64..5.0],
        3usize..40,
        0.0f64..1.0,
        prop::collection::vec(-1.0f64..1.0, 40),
        [-50.0f64..50.0, -50.0f64..50.0, -50.0f64..50.0],
        any::<bool>(),
    )
        .prop_map(|(truth, m, noise, jitter, start, bounded)| {
            let t: Vec<f64> = (0..m).map(|i| i as f64 / m as f64).collect();
            let y = t
                .iter()
                .zip(&jitter)
                .map(|(t, j)| truth[0] * (-truth[1] * t).exp() + truth[2] + noise * j)
                .collect();
            let bounds = bounded
                .then(|| Bounds::new(vec![-20.0, 0.0, -10.0], vec![20.0, 30.0, 10.0]).unwrap());
            (Decay { t, y }, start.to_vec(), bounds)
        })
}

fn finite(v: &[f64]) -> bool {
    v.iter().all(|x| x.is_finite())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    #[test]
    fn least_squares_fits_report_finite_results_or_an_error(
        (mut p, start, bounds) in problem()
    ) {
        let start: Vec<f64> = match &bounds {
            Some(b) => start.iter().zip(b.lower.iter().zip(&b.upper)).map(|(s, (l, u))| s.clamp(*l, *u)).collect(),
            None => start,
        };
        if let Ok(r) = levenberg_marquardt(&mut p, &start, bounds.as_ref(), &LevenbergMarquardtSettings::default()) {
            prop_assert!(finite(&r.params) && r.cost.is_finite(), "LM {:?}: {:?} cost {}", r.status, r.params, r.cost);
            prop_assert!(r.cost <= p.cost(&start) + 1e-12, "LM made the fit worse");
        }
        if let Ok(r) = gauss_newton(&mut p, &start, bounds.as_ref(), &GaussNewtonSettings::default()) {
            prop_assert!(finite(&r.params) && r.cost.is_finite(), "GN {:?}: {:?} cost {}", r.status, r.params, r.cost);
        }
        let cost = |q: &[f64]| p.cost(q);
        if let Ok(r) = nelder_mead(cost, &start, bounds.as_ref(), &NelderMeadSettings::default()) {
            prop_assert!(finite(&r.params), "NM {:?}: {:?}", r.status, r.params);
        }
    }
}
