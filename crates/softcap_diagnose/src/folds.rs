//! Fold statistics of the held-out errors: per probe location (fold), the fraction of the default
//! model's mean-square error a model explains; its mean and fold-to-fold spread; the confidence of
//! a named effect; whether two models' gains can be told apart on the data.
//!
//! A model's *fold gain* on location l is g_l = 1 − RSS_l(model) / RSS_l(default), both on the
//! same scored observations of l (held out: the model was fitted without l). Gains of different
//! hypotheses are comparable although each is scored on its own cells.

/// Per-fold gains 1 − after/before of the folds with scored observations (`before`, `after`: RSS
/// per fold on the same observations).
pub fn fold_gains(before_rss: &[f64], after_rss: &[f64]) -> Vec<f64> {
    before_rss
        .iter()
        .zip(after_rss)
        .filter(|(b, _)| **b > 0.0)
        .map(|(b, a)| 1.0 - a / b)
        .collect()
}

/// Mean and sample standard deviation (0 for fewer than two values).
pub fn mean_sd(x: &[f64]) -> (f64, f64) {
    if x.is_empty() {
        return (0.0, 0.0);
    }
    let n = x.len() as f64;
    let mean = x.iter().sum::<f64>() / n;
    if x.len() < 2 {
        return (mean, 0.0);
    }
    let var = x.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, var.sqrt())
}

/// The confidence that the gain a model brings exceeds `threshold` (the naming threshold,
/// `min_heldout_gain`): Φ((ḡ − threshold) / (s / √L)) over the L fold gains (normal approximation
/// of the mean's sampling spread; s floored at 0.02 so that L nearly equal gains do not claim
/// certainty). 0 without folds.
pub fn confidence(gains: &[f64], threshold: f64) -> f64 {
    if gains.is_empty() {
        return 0.0;
    }
    let (mean, sd) = mean_sd(gains);
    let se = sd.max(0.02) / (gains.len() as f64).sqrt();
    normal_cdf((mean - threshold) / se)
}

/// Two models can be told apart on the data when the mean of their paired fold-gain differences
/// exceeds the fold-to-fold spread of those differences (`a` and `b` per fold, same folds): issue
/// 37's "held-out errors within the fold-to-fold spread", as written. On L folds |d̄| > s is a
/// paired t-test at t = d̄ / (s/√L) > √L: 2 standard errors at the in-memory rig's 4 locations
/// (the z of the signatures' rules, `signatures::DELAY_GROWTH_Z`), 3 at 9. Two models that do
/// not differ pass it by chance in 14 % of sessions at L = 4 (Student's t, 3 degrees of freedom,
/// both signs) and 1.7 % at L = 9, if the folds were independent; leave-one-location-out folds
/// share training locations, which narrows the spread (Nadeau & Bengio 2003, Mach. Learn. 52):
/// at few locations this separates more often than that.
pub fn separable(a: &[f64], b: &[f64]) -> bool {
    let d: Vec<f64> = a.iter().zip(b).map(|(x, y)| x - y).collect();
    let (mean, sd) = mean_sd(&d);
    mean.abs() > sd
}

/// `a` removes more of the held-out error than `b` (fold gains on the same folds and
/// observations): the mean of their paired differences exceeds its fold-to-fold spread (the
/// one-sided [`separable`]).
pub fn outexplains(a: &[f64], b: &[f64]) -> bool {
    outexplains_by(a, b, 1.0)
}

/// `a` removes more of the held-out error than `b` by more than `spreads` fold-to-fold spreads:
/// the mean of their paired differences d̄ > `spreads` · s (on L folds a paired t above
/// `spreads` · √L; [`outexplains`] is `spreads` = 1).
pub fn outexplains_by(a: &[f64], b: &[f64], spreads: f64) -> bool {
    let d: Vec<f64> = a.iter().zip(b).map(|(x, y)| x - y).collect();
    let (mean, sd) = mean_sd(&d);
    mean > spreads * sd
}

/// The standard normal distribution function Φ(z) = ½ erfc(−z/√2). Hand-written (no special
/// function crate in the workspace for one call): erfc by Abramowitz & Stegun 7.1.26, absolute
/// error ≤ 1.5 × 10⁻⁷.
pub fn normal_cdf(z: f64) -> f64 {
    let x = z.abs() / std::f64::consts::SQRT_2;
    let t = 1.0 / (1.0 + 0.327_591_1 * x);
    let poly = t
        * (0.254_829_592
            + t * (-0.284_496_736
                + t * (1.421_413_741 + t * (-1.453_152_027 + t * 1.061_405_429))));
    let erfc = poly * (-x * x).exp();
    if z >= 0.0 {
        1.0 - 0.5 * erfc
    } else {
        0.5 * erfc
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normal_cdf_matches_known_values() {
        for (z, p) in [
            (0.0, 0.5),
            (1.0, 0.841_344_746),
            (-1.959_963_985, 0.025),
            (3.0, 0.998_650_102),
        ] {
            assert!(
                (normal_cdf(z) - p).abs() < 2e-7,
                "Φ({z}) = {}",
                normal_cdf(z)
            );
        }
    }

    #[test]
    fn gains_confidence_and_separability() {
        let g = fold_gains(&[4.0, 2.0, 0.0, 1.0], &[1.0, 0.5, 0.0, 0.25]);
        assert_eq!(g, vec![0.75, 0.75, 0.75]);
        // equal gains well above the threshold: the floored spread gives near certainty
        assert!(confidence(&g, 0.3) > 0.999);
        assert!((confidence(&[0.3, 0.3, 0.3], 0.3) - 0.5).abs() < 1e-6);
        assert!(confidence(&[], 0.3) == 0.0);
        // a consistent difference separates, a noisy one does not
        assert!(separable(&[0.9, 0.8, 0.85], &[0.5, 0.45, 0.55]));
        assert!(!separable(&[0.9, 0.2, 0.85], &[0.5, 0.8, 0.55]));
        // one-sided: only the first out-explains the second
        assert!(outexplains(&[0.9, 0.8, 0.85], &[0.5, 0.45, 0.55]));
        assert!(!outexplains(&[0.5, 0.45, 0.55], &[0.9, 0.8, 0.85]));
        // paired differences 0.4, 0.35, 0.3: mean 0.35, spread 0.05, seven spreads
        let (a, b) = ([0.9, 0.8, 0.85], [0.5, 0.45, 0.55]);
        assert!(outexplains_by(&a, &b, 6.9) && !outexplains_by(&a, &b, 7.1));
        assert!(!outexplains_by(&b, &a, 0.0));
    }
}
