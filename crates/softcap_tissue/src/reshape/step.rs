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
//! [`cg_step`] solves the same system by conjugate gradients on M (the paper's Table 1 baseline),
//! for the benches.

use faer::linalg::solvers::Solve;
use faer::{Mat, MatRef};
use nalgebra::{SMatrix, Vector6};
use rayon::prelude::*;

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

/// A column of an owned [`Mat`] as a slice (faer stores each column contiguously).
fn contiguous_mut(c: faer::ColMut<'_, f64>) -> &mut [f64] {
    match c.try_as_col_major_mut() {
        Some(c) => c.as_slice_mut(),
        None => unreachable!("columns of an owned Mat are contiguous"),
    }
}

/// What both solvers of the normal equations need.
pub struct NormalSystem<'a> {
    /// ∂f_int/∂s per tet (12×6, node-major rows).
    pub jacobians: &'a [SMatrix<f64, 12, 6>],
    /// Nodes of each tet.
    pub tets: &'a [[usize; 4]],
    /// Number of mesh nodes N.
    pub num_nodes: usize,
    /// Z = K⁻¹ (Dᵀ) Gᵀ, 3N × rows.
    pub z: &'a Mat<f64>,
    /// Weight of each constraint row (> 0).
    pub weights: &'a [f64],
    /// Gradient g of the objective with respect to s.
    pub gradient: &'a [Vector6<f64>],
    /// The plastic-strain Laplacian.
    pub laplacian: &'a PlasticLaplacian,
    /// Smoothness weight α.
    pub alpha: f64,
}

