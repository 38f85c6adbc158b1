//! The damped Gauss–Newton step of the eq. 9 fit: the umbrella operator L, the normal operator
//! J_mᵀJ_m + γLᵀL + γ_p I + μD applied matrix-free, and its preconditioned conjugate gradients.

use crate::StepPreconditioner;

/// The umbrella operator L of eq. 9, (Lv)_i = Σ_j (v_i − v_j) over the tets j sharing a vertex
/// with tet i, in compressed rows (one flat neighbour array). The LM steps apply LᵀL = LL to the
/// log-stiffness and the Poisson-ratio blocks at every conjugate-gradient iteration, so both
/// blocks are applied in one pass over the ≈ 60 neighbours of each tet.
pub(crate) struct Umbrella {
    offsets: Vec<usize>,
    neighbours: Vec<usize>,
}

impl Umbrella {
    pub(crate) fn new(adjacency: &[Vec<usize>]) -> Self {
        let mut offsets = Vec::with_capacity(adjacency.len() + 1);
        offsets.push(0);
        let mut neighbours = Vec::with_capacity(adjacency.iter().map(Vec::len).sum());
        for nb in adjacency {
            neighbours.extend_from_slice(nb);
            offsets.push(neighbours.len());
        }
        Self {
            offsets,
            neighbours,
        }
    }

    /// Number of neighbours of tet `i`.
    pub(crate) fn degree(&self, i: usize) -> usize {
        self.offsets[i + 1] - self.offsets[i]
    }

    /// (L a, L b) for the two parameter blocks at once.
    fn apply_pair(&self, a: &[f64], b: &[f64], out_a: &mut [f64], out_b: &mut [f64]) {
        for (i, w) in self.offsets.windows(2).enumerate() {
            let nb = &self.neighbours[w[0]..w[1]];
            let deg = nb.len() as f64;
            let (mut sa, mut sb) = (deg * a[i], deg * b[i]);
            for &j in nb {
                sa -= a[j];
                sb -= b[j];
            }
            out_a[i] = sa;
            out_b[i] = sb;
        }
    }

    /// γ_s LLv_s and γ_ν LLv_ν added to `out` for v = (v_s, v_ν) (blocks of length T).
    pub(crate) fn add_smoothing(
        &self,
        v: &[f64],
        gammas: [f64; 2],
        scratch: &mut UmbrellaScratch,
        out: &mut [f64],
    ) {
        let t = self.offsets.len() - 1;
        let UmbrellaScratch { la, lb, lla, llb } = scratch;
        self.apply_pair(&v[..t], &v[t..2 * t], la, lb);
        self.apply_pair(la, lb, lla, llb);
        for i in 0..t {
            out[i] += gammas[0] * lla[i];
            out[t + i] += gammas[1] * llb[i];
        }
    }

    /// γ_s‖L v_s‖² + γ_ν‖L v_ν‖².
    pub(crate) fn smoothing_cost(
        &self,
        v: &[f64],
        gammas: [f64; 2],
        scratch: &mut UmbrellaScratch,
    ) -> f64 {
        let t = self.offsets.len() - 1;
        let UmbrellaScratch { la, lb, .. } = scratch;
        self.apply_pair(&v[..t], &v[t..2 * t], la, lb);
        gammas[0] * la.iter().map(|v| v * v).sum::<f64>()
            + gammas[1] * lb.iter().map(|v| v * v).sum::<f64>()
    }
}

/// Work vectors of [`Umbrella`] (length T each).
pub(crate) struct UmbrellaScratch {
    la: Vec<f64>,
    lb: Vec<f64>,
    lla: Vec<f64>,
    llb: Vec<f64>,
}

impl UmbrellaScratch {
    pub(crate) fn new(t: usize) -> Self {
        Self {
            la: vec![0.0; t],
            lb: vec![0.0; t],
            lla: vec![0.0; t],
            llb: vec![0.0; t],
        }
    }
}

