//! The Gauss–Newton step over the plastic strains (saito-barbic §3.4, eq. 8–14).
//!
//! Linearizing the equilibrium x(s) (eq. 10: J = ∂x/∂s = −K⁻¹ ∂f/∂s, with the gauge projection D
//! for free-flying objects, [`super::gauge`]) turns the objective of eq. 6 into a quadratic in Δs
//! whose minimizer solves
//!
//! M Δs = −g,  M = A₀ + Vᵀ W V,  g = α A₀-gradient + Jᵀ ∇ₓE,
//!
//! with A₀ the plastic-strain Laplacian term ([`super::laplacian`]), V = G J the constraint rows of
//! the Jacobian (G selects the constrained points, W their weights). M is dense (6T × 6T); the
//! paper solves it with the Woodbury identity on the singular base A₀ made invertible by the
//! singular lemma (eq. 13–14): A = A₀ + μΣψψᵀ, U = [Vᵀ, Ψ], C = diag(W, −μI₆),
//!
//! M⁻¹ r = A⁻¹r − A⁻¹U (C⁻¹ + UᵀA⁻¹U)⁻¹ UᵀA⁻¹r.
//!
//! Nothing of size 6T × 6T or 6T × rows is stored: with Z = K⁻¹ (Dᵀ) Gᵀ (3N × rows, one
//! multi-right-hand-side solve with the equilibrium factor) V = −Zᵀ B (B = ∂f/∂s, 12×6 per tet),
//! so VA⁻¹Vᵀ = Zᵀ Y with Y = B A⁻¹ Bᵀ Z formed block by block (Bᵀ, six scalar Laplacian solves per
//! column with the factor computed once, B), and A⁻¹Ψ = Ψ/μ makes the Ψ block of the small matrix
//! zero: C⁻¹ + UᵀA⁻¹U = [[W⁻¹ + ZᵀY, −ZᵀBΨ/μ], [·ᵀ, 0]], factored by dense LU.
//!
//! The exact step applies A⁻¹ to 6 × rows columns (Table 1 size, 1,194 rows: ≈ 360 Gflop of
//! triangular sweeps). [`pcg_step`] is the **inexact** step: conjugate gradients on M
//! preconditioned by P = A₀ + V_sᵀW_sV_s, the same Woodbury solve with the singular lemma over
//! the *soft* rows s only ([`soft_rows`]; the attachment rows, whose points the equilibrium
//! holds by stiff springs, barely respond to the plastic strains; P = A + V_sᵀW_sV_s on the
//! shifted base when the soft rows do not determine the constant modes), stopped once the residual r = M Δs + g meets both
//! ‖r‖ ≤ η ‖g‖ (inexact Newton, Nocedal & Wright §7.1; η from [`forcing_term`]) and
//! ‖r‖_{P⁻¹} ≤ η ‖g‖_{P⁻¹}. The second test measures the error: ‖Δs − Δs*‖_M = ‖r‖_{M⁻¹} ≈
//! ‖r‖_{P⁻¹} (rᵀP⁻¹r is CG's ρ, free), which a small ‖r‖ does not bound when M is ill-conditioned
//! (a weak smoothness α). Noisy known-truth box (288 tets), α̂ = 3e-6: with the first test alone
//! the reshape stopped at a worse optimum (shape p95 1.443 mm, the exact step's 0.831 mm); with
//! both it is the exact step's (0.831 mm, 7–10 CG iterations per step). P⁻¹M = I + P⁻¹V_rᵀW_rV_r
//! is the identity plus a small part of rank ≤ r (r + 6 on the shifted base: −μΣψψᵀ as well),
//! so CG needs about as many iterations as that part has eigenvalues far from 1 (Nocedal &
//! Wright §5.1, Theorem 5.5; Table 1 size: 155 of 1,194 rows soft, 3 / 5 iterations to
//! η = 1e-4 / 1e-6, 15 / 16 on the shifted base). Every CG iterate from Δs = 0 is a descent direction of the
//! quadratic model with −gᵀΔs = ΔsᵀMΔs (Galerkin condition of the Krylov subspace), so the line
//! search's predicted decrease −½gᵀΔs stays exact.
//!
//! [`cg_step`] solves the same system by conjugate gradients on M without preconditioner (the
//! paper's Table 1 baseline), for the benches.

use faer::linalg::matmul::triangular::{self, BlockStructure};
use faer::linalg::solvers::Solve;
use faer::{Accum, Mat, MatMut, MatRef, Par};
use nalgebra::{SMatrix, Vector6};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::laplacian::PlasticLaplacian;

/// Columns per block of Y = B A⁻¹ Bᵀ Z (bounds the 6T × block scratch).
const BLOCK: usize = 64;

/// Columns per parallel tile of the Bᵀ and B products: each tet's 12×6 block (576 bytes) is
/// read once per tile, not once per column.
const TILE: usize = 8;

