//! Seeded k-means / k-medoids (thesis §8.3) and uniform cubic B-spline fitting (thesis §4.3.1).

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use softcap_core::{
    BSplineFitSettings, KMeansSettings, UniformCubicBSpline, fit_uniform_cubic_bspline, kmeans,
    kmedoids,
};

/// Three well-separated Gaussian blobs in 3-D (σ = 0.3, centres ≥ 5 apart), 60 points each.
fn blobs(seed: u64) -> (Vec<f64>, Vec<usize>) {
    let centres = [[0.0, 0.0, 0.0], [5.0, 1.0, -2.0], [-3.0, 6.0, 2.0]];
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let noise = Normal::new(0.0, 0.3).unwrap();
    let mut pts = Vec::new();
    let mut labels = Vec::new();
    for i in 0..180 {
        let c = i % 3;
        for j in 0..3 {
            pts.push(centres[c][j] + noise.sample(&mut rng));
        }
        labels.push(c);
    }
    (pts, labels)
}

/// True when `a` and `b` are the same partition up to relabelling.
fn same_partition(a: &[usize], b: &[usize]) -> bool {
    let mut map = std::collections::BTreeMap::new();
    let mut inv = std::collections::BTreeMap::new();
    a.iter()
        .zip(b)
        .all(|(x, y)| *map.entry(*x).or_insert(*y) == *y && *inv.entry(*y).or_insert(*x) == *x)
}

#[test]
fn kmeans_separates_seeded_clusters_deterministically() {
    let (pts, labels) = blobs(21);
    let settings = KMeansSettings {
        seed: 7,
        ..Default::default()
    };
    let a = kmeans(&pts, 3, 3, &settings).unwrap();
    assert!(a.converged);
    assert!(
        same_partition(&a.assignments, &labels),
        "clusters not recovered"
    );
    // Inertia ≈ n · d · σ² = 180 · 3 · 0.09 = 48.6 (within 25%).
    println!(
        "k-means inertia {:.2} (expected ≈ 48.6), {} iterations",
        a.inertia, a.iterations
    );
    assert!((a.inertia - 48.6).abs() < 0.25 * 48.6, "{}", a.inertia);
    let b = kmeans(&pts, 3, 3, &settings).unwrap();
    assert_eq!(a, b, "same seed must give identical output");
    // Another seed finds the same partition on such well-separated data.
    let c = kmeans(
        &pts,
        3,
        3,
        &KMeansSettings {
            seed: 99,
            ..Default::default()
        },
    )
    .unwrap();
    assert!(same_partition(&a.assignments, &c.assignments));
    assert!(
        kmeans(&pts[..6], 3, 3, &settings).is_err(),
        "k > n is an error"
    );
}

#[test]
fn kmedoids_with_custom_dissimilarity_separates_clusters() {
    let (pts, labels) = blobs(22);
    // Squared Euclidean distance as the "sum of squared displacement differences" of eq. 8.4.
    let d = |i: usize, j: usize| {
        (0..3)
            .map(|k| (pts[i * 3 + k] - pts[j * 3 + k]).powi(2))
            .sum::<f64>()
    };
    let settings = KMeansSettings {
        seed: 3,
        ..Default::default()
    };
    let r = kmedoids(180, 3, d, &settings).unwrap();
    assert!(r.converged);
    assert!(same_partition(&r.assignments, &labels));
    for (c, &m) in r.medoids.iter().enumerate() {
        assert_eq!(r.assignments[m], c, "a medoid belongs to its own cluster");
    }
    assert_eq!(r, kmedoids(180, 3, d, &settings).unwrap());
}

fn cubic(t: f64) -> [f64; 2] {
    [
        1.0 - 2.0 * t + 0.5 * t * t - 0.3 * t * t * t,
        4.0 + t * t * t,
    ]
}