/// Solves (J_mᵀJ_m + γLᵀL + γ_p I + μD) h = −g on the free variables by preconditioned CG
/// ([`StepPreconditioner`]).
#[allow(clippy::too_many_arguments)]
pub(crate) fn damped_step(
    umbrella: &Umbrella,
    scratch: &mut UmbrellaScratch,
    flat: &[f64],
    grad: &[f64],
    free: &[bool],
    diag: &[f64],
    mu: f64,
    prior: f64,
    gammas: [f64; 2],
    max_iter: usize,
    tolerance: f64,
    preconditioner: StepPreconditioner,
) -> (Vec<f64>, usize) {
    let n = grad.len();
    // J_m stored row by row = J_mᵀ column-major (n × m): J_mᵀ(J_m v) by `normal_product`.
    let m = flat.len() / n.max(1);
    let jt = faer::MatRef::from_column_major_slice(flat, n, m);
    let mut jv = vec![0.0; m];
    let mut apply = |v: &[f64], out: &mut [f64]| {
        normal_product(jt, v, &mut jv, out);
        umbrella.add_smoothing(v, gammas, scratch, out);
        for i in 0..n {
            out[i] += mu * diag[i] * v[i] + prior * v[i];
            if !free[i] {
                out[i] = 0.0;
            }
        }
    };
    let mut precondition: Box<dyn FnMut(&[f64], &mut [f64])> = match preconditioner {
        StepPreconditioner::Jacobi => {
            let inv: Vec<f64> = (0..n)
                .map(|i| {
                    if free[i] {
                        1.0 / (diag[i] * (1.0 + mu) + 1e-300)
                    } else {
                        0.0
                    }
                })
                .collect();
            Box::new(move |r: &[f64], z: &mut [f64]| {
                for i in 0..n {
                    z[i] = r[i] * inv[i];
                }
            })
        }
        StepPreconditioner::Woodbury => {
            woodbury_preconditioner(umbrella, flat, free, diag, mu, prior, gammas)
        }
    };
    let mut h = vec![0.0; n];
    let mut res: Vec<f64> = (0..n)
        .map(|i| if free[i] { -grad[i] } else { 0.0 })
        .collect();
    let mut z = vec![0.0; n];
    precondition(&res, &mut z);
    let mut p = z.clone();
    let mut rz: f64 = res.iter().zip(&z).map(|(a, b)| a * b).sum();
    let r0 = rz.abs().sqrt();
    let mut ap = vec![0.0; n];
    let mut iterations = 0;
    for _ in 0..max_iter {
        if rz.abs().sqrt() <= tolerance * r0 || r0 == 0.0 {
            break;
        }
        iterations += 1;
        apply(&p, &mut ap);
        let pap: f64 = p.iter().zip(&ap).map(|(a, b)| a * b).sum();
        if pap <= 0.0 || !pap.is_finite() {
            break;
        }
        let a = rz / pap;
        for i in 0..n {
            h[i] += a * p[i];
            res[i] -= a * ap[i];
        }
        precondition(&res, &mut z);
        let rz_new: f64 = res.iter().zip(&z).map(|(a, b)| a * b).sum();
        let beta = rz_new / rz;
        rz = rz_new;
        for i in 0..n {
            p[i] = z[i] + beta * p[i];
        }
    }
    (h, iterations)
}

/// Bytes of J_m rows [`normal_product`] multiplies per block: small enough that a block read
/// from memory for J_m v is still in the core's L2 cache (≥ 512 KiB on current x86-64 and
/// AArch64 cores, together with v and the output of length n) when J_mᵀ reads it again.
const NORMAL_PRODUCT_BLOCK_BYTES: usize = 256 * 1024;

/// The reference J_mᵀ(J_m v) that [`normal_product`] reproduces bit for bit: the two whole faer
/// products (session 12's LM step). Kept as the unit test's oracle and the bench's baseline.
#[doc(hidden)]
pub fn normal_product_unblocked(
    jt: faer::MatRef<'_, f64>,
    v: &[f64],
    jv: &mut [f64],
    out: &mut [f64],
) {
    let (n, m) = (jt.nrows(), jt.ncols());
    faer::linalg::matmul::matmul(
        faer::MatMut::from_column_major_slice_mut(jv, m, 1),
        faer::Accum::Replace,
        jt.transpose(),
        faer::MatRef::from_column_major_slice(v, n, 1),
        1.0,
        faer::Par::Seq,
    );
    faer::linalg::matmul::matmul(
        faer::MatMut::from_column_major_slice_mut(out, n, 1),
        faer::Accum::Replace,
        jt,
        faer::MatRef::from_column_major_slice(jv, m, 1),
        1.0,
        faer::Par::Seq,
    );
}

