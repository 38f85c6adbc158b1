//! Tetrahedron geometry and the linear corotational element (bickel2009 §3.2, eq. 7; Müller &
//! Gross 2004).
//!
//! Notation: rest nodes X_a, deformed nodes x_a (a = 0..3), shape-function gradients g_a = ∇N_a
//! (constant on a linear tet), deformation gradient F = Σ_a x_a g_aᵀ = D_s D_m⁻¹, rest volume V.
//!
//! Corotational force (Müller & Gross 2004, the force behind bickel2009 eq. 10):
//!
//! f_e = R_e K_e (R_eᵀ x_e − X_e),
//!
//! with R_e the rotation of the polar decomposition F = R S (scaled Newton iteration, falling back to
//! [`softcap_core::polar_decomposition`] for inverted elements).
//! Because R is the *polar* rotation, ∇(Rᵀx − X) = RᵀF − I = S − I is symmetric, so
//! f_a = V R σ(ε) g_a with ε = sym(RᵀF) − I and σ = 2μ ε + λ_L tr(ε) I. This is the gradient of
//! Ψ(F) = ½ ε : C : ε, i.e. the element is hyperelastic for fixed (λ, α).
//!
//! Two linearizations are offered ([`StiffnessKind`]):
//! * **warped** R K_e Rᵀ (bickel2009 §3.2, eq. 10–11): what the paper assembles; it drops the
//!   derivative of R and is the matrix of the fixed-point iteration of §3.4;
//! * **consistent** ∂f/∂x including dR (derived below in [`corotational_tangent`]): the exact
//!   Jacobian, used by Newton iterations and by the exact parameter Jacobian.

use crate::{FemError, LinearParams};
use nalgebra::{Matrix3, SMatrix, Vector3, Vector6};

/// 12×12 element matrix, node-major (rows 3a..3a+3 belong to node a).
pub type Matrix12 = SMatrix<f64, 12, 12>;

/// How an element is linearized for assembly.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum StiffnessKind {
    /// R K_e Rᵀ (bickel2009 eq. 10–11, Müller & Gross 2004); for the neo-Hookean element this is
    /// the same as `Consistent`.
    Warped,
    /// The exact derivative ∂f/∂x (includes ∂R/∂x for the corotational element).
    Consistent,
}

/// Precomputed rest geometry of one tet.
#[derive(Clone, Debug, PartialEq)]
pub struct TetGeometry {
    /// Vertex indices.
    pub nodes: [usize; 4],
    /// Shape-function gradients g_a = ∇N_a in the rest frame [1/m].
    pub grads: [Vector3<f64>; 4],
    /// Rest volume V_e \[m³\] (positive).
    pub volume_m3: f64,
}

impl TetGeometry {
    /// Rest geometry of the tet `nodes` over `rest` positions; `index` is used in errors.
    pub fn new(index: usize, nodes: [usize; 4], rest: &[Vector3<f64>]) -> Result<Self, FemError> {
        for &v in &nodes {
            if v >= rest.len() {
                return Err(FemError::VertexOutOfRange {
                    tet: index,
                    vertex: v,
                    num_vertices: rest.len(),
                });
            }
            if !rest[v].iter().all(|c| c.is_finite()) {
                return Err(FemError::NonFinite {
                    what: "rest vertex position",
                });
            }
        }
        let x0 = rest[nodes[0]];
        let dm = Matrix3::from_columns(&[
            rest[nodes[1]] - x0,
            rest[nodes[2]] - x0,
            rest[nodes[3]] - x0,
        ]);
        let det = dm.determinant();
        let scale = dm.column(0).norm() * dm.column(1).norm() * dm.column(2).norm();
        let inv = dm.try_inverse();
        let Some(dm_inv) = inv.filter(|_| det.abs() > 1e-12 * scale && scale > 0.0) else {
            return Err(FemError::DegenerateElement {
                tet: index,
                volume_m3: det / 6.0,
            });
        };
        let g1: Vector3<f64> = dm_inv.row(0).transpose();
        let g2: Vector3<f64> = dm_inv.row(1).transpose();
        let g3: Vector3<f64> = dm_inv.row(2).transpose();
        Ok(Self {
            nodes,
            grads: [-(g1 + g2 + g3), g1, g2, g3],
            volume_m3: det.abs() / 6.0,
        })
    }

