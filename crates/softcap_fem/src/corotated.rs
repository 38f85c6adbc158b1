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

/// Rotation R, stretch S = sym(RᵀF) and strain ε = S − I of element `geom` at `x`.
pub(crate) fn kinematics(
    geom: &TetGeometry,
    x: &[Vector3<f64>],
) -> (Matrix3<f64>, Matrix3<f64>, Matrix3<f64>) {
    let f = geom.deformation_gradient(x);
    let polar = softcap_core::polar_decomposition(&f);
    let r = polar.rotation;
    let rtf = r.transpose() * f;
    let s = 0.5 * (rtf + rtf.transpose());
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
    let sys = Matrix3::identity() * s.trace() - s;
    let sys_inv = if include_rotation && sys.determinant().abs() > 1e-10 * (1.0 + s.norm().powi(3))
    {
        sys.try_inverse()
    } else {
        None
    };
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
