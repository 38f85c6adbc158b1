//! Blend-shape baselines of thesis §5.5.1: global blend shapes (one convex weight vector per
//! pose, fitted to the marker positions) and local blend shapes (convex marker fits per handle
//! region under the locally supported kernel of eq. 5.4, blended smoothly to the vertices).

use crate::graph::EdgeWeights;
use nalgebra::Vector3;

/// Convex weights `c` (c ≥ 0, Σc = 1) minimising `Σ_i a_i (Σ_j c_j F[j][i] − f_i)²`, i.e.
/// `½ cᵀGc − bᵀc` with `G = F diag(a) Fᵀ`, `b = F diag(a) f`: accelerated projected gradient
/// (FISTA) on the simplex, `iterations` steps of size 1/‖G‖_∞ (a bound on λ_max).
pub fn simplex_least_squares(g: &[f64], b: &[f64], p: usize, iterations: usize, out: &mut [f64]) {
    let lip = (0..p)
        .map(|i| (0..p).map(|j| g[i * p + j].abs()).sum::<f64>())
        .fold(0.0, f64::max);
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

/// Normal equations of `min_c Σ_h κ_h ‖Σ_j c_j u_{h,j} − u_h‖²` (marker-position fit).
fn marker_normal_equations(
    basis_handles: &[&[Vector3<f64>]],
    target: &[Vector3<f64>],
    kappa: &[f64],
) -> (Vec<f64>, Vec<f64>) {
    let p = basis_handles.len();
    let mut g = vec![0.0; p * p];
    let mut b = vec![0.0; p];
    for (h, (&k, t)) in kappa.iter().zip(target).enumerate() {
        if k == 0.0 {
            continue;
        }
        for i in 0..p {
            let ui = basis_handles[i][h];
            b[i] += k * ui.dot(t);
            for j in 0..p {
                g[i * p + j] += k * ui.dot(&basis_handles[j][h]);
            }
        }
    }
    (g, b)
}

/// Global blend shapes (thesis §5.5.1): one convex weight vector `c` that best matches the
/// marker (handle) positions, `x = Σ_j c_j x_j`.
///
/// `basis_handles[j]` / `target_handles` are handle positions relative to the rest pose.
pub fn global_blend(
    basis_positions: &[&[Vector3<f64>]],
    basis_handles: &[&[Vector3<f64>]],
    target_handles: &[Vector3<f64>],
    iterations: usize,
) -> Vec<Vector3<f64>> {
    let p = basis_positions.len();
    let (g, b) = marker_normal_equations(
        basis_handles,
        target_handles,
        &vec![1.0; target_handles.len()],
    );
    let mut c = vec![0.0; p];
    simplex_least_squares(&g, &b, p, iterations, &mut c);
    let n = basis_positions[0].len();
    (0..n)
        .map(|v| (0..p).map(|j| c[j] * basis_positions[j][v]).sum())
        .collect()
}

/// Local blend shapes (thesis §5.5.1): one convex marker fit per handle region, with the markers
/// weighted by the locally supported kernel of eq. 5.4 seen from that handle
/// (`κ_h' = Σ_{i ∋ h'} α_{h,i} / 2`), blended smoothly to every vertex with its own edge
/// weights: `c_v = Σ_i α_{v,i} (c_{i,1} + c_{i,2}) / 2`, `x_v = Σ_j c_{v,j} x_{j,v}` — a smooth
/// version of region-segmented blend shapes.
pub fn local_blend(
    basis_positions: &[&[Vector3<f64>]],
    basis_handles: &[&[Vector3<f64>]],
    target_handles: &[Vector3<f64>],
    handles: &[usize],
    graph_edges: &[[usize; 2]],
    edge_weights: &EdgeWeights,
    iterations: usize,
) -> Vec<Vector3<f64>> {
    let p = basis_positions.len();
    let hn = handles.len();
    let mut region = vec![0.0; hn * p];
    for (h, &v) in handles.iter().enumerate() {
        let mut kappa = vec![0.0; hn];
        let (ids, al) = edge_weights.row(v);
        for (&i, &a) in ids.iter().zip(al) {
            for &e in &graph_edges[i as usize] {
                kappa[e] += 0.5 * a as f64;
            }
        }
        let (g, b) = marker_normal_equations(basis_handles, target_handles, &kappa);
        simplex_least_squares(&g, &b, p, iterations, &mut region[h * p..(h + 1) * p]);
    }
    let n = basis_positions[0].len();
    (0..n)
        .map(|v| {
            let (ids, al) = edge_weights.row(v);
            let mut x = Vector3::zeros();
            for (&i, &a) in ids.iter().zip(al) {
                if a == 0.0 {
                    continue;
                }
                for &e in &graph_edges[i as usize] {
                    for j in 0..p {
                        x += (0.5 * a as f64 * region[e * p + j]) * basis_positions[j][v];
                    }
                }
            }
            x
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn simplex_fit_recovers_convex_weights() {
        // features of 3 shapes in 4-D; target is 0.2/0.5/0.3 of them
        let fs = [
            [1.0, 0.0, 0.2, 0.0],
            [0.0, 1.0, 0.1, 0.3],
            [0.3, 0.2, 1.0, -0.4],
        ];
        let want = [0.2, 0.5, 0.3];
        let f: Vec<f64> = (0..4)
            .map(|i| (0..3).map(|j| want[j] * fs[j][i]).sum())
            .collect();
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