/// The columns of `m` as slices (copied when a column is not contiguous).
fn column_slices(m: MatRef<'_, f64>) -> Vec<std::borrow::Cow<'_, [f64]>> {
    m.col_iter()
        .map(|c| match c.try_as_col_major() {
            Some(c) => std::borrow::Cow::Borrowed(c.as_slice()),
            None => std::borrow::Cow::Owned(c.iter().copied().collect()),
        })
        .collect()
}

/// A column of an owned [`Mat`] or of a column-major slice as a slice (each column contiguous).
fn contiguous_mut(c: faer::ColMut<'_, f64>) -> &mut [f64] {
    match c.try_as_col_major_mut() {
        Some(c) => c.as_slice_mut(),
        None => unreachable!("columns of an owned Mat or a column-major slice are contiguous"),
    }
}

/// Row chunks of the products with the kept X = HBᵀZ ([`WoodburySolver`]), summed in a fixed
/// order: the chunks run in parallel and the result has the same bits on any number of threads.
const X_CHUNKS: usize = 16;

/// The row ranges of [`X_CHUNKS`] chunks of `n` rows.
fn x_chunks(n: usize) -> Vec<(usize, usize)> {
    let size = n.div_ceil(X_CHUNKS).max(1);
    (0..n)
        .step_by(size)
        .map(|r0| (r0, (r0 + size).min(n) - r0))
        .collect()
}

/// The lower triangle of XᵀX (the rest zero): sequential products of row chunks in parallel,
/// summed in chunk order.
fn gram_lower(x: MatRef<'_, f64>) -> Mat<f64> {
    let rows = x.ncols();
    let parts: Vec<Mat<f64>> = x_chunks(x.nrows())
        .into_par_iter()
        .map(|(r0, len)| {
            let xs = x.subrows(r0, len);
            let mut p = Mat::<f64>::zeros(rows, rows);
            triangular::matmul(
                p.as_mut(),
                BlockStructure::TriangularLower,
                Accum::Replace,
                xs.transpose(),
                BlockStructure::Rectangular,
                xs,
                BlockStructure::Rectangular,
                1.0,
                Par::Seq,
            );
            p
        })
        .collect();
    let mut sum = Mat::<f64>::zeros(rows, rows);
    for p in &parts {
        sum += p;
    }
    sum
}

/// Xᵀ h (h one column): row chunks in parallel, summed in chunk order.
fn xt_times(x: MatRef<'_, f64>, h: MatRef<'_, f64>) -> Mat<f64> {
    let parts: Vec<Mat<f64>> = x_chunks(x.nrows())
        .into_par_iter()
        .map(|(r0, len)| {
            let mut p = Mat::<f64>::zeros(x.ncols(), h.ncols());
            faer::linalg::matmul::matmul(
                p.as_mut(),
                Accum::Replace,
                x.subrows(r0, len).transpose(),
                h.subrows(r0, len),
                1.0,
                Par::Seq,
            );
            p
        })
        .collect();
    let mut sum = Mat::<f64>::zeros(x.ncols(), h.ncols());
    for p in &parts {
        sum += p;
    }
    sum
}

/// `acc` + X c, row chunks in parallel (each row's sum is sequential).
fn add_x_times(acc: &mut Mat<f64>, x: MatRef<'_, f64>, c: MatRef<'_, f64>) {
    let chunks = x_chunks(x.nrows());
    let mut rest = acc.as_mut();
    let mut pieces = Vec::with_capacity(chunks.len());
    for &(_, len) in &chunks {
        let (head, tail) = rest.split_at_row_mut(len);
        pieces.push(head);
        rest = tail;
    }
    pieces
        .into_par_iter()
        .zip(chunks)
        .for_each(|(dst, (r0, len))| {
            faer::linalg::matmul::matmul(dst, Accum::Add, x.subrows(r0, len), c, 1.0, Par::Seq);
        });
}

/// What both solvers of the normal equations need.
pub struct NormalSystem<'a> {
    /// ∂f_int/∂s per tet (12×6, node-major rows).
    pub jacobians: &'a [SMatrix<f64, 12, 6>],
    /// Nodes of each tet.
    pub tets: &'a [[usize; 4]],
    /// Number of mesh nodes N.
    pub num_nodes: usize,
    /// Z = K⁻¹ (Dᵀ) Gᵀ, 3N × rows; with `implicit`, only the columns of its kept rows.
    pub z: &'a Mat<f64>,
    /// Z applied through the equilibrium factor, the columns of some rows only kept in `z`
    /// (`None`: `z` holds every row's column).
    pub implicit: Option<ImplicitZ<'a>>,
    /// Weight of each constraint row (> 0).
    pub weights: &'a [f64],
    /// Gradient g of the objective with respect to s.
    pub gradient: &'a [Vector6<f64>],
    /// The plastic-strain Laplacian.
    pub laplacian: &'a PlasticLaplacian,
    /// Smoothness weight α.
    pub alpha: f64,
}

/// Z = K⁻¹ Gᵀ (3N × rows) applied without its columns: each product costs one multi-column
/// sparse solve with the equilibrium factor (K symmetric, so Zᵀ u = G K⁻¹ u).
pub trait ZOperator: Sync {
    /// Zᵀ u for the columns of `u` (3N × m): rows × m.
    fn transpose_apply(&self, u: MatRef<'_, f64>) -> Mat<f64>;
    /// Z c for the columns of `c` (rows × m): 3N × m.
    fn apply(&self, c: MatRef<'_, f64>) -> Mat<f64>;
    /// The columns of Z for `rows` (3N × rows.len()).
    fn columns(&self, rows: &[usize]) -> Mat<f64>;
}

/// Z kept as the columns of some rows, applied in full through a [`ZOperator`]: the inexact
/// step's preconditioner needs the columns of its soft rows only ([`soft_rows`]), M the whole
/// of Z once per CG iteration (two sparse solves instead of products with 3N × rows dense
/// columns, and no multi-column solve for the rows the step does not keep).
#[derive(Clone, Copy)]
pub struct ImplicitZ<'a> {
    /// The rows whose columns `NormalSystem::z` holds, increasing.
    pub kept: &'a [usize],
    /// Z and Zᵀ through the equilibrium factor.
    pub op: &'a dyn ZOperator,
}

impl NormalSystem<'_> {
    fn num_tets(&self) -> usize {
        self.jacobians.len()
    }

    /// Number of constraint rows (Z's columns, kept or not).
    pub fn rows(&self) -> usize {
        self.weights.len()
    }

    /// Zᵀ u (rows × m) for the columns of `u` (3N × m).
    pub fn zt_times(&self, u: MatRef<'_, f64>) -> Mat<f64> {
        match &self.implicit {
            Some(i) => i.op.transpose_apply(u),
            None => self.z.transpose() * u,
        }
    }

    /// Z c (3N × m) for the columns of `c` (rows × m).
    pub fn z_times(&self, c: MatRef<'_, f64>) -> Mat<f64> {
        match &self.implicit {
            Some(i) => i.op.apply(c),
            None => self.z * c,
        }
    }

