//! The plastic-strain Laplacian and its singular base operator (saito-barbic Appendix A, §3.5).
//!
//! L_t is the combinatorial Laplacian of the tet mesh's dual graph (tets sharing a face; Zhang 2004;
//! Appendix A eq. 28, [`softcap_mesh::umbrella_laplacian`] over [`softcap_mesh::tet_face_adjacency`]).
//! The plastic-strain Laplacian (eq. 29) applies it to each of the six components of s with a
//! weight √2 on the three off-diagonal ones (each appears twice in F_p), so the smoothness energy
//! of eq. 3 is
//!
//! E_s = α/2 ‖L s‖² = α/2 Σ_k w_k ‖L_t s_k‖²,  w = (1, 1, 1, 2, 2, 2),
//!
//! with gradient α Σ_k w_k L_t² s_k. On a connected mesh L_t has the single null vector 1, so
//! the base matrix A₀ = α diag(w) ⊗ L_t² has the six null vectors ψ_k (component k all 1/√T,
//! Appendix A lemma). [`PlasticLaplacian::apply_base_inverse`] applies the inverse of the invertible
//! A = A₀ + μ Σ_k ψ_k ψ_kᵀ by the singular lemma (§3.5): (iii) A⁻¹y = y_range + Σ_k (ψ_k·y/μ) ψ_k,
//! where y_range is the unique solution of A₀ z = y − Σ ψ_k(ψ_k·y) orthogonal to the ψ_k (ii).
//!
//! y_range = (α w_k)⁻¹ L_t⁺ L_t⁺ y_k per component, because L_t² and L_t share eigenvectors, so
//! the six components share one scalar factor of size T (A₀ is I₆ ⊗ L_t² up to the weights: six
//! times smaller solves than a factor of the 6T × 6T matrix). L_t⁺ is applied with one sparse
//! Cholesky factor, computed once (faer, AMD ordering): remove the mean of the right-hand side
//! (it is then in the range of L_t), solve with L_t grounded at its last row and column
//! (symmetric positive definite on a connected mesh) — a solution of the singular system, since
//! the dropped row is minus the sum of the others — and remove the mean of the solution, which by
//! lemma (ii) is the one orthogonal to the null space.
//!
//! Speed (saito-barbic Table 1): a Gauss–Newton step applies A⁻¹ to six columns per constraint
//! row. The columns are gathered once into the factor's (fill-reducing) ordering, both L_t⁺
//! applications — forward and backward supernodal sweeps on a block of columns, with the mean
//! removals between them, which do not depend on the ordering — run there, and the result is
//! scattered back once; blocks of columns run on all cores (rayon), each sweep sequential.

use crate::error::{Result, TissueError};
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::reborrow::{Reborrow, ReborrowMut};
use faer::sparse::SparseColMat;
use faer::sparse::linalg::cholesky::{
    SymbolicCholesky, SymbolicCholeskyRaw, SymmetricOrdering, factorize_symbolic_cholesky,
    simplicial::SimplicialLltRef, supernodal::SupernodalLltRef,
};
use faer::{Conj, Mat, MatMut, Par, Side};
use nalgebra::Vector6;
use rayon::prelude::*;

/// Component weights of the plastic-strain Laplacian (Appendix A eq. 29: √2 on off-diagonals).
pub const COMPONENT_WEIGHTS: [f64; 6] = [1.0, 1.0, 1.0, 2.0, 2.0, 2.0];

/// Columns per parallel task of [`PlasticLaplacian::apply_base_inverse`] (wide enough for the
/// supernodal sweeps to run as matrix–matrix products, narrow enough to share the cores).
const SOLVE_BLOCK: usize = 96;

/// L_t of a tet mesh with the factor of its grounded part (see the module docs).
#[derive(Debug)]
pub struct PlasticLaplacian {
    laplacian: SparseColMat<usize, f64>,
    grounded: Option<GroundedFactor>,
    num_tets: usize,
}

/// The Cholesky factor of L_t without its last row and column, in faer's fill-reducing order.
#[derive(Debug)]
struct GroundedFactor {
    symbolic: SymbolicCholesky<usize>,
    values: Vec<f64>,
    /// Row i of the factor's ordering is row `order[i]` of the grounded matrix.
    order: Vec<usize>,
}