    /// F = Σ_a x_a g_aᵀ.
    pub fn deformation_gradient(&self, x: &[Vector3<f64>]) -> Matrix3<f64> {
        let mut f = Matrix3::zeros();
        for a in 0..4 {
            f += x[self.nodes[a]] * self.grads[a].transpose();
        }
        f
    }

    /// The strain–displacement matrix B_e of bickel2009 eq. 7: ε = B_e u_e with the Voigt order
    /// (ε_xx, ε_yy, ε_zz, γ_xy, γ_xz, γ_yz) of bickel2009 §3.2 (engineering shears).
    pub fn b_matrix(&self) -> SMatrix<f64, 6, 12> {
        let mut b = SMatrix::<f64, 6, 12>::zeros();
        for a in 0..4 {
            let g = self.grads[a];
            let c = 3 * a;
            b[(0, c)] = g.x;
            b[(1, c + 1)] = g.y;
            b[(2, c + 2)] = g.z;
            b[(3, c)] = g.y;
            b[(3, c + 1)] = g.x;
            b[(4, c)] = g.z;
            b[(4, c + 2)] = g.x;
            b[(5, c + 1)] = g.z;
            b[(5, c + 2)] = g.y;
        }
        b
    }
}

/// Rest geometry of every tet; errors name the first bad tet.
pub fn tet_geometries(
    rest: &[Vector3<f64>],
    tets: &[[usize; 4]],
) -> Result<Vec<TetGeometry>, FemError> {
    tets.iter()
        .enumerate()
        .map(|(i, t)| TetGeometry::new(i, *t, rest))
        .collect()
}

/// (V B_eᵀ G B_e, V B_eᵀ H B_e): the two parameter-free parts of K_e = λ_e (·) + α_e (·)
/// (bickel2009 eq. 7), in closed form per 3×3 node block:
///
/// (V BᵀGB)_ab = V/2 ((g_a·g_b) I + g_b g_aᵀ),  (V BᵀHB)_ab = V (g_a g_bᵀ − g_b g_aᵀ − (g_a·g_b) I).
pub fn stiffness_basis(geom: &TetGeometry) -> (Matrix12, Matrix12) {
    let mut kg = Matrix12::zeros();
    let mut kh = Matrix12::zeros();
    let v = geom.volume_m3;
    for a in 0..4 {
        for b in 0..4 {
            let ga = geom.grads[a];
            let gb = geom.grads[b];
            let d = ga.dot(&gb);
            let bg = (gb * ga.transpose() + Matrix3::identity() * d) * (0.5 * v);
            let bh = (ga * gb.transpose() - gb * ga.transpose() - Matrix3::identity() * d) * v;
            kg.fixed_view_mut::<3, 3>(3 * a, 3 * b).copy_from(&bg);
            kh.fixed_view_mut::<3, 3>(3 * a, 3 * b).copy_from(&bh);
        }
    }
    (kg, kh)
}

/// Unwarped element stiffness K_e = λ_e V BᵀGB + α_e V BᵀHB (bickel2009 eq. 7).
pub fn element_stiffness(geom: &TetGeometry, p: &LinearParams) -> Matrix12 {
    let (kg, kh) = stiffness_basis(geom);
    kg * p.lambda + kh * p.alpha
}

/// Stress of the local linear material, σ = 2μ ε + λ_L tr(ε) I with (λ_L, μ) = (α, λ/2 − α):
/// the tensor form of σ = (λG + αH) ε (bickel2009 eq. 1, 5).
pub fn linear_stress(p: &LinearParams, strain: &Matrix3<f64>) -> Matrix3<f64> {
    lame_stress(p.lame(), strain)
}

/// σ = 2μ ε + λ_L tr(ε) I of the Lamé pair (λ_L, μ).
fn lame_stress((lame, mu): (f64, f64), strain: &Matrix3<f64>) -> Matrix3<f64> {
    strain * (2.0 * mu) + Matrix3::identity() * (lame * strain.trace())
}

/// Corotated small strain ε = sym(RᵀF) − I and the rotation R of F = R S (the polar rotation;
/// scaled Newton iteration for non-inverted F, SVD with inversion handling otherwise — see
/// `corotated::polar_rotation`).
pub fn corotated_strain(f: &Matrix3<f64>) -> (Matrix3<f64>, Matrix3<f64>) {
    let (r, s) = crate::corotated::rotation_stretch(f);
    (r, s - Matrix3::identity())
}