impl NormalSystem<'_> {
    fn num_tets(&self) -> usize {
        self.jacobians.len()
    }

    /// Bᵀ applied to the columns of `v` (3N × m): a T × 6m component-major block
    /// (column 6c + k = component k of the result for column c). Tiles of [`TILE`] columns run
    /// in parallel; each reads every tet's 12×6 block once per tile.
    pub(super) fn bt_times(&self, v: MatRef<'_, f64>) -> Mat<f64> {
        let t = self.num_tets();
        let inputs = column_slices(v);
        let mut out = Mat::<f64>::zeros(t, 6 * v.ncols());
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
        out
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
        let mut zt_bv = self.z.transpose() * &bv;
        for (i, w) in self.weights.iter().enumerate() {
            zt_bv[(i, 0)] *= w;
        }
        let back = self.z * &zt_bv;
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
pub fn woodbury_step(sys: &NormalSystem<'_>) -> Option<Vec<Vector6<f64>>> {
    let minus_g: Vec<Vector6<f64>> = sys.gradient.iter().map(|g| -g).collect();
    WoodburySolver::new(sys)?.solve(&minus_g)
}

/// M⁻¹ by the Woodbury identity (module docs) with the small matrix C⁻¹ + UᵀA⁻¹U formed and
/// factored once: each further right-hand side costs two A⁻¹ applications (six columns each)
/// and products with Z and B, not the (rows × 6) columns of the factorization.
pub struct WoodburySolver<'s, 'a> {
    sys: &'s NormalSystem<'a>,
    lu: faer::linalg::solvers::PartialPivLu<f64>,
}

impl<'s, 'a> WoodburySolver<'s, 'a> {
    /// Forms C⁻¹ + UᵀA⁻¹U (rows + 6 square) and its LU.
    pub fn new(sys: &'s NormalSystem<'a>) -> Option<Self> {
        let rows = sys.z.ncols();
        let t = sys.num_tets();
        let mu = sys.mu();
        let lap = sys.laplacian;
        // P = W⁻¹ + Zᵀ Y, Y = B A⁻¹ Bᵀ Z block by block.
        let mut small = Mat::<f64>::zeros(rows + 6, rows + 6);
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
        for (i, w) in sys.weights.iter().enumerate() {
            small[(i, i)] += 1.0 / w;
        }
        // Q = −Zᵀ B Ψ / μ (Ψ_k: component k all 1/√T).
        // Six fields (component-major block T × 36): field k has component k = 1/√T.
        let mut psi = Mat::<f64>::zeros(t, 36);
        let inv_sqrt_t = 1.0 / (t as f64).sqrt();
        for e in 0..t {
            for k in 0..6 {
                psi[(e, 6 * k + k)] = inv_sqrt_t;
            }
        }
        let b_psi = sys.b_times(psi.as_ref());
        let q = sys.z.transpose() * &b_psi * (-1.0 / mu);
        for i in 0..rows {
            for k in 0..6 {
                small[(i, rows + k)] = q[(i, k)];
                small[(rows + k, i)] = q[(i, k)];
            }
        }
        let lu = small.partial_piv_lu();
        let ok = (0..rows + 6).all(|i| {
            let d = lu.U()[(i, i)];
            d.is_finite() && d != 0.0
        });
        ok.then_some(Self { sys, lu })
    }

    /// x = M⁻¹ r (`None` if it is not finite).
    pub fn solve(&self, r: &[Vector6<f64>]) -> Option<Vec<Vector6<f64>>> {
        let sys = self.sys;
        let rows = sys.z.ncols();
        let t = sys.num_tets();
        let mu = sys.mu();
        let lap = sys.laplacian;
        let inv_sqrt_t = 1.0 / (t as f64).sqrt();
        // a = A⁻¹ r.
        let mut a = NormalSystem::field_block(r);
        lap.apply_base_inverse(a.as_mut(), sys.alpha, mu);
        // Uᵀ a = [V a; Ψᵀ a] = [−Zᵀ B a; Σ_e a_k / √T].
        let ba = sys.b_times(a.as_ref());
        let va = sys.z.transpose() * &ba * (-1.0);
        let mut rhs = Mat::<f64>::zeros(rows + 6, 1);
        for i in 0..rows {
            rhs[(i, 0)] = va[(i, 0)];
        }
        for k in 0..6 {
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
                s[k] -= w[(e, k)] + c[(rows + k, 0)] * inv_sqrt_t / mu;
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
}

/// Δs = −M⁻¹ g by conjugate gradients on M (no preconditioner, as the paper's CG baseline), to
/// ‖r‖ ≤ `tolerance` ‖g‖ or `max_iterations`.
pub fn cg_step(sys: &NormalSystem<'_>, tolerance: f64, max_iterations: usize) -> CgOutcome {
    let dot = |a: &[Vector6<f64>], b: &[Vector6<f64>]| {
        a.iter().zip(b).map(|(u, v)| u.dot(v)).sum::<f64>()
    };
    let t = sys.num_tets();
    let mut x = vec![Vector6::zeros(); t];
    let mut r: Vec<Vector6<f64>> = sys.gradient.iter().map(|g| -g).collect();
    let g_norm = dot(&r, &r).sqrt().max(f64::MIN_POSITIVE);
    let mut p = r.clone();
    let mut rr = dot(&r, &r);
    let mut iterations = 0;
    while iterations < max_iterations && rr.sqrt() > tolerance * g_norm {
        let mp = sys.apply_normal(&p);
        let pmp = dot(&p, &mp);
        if pmp <= 0.0 || !pmp.is_finite() {
            break;
        }
        let step = rr / pmp;
        for i in 0..t {
            x[i] += p[i] * step;
            r[i] -= mp[i] * step;
        }
        let rr_next = dot(&r, &r);
        let beta = rr_next / rr;
        for i in 0..t {
            p[i] = r[i] + p[i] * beta;
        }
        rr = rr_next;
        iterations += 1;
    }
    CgOutcome {
        step: x,
        iterations,
        relative_residual: rr.sqrt() / g_norm,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A deterministic pseudo-random number in (−1, 1).
    fn noise(i: usize) -> f64 {
        ((i as f64 * 12.9898).sin() * 43758.5453).fract()
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
            weights: &weights,
            gradient: &gradient,
            laplacian: &laplacian,
            alpha: 0.3,
        };
        let step = woodbury_step(&sys).unwrap();
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
        let size = step.iter().map(|s| s.amax()).fold(0.0, f64::max);
        assert!(diff < 1e-6 * size, "CG vs Woodbury {diff} (step {size})");
    }
}
