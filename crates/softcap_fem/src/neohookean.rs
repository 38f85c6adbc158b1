//! The stable neo-Hookean tet (Smith, de Goes & Kim 2018):
//!
//! Ψ(F) = μ/2 (I_C − 3) − μ (J − 1) + λ/2 (J − 1)²,  I_C = ‖F‖²_F, J = det F,
//!
//! with the reparameterized λ = λ_Lamé + μ ([`NeoHookeanParams`]). It is rest-stable (P(I) = 0),
//! defined through inversion (no log J), and is the nonlinear reference / synthetic-truth material.
//!
//! PK1 (Smith 2018 eq. 18 without the log term): P = μF + (λ(J − 1) − μ) ∂J/∂F, with
//! ∂J/∂F = [f₁×f₂, f₂×f₀, f₀×f₁] (columns f_i of F).
//!
//! Tangent (Smith 2018 eq. 32–35 analogue): vec(dP) = [μ I₉ + λ g gᵀ + (λ(J − 1) − μ) H_J] vec(dF),
//! g = vec(∂J/∂F), H_J the Hessian of det F, built from cross-product matrices of the columns.
//! vec is column-major: index(i, k) = i + 3k.

use crate::NeoHookeanParams;
use crate::element::{Matrix12, TetGeometry};
use nalgebra::{Matrix3, SMatrix, Vector3};

/// 9×9 matrix acting on column-major vec(F).
pub type Matrix9 = SMatrix<f64, 9, 9>;

fn cofactor(f: &Matrix3<f64>) -> Matrix3<f64> {
    let (f0, f1, f2) = (
        f.column(0).into_owned(),
        f.column(1).into_owned(),
        f.column(2).into_owned(),
    );
    Matrix3::from_columns(&[f1.cross(&f2), f2.cross(&f0), f0.cross(&f1)])
}

/// Energy density Ψ(F) [J/m³].
pub fn energy_density(p: &NeoHookeanParams, f: &Matrix3<f64>) -> f64 {
    let j = f.determinant();
    0.5 * p.mu * (f.norm_squared() - 3.0) - p.mu * (j - 1.0)
        + 0.5 * p.lambda * (j - 1.0) * (j - 1.0)
}

/// First Piola–Kirchhoff stress P = ∂Ψ/∂F \[Pa\].
pub fn pk1(p: &NeoHookeanParams, f: &Matrix3<f64>) -> Matrix3<f64> {
    let j = f.determinant();
    f * p.mu + cofactor(f) * (p.lambda * (j - 1.0) - p.mu)
}

/// ∂P/∂F as a 9×9 matrix on column-major vec(F).
pub fn pk1_derivative(p: &NeoHookeanParams, f: &Matrix3<f64>) -> Matrix9 {
    let j = f.determinant();
    let cof = cofactor(f);
    let g = nalgebra::SVector::<f64, 9>::from_column_slice(cof.as_slice());
    let mut d = Matrix9::identity() * p.mu + g * g.transpose() * p.lambda;
    // Hessian of det F: blocks (col r, col c) = ∂²J/∂f_r∂f_c.
    let s = p.lambda * (j - 1.0) - p.mu;
    let (f0, f1, f2) = (
        f.column(0).into_owned(),
        f.column(1).into_owned(),
        f.column(2).into_owned(),
    );
    let blocks = [
        (0, 1, -f2.cross_matrix()),
        (0, 2, f1.cross_matrix()),
        (1, 2, -f0.cross_matrix()),
    ];
    for (r, c, m) in blocks {
        let m = m * s;
        let mut v = d.fixed_view_mut::<3, 3>(3 * r, 3 * c);
        v += m;
        let mut v = d.fixed_view_mut::<3, 3>(3 * c, 3 * r);
        v += m.transpose();
    }
    d
}

/// Internal forces f_a = V P g_a of one element (∂(VΨ)/∂x_a).
pub fn neohookean_forces(
    geom: &TetGeometry,
    p: &NeoHookeanParams,
    x: &[Vector3<f64>],
) -> [Vector3<f64>; 4] {
    let pm = pk1(p, &geom.deformation_gradient(x)) * geom.volume_m3;
    [
        pm * geom.grads[0],
        pm * geom.grads[1],
        pm * geom.grads[2],
        pm * geom.grads[3],
    ]
}

/// Element energy V Ψ(F) \[J\].
pub fn neohookean_energy(geom: &TetGeometry, p: &NeoHookeanParams, x: &[Vector3<f64>]) -> f64 {
    geom.volume_m3 * energy_density(p, &geom.deformation_gradient(x))
}

/// Analytic element tangent K_ab,ij = V Σ_kl (∂P_ik/∂F_jl) g_a,k g_b,l.
pub fn neohookean_tangent(
    geom: &TetGeometry,
    p: &NeoHookeanParams,
    x: &[Vector3<f64>],
) -> Matrix12 {
    let d = pk1_derivative(p, &geom.deformation_gradient(x));
    // dF/dx_bj = e_j g_bᵀ  ⇒  vec index (j + 3l) weight g_b,l. Build the 9×12 map.
    let mut dfdx = SMatrix::<f64, 9, 12>::zeros();
    for b in 0..4 {
        for j in 0..3 {
            for l in 0..3 {
                dfdx[(j + 3 * l, 3 * b + j)] = geom.grads[b][l];
            }
        }
    }
    dfdx.transpose() * d * dfdx * geom.volume_m3
}
