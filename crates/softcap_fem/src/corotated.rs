//! Corotational element kernels for a *general* small-strain stress law σ(ε) (shared by
//! [`crate::plasticity`] and [`crate::anisotropy`]).
//!
//! Same kinematics as [`crate::element`]: F = R S (polar), ε = sym(RᵀF) − I in the rest frame,
//! first Piola stress P = R σ(ε), nodal forces f_a = V P g_a. For the tangent, with a direction dF,
//! M = RᵀdF and W = RᵀdR = [w]×, w = (tr S I − S)⁻¹ axial(M − Mᵀ) (McAdams et al. 2011), so
//! dε = sym(M − W S) and dP = R W σ + R dσ(dε), where dσ = C_t : dε is the material tangent
//! supplied by the caller (elastic C, or the algorithmic elastoplastic tangent).

use crate::element::{Matrix12, TetGeometry};
use nalgebra::{Matrix3, Vector3};

/// Rotation R of the polar decomposition F = R S (R ∈ SO(3)).
///
/// Fast path for well-conditioned, non-inverted F (det F > 10⁻⁶ ‖F‖³, i.e. every element of a
/// sane soft-tissue simulation): Higham's scaled Newton iteration X ← ½(γX + γ⁻¹X⁻ᵀ),
/// γ = (‖X⁻¹‖_F / ‖X‖_F)^{1/2} (Higham 1986, "Computing the polar decomposition — with
/// applications", §3), which converges quadratically to the orthogonal polar factor; for
/// det F > 0 that factor is the rotation. X⁻ᵀ = cof(X) / det X (3×3 cofactors, no general
/// inverse). Every iterate is X_k = R H_k with H_k symmetric, and an unscaled step maps
/// H = I + E to I + ½E²(I + E)⁻¹, so once a step moves X by δ ≤ 10⁻⁸ the new iterate is R to
/// ≈ ½δ² ≤ 5·10⁻¹⁷: it is returned as is (the same R as the SVD route to rounding, for the cost
/// of a few 3×3 cofactor matrices instead of a 3×3 SVD). Inverted, near-singular or non-finite F
/// — and an iteration that fails to settle — go to [`softcap_core::polar_decomposition`] (SVD
/// with the Irving et al. 2004 inversion handling).
pub(crate) fn polar_rotation(f: &Matrix3<f64>) -> Matrix3<f64> {
    let norm2 = f.norm_squared();
    let det = f.determinant();
    if norm2.is_finite() && det > 0.0 && det > 1e-6 * norm2 * norm2.sqrt() / 5.196_152_422_706_632 {
        // Column-major scalars (x[i + 3j] = X_ij): no index checks in the hot loop.
        let mut x = [0.0; 9];
        x.copy_from_slice(f.as_slice());
        let mut scaled = true;
        for _ in 0..40 {
            let c = cofactor(&x);
            let d = x[0] * c[0] + x[3] * c[3] + x[6] * c[6];
            if !(d > 0.0 && d.is_finite()) {
                break;
            }
            let (gx, gc) = if scaled {
                let nx: f64 = x.iter().map(|v| v * v).sum();
                let nc: f64 = c.iter().map(|v| v * v).sum();
                let gamma = (nc / (d * d * nx)).sqrt().sqrt();
                (0.5 * gamma, 0.5 / (gamma * d))
            } else {
                (0.5, 0.5 / d)
            };
            let mut delta2 = 0.0;
            for (xk, ck) in x.iter_mut().zip(&c) {
                let next = gx * *xk + gc * ck;
                delta2 += (next - *xk) * (next - *xk);
                *xk = next;
            }
            if delta2 < 1e-4 {
                scaled = false;
            }
            if delta2 <= 1e-16 {
                return Matrix3::from_column_slice(&x);
            }
        }
    }
    softcap_core::polar_decomposition(f).rotation
}

/// Cofactor matrix of a 3×3 matrix, both column-major: cof(X) = det(X) X⁻ᵀ.
#[inline]
fn cofactor(x: &[f64; 9]) -> [f64; 9] {
    let [x00, x10, x20, x01, x11, x21, x02, x12, x22] = *x;
    [
        x11 * x22 - x12 * x21,
        x02 * x21 - x01 * x22,
        x01 * x12 - x02 * x11,
        x12 * x20 - x10 * x22,
        x00 * x22 - x02 * x20,
        x02 * x10 - x00 * x12,
        x10 * x21 - x11 * x20,
        x01 * x20 - x00 * x21,
        x00 * x11 - x01 * x10,
    ]
}

/// Rotation R and stretch S = sym(RᵀF) of F = R S ([`polar_rotation`]).
pub(crate) fn rotation_stretch(f: &Matrix3<f64>) -> (Matrix3<f64>, Matrix3<f64>) {
    let r = polar_rotation(f);
    let rtf = r.transpose() * f;
    (r, 0.5 * (rtf + rtf.transpose()))
}