    /// Every row's column of Z: `z` itself, or formed through the operator (one multi-column
    /// solve).
    pub fn dense_z(&self) -> std::borrow::Cow<'_, Mat<f64>> {
        match &self.implicit {
            Some(i) => std::borrow::Cow::Owned(i.op.columns(&(0..self.rows()).collect::<Vec<_>>())),
            None => std::borrow::Cow::Borrowed(self.z),
        }
    }

    /// The kept column of row `j` of Z, if it is kept.
    fn kept_column(&self, j: usize) -> Option<usize> {
        match &self.implicit {
            Some(i) => i.kept.binary_search(&j).ok(),
            None => Some(j),
        }
    }

    /// Bᵀ applied to the columns of `v` (3N × m): a T × 6m component-major block
    /// (column 6c + k = component k of the result for column c). Tiles of [`TILE`] columns run
    /// in parallel; each reads every tet's 12×6 block once per tile.
    pub(super) fn bt_times(&self, v: MatRef<'_, f64>) -> Mat<f64> {
        let mut out = Mat::<f64>::zeros(self.num_tets(), 6 * v.ncols());
        self.bt_times_into(v, out.as_mut());
        out
    }

    /// [`Self::bt_times`] written into `out` (T × 6m, contiguous columns), every entry
    /// overwritten.
    fn bt_times_into(&self, v: MatRef<'_, f64>, out: MatMut<'_, f64>) {
        let inputs = column_slices(v);
        let mut outputs: Vec<&mut [f64]> = out.col_iter_mut().map(contiguous_mut).collect();
        outputs
            .par_chunks_mut(6 * TILE)
            .zip(inputs.par_chunks(TILE))
            .for_each(|(outs, ins)| {
                let mut local = SMatrix::<f64, 12, TILE>::zeros();
                for (e, (b, tet)) in self.jacobians.iter().zip(self.tets).enumerate() {
                    for (a, &node) in tet.iter().enumerate() {
                        for i in 0..3 {
                            for (c, col) in ins.iter().enumerate() {
                                local[(3 * a + i, c)] = col[3 * node + i];
                            }
                        }
                    }
                    let r = b.tr_mul(&local);
                    for c in 0..ins.len() {
                        for k in 0..6 {
                            outs[6 * c + k][e] = r[(k, c)];
                        }
                    }
                }
            });
    }

    /// B applied to a T × 6m component-major block: 3N × m (tiles of [`TILE`] columns in
    /// parallel).
    fn b_times(&self, v: MatRef<'_, f64>) -> Mat<f64> {
        let m = v.ncols() / 6;
        let inputs = column_slices(v);
        let mut out = Mat::<f64>::zeros(3 * self.num_nodes, m);
        let mut outputs: Vec<&mut [f64]> = out.col_iter_mut().map(contiguous_mut).collect();
        outputs
            .par_chunks_mut(TILE)
            .zip(inputs.par_chunks(6 * TILE))
            .for_each(|(outs, ins)| {
                for (e, (b, tet)) in self.jacobians.iter().zip(self.tets).enumerate() {
                    for (c, y) in outs.iter_mut().enumerate() {
                        let s = Vector6::from_fn(|k, _| ins[6 * c + k][e]);
                        let f = b * s;
                        for (a, &node) in tet.iter().enumerate() {
                            for i in 0..3 {
                                y[3 * node + i] += f[3 * a + i];
                            }
                        }
                    }
                }
            });
        out
    }

    /// B Ψ (3N × 6): B applied to the six constant modes ψ_k (component k all 1/√T), whose
    /// constraint rows are V Ψ = −Zᵀ B Ψ.
    fn b_psi(&self) -> Mat<f64> {
        let t = self.num_tets();
        let inv_sqrt_t = 1.0 / (t as f64).sqrt();
        // Six fields as a component-major block T × 36: field k has component k = 1/√T.
        let mut psi = Mat::<f64>::zeros(t, 36);
        for e in 0..t {
            for k in 0..6 {
                psi[(e, 6 * k + k)] = inv_sqrt_t;
            }
        }
        self.b_times(psi.as_ref())
    }

    /// A 6-vector field (T entries) as a T × 6 component-major block.
    pub(super) fn field_block(field: &[Vector6<f64>]) -> Mat<f64> {
        Mat::from_fn(field.len(), 6, |e, k| field[e][k])
    }

    fn block_field(m: MatRef<'_, f64>) -> Vec<Vector6<f64>> {
        (0..m.nrows())
            .map(|e| Vector6::from_fn(|k, _| m[(e, k)]))
            .collect()
    }

    /// μ of the singular-lemma shift: α (the scale of A₀'s largest eigenvalues).
    fn mu(&self) -> f64 {
        self.alpha
    }

    /// M v = α Σ w_k L_t² v_k + Bᵀ Z W Zᵀ B v.
    fn apply_normal(&self, v: &[Vector6<f64>]) -> Vec<Vector6<f64>> {
        let mut out = self.laplacian.normal_apply(v);
        for o in &mut out {
            *o *= self.alpha;
        }
        let bv = self.b_times(Self::field_block(v).as_ref());
        let mut zt_bv = self.zt_times(bv.as_ref());
        for (i, w) in self.weights.iter().enumerate() {
            zt_bv[(i, 0)] *= w;
        }
        let back = self.z_times(zt_bv.as_ref());
        let btb = self.bt_times(back.as_ref());
        for (e, o) in out.iter_mut().enumerate() {
            for k in 0..6 {
                o[k] += btb[(e, k)];
            }
        }
        out
    }
}

/// Δs = −M⁻¹ g by the Woodbury identity with the singular lemma (module docs). `None` when the
/// small system is singular (the constraints do not determine the six constant plastic modes).
/// Every row's column of Z is formed when `sys` keeps only some.
pub fn woodbury_step(sys: &NormalSystem<'_>) -> Option<Vec<Vector6<f64>>> {
    let minus_g: Vec<Vector6<f64>> = sys.gradient.iter().map(|g| -g).collect();
    let z = sys.dense_z();
    let dense = NormalSystem {
        z: &z,
        implicit: None,
        ..*sys
    };
    WoodburySolver::new(&dense)?.solve(&minus_g)
}

/// M⁻¹ by the Woodbury identity (module docs) with the small matrix C⁻¹ + UᵀA⁻¹U formed and
/// factored once: each further right-hand side costs A⁻¹ on six columns and products with the
/// kept columns (or with Z and B), not the (rows × 6) columns of the factorization.
///
/// With A⁻¹ = H² + μ⁻¹ΨΨᵀ ([`PlasticLaplacian::apply_half_inverse`]: H = (αw)^(−1/2) L_t⁺,
/// symmetric, HΨ = 0) the Gram form ZᵀBA⁻¹BᵀZ = XᵀX + μ⁻¹SᵀS with X = HBᵀZ (6T × rows) and
/// S = ΨᵀBᵀZ (6 × rows) needs one L_t⁺ application per column of BᵀZ instead of A⁻¹'s two.
/// X is kept when it fits in 400 MB (the inexact step's preconditioner: Table 1 size, 155 soft
/// rows, 295 MB) and each solve is then H r, a product with Xᵀ, the small solve, a product with
/// X and H once more: A⁻¹ once. Otherwise (the exact step at Table 1 size, 1,194 rows) the small
/// matrix is Zᵀ(B A⁻¹BᵀZ) by blocks of 64 columns and each solve applies A⁻¹ twice.
pub struct WoodburySolver<'s, 'a> {
    sys: &'s NormalSystem<'a>,
    lu: faer::linalg::solvers::PartialPivLu<f64>,
    /// false: (A + VᵀWV)⁻¹, the shift μΣψψᵀ kept (symmetric positive definite for any rows;
    /// the inexact step's preconditioner, [`pcg_step`]).
    singular_lemma: bool,
    /// X = HBᵀZ and S = ΨᵀBᵀZ when kept; rows 6T of X stacked component-major (row kT + e is
    /// component k of tet e, the layout of `NormalSystem::field_block` read column-major).
    gram: Option<(Vec<f64>, Mat<f64>)>,
}

/// Largest X = HBᵀZ kept by a [`WoodburySolver`] (Table 1 size, the inexact step's 155 soft
/// rows: 39,600 × 6 × 155 values, 295 MB).
const CACHE_BYTES: usize = 400 << 20;

impl<'s, 'a> WoodburySolver<'s, 'a> {
    /// Forms C⁻¹ + UᵀA⁻¹U (rows + 6 square) and its LU.
    pub fn new(sys: &'s NormalSystem<'a>) -> Option<Self> {
        Self::with_lemma(sys, true)
    }

