//! Anderson acceleration (type II, Walker & Ni 2011) of a fixed-point iteration x ← G(x) on node
//! positions.

use nalgebra::{DMatrix, DVector, Vector3};

/// The last few iterates and their images; see [`Anderson::next`].
#[derive(Clone, Debug, Default)]
pub struct Anderson {
    memory: usize,
    /// (x_i, G(x_i)) as flat vectors, oldest first.
    history: Vec<(Vec<f64>, Vec<f64>)>,
}

fn flat(v: &[Vector3<f64>]) -> Vec<f64> {
    v.iter().flat_map(|p| [p.x, p.y, p.z]).collect()
}

impl Anderson {
    /// Acceleration over the last `memory` differences (0: plain iteration).
    pub fn new(memory: usize) -> Self {
        Self {
            memory,
            history: Vec::new(),
        }
    }

    /// The next iterate after x_k with image g_k = G(x_k): g_k − ΔG γ with γ minimising
    /// ‖f_k − ΔF γ‖₂ over the stored differences (f = G(x) − x). Falls back to g_k (and restarts
    /// the history) when the residual grew or the least-squares problem is degenerate.
    pub fn next(&mut self, x: &[Vector3<f64>], g: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        let (xf, gf) = (flat(x), flat(g));
        let f: Vec<f64> = gf.iter().zip(&xf).map(|(a, b)| a - b).collect();
        let norm = |v: &[f64]| v.iter().map(|a| a * a).sum::<f64>().sqrt();
        if let Some((px, pg)) = self.history.last() {
            let pf: Vec<f64> = pg.iter().zip(px).map(|(a, b)| a - b).collect();
            if norm(&f) >= norm(&pf) {
                self.history.clear();
            }
        }
        self.history.push((xf, gf.clone()));
        if self.history.len() > self.memory + 1 {
            self.history.remove(0);
        }
        let m = self.history.len() - 1;
        if m == 0 {
            return g.to_vec();
        }
        let n = f.len();
        let res = |i: usize| -> Vec<f64> {
            let (x, g) = &self.history[i];
            g.iter().zip(x).map(|(a, b)| a - b).collect()
        };
        let fs: Vec<Vec<f64>> = (0..=m).map(res).collect();
        let df = DMatrix::from_fn(n, m, |r, c| fs[c + 1][r] - fs[c][r]);
        let dtd = df.transpose() * &df;
        let rhs = df.transpose() * DVector::from_column_slice(&f);
        let scale = dtd.diagonal().max().max(f64::MIN_POSITIVE);
        let reg = dtd + DMatrix::identity(m, m) * (1e-10 * scale);
        let Some(gamma) = reg.cholesky().map(|c| c.solve(&rhs)) else {
            self.history.drain(..m);
            return g.to_vec();
        };
        let mut out = gf;
        for c in 0..m {
            let (g1, g0) = (&self.history[c + 1].1, &self.history[c].1);
            for r in 0..n {
                out[r] -= gamma[c] * (g1[r] - g0[r]);
            }
        }
        out.chunks_exact(3)
            .map(|c| Vector3::new(c[0], c[1], c[2]))
            .collect()
    }
}