/// Rotation R, stretch S = sym(RᵀF) and strain ε = S − I of element `geom` at `x`
/// ([`rotation_stretch`]: Higham's scaled Newton polar factor, the SVD route only for inverted or
/// near-singular F). The plastic return mapping and the anisotropic element ran the 3 × 3 SVD
/// here; in a rigid-tip J2 replay that was ≈ 40 % of the time, and the two rotations agree to
/// rounding (`newton_polar_matches_svd`).
pub(crate) fn kinematics(
    geom: &TetGeometry,
    x: &[Vector3<f64>],
) -> (Matrix3<f64>, Matrix3<f64>, Matrix3<f64>) {
    let (r, s) = rotation_stretch(&geom.deformation_gradient(x));
    (r, s, s - Matrix3::identity())
}

/// f_a = V R σ g_a.
pub(crate) fn forces_from_stress(
    geom: &TetGeometry,
    rotation: &Matrix3<f64>,
    sigma: &Matrix3<f64>,
) -> [Vector3<f64>; 4] {
    let p = rotation * sigma * geom.volume_m3;
    [
        p * geom.grads[0],
        p * geom.grads[1],
        p * geom.grads[2],
        p * geom.grads[3],
    ]
}

/// (tr S I − S)⁻¹ of the rotation derivative w = (tr S I − S)⁻¹ axial(M − Mᵀ) for the stretch S
/// (McAdams et al. 2011), `None` near inversion (the matrix singular), where the rotation term
/// is dropped.
pub(crate) fn spin_inverse(stretch: &Matrix3<f64>) -> Option<Matrix3<f64>> {
    let s = stretch;
    let sys = Matrix3::identity() * s.trace() - s;
    if sys.determinant().abs() > 1e-10 * (1.0 + s.norm().powi(3)) {
        sys.try_inverse()
    } else {
        None
    }
}

/// Element matrix ∂f/∂x for stress σ at the current state and material tangent `dsigma`
/// (dε ↦ dσ). With `include_rotation = false` the ∂R terms are dropped, which gives the warped
/// matrix R (V Bᵀ C_t B) Rᵀ (bickel2009 eq. 10–11 with C_t in place of E).
pub(crate) fn tangent_from_stress(
    geom: &TetGeometry,
    rotation: &Matrix3<f64>,
    stretch: &Matrix3<f64>,
    sigma: &Matrix3<f64>,
    dsigma: impl Fn(&Matrix3<f64>) -> Matrix3<f64>,
    include_rotation: bool,
) -> Matrix12 {
    let r = rotation;
    let s = stretch;
    let sys_inv = include_rotation.then(|| spin_inverse(s)).flatten();
    let mut out = Matrix12::zeros();
    for b in 0..4 {
        for j in 0..3 {
            let mut df = Matrix3::zeros();
            for k in 0..3 {
                df[(j, k)] = geom.grads[b][k];
            }
            let m = r.transpose() * df;
            let a_mat = m - m.transpose();
            let axial = Vector3::new(a_mat[(2, 1)], a_mat[(0, 2)], a_mat[(1, 0)]);
            let w = sys_inv.map_or_else(Vector3::zeros, |inv| inv * axial);
            let wm = w.cross_matrix();
            let de = m - wm * s;
            let de = 0.5 * (de + de.transpose());
            let dp = (r * wm * sigma + r * dsigma(&de)) * geom.volume_m3;
            for a in 0..4 {
                let col = dp * geom.grads[a];
                for i in 0..3 {
                    out[(3 * a + i, 3 * b + j)] = col[i];
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The fast scaled-Newton rotation equals the SVD polar factor to rounding, from tiny strains
    /// to stretches of 3× and near-inversion (det F → 10⁻⁴), and the stretch is symmetric PD.
    #[test]
    fn newton_polar_matches_svd() {
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut uniform = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        let mut worst = 0.0f64;
        for case in 0..2000 {
            let amplitude = [1e-6, 1e-3, 0.1, 0.5, 2.0][case % 5];
            let axis = Vector3::new(uniform(), uniform(), uniform());
            let rot = nalgebra::Rotation3::new(axis * 3.0).into_inner();
            let mut h = Matrix3::identity();
            for i in 0..3 {
                for j in 0..3 {
                    h[(i, j)] += amplitude * uniform();
                }
            }
            let f = rot * h;
            if f.determinant() <= 1e-4 {
                continue;
            }
            let fast = polar_rotation(&f);
            let svd = softcap_core::polar_decomposition(&f).rotation;
            worst = worst.max((fast - svd).norm());
            assert!((fast.transpose() * fast - Matrix3::identity()).norm() < 1e-14);
            let (_, s) = rotation_stretch(&f);
            assert!((s - s.transpose()).norm() == 0.0);
        }
        assert!(worst < 1e-12, "max |R_newton − R_svd| = {worst:e}");
    }
}