/// Voigt vector (ε_xx, ε_yy, ε_zz, γ_xy, γ_xz, γ_yz) of a symmetric strain tensor
/// (bickel2009 §3.2; engineering shears so that σ = Eε with E of eq. 5).
pub fn strain_voigt(e: &Matrix3<f64>) -> Vector6<f64> {
    Vector6::new(
        e[(0, 0)],
        e[(1, 1)],
        e[(2, 2)],
        2.0 * e[(0, 1)],
        2.0 * e[(0, 2)],
        2.0 * e[(1, 2)],
    )
}

/// Internal (elastic restoring) forces f_e = R K_e (Rᵀ x_e − X_e) of one corotational element
/// (Müller & Gross 2004; bickel2009 eq. 10), evaluated as f_a = V R σ(sym(RᵀF) − I) g_a.
/// Returns the forces *exerted by the nodes on the element*: equilibrium is f_int = f_ext.
pub fn corotational_forces(
    geom: &TetGeometry,
    p: &LinearParams,
    x: &[Vector3<f64>],
) -> [Vector3<f64>; 4] {
    let f = geom.deformation_gradient(x);
    let (r, eps) = corotated_strain(&f);
    let p_mat = r * linear_stress(p, &eps) * geom.volume_m3;
    [
        p_mat * geom.grads[0],
        p_mat * geom.grads[1],
        p_mat * geom.grads[2],
        p_mat * geom.grads[3],
    ]
}

/// The warped stiffness R K_e Rᵀ (bickel2009 §3.2, Müller & Gross 2004) for a given rotation.
///
/// Evaluated in closed form from the rotated gradients r_a = R g_a (R Rᵀ = I): with
/// d = g_a·g_b = r_a·r_b, the node block (a, b) of [`stiffness_basis`] rotates to
///
/// (R K_e Rᵀ)_ab = λ V/2 (d I + r_b r_aᵀ) + α V (r_a r_bᵀ − r_b r_aᵀ − d I),
///
/// which is R K_e Rᵀ without forming K_e or the 16 triple products.
pub fn warped_stiffness(geom: &TetGeometry, p: &LinearParams, rotation: &Matrix3<f64>) -> Matrix12 {
    let mut out = Matrix12::zeros();
    warped_stiffness_into(geom, p, rotation, &mut out);
    out
}

/// [`warped_stiffness`] written into `out` (every entry), for element loops that fill their
/// matrices in place.
pub fn warped_stiffness_into(
    geom: &TetGeometry,
    p: &LinearParams,
    rotation: &Matrix3<f64>,
    out: &mut Matrix12,
) {
    let r = [
        rotation * geom.grads[0],
        rotation * geom.grads[1],
        rotation * geom.grads[2],
        rotation * geom.grads[3],
    ];
    let cg = 0.5 * p.lambda * geom.volume_m3;
    let ch = p.alpha * geom.volume_m3;
    for a in 0..4 {
        for b in a..4 {
            let d = geom.grads[a].dot(&geom.grads[b]);
            let diag = (cg - ch) * d;
            for i in 0..3 {
                for j in 0..3 {
                    let ab = r[a][i] * r[b][j];
                    let ba = r[b][i] * r[a][j];
                    let mut v = cg * ba + ch * (ab - ba);
                    if i == j {
                        v += diag;
                    }
                    out[(3 * a + i, 3 * b + j)] = v;
                    out[(3 * b + j, 3 * a + i)] = v;
                }
            }
        }
    }
}

/// Forces, warped stiffness and elastic energy of one corotational element from a single polar
/// decomposition: (f_a = V R σ g_a, ½ V σ : ε) returned and R K_e Rᵀ written into `stiffness`
/// (every entry; element loops fill their matrices in place) — [`corotational_forces`],
/// [`warped_stiffness`] and the element term of the model energy, evaluated together (what the
/// equilibrium iterations of bickel2009 §3.4 need at every iterate).
pub fn corotational_linearization(
    geom: &TetGeometry,
    p: &LinearParams,
    x: &[Vector3<f64>],
    stiffness: &mut Matrix12,
) -> ([Vector3<f64>; 4], f64) {
    let f = geom.deformation_gradient(x);
    let (r, eps) = corotated_strain(&f);
    let sigma = linear_stress(p, &eps);
    let energy = 0.5 * geom.volume_m3 * sigma.component_mul(&eps).sum();
    let p_mat = r * sigma * geom.volume_m3;
    let forces = [
        p_mat * geom.grads[0],
        p_mat * geom.grads[1],
        p_mat * geom.grads[2],
        p_mat * geom.grads[3],
    ];
    warped_stiffness_into(geom, p, &r, stiffness);
    (forces, energy)
}