    /// (A + VᵀWV)⁻¹ = A⁻¹ − A⁻¹Vᵀ(W⁻¹ + VA⁻¹Vᵀ)⁻¹VA⁻¹: the Woodbury identity on the shifted
    /// base A without removing the shift (U = Vᵀ, C = W; small matrix rows square).
    pub fn shifted(sys: &'s NormalSystem<'a>) -> Option<Self> {
        Self::with_lemma(sys, false)
    }

    /// X = HBᵀZ (stacked, 6T × rows, column-major in one buffer) and S = ΨᵀBᵀZ (6 × rows), by
    /// blocks of [`BLOCK`] columns. Column j of X is field j's T × 6 component-major block read
    /// column-major, so BᵀZ is written into X and H applied there in place.
    fn gram_columns(sys: &NormalSystem<'_>) -> (Vec<f64>, Mat<f64>) {
        let (rows, t) = (sys.z.ncols(), sys.num_tets());
        let inv_sqrt_t = 1.0 / (t as f64).sqrt();
        let mut x = vec![0.0; 6 * t * rows];
        let mut s = Mat::<f64>::zeros(6, rows);
        for (b, chunk) in x.chunks_mut(6 * t * BLOCK).enumerate() {
            let c0 = b * BLOCK;
            let m = chunk.len() / (6 * t);
            let mut btz = MatMut::from_column_major_slice_mut(chunk, t, 6 * m);
            sys.bt_times_into(sys.z.as_ref().subcols(c0, m), btz.as_mut());
            for j in 0..m {
                for k in 0..6 {
                    s[(k, c0 + j)] = btz.as_ref().col(6 * j + k).sum() * inv_sqrt_t;
                }
            }
            sys.laplacian.apply_half_inverse(btz, sys.alpha);
        }
        (x, s)
    }

    /// The kept X = HBᵀZ (6T × rows).
    fn x_ref(x: &[f64], rows: usize) -> MatRef<'_, f64> {
        MatRef::from_column_major_slice(x, x.len() / rows.max(1), rows)
    }

    fn with_lemma(sys: &'s NormalSystem<'a>, singular_lemma: bool) -> Option<Self> {
        Self::with_cache(sys, singular_lemma, CACHE_BYTES)
    }

    /// The solver keeping X when it fits in `cache_bytes`.
    fn with_cache(
        sys: &'s NormalSystem<'a>,
        singular_lemma: bool,
        cache_bytes: usize,
    ) -> Option<Self> {
        if sys.implicit.is_some() {
            // Needs every row's column ([`woodbury_step`] forms them).
            return None;
        }
        let rows = sys.z.ncols();
        let t = sys.num_tets();
        let mu = sys.mu();
        let lap = sys.laplacian;
        // P = W⁻¹ + ZᵀBA⁻¹BᵀZ.
        let extra = if singular_lemma { 6 } else { 0 };
        let mut small = Mat::<f64>::zeros(rows + extra, rows + extra);
        let keep = t * 6 * rows * std::mem::size_of::<f64>() <= cache_bytes;
        let gram = if keep {
            let (x, s) = Self::gram_columns(sys);
            // XᵀX is symmetric: its lower half only (half the flops of the full product).
            let p = gram_lower(Self::x_ref(&x, rows));
            let sts = s.transpose() * &s;
            for j in 0..rows {
                for i in j..rows {
                    let v = p[(i, j)] + sts[(i, j)] / mu;
                    small[(i, j)] = v;
                    small[(j, i)] = v;
                }
            }
            Some((x, s))
        } else {
            // Y = B A⁻¹ Bᵀ Z block by block.
            for c0 in (0..rows).step_by(BLOCK) {
                let c1 = (c0 + BLOCK).min(rows);
                let mut btz = sys.bt_times(sys.z.as_ref().subcols(c0, c1 - c0));
                lap.apply_base_inverse(btz.as_mut(), sys.alpha, mu);
                let y = sys.b_times(btz.as_ref());
                // ZᵀY is symmetric: rows below c1 of these columns are the mirror of later blocks.
                let block = sys.z.as_ref().subcols(0, c1).transpose() * &y;
                for j in 0..c1 - c0 {
                    for i in 0..c1 {
                        small[(i, c0 + j)] = block[(i, j)];
                        small[(c0 + j, i)] = block[(i, j)];
                    }
                }
            }
            None
        };
        for (i, w) in sys.weights.iter().enumerate() {
            small[(i, i)] += 1.0 / w;
        }
        if singular_lemma {
            // Q = −Zᵀ B Ψ / μ (Ψ_k: component k all 1/√T).
            let q = sys.z.transpose() * sys.b_psi() * (-1.0 / mu);
            for i in 0..rows {
                for k in 0..6 {
                    small[(i, rows + k)] = q[(i, k)];
                    small[(rows + k, i)] = q[(i, k)];
                }
            }
        }
        let lu = small.partial_piv_lu();
        let ok = (0..rows + extra).all(|i| {
            let d = lu.U()[(i, i)];
            d.is_finite() && d != 0.0
        });
        ok.then_some(Self {
            sys,
            lu,
            singular_lemma,
            gram,
        })
    }

    /// x = M⁻¹ r (`None` if it is not finite).
    pub fn solve(&self, r: &[Vector6<f64>]) -> Option<Vec<Vector6<f64>>> {
        let sys = self.sys;
        let rows = sys.z.ncols();
        let t = sys.num_tets();
        let mu = sys.mu();
        let lap = sys.laplacian;
        let inv_sqrt_t = 1.0 / (t as f64).sqrt();
        let extra = if self.singular_lemma { 6 } else { 0 };
        let mut rhs = Mat::<f64>::zeros(rows + extra, 1);
        if let Some((x, s)) = &self.gram {
            // h = H r, p = Ψᵀ r: A⁻¹ r = H h + Ψ p / μ.
            let mut h = NormalSystem::field_block(r);
            let p: Vec<f64> = (0..6).map(|k| h.col(k).sum() * inv_sqrt_t).collect();
            lap.apply_half_inverse(h.as_mut(), sys.alpha);
            let h = Mat::from_fn(6 * t, 1, |i, _| h[(i % t, i / t)]);
            let pm = Mat::from_fn(6, 1, |k, _| p[k] / mu);
            // Uᵀ A⁻¹ r = [V A⁻¹ r; Ψᵀ A⁻¹ r] = [−(Xᵀ h + Sᵀ p / μ); p / μ].
            let x = Self::x_ref(x, rows);
            let va = (xt_times(x, h.as_ref()) + s.transpose() * &pm) * (-1.0);
            rhs.as_mut().subrows_mut(0, rows).copy_from(&va);
            for k in 0..extra {
                rhs[(rows + k, 0)] = pm[(k, 0)];
            }
            let c = self.lu.solve(&rhs);
            if !c.col(0).iter().all(|v| v.is_finite()) {
                return None;
            }
            // x = A⁻¹ r − A⁻¹ U c = H (h + X c₁) + Ψ (p + S c₁ − c₂) / μ.
            let c1 = c.as_ref().subrows(0, rows);
            let mut u = h;
            add_x_times(&mut u, x, c1);
            let mean = Mat::from_fn(6, 1, |k, _| p[k]) + s * c1;
            let mut out = Mat::from_fn(t, 6, |e, k| u[(k * t + e, 0)]);
            lap.apply_half_inverse(out.as_mut(), sys.alpha);
            let result: Vec<Vector6<f64>> = (0..t)
                .map(|e| {
                    Vector6::from_fn(|k, _| {
                        let c2 = if self.singular_lemma {
                            c[(rows + k, 0)]
                        } else {
                            0.0
                        };
                        out[(e, k)] + (mean[(k, 0)] - c2) * inv_sqrt_t / mu
                    })
                })
                .collect();
            return result
                .iter()
                .all(|s| s.iter().all(|v| v.is_finite()))
                .then_some(result);
        }
        // a = A⁻¹ r.
        let mut a = NormalSystem::field_block(r);
        lap.apply_base_inverse(a.as_mut(), sys.alpha, mu);
        // Uᵀ a = [V a; Ψᵀ a] = [−Zᵀ B a; Σ_e a_k / √T].
        let ba = sys.b_times(a.as_ref());
        let va = sys.z.transpose() * &ba * (-1.0);
        for i in 0..rows {
            rhs[(i, 0)] = va[(i, 0)];
        }
        for k in 0..extra {
            rhs[(rows + k, 0)] = a.col(k).iter().sum::<f64>() * inv_sqrt_t;
        }
        let c = self.lu.solve(&rhs);
        if !c.col(0).iter().all(|v| v.is_finite()) {
            return None;
        }
        // A⁻¹ U c = A⁻¹(−Bᵀ Z c₁) + Ψ c₂ / μ.
        let zc = sys.z * c.as_ref().subrows(0, rows);
        let mut w = sys.bt_times(zc.as_ref()) * (-1.0);
        lap.apply_base_inverse(w.as_mut(), sys.alpha, mu);
        let mut x = NormalSystem::block_field(a.as_ref());
        for (e, s) in x.iter_mut().enumerate() {
            for k in 0..6 {
                let shift = if self.singular_lemma {
                    c[(rows + k, 0)] * inv_sqrt_t / mu
                } else {
                    0.0
                };
                s[k] -= w[(e, k)] + shift;
            }
        }
        x.iter()
            .all(|s| s.iter().all(|v| v.is_finite()))
            .then_some(x)
    }
}