#[test]
fn bspline_fit_reproduces_a_cubic_exactly() {
    let ts: Vec<f64> = (0..50).map(|i| -1.0 + 3.0 * i as f64 / 49.0).collect();
    let ys: Vec<f64> = ts.iter().flat_map(|&t| cubic(t)).collect();
    let w: Vec<f64> = (0..50).map(|i| 0.5 + (i % 5) as f64).collect();
    for n in [4, 5, 8, 12] {
        let settings = BSplineFitSettings {
            num_control_points: n,
            ..Default::default()
        };
        let spline = fit_uniform_cubic_bspline(&ts, &ys, 2, Some(&w), &settings).unwrap();
        let mut err: f64 = 0.0;
        let mut derr: f64 = 0.0;
        for i in 0..200 {
            let t = -1.0 + 3.0 * i as f64 / 199.0;
            let v = spline.evaluate(t);
            let want = cubic(t);
            err = err.max((v[0] - want[0]).abs()).max((v[1] - want[1]).abs());
            let dv = spline.derivative(t);
            let dwant = [-2.0 + t - 0.9 * t * t, 3.0 * t * t];
            derr = derr
                .max((dv[0] - dwant[0]).abs())
                .max((dv[1] - dwant[1]).abs());
            let ddv = spline.second_derivative(t);
            derr = derr
                .max((ddv[0] - (1.0 - 1.8 * t)).abs())
                .max((ddv[1] - 6.0 * t).abs());
        }
        println!("n = {n}: cubic reproduction max error {err:.2e}, derivatives {derr:.2e}");
        assert!(err < 1e-11 && derr < 1e-9, "n={n}: {err} {derr}");
    }
}

#[test]
fn bspline_fit_of_noisy_curve_is_within_noise() {
    // A wrinkle-valley-like curve sampled at 400 pixels with σ = 0.5 px noise, 10 control points.
    let truth = |t: f64| [t, 20.0 + 8.0 * (t / 25.0).sin() + 0.002 * t * t];
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let noise = Normal::new(0.0, 0.5).unwrap();
    let ts: Vec<f64> = (0..400).map(|i| i as f64 * 0.25).collect();
    let ys: Vec<f64> = ts
        .iter()
        .flat_map(|&t| truth(t).map(|v| v + noise.sample(&mut rng)))
        .collect();
    let settings = BSplineFitSettings {
        num_control_points: 10,
        ..Default::default()
    };
    let spline = fit_uniform_cubic_bspline(&ts, &ys, 2, None, &settings).unwrap();
    let rms = (ts
        .iter()
        .map(|&t| {
            let v = spline.evaluate(t);
            let w = truth(t);
            (v[0] - w[0]).powi(2) + (v[1] - w[1]).powi(2)
        })
        .sum::<f64>()
        / ts.len() as f64)
        .sqrt();
    // LS with p = 10 coefficients per coordinate averages noise: expected RMS ≈ σ √(2p/N) ≈ 0.11.
    println!("noisy fit: RMS error to the true curve {rms:.3} px (noise σ = 0.5 px)");
    assert!(rms < 0.2, "{rms}");
}

#[test]
fn bspline_input_errors_and_smoothing() {
    // Two samples cannot determine 6 control points …
    let s = BSplineFitSettings {
        num_control_points: 6,
        ..Default::default()
    };
    assert!(fit_uniform_cubic_bspline(&[0.0, 1.0], &[0.0, 1.0], 1, None, &s).is_err());
    // … unless the smoothing term fills the gap; then the fit is a straight line through them.
    let s = BSplineFitSettings {
        num_control_points: 6,
        smoothing: 1e-3,
        ..Default::default()
    };
    let sp = fit_uniform_cubic_bspline(&[0.0, 1.0], &[0.0, 1.0], 1, None, &s).unwrap();
    assert!(
        (sp.evaluate(0.5)[0] - 0.5).abs() < 1e-9,
        "{}",
        sp.evaluate(0.5)[0]
    );
    assert!(fit_uniform_cubic_bspline(&[0.0, 1.0], &[0.0], 1, None, &s).is_err());
    assert!(
        fit_uniform_cubic_bspline(&[0.0, 1.0], &[0.0, 1.0], 1, Some(&[1.0, -1.0]), &s).is_err()
    );
    assert!(
        UniformCubicBSpline::new(vec![0.0; 6], 2, 0.0, 1.0).is_err(),
        "3 control points"
    );
    assert!(
        UniformCubicBSpline::new(vec![0.0; 8], 2, 1.0, 1.0).is_err(),
        "empty domain"
    );
}