/// Consistent tangent ∂f_e/∂x_e of the corotational element (parameters held fixed).
///
/// With P(F) = R σ(ε), ε = sym(RᵀF) − I and F = RS: for a direction dF let M = RᵀdF and
/// W = RᵀdR = \[w\]×. Differentiating F = RS gives M − Mᵀ = WS + SW = [(tr S I − S) w]×, hence
/// w = (tr S I − S)⁻¹ axial(M − Mᵀ) (the rotation-derivative formula of McAdams et al. 2011 / Twigg
/// & Kačić-Alesić 2010). Then dε = sym(M − W S) and dP = R W σ + R σ(dε); column (b, j) of the
/// element matrix is V dP g_a for dF = e_j g_bᵀ. Near inversion (tr S I − S singular) the rotation
/// term is dropped.
pub fn corotational_tangent(geom: &TetGeometry, p: &LinearParams, x: &[Vector3<f64>]) -> Matrix12 {
    let f = geom.deformation_gradient(x);
    let (r, s) = crate::corotated::rotation_stretch(&f);
    let eps = s - Matrix3::identity();
    let sigma = linear_stress(p, &eps);
    crate::corotated::tangent_from_stress(geom, &r, &s, &sigma, |de| linear_stress(p, de), true)
}

/// One corotational element at a fixed step state (x, v), kept for the exact derivative of the
/// element's share of a dynamic step's residual, f_e(x) + β K_e(x) v_e with the warped
/// K_e(x) = R K_e Rᵀ (bickel2009 eq. 10) and v = v(x) of the integrator, along any number of
/// directions ([`corotational_step_differential`]): what a direction does not change — the
/// polar decomposition F = R S, the stress and the rotated velocity gradient — evaluated once.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CorotationalStepFrame {
    rotation: Matrix3<f64>,
    /// (tr S I − S)⁻¹ of the rotation derivative, zero near inversion (as in
    /// [`corotational_tangent`]).
    spin: Matrix3<f64>,
    /// S + β Rᵀ Ḟ: what W = RᵀdR multiplies inside the strain increment.
    stretch_rate: Matrix3<f64>,
    /// σ(ε) + β σ(sym(Rᵀ Ḟ)): what W multiplies outside it.
    stress: Matrix3<f64>,
    /// (λ_L, μ) of [`LinearParams::lame`].
    lame: (f64, f64),
    /// 1 + β c_v (c_v = ∂v/∂x of the integrator).
    rate_factor: f64,
}

/// The [`CorotationalStepFrame`] of element `geom` with parameters `p` at positions `x`,
/// velocities `v`, stiffness-proportional damping `beta` and the integrator's c_v = ∂v/∂x.
pub fn corotational_step_frame(
    geom: &TetGeometry,
    p: &LinearParams,
    x: &[Vector3<f64>],
    v: &[Vector3<f64>],
    beta: f64,
    cv: f64,
) -> CorotationalStepFrame {
    let (r, s) = crate::corotated::rotation_stretch(&geom.deformation_gradient(x));
    let spin = crate::corotated::spin_inverse(&s).unwrap_or_else(Matrix3::zeros);
    let rate = r.transpose() * geom.deformation_gradient(v);
    let sigma = linear_stress(p, &(s - Matrix3::identity()));
    let sigma_v = linear_stress(p, &((rate + rate.transpose()) * 0.5));
    CorotationalStepFrame {
        rotation: r,
        spin,
        stretch_rate: s + rate * beta,
        stress: sigma + sigma_v * beta,
        lame: p.lame(),
        rate_factor: 1.0 + beta * cv,
    }
}