/// Outcome of [`cg_step`].
#[derive(Clone, Debug)]
pub struct CgOutcome {
    /// The approximate step.
    pub step: Vec<Vector6<f64>>,
    /// Iterations performed.
    pub iterations: usize,
    /// Final ‖r‖ / ‖g‖.
    pub relative_residual: f64,
    /// Rows in the Woodbury part of the preconditioner ([`pcg_step`]; 0 for [`cg_step`]).
    pub woodbury_rows: usize,
    /// The preconditioner is A₀ + V_sᵀW_sV_s by the singular lemma, not the shifted base
    /// ([`pcg_step`]; false for [`cg_step`]).
    pub singular_lemma: bool,
}

/// Δs = −M⁻¹ g by conjugate gradients on M (no preconditioner, as the paper's CG baseline), to
/// ‖r‖ ≤ `tolerance` ‖g‖ or `max_iterations`: `preconditioned_cg` with P = I.
pub fn cg_step(sys: &NormalSystem<'_>, tolerance: f64, max_iterations: usize) -> CgOutcome {
    preconditioned_cg(sys, |r| r.to_vec(), tolerance, max_iterations, 0)
}

/// How the Gauss–Newton step's normal equations are solved (`step_solver` of
/// [`super::ReshapeSettings`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum StepSolver {
    /// The exact step: Woodbury identity with the singular lemma (§3.5, eq. 13–15;
    /// [`woodbury_step`]).
    Woodbury,
    /// The inexact step: conjugate gradients on M preconditioned by the Woodbury base A
    /// ([`pcg_step`]) to ‖M Δs + g‖ ≤ η ‖g‖ (and in the P⁻¹-norm), η from [`forcing_term`].
    #[default]
    Pcg,
}

/// The forcing term η of an inexact Newton step, min(η_max, √(‖g‖ / ‖g₀‖)) with g₀ the gradient
/// at the start of the stage: Nocedal & Wright §7.1 eq. (7.3)'s η_k = min(0.5, √‖∇f_k‖), made
/// scale-free by ‖g₀‖ (η → 0 as the gradient vanishes, so the step tends to the exact one).
pub fn forcing_term(max_forcing: f64, gradient_norm: f64, initial_gradient_norm: f64) -> f64 {
    let ratio = gradient_norm / initial_gradient_norm.max(f64::MIN_POSITIVE);
    max_forcing.min(ratio.sqrt())
}

/// Euclidean norm of a 6-vector field.
pub fn field_norm(v: &[Vector6<f64>]) -> f64 {
    v.iter().map(|x| x.norm_squared()).sum::<f64>().sqrt()
}

/// Rows whose Jacobian is this much smaller than the largest (w‖z‖² relative) are left to CG
/// by the inexact step's preconditioner ([`pcg_step`]).
pub const STIFF_ROW_RATIO: f64 = 1e-4;

/// The constraint rows the inexact step's preconditioner keeps exact: w_j ‖z_j‖² ≥
/// [`STIFF_ROW_RATIO`] × the largest. A row's outlier in the preconditioned spectrum is about
/// w_j ‖A^{-1/2} Bᵀ z_j‖², so rows with small z_j — points the equilibrium holds by the stiff
/// attachment springs, whose displacement hardly responds to the plastic strains — barely move
/// the spectrum away from 1 and are left to CG.
/// With an [`ImplicitZ`] the rows whose columns are not kept count as stiff (the attachment
/// rows, [`super::solve`]) and the test runs over the kept ones.
pub fn soft_rows(sys: &NormalSystem<'_>) -> Vec<usize> {
    let kept: Vec<usize> = match &sys.implicit {
        Some(i) => i.kept.to_vec(),
        None => (0..sys.rows()).collect(),
    };
    let size: Vec<f64> = kept
        .iter()
        .enumerate()
        .map(|(c, &j)| sys.weights[j] * sys.z.col(c).iter().map(|v| v * v).sum::<f64>())
        .collect();
    let largest = size.iter().copied().fold(0.0, f64::max);
    kept.iter()
        .zip(&size)
        .filter(|&(_, &size)| size >= STIFF_ROW_RATIO * largest && size > 0.0)
        .map(|(&j, _)| j)
        .collect()
}