/// out = J_mᵀ (J_m v) for J_m stored row by row (`jt` = J_mᵀ, n × m column-major; `jv`: m
/// scratch), the dense part of the normal operator of the LM step (bickel2009 eq. 9's
/// Gauss–Newton matrix J_mᵀJ_m, applied at every CG iteration).
///
/// Blocked over the rows of J_m so that each row is read from memory once (J_m is 3k × 2T: 37 MB
/// on the 5,184-tet suite template, so two whole products stream it twice). Bit-identical to the
/// two whole products `J_m v` then `J_mᵀ (J_m v)`, which the fit's results depend on (docs/tissue.md,
/// "Rounding sensitivity"): faer's row-major product computes each entry of J_m v as one dot
/// product of one row, and its column-major product accumulates the columns of J_mᵀ in order
/// (`dst ← x_j · s_j + dst`, j = 0, 1, …), so continuing it block after block (`Accum::Add`)
/// performs the same operations in the same order (tested:
/// `normal_product_is_bitwise_the_two_products`). Bench: `lm_normal_product` in benches/probing.rs.
pub fn normal_product(jt: faer::MatRef<'_, f64>, v: &[f64], jv: &mut [f64], out: &mut [f64]) {
    let (n, m) = (jt.nrows(), jt.ncols());
    if m == 0 {
        out.fill(0.0);
        return;
    }
    let block = (NORMAL_PRODUCT_BLOCK_BYTES / (8 * n.max(1))).clamp(1, m);
    let vm = faer::MatRef::from_column_major_slice(v, n, 1);
    let mut outm = faer::MatMut::from_column_major_slice_mut(out, n, 1);
    for start in (0..m).step_by(block) {
        let len = block.min(m - start);
        let rows = jt.subcols(start, len);
        let s = &mut jv[start..start + len];
        faer::linalg::matmul::matmul(
            faer::MatMut::from_column_major_slice_mut(s, len, 1),
            faer::Accum::Replace,
            rows.transpose(),
            vm,
            1.0,
            faer::Par::Seq,
        );
        faer::linalg::matmul::matmul(
            outm.as_mut(),
            if start == 0 {
                faer::Accum::Replace
            } else {
                faer::Accum::Add
            },
            rows,
            faer::MatRef::from_column_major_slice(s, len, 1),
            1.0,
            faer::Par::Seq,
        );
    }
}

