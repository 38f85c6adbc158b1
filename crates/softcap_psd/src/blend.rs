//! Blend-shape baselines of thesis §5.5.1: global blend shapes (one convex weight vector per
//! pose, matched in the feature space of §5.4.1) and local blend shapes (per-vertex convex
//! weights matched with the weighted metric of eq. 5.3).

use crate::graph::EdgeWeights;
use nalgebra::Vector3;
use rayon::prelude::*;

/// Convex weights `c` (c ≥ 0, Σc = 1) minimising `Σ_i a_i (Σ_j c_j F[j][i] − f_i)²`, i.e.
/// `½ cᵀGc − bᵀc` with `G = F diag(a) Fᵀ`, `b = F diag(a) f`: accelerated projected gradient
/// (FISTA) on the simplex, `iterations` steps of size 1/‖G‖_∞ (a bound on λ_max).
pub fn simplex_least_squares(g: &[f64], b: &[f64], p: usize, iterations: usize, out: &mut [f64]) {
    let lip = (0..p).map(|i| (0..p).map(|j| g[i * p + j].abs()).sum::<f64>()).fold(0.0, f64::max);
    out[..p].fill(1.0 / p as f64);
    if lip <= 0.0 || p == 1 {
        return;
    }
    let step = 1.0 / lip;
    let mut y = out[..p].to_vec();
    let mut prev = y.clone();
    let mut grad = vec![0.0; p];
    let mut tk = 1.0f64;
    for _ in 0..iterations {
        for i in 0..p {
            grad[i] = (0..p).map(|j| g[i * p + j] * y[j]).sum::<f64>() - b[i];
        }
        let mut z: Vec<f64> = (0..p).map(|i| y[i] - step * grad[i]).collect();
        project_simplex(&mut z);
        let tn = 0.5 * (1.0 + (1.0 + 4.0 * tk * tk).sqrt());
        for i in 0..p {
            y[i] = z[i] + (tk - 1.0) / tn * (z[i] - prev[i]);
        }
        prev.copy_from_slice(&z);
        tk = tn;
    }
    out[..p].copy_from_slice(&prev);
}

/// Euclidean projection onto the probability simplex (sort-based, Held et al. 1974).
pub fn project_simplex(x: &mut [f64]) {
    let mut s: Vec<f64> = x.to_vec();
    s.sort_by(|a, b| b.total_cmp(a));
    let mut cum = 0.0;
    let mut theta = 0.0;
    for (k, v) in s.iter().enumerate() {
        cum += v;
        let t = (cum - 1.0) / (k + 1) as f64;
        if v - t > 0.0 {
            theta = t;
        }
    }
    for v in x.iter_mut() {
        *v = (*v - theta).max(0.0);
    }
}

/// Global blend shapes: `x = Σ_j c_j x_j` with one convex `c` fitted in feature space.
pub fn global_blend(
    basis_positions: &[&[Vector3<f64>]],
    basis_features: &[&[f64]],
    f: &[f64],
    iterations: usize,
) -> Vec<Vector3<f64>> {
    let p = basis_positions.len();
    let mut g = vec![0.0; p * p];
    let mut b = vec![0.0; p];
    for i in 0..p {
        b[i] = basis_features[i].iter().zip(f).map(|(x, y)| x * y).sum();
        for j in 0..p {
            g[i * p + j] = basis_features[i].iter().zip(basis_features[j]).map(|(x, y)| x * y).sum();
        }
    }
    let mut c = vec![0.0; p];
    simplex_least_squares(&g, &b, p, iterations, &mut c);
    let n = basis_positions[0].len();
    (0..n).map(|v| (0..p).map(|j| c[j] * basis_positions[j][v]).sum()).collect()
}

/// Local blend shapes: per vertex `x_v = Σ_j c_{v,j} x_{j,v}` with convex `c_v` fitted under
/// the weighted feature metric of eq. 5.3 (only the ≤16 edges the vertex sees).
pub fn local_blend(
    basis_positions: &[&[Vector3<f64>]],
    basis_features: &[&[f64]],
    edge_weights: &EdgeWeights,
    f: &[f64],
    iterations: usize,
) -> Vec<Vector3<f64>> {
    let p = basis_positions.len();
    let n = basis_positions[0].len();
    (0..n)
        .into_par_iter()
        .map(|v| {
            let (ids, al) = edge_weights.row(v);
            let mut g = vec![0.0; p * p];
            let mut b = vec![0.0; p];
            for (&i, &a) in ids.iter().zip(al) {
                if a == 0.0 {
                    continue;
                }
                let (i, a) = (i as usize, a as f64);
                for j in 0..p {
                    let fj = basis_features[j][i];
                    b[j] += a * fj * f[i];
                    for k in 0..p {
                        g[j * p + k] += a * fj * basis_features[k][i];
                    }
                }
            }
            let mut c = vec![0.0; p];
            simplex_least_squares(&g, &b, p, iterations, &mut c);
            (0..p).map(|j| c[j] * basis_positions[j][v]).sum()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn simplex_fit_recovers_convex_weights() {
        // features of 3 shapes in 4-D; target is 0.2/0.5/0.3 of them
        let fs = [[1.0, 0.0, 0.2, 0.0], [0.0, 1.0, 0.1, 0.3], [0.3, 0.2, 1.0, -0.4]];
        let want = [0.2, 0.5, 0.3];
        let f: Vec<f64> = (0..4).map(|i| (0..3).map(|j| want[j] * fs[j][i]).sum()).collect();
        let mut g = vec![0.0; 9];
        let mut b = vec![0.0; 3];
        for i in 0..3 {
            b[i] = (0..4).map(|k| fs[i][k] * f[k]).sum();
            for j in 0..3 {
                g[i * 3 + j] = (0..4).map(|k| fs[i][k] * fs[j][k]).sum();
            }
        }
        let mut c = [0.0; 3];
        simplex_least_squares(&g, &b, 3, 2000, &mut c);
        for j in 0..3 {
            assert!((c[j] - want[j]).abs() < 1e-6, "{c:?}");
        }
        let mut x = [0.9, 0.8, -2.0];
        project_simplex(&mut x);
        assert!((x[0] - 0.55).abs() < 1e-12 && (x[1] - 0.45).abs() < 1e-12 && x[2] == 0.0);
    }
}