/// Smallest eigenvalue of the soft rows' Gram matrix on the six constant modes, (V_sΨ)ᵀ W_s
/// (V_sΨ), relative to its largest, above which [`pcg_step`]'s preconditioner drops the shift
/// μΣψψᵀ (the soft rows determine the constant modes; below it, or with fewer than six soft
/// rows, P = A + V_sᵀW_sV_s keeps it and stays positive definite).
pub const CONSTANT_MODE_RATIO: f64 = 1e-8;

/// Whether the rows of `sys` determine the six constant modes ψ_k of A₀'s null space: the 6 × 6
/// Gram matrix (VΨ)ᵀ W (VΨ), VΨ = −Zᵀ B Ψ, has its smallest eigenvalue ≥
/// [`CONSTANT_MODE_RATIO`] × its largest (then A₀ + VᵀWV is positive definite: the singular
/// lemma's condition, saito-barbic §3.5).
fn determines_constant_modes(sys: &NormalSystem<'_>) -> bool {
    if sys.z.ncols() < 6 {
        return false;
    }
    let q = sys.z.transpose() * sys.b_psi();
    let gram = nalgebra::Matrix6::from_fn(|a, b| {
        (0..q.nrows())
            .map(|i| sys.weights[i] * q[(i, a)] * q[(i, b)])
            .sum::<f64>()
    });
    let eig = gram.symmetric_eigenvalues();
    let (low, high) = (eig.min(), eig.max());
    low.is_finite() && high > 0.0 && low >= CONSTANT_MODE_RATIO * high
}

/// Δs ≈ −M⁻¹ g by preconditioned conjugate gradients on M (Nocedal & Wright §5.1,
/// Algorithm 5.3), from Δs = 0 to ‖M Δs + g‖ ≤ `tolerance` ‖g‖ and the same in the P⁻¹-norm,
/// or `max_iterations` (module docs). The preconditioner is the Woodbury solve over the soft
/// rows s ([`soft_rows`]), symmetric positive definite whatever the rows:
/// - when the soft rows determine the six constant modes ([`CONSTANT_MODE_RATIO`]),
///   P = A₀ + V_sᵀ W_s V_s by the singular lemma ([`WoodburySolver::new`]):
///   P⁻¹M = I + P⁻¹V_rᵀ W_r V_r, the identity plus a positive part of rank ≤ r from the
///   remaining rows r (small);
/// - otherwise P = A + V_sᵀ W_s V_s on the shifted base ([`WoodburySolver::shifted`]; A⁻¹ alone
///   when there are no soft rows): P⁻¹M = I + P⁻¹(V_rᵀ W_r V_r − μΣψψᵀ), rank ≤ r + 6, with up
///   to six eigenvalues below 1 from the constant modes — where the soft rows' curvature is
///   small against μ = α, six outliers near 0 (Table 1 size: 15 iterations to η = 1e-4
///   instead of 3).
pub fn pcg_step(sys: &NormalSystem<'_>, tolerance: f64, max_iterations: usize) -> CgOutcome {
    let soft = soft_rows(sys);
    let columns: Vec<usize> = soft.iter().filter_map(|&j| sys.kept_column(j)).collect();
    let z_soft = Mat::from_fn(sys.z.nrows(), columns.len(), |i, j| sys.z[(i, columns[j])]);
    let w_soft: Vec<f64> = soft.iter().map(|&j| sys.weights[j]).collect();
    let sub = NormalSystem {
        z: &z_soft,
        weights: &w_soft,
        implicit: None,
        ..*sys
    };
    let lemma = determines_constant_modes(&sub);
    let (woodbury, singular_lemma) = match soft.is_empty() {
        true => (None, false),
        false if lemma => match WoodburySolver::new(&sub) {
            Some(w) => (Some(w), true),
            None => (WoodburySolver::shifted(&sub), false),
        },
        false => (WoodburySolver::shifted(&sub), false),
    };
    let base = |r: &[Vector6<f64>]| {
        let mut m = NormalSystem::field_block(r);
        sys.laplacian
            .apply_base_inverse(m.as_mut(), sys.alpha, sys.mu());
        NormalSystem::block_field(m.as_ref())
    };
    let precondition = |r: &[Vector6<f64>]| match &woodbury {
        Some(w) => w.solve(r).unwrap_or_else(|| base(r)),
        None => base(r),
    };
    let woodbury_rows = woodbury.as_ref().map_or(0, |_| soft.len());
    let mut outcome =
        preconditioned_cg(sys, precondition, tolerance, max_iterations, woodbury_rows);
    outcome.singular_lemma = singular_lemma;
    outcome
}