impl GroundedFactor {
    fn new(lower: SparseColMat<usize, f64>) -> Result<Self> {
        let failed = |e: String| TissueError::NotConverged {
            what: "Cholesky factorization of the plastic-strain Laplacian".into(),
            status: e,
        };
        let symbolic = factorize_symbolic_cholesky(
            lower.symbolic(),
            Side::Lower,
            SymmetricOrdering::Amd,
            Default::default(),
        )
        .map_err(|e| failed(format!("{e:?}")))?;
        let mut values = vec![0.0; symbolic.len_val()];
        let req = symbolic.factorize_numeric_llt_scratch::<f64>(Par::Seq, Default::default());
        symbolic
            .factorize_numeric_llt::<f64>(
                &mut values,
                lower.as_ref(),
                Side::Lower,
                Default::default(),
                Par::Seq,
                MemStack::new(&mut MemBuffer::new(req)),
                Default::default(),
            )
            .map_err(|e| failed(format!("{e:?}")))?;
        let n = symbolic.nrows();
        let order = match symbolic.perm() {
            Some(p) => p.arrays().0.to_vec(),
            None => (0..n).collect(),
        };
        Ok(Self {
            symbolic,
            values,
            order,
        })
    }

    /// Solves with the factor in place; `rhs` rows are in the factor's ordering.
    fn solve_ordered(&self, rhs: MatMut<'_, f64>, stack: &mut MemStack) {
        match self.symbolic.raw() {
            SymbolicCholeskyRaw::Supernodal(s) => SupernodalLltRef::new(s, &self.values)
                .solve_in_place_with_conj(Conj::No, rhs, Par::Seq, stack),
            SymbolicCholeskyRaw::Simplicial(s) => SimplicialLltRef::new(s, &self.values)
                .solve_in_place_with_conj(Conj::No, rhs, Par::Seq, stack),
        }
    }

    fn scratch(&self, ncols: usize) -> MemBuffer {
        let req = match self.symbolic.raw() {
            SymbolicCholeskyRaw::Supernodal(s) => s.solve_in_place_scratch::<f64>(ncols, Par::Seq),
            SymbolicCholeskyRaw::Simplicial(s) => s.solve_in_place_scratch::<f64>(ncols),
        };
        MemBuffer::new(req)
    }
}

impl PlasticLaplacian {
    /// The dual-graph Laplacian of `tets` and the factor of its grounded part. Fails when the mesh
    /// is not connected through faces (the null space would be larger than six, Appendix A).
    pub fn new(tets: &[[usize; 4]]) -> Result<Self> {
        let adjacency = softcap_mesh::tet_face_adjacency(tets);
        let parts = components(&adjacency);
        if parts > 1 {
            return Err(TissueError::BadSettings {
                field: "template".into(),
                problem: format!(
                    "the tet mesh has {parts} parts not connected through faces; the plastic-strain \
                     Laplacian needs one (saito-barbic Appendix A)"
                ),
            });
        }
        let laplacian = softcap_mesh::umbrella_laplacian(&adjacency);
        let num_tets = tets.len();
        let grounded = if num_tets > 1 {
            let mut entries = Vec::new();
            let sym = laplacian.symbolic();
            for j in 0..num_tets - 1 {
                for k in sym.col_range(j) {
                    let i = sym.row_idx()[k];
                    if i >= j && i < num_tets - 1 {
                        entries.push((i, j, laplacian.val()[k]));
                    }
                }
            }
            let lower = softcap_mesh::sparse_from_triplets(num_tets - 1, num_tets - 1, entries);
            Some(GroundedFactor::new(lower)?)
        } else {
            None
        };
        Ok(Self {
            laplacian,
            grounded,
            num_tets,
        })
    }

    /// Stored values of the grounded Laplacian's Cholesky factor (0 for one tet): each L_t⁺
    /// application costs about 4 flops per value and column (two triangular sweeps).
    pub fn factor_len(&self) -> usize {
        self.grounded.as_ref().map_or(0, |f| f.values.len())
    }

    /// Number of tets T.
    pub fn num_tets(&self) -> usize {
        self.num_tets
    }

    /// L_t v.
    pub fn apply_scalar(&self, v: &[f64]) -> Vec<f64> {
        softcap_mesh::sparse_mul_vec(self.laplacian.as_ref(), v)
    }

    /// Σ_k w_k ‖L_t s_k‖² (E_s = α/2 times this).
    pub fn energy(&self, s: &[Vector6<f64>]) -> f64 {
        (0..6)
            .map(|k| {
                let c: Vec<f64> = s.iter().map(|v| v[k]).collect();
                let l = self.apply_scalar(&c);
                COMPONENT_WEIGHTS[k] * l.iter().map(|v| v * v).sum::<f64>()
            })
            .sum()
    }

    /// Σ_k w_k L_t² s_k per tet (the gradient of E_s is α times this).
    pub fn normal_apply(&self, s: &[Vector6<f64>]) -> Vec<Vector6<f64>> {
        let mut out = vec![Vector6::zeros(); s.len()];
        for k in 0..6 {
            let c: Vec<f64> = s.iter().map(|v| v[k]).collect();
            let l2 = self.apply_scalar(&self.apply_scalar(&c));
            for (o, v) in out.iter_mut().zip(l2) {
                o[k] = COMPONENT_WEIGHTS[k] * v;
            }
        }
        out
    }