/// The warped K_e w_e = R K_e Rᵀ w_e of a nodal field `w` (per element node) at the state of
/// `frame`: V R σ(sym(Rᵀ ∇w)) g_a with ∇w = Σ_a w_a g_aᵀ (as
/// [`crate::ElasticModel::element_forces_products`], the rotation kept).
pub fn corotational_step_warped_product(
    geom: &TetGeometry,
    frame: &CorotationalStepFrame,
    w: &[Vector3<f64>; 4],
) -> [Vector3<f64>; 4] {
    let rate = frame.rotation.transpose() * nodal_gradient(geom, w);
    let p = frame.rotation * lame_stress(frame.lame, &((rate + rate.transpose()) * 0.5));
    let p = p * geom.volume_m3;
    std::array::from_fn(|a| p * geom.grads[a])
}

/// Σ_a u_a g_aᵀ of the element's node values `u`.
fn nodal_gradient(geom: &TetGeometry, u: &[Vector3<f64>; 4]) -> Matrix3<f64> {
    let mut grad = Matrix3::zeros();
    for a in 0..4 {
        grad += u[a] * geom.grads[a].transpose();
    }
    grad
}

/// The change of f_e + β K_e(x) v_e (per element node) when the element's nodes move by `du`
/// and the velocities by c_v du, to first order, at the state of `frame` — the product of the
/// exact step tangent ∂f_e/∂x + β ∂(K_e v_e)/∂x + β c_v K_e with `du`, without forming it.
///
/// With M = Rᵀ dF (dF = Σ_b du_b g_bᵀ) and W = RᵀdR = \[w\]×, w = (tr S I − S)⁻¹ axial(M − Mᵀ)
/// (the rotation derivative of [`corotational_tangent`], McAdams et al. 2011), the elastic part
/// is dP = R W σ + R σ(sym(M − W S)); the damping force V R σ(sym(Rᵀ Ḟ)) g_a (the warped
/// K_e v_e, [`crate::ElasticModel::element_forces_products`]) changes by R W σ_v − R σ(sym(W Rᵀ Ḟ))
/// through R and by c_v R σ(sym M) through v. Summed (σ is linear):
/// dP = R (W (σ + β σ_v) + σ(sym((1 + β c_v) M − W (S + β Rᵀ Ḟ)))), and df_a = V dP g_a.
pub fn corotational_step_differential(
    geom: &TetGeometry,
    frame: &CorotationalStepFrame,
    du: &[Vector3<f64>; 4],
) -> [Vector3<f64>; 4] {
    let r = &frame.rotation;
    let m = r.transpose() * nodal_gradient(geom, du);
    let axial = Vector3::new(
        m[(2, 1)] - m[(1, 2)],
        m[(0, 2)] - m[(2, 0)],
        m[(1, 0)] - m[(0, 1)],
    );
    let w = (frame.spin * axial).cross_matrix();
    let e = m * frame.rate_factor - w * frame.stretch_rate;
    let e = (e + e.transpose()) * 0.5;
    let dp = r * (w * frame.stress + lame_stress(frame.lame, &e)) * geom.volume_m3;
    std::array::from_fn(|a| dp * geom.grads[a])
}