/// Preconditioned conjugate gradients on M Δs = −g from Δs = 0 (Nocedal & Wright §5.1,
/// Algorithm 5.3), `precondition(r)` = P⁻¹ r, stopped once r = M Δs + g has ‖r‖ ≤ `tolerance` ‖g‖
/// and rᵀP⁻¹r ≤ `tolerance`² gᵀP⁻¹g (module docs), after `max_iterations`, or where M stops being positive along a search direction. The one CG kernel
/// of the reshape: [`cg_step`] (P = I) and [`pcg_step`] (P from the soft rows).
fn preconditioned_cg(
    sys: &NormalSystem<'_>,
    precondition: impl Fn(&[Vector6<f64>]) -> Vec<Vector6<f64>>,
    tolerance: f64,
    max_iterations: usize,
    woodbury_rows: usize,
) -> CgOutcome {
    let dot = |a: &[Vector6<f64>], b: &[Vector6<f64>]| {
        a.iter().zip(b).map(|(u, v)| u.dot(v)).sum::<f64>()
    };
    let t = sys.num_tets();
    let mut x = vec![Vector6::zeros(); t];
    let mut r: Vec<Vector6<f64>> = sys.gradient.iter().map(|g| -g).collect();
    let g_norm = field_norm(&r).max(f64::MIN_POSITIVE);
    let mut y = precondition(&r);
    let mut p = y.clone();
    let mut ry = dot(&r, &y);
    let ry0 = ry;
    let mut residual = field_norm(&r);
    let mut iterations = 0;
    let done = |residual: f64, ry: f64| {
        residual <= tolerance * g_norm && ry <= tolerance * tolerance * ry0
    };
    while iterations < max_iterations && !done(residual, ry) {
        let mp = sys.apply_normal(&p);
        let pmp = dot(&p, &mp);
        if pmp <= 0.0 || !pmp.is_finite() {
            break;
        }
        let step = ry / pmp;
        for i in 0..t {
            x[i] += p[i] * step;
            r[i] -= mp[i] * step;
        }
        iterations += 1;
        residual = field_norm(&r);
        y = precondition(&r);
        let ry_next = dot(&r, &y);
        if done(residual, ry_next) {
            break;
        }
        let beta = ry_next / ry;
        for i in 0..t {
            p[i] = y[i] + p[i] * beta;
        }
        ry = ry_next;
    }
    CgOutcome {
        step: x,
        iterations,
        relative_residual: residual / g_norm,
        woodbury_rows,
        singular_lemma: false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A deterministic pseudo-random number in (−1, 1).
    fn noise(i: usize) -> f64 {
        ((i as f64 * 12.9898).sin() * 43758.5453).fract()
    }

    /// A random normal system on a box of `cells` (9 constraint rows, the last `stiff` of them
    /// with a 1e-3 times smaller Jacobian, like points held by attachment springs).
    struct Random {
        mesh: softcap_mesh::TetMesh,
        laplacian: PlasticLaplacian,
        jacobians: Vec<SMatrix<f64, 12, 6>>,
        z: Mat<f64>,
        weights: Vec<f64>,
        gradient: Vec<Vector6<f64>>,
    }

    impl Random {
        fn new(cells: [usize; 3], stiff: usize) -> Self {
            let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [1.0, 0.7, 0.5], cells);
            let laplacian = PlasticLaplacian::new(&mesh.tets).unwrap();
            let (t, n, rows) = (mesh.tets.len(), mesh.vertices.len(), 9);
            let jacobians = (0..t)
                .map(|e| SMatrix::from_fn(|i, j| noise(1000 * e + 12 * j + i)))
                .collect();
            let z = Mat::from_fn(3 * n, rows, |i, j| {
                let scale = if j + stiff >= rows { 1e-3 } else { 1.0 };
                scale * noise(7 + 31 * i + 1013 * j)
            });
            let weights = (0..rows).map(|i| 0.5 + 0.1 * i as f64).collect();
            let gradient = (0..t)
                .map(|e| Vector6::from_fn(|k, _| noise(99_991 + 6 * e + k)))
                .collect();
            Self {
                mesh,
                laplacian,
                jacobians,
                z,
                weights,
                gradient,
            }
        }

        fn system(&self) -> NormalSystem<'_> {
            NormalSystem {
                jacobians: &self.jacobians,
                tets: &self.mesh.tets,
                num_nodes: self.mesh.vertices.len(),
                z: &self.z,
                implicit: None,
                weights: &self.weights,
                gradient: &self.gradient,
                laplacian: &self.laplacian,
                alpha: 0.3,
            }
        }
    }

    /// The inexact step (PCG, the soft rows in its Woodbury preconditioner) meets its stated
    /// tolerance ‖M Δs + g‖ ≤ η ‖g‖ (M applied independently of CG's recurrences), is a descent
    /// direction with the Galerkin property ΔsᵀMΔs = −gᵀΔs the line search relies on, and at a
    /// tight tolerance is the exact (Woodbury) step, reached within stiff rows + 7 iterations up
    /// to rounding (the preconditioned operator is I plus a part of rank ≤ stiff rows + 6). Five
    /// soft rows cannot fix the six constant modes: the preconditioner keeps the shift. Seven
    /// (two stiff rows) do: the preconditioner drops it (singular lemma), the preconditioned
    /// operator is I plus a part of rank ≤ stiff rows, reached within stiff rows + 1 iterations.
    #[test]
    fn inexact_step_meets_its_tolerance_and_tends_to_the_woodbury_step() {
        for (stiff, lemma) in [(4, false), (2, true)] {
            let random = Random::new([3, 2, 2], stiff);
            let sys = random.system();
            assert_eq!(soft_rows(&sys), (0..9 - stiff).collect::<Vec<_>>());
            let exact = woodbury_step(&sys).unwrap();
            let g_norm = field_norm(sys.gradient);
            let dot = |a: &[Vector6<f64>], b: &[Vector6<f64>]| {
                a.iter().zip(b).map(|(u, v)| u.dot(v)).sum::<f64>()
            };
            let mut previous = f64::INFINITY;
            for eta in [0.5, 1e-1, 1e-2, 1e-4] {
                let cg = pcg_step(&sys, eta, 1000);
                assert_eq!(cg.singular_lemma, lemma, "stiff {stiff}");
                let m_ds = sys.apply_normal(&cg.step);
                let r: Vec<Vector6<f64>> =
                    m_ds.iter().zip(sys.gradient).map(|(a, g)| a + g).collect();
                let relative = field_norm(&r) / g_norm;
                assert!(
                    relative <= eta,
                    "stiff {stiff}, η {eta}: residual {relative}"
                );
                let g_ds = dot(sys.gradient, &cg.step);
                let ds_m_ds = dot(&cg.step, &m_ds);
                assert!(
                    g_ds < 0.0,
                    "stiff {stiff}, η {eta}: not a descent direction"
                );
                assert!(
                    (ds_m_ds + g_ds).abs() < 1e-9 * ds_m_ds,
                    "stiff {stiff}, η {eta}: ΔsᵀMΔs {ds_m_ds} vs −gᵀΔs {}",
                    -g_ds
                );
                // The error in the M-norm, ‖Δs − Δs*‖_M² = rᵀM⁻¹r, falls with η.
                let e: Vec<Vector6<f64>> = cg.step.iter().zip(&exact).map(|(a, b)| a - b).collect();
                let error = dot(&e, &sys.apply_normal(&e)).sqrt();
                assert!(
                    error <= previous,
                    "stiff {stiff}, η {eta}: M-norm error {error} > {previous}"
                );
                previous = error;
            }
            let tight = pcg_step(&sys, 1e-12, 1000);
            assert_eq!(tight.woodbury_rows, 9 - stiff);
            let diff: Vec<Vector6<f64>> =
                tight.step.iter().zip(&exact).map(|(a, b)| a - b).collect();
            let relative = field_norm(&diff) / field_norm(&exact);
            assert!(
                relative < 1e-6,
                "stiff {stiff}: PCG vs Woodbury {relative:e}"
            );
            // Rounding (loss of conjugacy) costs a few iterations beyond the exact-arithmetic
            // bound.
            let bound = if lemma { stiff + 1 } else { stiff + 7 };
            assert!(
                tight.iterations <= 2 * bound,
                "stiff {stiff}: {} iterations for the bound {bound}",
                tight.iterations,
            );
            eprintln!("stiff {stiff}: {} iterations to 1e-12", tight.iterations);
        }
    }

    /// The chunked products with the kept X (Gram matrix, Xᵀh, X c) are faer's plain products up
    /// to rounding (1e-12 relative), and the inexact step (their only user) has the same bits
    /// on one thread and on two.
    #[test]
    fn chunked_x_products_match_the_plain_ones_and_the_step_is_thread_independent() {
        let (n, rows) = (1003, 7);
        let x = Mat::from_fn(n, rows, |i, j| noise(3 + 17 * i + 7919 * j));
        let h = Mat::from_fn(n, 1, |i, _| noise(11 + 5 * i));
        let c = Mat::from_fn(rows, 1, |j, _| noise(13 + j));
        let relative = |a: &Mat<f64>, b: &Mat<f64>| (a - b).norm_l2() / b.norm_l2();
        let full = x.transpose() * &x;
        let lower = Mat::from_fn(rows, rows, |i, j| if i >= j { full[(i, j)] } else { 0.0 });
        assert!(relative(&gram_lower(x.as_ref()), &lower) < 1e-12);
        assert!(relative(&xt_times(x.as_ref(), h.as_ref()), &(x.transpose() * &h)) < 1e-12);
        let mut acc = h.clone();
        add_x_times(&mut acc, x.as_ref(), c.as_ref());
        assert!(relative(&acc, &(&h + &x * &c)) < 1e-12);
        let random = Random::new([3, 2, 2], 2);
        let sys = random.system();
        let steps: Vec<CgOutcome> = [1, 2]
            .iter()
            .map(|&threads| {
                rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap()
                    .install(|| pcg_step(&sys, 1e-10, 1000))
            })
            .collect();
        assert_eq!(steps[0].iterations, steps[1].iterations);
        assert!(steps[0].singular_lemma && steps[1].singular_lemma);
        for (a, b) in steps[0].step.iter().zip(&steps[1].step) {
            for k in 0..6 {
                assert_eq!(a[k].to_bits(), b[k].to_bits(), "{} vs {}", a[k], b[k]);
            }
        }
    }

    /// Z applied through a [`ZOperator`] (the equilibrium factor's role) backed by its dense
    /// columns.
    struct DenseOp<'a>(&'a Mat<f64>);

    impl ZOperator for DenseOp<'_> {
        fn transpose_apply(&self, u: MatRef<'_, f64>) -> Mat<f64> {
            self.0.transpose() * u
        }

        fn apply(&self, c: MatRef<'_, f64>) -> Mat<f64> {
            self.0 * c
        }

        fn columns(&self, rows: &[usize]) -> Mat<f64> {
            Mat::from_fn(self.0.nrows(), rows.len(), |i, j| self.0[(i, rows[j])])
        }
    }

    /// With only the soft rows' columns of Z kept and the whole of Z applied through the
    /// operator, the soft rows, the inexact steps (to a loose and a tight tolerance) and the
    /// exact step are those of the dense Z up to rounding.
    #[test]
    fn implicit_z_gives_the_steps_of_the_dense_z() {
        let stiff = 4;
        let random = Random::new([3, 2, 2], stiff);
        let sys = random.system();
        let op = DenseOp(&random.z);
        let kept: Vec<usize> = (0..9 - stiff).collect();
        let z_kept = op.columns(&kept);
        let implicit = NormalSystem {
            z: &z_kept,
            implicit: Some(ImplicitZ {
                kept: &kept,
                op: &op,
            }),
            ..sys
        };
        assert_eq!(soft_rows(&implicit), soft_rows(&sys));
        let gap = |a: &[Vector6<f64>], b: &[Vector6<f64>]| {
            let d: Vec<Vector6<f64>> = a.iter().zip(b).map(|(x, y)| x - y).collect();
            field_norm(&d) / field_norm(b)
        };
        for eta in [1e-2, 1e-10] {
            let (a, b) = (pcg_step(&implicit, eta, 1000), pcg_step(&sys, eta, 1000));
            assert_eq!(a.iterations, b.iterations, "η {eta}");
            assert!(
                gap(&a.step, &b.step) < 1e-10,
                "η {eta}: {:e}",
                gap(&a.step, &b.step)
            );
        }
        let (a, b) = (
            woodbury_step(&implicit).unwrap(),
            woodbury_step(&sys).unwrap(),
        );
        assert!(gap(&a, &b) < 1e-10, "Woodbury: {:e}", gap(&a, &b));
    }

    /// The Woodbury step with the singular lemma solves M Δs = −g: checked against the dense M
    /// (built column by column from `apply_normal`) and against CG.
    #[test]
    fn woodbury_step_solves_the_dense_normal_equations() {
        let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [1.0, 0.7, 0.5], [2, 2, 1]);
        let laplacian = PlasticLaplacian::new(&mesh.tets).unwrap();
        let (t, n, rows) = (mesh.tets.len(), mesh.vertices.len(), 9);
        let jacobians: Vec<SMatrix<f64, 12, 6>> = (0..t)
            .map(|e| SMatrix::from_fn(|i, j| noise(1000 * e + 12 * j + i)))
            .collect();
        let z = Mat::from_fn(3 * n, rows, |i, j| noise(7 + 31 * i + 1013 * j));
        let weights: Vec<f64> = (0..rows).map(|i| 0.5 + 0.1 * i as f64).collect();
        let gradient: Vec<Vector6<f64>> = (0..t)
            .map(|e| Vector6::from_fn(|k, _| noise(99_991 + 6 * e + k)))
            .collect();
        let sys = NormalSystem {
            jacobians: &jacobians,
            tets: &mesh.tets,
            num_nodes: n,
            z: &z,
            implicit: None,
            weights: &weights,
            gradient: &gradient,
            laplacian: &laplacian,
            alpha: 0.3,
        };
        let step = woodbury_step(&sys).unwrap();
        // Without the kept X (the exact step at Table 1 size): the same step.
        let minus_g: Vec<Vector6<f64>> = gradient.iter().map(|g| -g).collect();
        let uncached = WoodburySolver::with_cache(&sys, true, 0)
            .unwrap()
            .solve(&minus_g)
            .unwrap();
        let size = step.iter().map(|s| s.amax()).fold(0.0, f64::max);
        let gap = uncached
            .iter()
            .zip(&step)
            .map(|(a, b)| (a - b).amax())
            .fold(0.0, f64::max);
        assert!(gap < 1e-9 * size, "kept X vs not: {gap} (step {size})");
        // Dense M.
        let mut m = Mat::<f64>::zeros(6 * t, 6 * t);
        for j in 0..6 * t {
            let mut unit = vec![Vector6::zeros(); t];
            unit[j / 6][j % 6] = 1.0;
            for (e, v) in sys.apply_normal(&unit).iter().enumerate() {
                for k in 0..6 {
                    m[(6 * e + k, j)] = v[k];
                }
            }
        }
        let ds = Mat::from_fn(6 * t, 1, |i, _| step[i / 6][i % 6]);
        let residual = &m * &ds;
        let scale = gradient.iter().map(|g| g.amax()).fold(0.0, f64::max);
        for i in 0..6 * t {
            let r = residual[(i, 0)] + gradient[i / 6][i % 6];
            assert!(r.abs() < 1e-9 * scale, "row {i}: residual {r}");
        }
        let cg = cg_step(&sys, 1e-12, 10_000);
        let diff = cg
            .step
            .iter()
            .zip(&step)
            .map(|(a, b)| (a - b).amax())
            .fold(0.0, f64::max);
        assert!(diff < 1e-6 * size, "CG vs Woodbury {diff} (step {size})");
    }
}
