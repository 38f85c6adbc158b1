//! The virtual forces of wang2015 eq. 5 as a node-level term of the implicit dynamic step
//! (`softcap_fem::NodalTerm`): with the responsibilities of the E-step fixed, the force on
//! sample k,
//!
//! f_k = η Σ_n p(z_kn) σ⁻² (c_n − s_k) = κ_k (ĉ_k − s_k),  κ_k = η W_k / σ²,
//!
//! is linear in s_k = Σ_a w_ka x_a, so it enters the Newton system exactly: node a receives
//! w_ka f_k and the matrix gets −∂f_a/∂x_b = κ_k w_ka w_kb I (mesh embedding, Kim & Pollard 2011:
//! forces go from the surface to the simulation nodes by the same weights that carry positions
//! back).

use nalgebra::{Matrix3, Vector3};
use softcap_fem::NodalTerm;

use super::samples::SurfaceSamples;

/// Springs κ_k towards ĉ_k on the samples with W_k > 0.
#[derive(Debug)]
pub struct VirtualForces<'a> {
    samples: &'a SurfaceSamples,
    /// (sample, κ_k [N/m], ĉ_k [m])
    springs: Vec<(usize, f64, Vector3<f64>)>,
    /// Σ_k κ_k w_ka² per node, and κ_k w_ka w_kb per node pair a < b (fixed while the
    /// responsibilities are), each ascending by node (pair), every sum in sample order.
    diagonal: Vec<(usize, f64)>,
    pairs: Vec<((usize, usize), f64)>,
}

impl<'a> VirtualForces<'a> {
    /// The term for stiffnesses `kappa` (one per sample, N/m) and targets (one per sample, m);
    /// samples with κ = 0 exert nothing.
    pub fn new(samples: &'a SurfaceSamples, kappa: &[f64], targets: &[Vector3<f64>]) -> Self {
        let mut springs = Vec::new();
        let mut diagonal = Vec::new();
        let mut pairs = Vec::new();
        for k in 0..samples.len() {
            let kk = kappa[k];
            if !(kk > 0.0 && kk.is_finite()) {
                continue;
            }
            springs.push((k, kk, targets[k]));
            let e = samples.entries(k);
            for (i, &(a, wa)) in e.iter().enumerate() {
                diagonal.push((a, kk * wa * wa));
                for &(b, wb) in &e[i + 1..] {
                    pairs.push(((a.min(b), a.max(b)), kk * wa * wb));
                }
            }
        }
        Self {
            samples,
            springs,
            diagonal: sum_by_key(diagonal),
            pairs: sum_by_key(pairs),
        }
    }

    /// Σ_k ‖f_k‖ at positions `x` (N).
    pub fn total_force_n(&self, x: &[Vector3<f64>]) -> f64 {
        self.springs
            .iter()
            .map(|&(k, kk, c)| (self.sample(k, x) - c).norm() * kk)
            .sum()
    }

    fn sample(&self, k: usize, x: &[Vector3<f64>]) -> Vector3<f64> {
        self.samples.entries(k).iter().map(|&(a, w)| x[a] * w).sum()
    }
}

impl NodalTerm for VirtualForces<'_> {
    fn refresh(&mut self, _x: &[Vector3<f64>], _k: &dyn Fn(usize) -> f64, _requery: bool) {}

    fn add_forces(&self, x: &[Vector3<f64>], out: &mut [Vector3<f64>]) {
        for &(k, kk, c) in &self.springs {
            let f = (c - self.sample(k, x)) * kk;
            for &(a, w) in self.samples.entries(k) {
                out[a] += f * w;
            }
        }
    }

    fn blocks(&self, _x: &[Vector3<f64>]) -> Vec<(usize, Matrix3<f64>)> {
        self.diagonal
            .iter()
            .map(|&(a, v)| (a, Matrix3::identity() * v))
            .collect()
    }

    fn pair_blocks(&self, _x: &[Vector3<f64>]) -> Vec<(usize, usize, Matrix3<f64>)> {
        self.pairs
            .iter()
            .map(|&((a, b), v)| (a, b, Matrix3::identity() * v))
            .collect()
    }
}

/// The values of equal keys summed in their order in `items` (a stable sort, then one pass), in
/// ascending key order: the sums of a map accumulated in that order, without the map.
fn sum_by_key<K: Ord + Copy>(mut items: Vec<(K, f64)>) -> Vec<(K, f64)> {
    items.sort_by_key(|&(key, _)| key);
    let mut out: Vec<(K, f64)> = Vec::with_capacity(items.len());
    for (key, v) in items {
        match out.last_mut() {
            Some((last, sum)) if *last == key => *sum += v,
            _ => out.push((key, v)),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The blocks are −∂f/∂x of the forces (finite differences).
    #[test]
    fn stiffness_blocks_are_the_force_jacobian() {
        let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [0.02, 0.01, 0.01], [2, 1, 1]);
        let samples = SurfaceSamples::new(&mesh, 0.004);
        let n = samples.len();
        let kappa: Vec<f64> = (0..n).map(|k| 1.0 + (k % 5) as f64).collect();
        let targets: Vec<Vector3<f64>> = samples
            .positions(&mesh.vertices)
            .iter()
            .map(|p| p + Vector3::new(0.001, -0.0005, 0.0002))
            .collect();
        let term = VirtualForces::new(&samples, &kappa, &targets);
        let x = mesh.vertices.clone();
        let nn = x.len();
        let mut dense = vec![vec![0.0; 3 * nn]; 3 * nn];
        for (a, m) in term.blocks(&x) {
            for r in 0..3 {
                for c in 0..3 {
                    dense[3 * a + r][3 * a + c] += m[(r, c)];
                }
            }
        }
        for (a, b, m) in term.pair_blocks(&x) {
            for r in 0..3 {
                for c in 0..3 {
                    dense[3 * a + r][3 * b + c] += m[(r, c)];
                    dense[3 * b + c][3 * a + r] += m[(r, c)];
                }
            }
        }
        let h = 1e-7;
        for j in 0..3 * nn {
            let (mut xp, mut xm) = (x.clone(), x.clone());
            xp[j / 3][j % 3] += h;
            xm[j / 3][j % 3] -= h;
            let (mut fp, mut fm) = (vec![Vector3::zeros(); nn], vec![Vector3::zeros(); nn]);
            term.add_forces(&xp, &mut fp);
            term.add_forces(&xm, &mut fm);
            for i in 0..3 * nn {
                let fd = -(fp[i / 3][i % 3] - fm[i / 3][i % 3]) / (2.0 * h);
                assert!(
                    (fd - dense[i][j]).abs() < 1e-6 * (1.0 + fd.abs()),
                    "({i},{j})"
                );
            }
        }
    }
}