/// ∂f_e/∂λ_e and ∂f_e/∂α_e at fixed rotation: R (V BᵀGB)(Rᵀx − X) and R (V BᵀHB)(Rᵀx − X)
/// (the per-element right-hand sides of bickel2009 appendix eq. 11–12). Evaluated as V R σ g_a
/// with σ_G = ε and σ_H = tr(ε) I − 2ε.
pub fn corotational_parameter_forces(
    geom: &TetGeometry,
    x: &[Vector3<f64>],
) -> ([Vector3<f64>; 4], [Vector3<f64>; 4]) {
    let f = geom.deformation_gradient(x);
    let (r, eps) = corotated_strain(&f);
    let pg = r * eps * geom.volume_m3;
    let ph = r * (Matrix3::identity() * eps.trace() - eps * 2.0) * geom.volume_m3;
    let g = geom.grads;
    (
        [pg * g[0], pg * g[1], pg * g[2], pg * g[3]],
        [ph * g[0], ph * g[1], ph * g[2], ph * g[3]],
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::material::{matrix_g, matrix_h};

    fn sample() -> (Vec<Vector3<f64>>, TetGeometry) {
        let rest = vec![
            Vector3::new(0.1, 0.0, 0.0),
            Vector3::new(1.0, 0.2, 0.1),
            Vector3::new(0.2, 1.1, 0.0),
            Vector3::new(0.0, 0.3, 0.9),
        ];
        let g = TetGeometry::new(0, [0, 1, 2, 3], &rest).unwrap();
        (rest, g)
    }

    #[test]
    fn closed_form_basis_equals_bt_g_b() {
        let (_, g) = sample();
        let b = g.b_matrix();
        let (kg, kh) = stiffness_basis(&g);
        let kg_ref = b.transpose() * matrix_g() * b * g.volume_m3;
        let kh_ref = b.transpose() * matrix_h() * b * g.volume_m3;
        assert!((kg - kg_ref).norm() < 1e-12 * kg_ref.norm());
        assert!((kh - kh_ref).norm() < 1e-12 * kh_ref.norm());
    }

    #[test]
    fn closed_form_warped_stiffness_equals_r_k_rt() {
        let (_, g) = sample();
        let p = LinearParams::from_young_poisson(3.0e4, 0.35).unwrap();
        let r = nalgebra::Rotation3::from_scaled_axis(Vector3::new(0.4, -0.7, 0.2)).into_inner();
        let k = element_stiffness(&g, &p);
        let mut reference = Matrix12::zeros();
        for a in 0..4 {
            for b in 0..4 {
                let blk = r * k.fixed_view::<3, 3>(3 * a, 3 * b) * r.transpose();
                reference
                    .fixed_view_mut::<3, 3>(3 * a, 3 * b)
                    .copy_from(&blk);
            }
        }
        let w = warped_stiffness(&g, &p, &r);
        assert!((w - reference).norm() < 1e-12 * reference.norm());
        assert_eq!(w, w.transpose());
    }

    #[test]
    fn newton_polar_matches_svd_polar_and_fused_linearization_matches_parts() {
        let (rest, g) = sample();
        let p = LinearParams::from_young_poisson(1.0e4, 0.3).unwrap();
        let rot = nalgebra::Rotation3::from_scaled_axis(Vector3::new(1.1, 0.3, -2.0)).into_inner();
        for (k, stretch) in [
            Matrix3::identity(),
            Matrix3::new(1.01, 0.002, 0.0, 0.002, 0.99, 0.001, 0.0, 0.001, 1.0),
            Matrix3::new(1.6, 0.3, -0.2, 0.3, 0.4, 0.1, -0.2, 0.1, 1.1),
            Matrix3::new(0.05, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 1.0),
            // inverted: SVD route
            Matrix3::new(-0.2, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0),
        ]
        .into_iter()
        .enumerate()
        {
            let f = rot * stretch;
            let svd = softcap_core::polar_decomposition(&f);
            let (r, s) = crate::corotated::rotation_stretch(&f);
            assert!(
                (r - svd.rotation).norm() < 1e-12,
                "case {k}: {r} vs {}",
                svd.rotation
            );
            assert!(
                (s - svd.stretch).norm() < 1e-12 * (1.0 + f.norm()),
                "case {k}"
            );
            assert!((r.determinant() - 1.0).abs() < 1e-13);
            // Fused forces / warped matrix / energy = the separate kernels.
            let x: Vec<Vector3<f64>> = rest.iter().map(|v| f * v).collect();
            let mut km = Matrix12::from_element(f64::NAN);
            let (fo, en) = corotational_linearization(&g, &p, &x, &mut km);
            let fr = corotational_forces(&g, &p, &x);
            for a in 0..4 {
                assert!((fo[a] - fr[a]).norm() <= 1e-12 * (1.0 + fr[a].norm()));
            }
            let (rr, eps) = corotated_strain(&g.deformation_gradient(&x));
            assert!((km - warped_stiffness(&g, &p, &rr)).norm() == 0.0);
            let e_ref = 0.5 * g.volume_m3 * linear_stress(&p, &eps).component_mul(&eps).sum();
            assert!((en - e_ref).abs() <= 1e-12 * e_ref.abs().max(1e-300));
        }
    }

    #[test]
    fn degenerate_tet_is_an_error() {
        let rest = vec![
            Vector3::zeros(),
            Vector3::x(),
            Vector3::y(),
            Vector3::new(1.0, 1.0, 0.0),
        ];
        assert!(matches!(
            TetGeometry::new(7, [0, 1, 2, 3], &rest),
            Err(FemError::DegenerateElement { tet: 7, .. })
        ));
    }
}