    /// A⁻¹ applied in place to a block of 6-vector fields stored component-major: column
    /// 6c + k of `m` (T rows) is component k of field c (module docs; singular lemma (iii)
    /// with the null vectors ψ_k and shift `mu`, scale `alpha`). Each column's result does not
    /// depend on the blocking.
    pub fn apply_base_inverse(&self, m: MatMut<'_, f64>, alpha: f64, mu: f64) {
        self.apply_pseudo_inverse(m, 2, alpha, Some(mu));
    }

    /// H applied in place to a block laid out as for [`Self::apply_base_inverse`]: the "half"
    /// of A⁻¹ with H = (α w_k)^(−1/2) L_t⁺ per component, so that A⁻¹ = H² + μ⁻¹ Σ_k ψ_k ψ_kᵀ
    /// (L_t⁺ is symmetric and annihilates the ψ_k, so H is symmetric with Hψ_k = 0). One
    /// application of L_t⁺ (two triangular sweeps), half the cost of A⁻¹: a quadratic form
    /// yᵀA⁻¹y′ = (Hy)ᵀ(Hy′) + μ⁻¹ Σ_k (ψ_k·y)(ψ_k·y′) needs one per column, not two.
    pub fn apply_half_inverse(&self, m: MatMut<'_, f64>, alpha: f64) {
        self.apply_pseudo_inverse(m, 1, alpha, None);
    }

    /// (α w_k)^(−passes/2) (L_t⁺)^passes per column, plus the mean over μ when `mu` is given.
    fn apply_pseudo_inverse(&self, m: MatMut<'_, f64>, passes: i32, alpha: f64, mu: Option<f64>) {
        let Some(factor) = &self.grounded else {
            // One tet: L_t = 0 (L_t⁺ = 0), A = μ ψψᵀ with ψ = 1.
            for col in m.col_iter_mut() {
                for v in col.iter_mut() {
                    *v = mu.map_or(0.0, |mu| *v / mu);
                }
            }
            return;
        };
        // A few columns (one preconditioner application of the inexact step, [`super::step`])
        // are split over the cores too; a column's result does not depend on the blocking.
        let width = m
            .ncols()
            .div_ceil(rayon::current_num_threads())
            .clamp(1, SOLVE_BLOCK);
        let mut blocks: Vec<(usize, MatMut<'_, f64>)> = Vec::new();
        let mut rest = m;
        let mut start = 0;
        while rest.ncols() > 0 {
            let take = width.min(rest.ncols());
            let (head, tail) = rest.split_at_col_mut(take);
            blocks.push((start, head));
            start += take;
            rest = tail;
        }
        blocks.into_par_iter().for_each(|(start, block)| {
            self.pseudo_inverse_block(factor, block, start, passes, alpha, mu);
        });
    }

    /// [`Self::apply_pseudo_inverse`] on columns `start..` of the whole block (the column index
    /// picks the component weight).
    fn pseudo_inverse_block(
        &self,
        factor: &GroundedFactor,
        mut m: MatMut<'_, f64>,
        start: usize,
        passes: i32,
        alpha: f64,
        mu: Option<f64>,
    ) {
        let t = self.num_tets;
        let inv_t = 1.0 / t as f64;
        let (g, k) = (t - 1, m.ncols());
        let means: Vec<f64> = (0..k)
            .map(|j| m.rb().col(j).iter().sum::<f64>() * inv_t)
            .collect();
        // Gather the centred right-hand sides' grounded rows into the factor's ordering.
        let mut x = Mat::<f64>::zeros(g, k);
        for j in 0..k {
            let src = m.rb().col(j);
            for (d, &o) in x.col_mut(j).iter_mut().zip(&factor.order) {
                *d = src[o] - means[j];
            }
        }
        let mut buf = factor.scratch(k);
        let stack = MemStack::new(&mut buf);
        // Last-row entries (not in the factor) of the current iterate.
        let mut last = vec![0.0; k];
        // L_t⁺ per pass; after the first the right-hand side is already centred (lemma (ii)),
        // and the grounded solve ignores the last row.
        for _ in 0..passes {
            factor.solve_ordered(x.as_mut(), stack);
            for (j, l) in last.iter_mut().enumerate() {
                let col = x.col_mut(j);
                let mean = col.rb().iter().sum::<f64>() * inv_t;
                for v in col.iter_mut() {
                    *v -= mean;
                }
                *l = -mean;
            }
        }
        for j in 0..k {
            let weight = alpha * COMPONENT_WEIGHTS[(start + j) % 6];
            let scale = if passes == 2 {
                1.0 / weight
            } else {
                weight.powf(-0.5 * passes as f64)
            };
            let shift = mu.map_or(0.0, |mu| means[j] / mu);
            let mut dst = m.rb_mut().col_mut(j);
            for (i, &o) in factor.order.iter().enumerate() {
                dst[o] = x[(i, j)] * scale + shift;
            }
            dst[g] = last[j] * scale + shift;
        }
    }
}

/// Number of connected components of a graph given by adjacency lists.
fn components(adjacency: &[Vec<usize>]) -> usize {
    let mut seen = vec![false; adjacency.len()];
    let mut parts = 0;
    let mut stack = Vec::new();
    for start in 0..adjacency.len() {
        if seen[start] {
            continue;
        }
        parts += 1;
        seen[start] = true;
        stack.push(start);
        while let Some(v) = stack.pop() {
            for &w in &adjacency[v] {
                if !seen[w] {
                    seen[w] = true;
                    stack.push(w);
                }
            }
        }
    }
    parts
}

#[cfg(test)]
mod tests {
    use super::*;
    use faer::Mat;