/// P⁻¹ of [`StepPreconditioner::Woodbury`] on the free variables: P = J_Fᵀ J_F + Δ with
/// Δᵢ = μDᵢ + γ_p + γᵢ (LᵀL)ᵢᵢ ((LᵀL)ᵢᵢ = deg² + deg for the umbrella operator), applied as
/// P⁻¹v = Δ⁻¹v − Δ⁻¹J_Fᵀ S⁻¹ J_F Δ⁻¹v with S = I + J_F Δ⁻¹ J_Fᵀ (k × k, Cholesky once per
/// step). Falls back to Δ⁻¹ (Jacobi) if S does not factor.
fn woodbury_preconditioner<'a>(
    umbrella: &Umbrella,
    jt_flat: &'a [f64],
    free: &'a [bool],
    diag: &[f64],
    mu: f64,
    prior: f64,
    gammas: [f64; 2],
) -> Box<dyn FnMut(&[f64], &mut [f64]) + 'a> {
    let n = free.len();
    let m = jt_flat.len() / n.max(1);
    let t = n / 2;
    let jt = faer::MatRef::from_column_major_slice(jt_flat, n, m);
    let inv_delta: Vec<f64> = (0..n)
        .map(|i| {
            if free[i] {
                let deg = umbrella.degree(i % t) as f64;
                let gam = gammas[usize::from(i >= t)];
                1.0 / (mu * diag[i] + prior + gam * (deg * deg + deg)).max(1e-300)
            } else {
                0.0
            }
        })
        .collect();
    // W = Δ^{-1/2} J_Fᵀ (n × m, column-major like `jt_flat`), S = I + WᵀW.
    let sqrt_inv: Vec<f64> = inv_delta.iter().map(|v| v.sqrt()).collect();
    let w: Vec<f64> = jt_flat
        .chunks_exact(n)
        .flat_map(|col| col.iter().zip(&sqrt_inv).map(|(j, s)| j * s))
        .collect();
    let w = faer::MatRef::from_column_major_slice(&w, n, m);
    let mut s = faer::Mat::<f64>::identity(m, m);
    faer::linalg::matmul::matmul(
        s.as_mut(),
        faer::Accum::Add,
        w.transpose(),
        w,
        1.0,
        faer::Par::Seq,
    );
    let s = nalgebra::DMatrix::<f64>::from_fn(m, m, |a, b| s[(a, b)]);
    let Some(chol) = s.cholesky() else {
        return Box::new(move |r: &[f64], z: &mut [f64]| {
            for i in 0..n {
                z[i] = r[i] * inv_delta[i];
            }
        });
    };
    let mut y = nalgebra::DVector::<f64>::zeros(m);
    let mut jy = vec![0.0; n];
    Box::new(move |r: &[f64], z: &mut [f64]| {
        for i in 0..n {
            z[i] = r[i] * inv_delta[i];
        }
        faer::linalg::matmul::matmul(
            faer::MatMut::from_column_major_slice_mut(y.as_mut_slice(), m, 1),
            faer::Accum::Replace,
            jt.transpose(),
            faer::MatRef::from_column_major_slice(z, n, 1),
            1.0,
            faer::Par::Seq,
        );
        chol.solve_mut(&mut y);
        // z ← z − Δ⁻¹ J_Fᵀ S⁻¹ J_F Δ⁻¹ r (entries of constrained variables stay 0).
        faer::linalg::matmul::matmul(
            faer::MatMut::from_column_major_slice_mut(&mut jy, n, 1),
            faer::Accum::Replace,
            jt,
            faer::MatRef::from_column_major_slice(y.as_slice(), m, 1),
            1.0,
            faer::Par::Seq,
        );
        for i in 0..n {
            z[i] -= inv_delta[i] * jy[i];
        }
    })
}

#[cfg(test)]
mod tests {
    use super::{normal_product, normal_product_unblocked};

    /// Deterministic entries of mixed sign and magnitude (a fixed hash of the index, no RNG).
    fn entries(len: usize, salt: u64) -> Vec<f64> {
        (0..len as u64)
            .map(|i| {
                let h = (i.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ salt)
                    .wrapping_mul(0xBF58_476D_1CE4_E5B9);
                let unit = (h >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
                unit * 10f64.powi((h % 7) as i32 - 3)
            })
            .collect()
    }

    /// The blocked J_mᵀ(J_m v) of the LM step is bit for bit the two whole faer products it
    /// replaces (the fit's results depend on the last bit, docs/tissue.md): one block, several
    /// blocks with a partial last one, one row per block, and no rows.
    #[test]
    fn normal_product_is_bitwise_the_two_products() {
        for (n, m) in [(1000, 20), (1000, 75), (40_000, 5), (333, 1), (500, 0)] {
            let flat = entries(n * m, 1);
            let v = entries(n, 2);
            let jt = faer::MatRef::from_column_major_slice(&flat, n, m);
            let mut jv = vec![f64::NAN; m];
            let mut want = vec![f64::NAN; n];
            normal_product_unblocked(jt, &v, &mut jv, &mut want);
            let mut got = vec![f64::NAN; n];
            let mut scratch = vec![0.0; m];
            normal_product(jt, &v, &mut scratch, &mut got);
            for i in 0..n {
                assert_eq!(
                    got[i].to_bits(),
                    want[i].to_bits(),
                    "n {n}, m {m}, entry {i}"
                );
            }
            for r in 0..m {
                assert_eq!(
                    scratch[r].to_bits(),
                    jv[r].to_bits(),
                    "n {n}, m {m}, row {r}"
                );
            }
        }
    }
}