    #[test]
    fn base_inverse_matches_a_dense_solve() {
        let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [1.0, 0.6, 0.4], [3, 2, 2]);
        let lap = PlasticLaplacian::new(&mesh.tets).unwrap();
        let t = mesh.tets.len();
        let (alpha, mu) = (0.7, 1.3);
        // Dense A = α diag(w) ⊗ L² + μ Σ ψψᵀ on one component (k = 4, weight 2).
        let mut l = Mat::<f64>::zeros(t, t);
        for j in 0..t {
            let mut e = vec![0.0; t];
            e[j] = 1.0;
            for (i, v) in lap.apply_scalar(&e).into_iter().enumerate() {
                l[(i, j)] = v;
            }
        }
        let a = (&l * &l) * (alpha * 2.0) + Mat::<f64>::full(t, t, mu / t as f64);
        let y: Vec<f64> = (0..t).map(|i| (i as f64 * 0.37).sin() + 0.2).collect();
        let mut m = Mat::<f64>::zeros(t, 6);
        for i in 0..t {
            m[(i, 4)] = y[i];
        }
        lap.apply_base_inverse(m.as_mut(), alpha, mu);
        let x = m.col(4).to_owned();
        let r = &a * &x;
        let err = (0..t).map(|i| (r[i] - y[i]).abs()).fold(0.0, f64::max);
        assert!(err < 1e-9, "residual {err}");
    }

    /// A⁻¹ = H² + μ⁻¹ Σ ψ_k ψ_kᵀ with H symmetric: H applied twice plus the mean over μ is
    /// A⁻¹ column by column, and (Hy)·(Hy′) + μ⁻¹ (ψ·y)(ψ·y′) = y·A⁻¹y′.
    #[test]
    fn half_inverse_squares_to_the_base_inverse() {
        let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [1.0, 0.6, 0.4], [3, 2, 2]);
        let lap = PlasticLaplacian::new(&mesh.tets).unwrap();
        let t = mesh.tets.len();
        let (alpha, mu) = (0.7, 1.3);
        let y = Mat::<f64>::from_fn(t, 12, |i, j| ((i * 13 + j * 7) as f64 * 0.37).sin() + 0.1);
        let mut full = y.clone();
        lap.apply_base_inverse(full.as_mut(), alpha, mu);
        let mut half = y.clone();
        lap.apply_half_inverse(half.as_mut(), alpha);
        let mut twice = half.clone();
        lap.apply_half_inverse(twice.as_mut(), alpha);
        let scale = full.norm_max();
        for j in 0..12 {
            let mean = y.col(j).sum() / t as f64;
            for i in 0..t {
                let err = (twice[(i, j)] + mean / mu - full[(i, j)]).abs();
                assert!(err < 1e-12 * scale, "({i}, {j}): {err}");
            }
            // Columns j and j + 6 carry the same component.
            let j2 = (j + 6) % 12;
            let quadratic = half.col(j).transpose() * half.col(j2)
                + y.col(j).sum() * y.col(j2).sum() / (t as f64 * mu);
            let exact = y.col(j).transpose() * full.col(j2);
            assert!((quadratic - exact).abs() < 1e-12 * exact.abs().max(scale));
        }
    }

    #[test]
    fn disconnected_meshes_are_rejected() {
        let mut mesh = softcap_mesh::box_tet_mesh([0.0; 3], [1.0, 1.0, 1.0], [1, 1, 1]);
        let n = mesh.vertices.len();
        let far: Vec<_> = mesh.vertices.iter().map(|v| v.add_scalar(5.0)).collect();
        mesh.vertices.extend(far);
        let extra: Vec<[usize; 4]> = mesh.tets.iter().map(|t| t.map(|v| v + n)).collect();
        mesh.tets.extend(extra);
        assert!(PlasticLaplacian::new(&mesh.tets).is_err());
    }
}
