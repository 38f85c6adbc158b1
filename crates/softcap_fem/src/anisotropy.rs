//! Transversely isotropic linear elasticity on the corotational element (thesis §8.5, eq. 8.5).
//!
//! In the material frame whose third axis is the fibre direction a (the printed tube axis of
//! thesis §8.5), the stress–strain matrix on the Voigt strain (ε_xx, ε_yy, ε_zz, γ_xy, γ_xz, γ_yz)
//! (engineering shears, as [`crate::LinearParams::stress_strain_matrix`]) has five parameters
//! {E11, E12, E13, E33, E44}:
//!
//! ```text
//!     ⎡E11 E12 E13  0   0   0 ⎤
//!     ⎢E12 E11 E13  0   0   0 ⎥
//! E = ⎢E13 E13 E33  0   0   0 ⎥      (thesis eq. 8.5)
//!     ⎢ 0   0   0  E66  0   0 ⎥      E66 = (E11 − E12)/2  (shear in the plane ⊥ a)
//!     ⎢ 0   0   0   0  E44  0 ⎥
//!     ⎣ 0   0   0   0   0  E44⎦
//! ```
//!
//! The thesis prints (E11 − E12)/2 in the last diagonal slot; with its Voigt order and the fibre
//! along z, transverse isotropy puts it on the xy shear (the plane ⊥ fibre) and E44 on the two
//! shears that involve the fibre — that is what is implemented (the isotropic case
//! E11 = λ_L + 2μ, E12 = E13 = λ_L, E33 = E11, E44 = μ then reproduces bickel2009 eq. 5 exactly).
//!
//! Uniaxial moduli (inverting the normal block): along the fibre E_a = E33 − 2E13²/(E11 + E12);
//! across it E_t = (E11 − E12)((E11 + E12)E33 − 2E13²)/(E11 E33 − E13²).
//!
//! **Positive definiteness.** In the Mandel basis (shears × √2, where the matrix is a true
//! quadratic form) the eigenvalues are E11 − E12 (twice: the in-plane normal difference and the
//! in-plane shear), 2E44 (twice) and those of the 2×2 block [[E11 + E12, √2 E13], [√2 E13, E33]].
//! [`TransverselyIsotropicParams::is_positive_definite`] checks them;
//! [`TransverselyIsotropicParams::project_positive_definite`] clips them at a floor and rebuilds
//! the five parameters — eigenvalue clipping (Rebonato & Jäckel 1999, the technique thesis §8.4
//! names for keeping fitted transversely isotropic matrices PD). The clipped matrix is the
//! nearest (Frobenius, Mandel basis) matrix with eigenvalues ≥ floor and stays of the eq. 8.5 form.
//!
//! **Element.** With the fibre a_e given in the rest frame, the corotational element uses
//! σ = C_e ε, ε = sym(RᵀF) − I, f_a = V R σ g_a (the anisotropic analogue of bickel2009 eq. 7,
//! warped as in eq. 10). E is linear in the five parameters, so ∂f_e/∂p_k = V R (E_k ε) g_a exactly
//! ([`AnisotropicModel::parameter_forces`]). As in Müller & Gross 2004 the force is R K (Rᵀx − X);
//! for an anisotropic C it is not the gradient of an energy (σ is not coaxial with the stretch),
//! so [`ElasticModel::energy`] is `None` and the consistent tangent is the exact ∂f/∂x
//! (non-symmetric in general; the warped matrix R K Rᵀ is the symmetric alternative).
//!
//! **Fibre families** ([`AnisotropicModel::with_fibre_families`]). The HGO material (Holzapfel,
//! Gasser & Ogden 2000, J. Elasticity 61, §4.2) adds to an isotropic matrix one term per fibre
//! family a_i, Ψ_i = k1/(2k2) (exp(k2 (I4_i − 1)²) − 1) with I4_i = a_i·C a_i; two families
//! symmetric about an axis (angles ±θ) make the body orthotropic, not transversely isotropic.
//! At the rest state ∂Ψ_i/∂I4_i = 0 and ∂²Ψ_i/∂I4_i² = k1, and I4_i − 1 = 2 a_i·E a_i, so to first
//! order the family's stress is S_i = 4 k1 (a_i·E a_i) a_i ⊗ a_i: on the Voigt strain the rank-one
//! matrix 4 k1 w_i w_iᵀ, w_i = (a_x², a_y², a_z², a_x a_y, a_x a_z, a_y a_z)
//! ([`fibre_family_stiffness`]). It is added to the element's rest-frame matrix C_e, so the same
//! corotational kernel carries it. The families bear tension and compression alike (HGO's
//! tension-only switch is a finite-strain refinement that this linear element does not carry).

use crate::corotated::{forces_from_stress, kinematics, tangent_from_stress};
use crate::element::{Matrix12, StiffnessKind, TetGeometry, strain_voigt, tet_geometries};
use crate::model::ElasticModel;
use crate::{FemError, LinearParams};
use nalgebra::{Matrix2, Matrix3, Matrix6, Unit, Vector3, Vector6};
use serde::{Deserialize, Serialize};
use softcap_mesh::TetMesh;

/// The five parameters of thesis eq. 8.5 \[Pa\]; the fibre is the material frame's third axis.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct TransverselyIsotropicParams {
    /// E11 (normal stiffness in the plane ⊥ fibre).
    pub e11_pa: f64,
    /// E12 (in-plane normal coupling).
    pub e12_pa: f64,
    /// E13 (in-plane ↔ fibre normal coupling).
    pub e13_pa: f64,
    /// E33 (normal stiffness along the fibre).
    pub e33_pa: f64,
    /// E44 (shear in planes containing the fibre).
    pub e44_pa: f64,
}

fn voigt_to_tensor(v: &Vector6<f64>) -> Matrix3<f64> {
    Matrix3::new(
        v[0],
        0.5 * v[3],
        0.5 * v[4],
        0.5 * v[3],
        v[1],
        0.5 * v[5],
        0.5 * v[4],
        0.5 * v[5],
        v[2],
    )
}

fn stress_to_tensor(s: &Vector6<f64>) -> Matrix3<f64> {
    Matrix3::new(s[0], s[3], s[4], s[3], s[1], s[5], s[4], s[5], s[2])
}

impl TransverselyIsotropicParams {
    /// Parameter vector (E11, E12, E13, E33, E44).
    pub fn to_vector(&self) -> [f64; 5] {
        [
            self.e11_pa,
            self.e12_pa,
            self.e13_pa,
            self.e33_pa,
            self.e44_pa,
        ]
    }

    /// From (E11, E12, E13, E33, E44).
    pub fn from_vector(p: [f64; 5]) -> Self {
        Self {
            e11_pa: p[0],
            e12_pa: p[1],
            e13_pa: p[2],
            e33_pa: p[3],
            e44_pa: p[4],
        }
    }

    /// The isotropic special case of a corotational (λ, α) material (bickel2009 eq. 5).
    pub fn from_isotropic(p: &LinearParams) -> Self {
        let (l, m) = p.lame();
        Self {
            e11_pa: l + 2.0 * m,
            e12_pa: l,
            e13_pa: l,
            e33_pa: l + 2.0 * m,
            e44_pa: m,
        }
    }

    /// From engineering constants: transverse Young's modulus E_t, fibre Young's modulus E_a,
    /// in-plane Poisson ratio ν_t, fibre Poisson ratio ν_a (transverse contraction per fibre
    /// stretch), fibre shear modulus G_a. Inverts the compliance; errors if not PD.
    pub fn from_engineering(
        young_transverse_pa: f64,
        young_fibre_pa: f64,
        poisson_transverse: f64,
        poisson_fibre: f64,
        shear_fibre_pa: f64,
    ) -> Result<Self, FemError> {
        let (et, ea, nt, na) = (
            young_transverse_pa,
            young_fibre_pa,
            poisson_transverse,
            poisson_fibre,
        );
        let s = Matrix3::new(
            1.0 / et,
            -nt / et,
            -na / ea,
            -nt / et,
            1.0 / et,
            -na / ea,
            -na / ea,
            -na / ea,
            1.0 / ea,
        );
        let c = s.try_inverse().ok_or(FemError::NotPositiveDefinite {
            element: usize::MAX,
            min_eigenvalue_pa: 0.0,
        })?;
        let p = Self {
            e11_pa: c[(0, 0)],
            e12_pa: c[(0, 1)],
            e13_pa: c[(0, 2)],
            e33_pa: c[(2, 2)],
            e44_pa: shear_fibre_pa,
        };
        p.validate(usize::MAX)?;
        Ok(p)
    }

    /// The 6×6 matrix of eq. 8.5 in the material frame (fibre = third axis).
    #[rustfmt::skip]
    pub fn stiffness_local(&self) -> Matrix6<f64> {
        let (a, b, c, d, g) = (self.e11_pa, self.e12_pa, self.e13_pa, self.e33_pa, self.e44_pa);
        let s = 0.5 * (a - b);
        Matrix6::new(
            a, b, c, 0.0, 0.0, 0.0,
            b, a, c, 0.0, 0.0, 0.0,
            c, c, d, 0.0, 0.0, 0.0,
            0.0, 0.0, 0.0, s, 0.0, 0.0,
            0.0, 0.0, 0.0, 0.0, g, 0.0,
            0.0, 0.0, 0.0, 0.0, 0.0, g,
        )
    }

    /// ∂E/∂p_k of the local matrix, k over (E11, E12, E13, E33, E44) (E is linear in p).
    pub fn stiffness_local_derivatives() -> [Matrix6<f64>; 5] {
        let mut out = [Matrix6::zeros(); 5];
        for (k, o) in out.iter_mut().enumerate() {
            let mut p = [0.0; 5];
            p[k] = 1.0;
            *o = Self::from_vector(p).stiffness_local();
        }
        out
    }

    /// Eigenvalues of the Mandel-basis matrix: [E11 − E12, 2E44, μ₋, μ₊] (the first two double),
    /// μ± those of [[E11 + E12, √2 E13], [√2 E13, E33]].
    pub fn mandel_eigenvalues(&self) -> [f64; 4] {
        let (a, b, c, d) = (self.e11_pa, self.e12_pa, self.e13_pa, self.e33_pa);
        let m = Matrix2::new(a + b, 2f64.sqrt() * c, 2f64.sqrt() * c, d);
        let e = m.symmetric_eigenvalues();
        let (lo, hi) = if e[0] <= e[1] {
            (e[0], e[1])
        } else {
            (e[1], e[0])
        };
        [a - b, 2.0 * self.e44_pa, lo, hi]
    }

    /// True if every parameter is finite and the matrix is positive definite.
    pub fn is_positive_definite(&self) -> bool {
        self.to_vector().iter().all(|v| v.is_finite())
            && self.mandel_eigenvalues().iter().all(|&l| l > 0.0)
    }

    /// Error naming `element` unless positive definite.
    pub fn validate(&self, element: usize) -> Result<(), FemError> {
        if self.is_positive_definite() {
            Ok(())
        } else {
            let min = self
                .mandel_eigenvalues()
                .iter()
                .fold(f64::INFINITY, |m, &v| m.min(v));
            Err(FemError::NotPositiveDefinite {
                element,
                min_eigenvalue_pa: min,
            })
        }
    }

    /// Eigenvalue clipping (Rebonato & Jäckel 1999) in the Mandel basis: every eigenvalue below
    /// `min_eigenvalue_pa` (> 0) is raised to it; the result is the nearest eq. 8.5 matrix with
    /// that floor. A PD matrix whose eigenvalues are all ≥ the floor is returned unchanged.
    pub fn project_positive_definite(&self, min_eigenvalue_pa: f64) -> Self {
        let floor = min_eigenvalue_pa.max(f64::MIN_POSITIVE);
        let (a, b, c, d) = (self.e11_pa, self.e12_pa, self.e13_pa, self.e33_pa);
        let diff = (a - b).max(floor);
        let g = self.e44_pa.max(0.5 * floor);
        let m = Matrix2::new(a + b, 2f64.sqrt() * c, 2f64.sqrt() * c, d);
        let eig = m.symmetric_eigen();
        let clipped = eig.eigenvalues.map(|l| l.max(floor));
        let m2 = eig.eigenvectors * Matrix2::from_diagonal(&clipped) * eig.eigenvectors.transpose();
        let sum = m2[(0, 0)];
        Self {
            e11_pa: 0.5 * (sum + diff),
            e12_pa: 0.5 * (sum - diff),
            e13_pa: 0.5 * (m2[(0, 1)] + m2[(1, 0)]) / 2f64.sqrt(),
            e33_pa: m2[(1, 1)],
            e44_pa: g,
        }
    }

    /// Uniaxial Young's modulus along the fibre: E33 − 2E13²/(E11 + E12).
    pub fn young_fibre_pa(&self) -> f64 {
        self.e33_pa - 2.0 * self.e13_pa * self.e13_pa / (self.e11_pa + self.e12_pa)
    }

    /// Uniaxial Young's modulus across the fibre:
    /// (E11 − E12)((E11 + E12)E33 − 2E13²)/(E11 E33 − E13²).
    pub fn young_transverse_pa(&self) -> f64 {
        let (a, b, c, d) = (self.e11_pa, self.e12_pa, self.e13_pa, self.e33_pa);
        (a - b) * ((a + b) * d - 2.0 * c * c) / (a * d - c * c)
    }

    /// Stress tensor σ = C ε for a rest-frame strain tensor ε and fibre `fibre` (rest frame).
    pub fn stress(&self, fibre: &Unit<Vector3<f64>>, strain: &Matrix3<f64>) -> Matrix3<f64> {
        stress_with(&self.stiffness_local(), &material_frame(fibre), strain)
    }
}

/// Rotation whose third column is the fibre (columns = material axes in the rest frame).
pub fn material_frame(fibre: &Unit<Vector3<f64>>) -> Matrix3<f64> {
    let a = fibre.into_inner();
    let helper = if a.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let t1 = (helper - a * a.dot(&helper)).normalize();
    let t2 = a.cross(&t1);
    Matrix3::from_columns(&[t1, t2, a])
}

fn stress_with(c_local: &Matrix6<f64>, q: &Matrix3<f64>, strain: &Matrix3<f64>) -> Matrix3<f64> {
    let local = q.transpose() * strain * q;
    let s = c_local * strain_voigt(&local);
    q * stress_to_tensor(&s) * q.transpose()
}

/// The 6×6 Voigt matrix (engineering shears) in the rest frame for fibre `fibre`.
pub fn stiffness_in_frame(c_local: &Matrix6<f64>, fibre: &Unit<Vector3<f64>>) -> Matrix6<f64> {
    let q = material_frame(fibre);
    let mut out = Matrix6::zeros();
    for k in 0..6 {
        let mut e = Vector6::zeros();
        e[k] = 1.0;
        let s = stress_with(c_local, &q, &voigt_to_tensor(&e));
        let sv = Vector6::new(
            s[(0, 0)],
            s[(1, 1)],
            s[(2, 2)],
            s[(0, 1)],
            s[(0, 2)],
            s[(1, 2)],
        );
        out.set_column(k, &sv);
    }
    out
}

/// One HGO fibre family (Holzapfel, Gasser & Ogden 2000, §4.2) linearized at the rest state.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FibreFamily {
    /// Fibre direction a_i (rest frame).
    pub direction: Unit<Vector3<f64>>,
    /// HGO stiffness-like parameter k1 \[Pa\] (the family's uniaxial modulus along a_i is 4 k1).
    pub k1_pa: f64,
}

/// The dyad a ⊗ a of a direction in the Voigt order of this module:
/// w = (a_x², a_y², a_z², a_x a_y, a_x a_z, a_y a_z). On the Voigt strain (engineering shears)
/// w·ε = a·E a, the normal strain along a unit a; as a Voigt stress it is the uniaxial stress of
/// unit magnitude along a unit a.
pub fn voigt_dyad(a: &Vector3<f64>) -> Vector6<f64> {
    Vector6::new(
        a.x * a.x,
        a.y * a.y,
        a.z * a.z,
        a.x * a.y,
        a.x * a.z,
        a.y * a.z,
    )
}

/// Voigt matrix (engineering shears) of one linearized fibre family: 4 k1 w wᵀ with
/// w = [`voigt_dyad`]`(a)` = (a_x², a_y², a_z², a_x a_y, a_x a_z, a_y a_z), the first-order stress
/// S = 4 k1 (a·E a) a ⊗ a of Ψ = k1/(2k2) (exp(k2 (I4 − 1)²) − 1) (HGO 2000 §4.2).
pub fn fibre_family_stiffness(family: &FibreFamily) -> Matrix6<f64> {
    let w = voigt_dyad(&family.direction.into_inner());
    w * w.transpose() * (4.0 * family.k1_pa)
}

/// The two fibre directions at angles ±`half_angle_rad` about `bisector` in the plane with unit
/// normal `normal` (`bisector` is projected into that plane first): a_± = cos θ b ± sin θ (n × b).
/// θ = 0 gives one family twice. `None` when `bisector` is (nearly) along `normal`.
pub fn symmetric_fibre_pair(
    bisector: &Vector3<f64>,
    normal: &Vector3<f64>,
    half_angle_rad: f64,
) -> Option<[Unit<Vector3<f64>>; 2]> {
    let n = normal.try_normalize(1e-12)?;
    let b = (bisector - n * n.dot(bisector)).try_normalize(1e-9)?;
    let t = n.cross(&b);
    let (s, c) = half_angle_rad.sin_cos();
    Some([
        Unit::new_normalize(b * c + t * s),
        Unit::new_normalize(b * c - t * s),
    ])
}

/// Corotational tet model with per-element transversely isotropic stiffness and fibre direction,
/// optionally reinforced by HGO fibre families ([`AnisotropicModel::with_fibre_families`]).
#[derive(Clone, Debug)]
pub struct AnisotropicModel {
    rest: Vec<Vector3<f64>>,
    geometry: Vec<TetGeometry>,
    params: Vec<TransverselyIsotropicParams>,
    fibres: Vec<Unit<Vector3<f64>>>,
    /// Per-element sum of the fibre families' matrices ([`fibre_family_stiffness`]); zero
    /// without families.
    reinforcement: Vec<Matrix6<f64>>,
    /// Rest-frame Voigt matrices C_e (cached), reinforcement included.
    stiffness: Vec<Matrix6<f64>>,
}

impl AnisotropicModel {
    /// Model over `mesh`; every element's parameters must be PD (the first bad one is named).
    pub fn new(
        mesh: &TetMesh,
        params: Vec<TransverselyIsotropicParams>,
        fibres: Vec<Unit<Vector3<f64>>>,
    ) -> Result<Self, FemError> {
        let geometry = tet_geometries(&mesh.vertices, &mesh.tets)?;
        for (what, len) in [
            ("per-element parameters", params.len()),
            ("per-element fibres", fibres.len()),
        ] {
            if len != geometry.len() {
                return Err(FemError::LengthMismatch {
                    what,
                    expected: geometry.len(),
                    got: len,
                });
            }
        }
        for (e, p) in params.iter().enumerate() {
            p.validate(e)?;
        }
        let stiffness = params
            .iter()
            .zip(&fibres)
            .map(|(p, a)| stiffness_in_frame(&p.stiffness_local(), a))
            .collect();
        Ok(Self {
            rest: mesh.vertices.clone(),
            geometry,
            reinforcement: vec![Matrix6::zeros(); params.len()],
            params,
            fibres,
            stiffness,
        })
    }

    /// [`Self::new`] plus, per element, HGO fibre families linearized at the rest state
    /// (HGO 2000 §4.2, [`fibre_family_stiffness`]) added to C_e: an isotropic matrix
    /// ([`TransverselyIsotropicParams::from_isotropic`]) with two families at ±θ is the
    /// orthotropic two-family material. Every k1 must be finite and ≥ 0 (the sum then stays PD).
    pub fn with_fibre_families(
        mesh: &TetMesh,
        params: Vec<TransverselyIsotropicParams>,
        fibres: Vec<Unit<Vector3<f64>>>,
        families: &[Vec<FibreFamily>],
    ) -> Result<Self, FemError> {
        let mut model = Self::new(mesh, params, fibres)?;
        if families.len() != model.params.len() {
            return Err(FemError::LengthMismatch {
                what: "per-element fibre families",
                expected: model.params.len(),
                got: families.len(),
            });
        }
        for (e, fam) in families.iter().enumerate() {
            if fam.iter().any(|f| !(f.k1_pa.is_finite() && f.k1_pa >= 0.0)) {
                return Err(FemError::NonFinite {
                    what: "fibre family k1 (finite and >= 0 needed)",
                });
            }
            model.reinforcement[e] = fam.iter().map(fibre_family_stiffness).sum();
            model.stiffness[e] += model.reinforcement[e];
        }
        Ok(model)
    }

    /// Homogeneous model with one fibre direction.
    pub fn homogeneous(
        mesh: &TetMesh,
        p: TransverselyIsotropicParams,
        fibre: Unit<Vector3<f64>>,
    ) -> Result<Self, FemError> {
        Self::new(mesh, vec![p; mesh.tets.len()], vec![fibre; mesh.tets.len()])
    }

    /// Per-element parameters.
    pub fn params(&self) -> &[TransverselyIsotropicParams] {
        &self.params
    }

    /// Per-element fibres.
    pub fn fibres(&self) -> &[Unit<Vector3<f64>>] {
        &self.fibres
    }

    /// Rest-frame Voigt stiffness of element `e`.
    pub fn element_stiffness_matrix(&self, e: usize) -> &Matrix6<f64> {
        &self.stiffness[e]
    }

    /// Replaces the parameters (a fitter's entry point). Non-PD sets are projected with
    /// [`TransverselyIsotropicParams::project_positive_definite`] at floor
    /// `min_eigenvalue_rel` × (largest Mandel eigenvalue); returns how many were projected.
    pub fn set_params(
        &mut self,
        params: &[TransverselyIsotropicParams],
        min_eigenvalue_rel: f64,
    ) -> Result<usize, FemError> {
        if params.len() != self.params.len() {
            return Err(FemError::LengthMismatch {
                what: "per-element parameters",
                expected: self.params.len(),
                got: params.len(),
            });
        }
        let mut projected = 0;
        for (e, p) in params.iter().enumerate() {
            if p.to_vector().iter().any(|v| !v.is_finite()) {
                return Err(FemError::NonFinite {
                    what: "transversely isotropic parameters",
                });
            }
            let q = if p.is_positive_definite() {
                *p
            } else {
                projected += 1;
                let top = p
                    .mandel_eigenvalues()
                    .iter()
                    .fold(0.0f64, |m, &v| m.max(v.abs()));
                p.project_positive_definite(min_eigenvalue_rel * top)
            };
            self.params[e] = q;
            self.stiffness[e] =
                stiffness_in_frame(&q.stiffness_local(), &self.fibres[e]) + self.reinforcement[e];
        }
        Ok(projected)
    }

    fn stress(&self, e: usize, strain: &Matrix3<f64>) -> Matrix3<f64> {
        stress_to_tensor(&(self.stiffness[e] * strain_voigt(strain)))
    }

    /// ∂f_e/∂p_k for k over (E11, E12, E13, E33, E44) at fixed rotation (exact: E is linear in p;
    /// the fibre families do not depend on p);
    /// the per-element right-hand sides of the adjoint Jacobian (bickel2009 appendix eq. 11–12
    /// with five parameters).
    pub fn parameter_forces(&self, e: usize, x: &[Vector3<f64>]) -> [[Vector3<f64>; 4]; 5] {
        let (r, _, eps) = kinematics(&self.geometry[e], x);
        let ev = strain_voigt(&eps);
        let d = TransverselyIsotropicParams::stiffness_local_derivatives();
        let mut out = [[Vector3::zeros(); 4]; 5];
        for k in 0..5 {
            let ck = stiffness_in_frame(&d[k], &self.fibres[e]);
            let s = stress_to_tensor(&(ck * ev));
            out[k] = forces_from_stress(&self.geometry[e], &r, &s);
        }
        out
    }
}

impl ElasticModel for AnisotropicModel {
    fn rest_positions(&self) -> &[Vector3<f64>] {
        &self.rest
    }
    fn elements(&self) -> &[TetGeometry] {
        &self.geometry
    }
    fn element_forces(&self, e: usize, x: &[Vector3<f64>]) -> [Vector3<f64>; 4] {
        let (r, _, eps) = kinematics(&self.geometry[e], x);
        forces_from_stress(&self.geometry[e], &r, &self.stress(e, &eps))
    }
    fn element_matrix(&self, e: usize, x: &[Vector3<f64>], kind: StiffnessKind) -> Matrix12 {
        let (r, s, eps) = kinematics(&self.geometry[e], x);
        let sigma = self.stress(e, &eps);
        tangent_from_stress(
            &self.geometry[e],
            &r,
            &s,
            &sigma,
            |de| self.stress(e, de),
            kind == StiffnessKind::Consistent,
        )
    }
    fn tangent_is_symmetric(&self, kind: StiffnessKind) -> bool {
        // The exact ∂f/∂x carries R W σ with σ not coaxial with the stretch: not symmetric. The
        // warped R K Rᵀ is (K = V Bᵀ C B with C symmetric).
        kind != StiffnessKind::Consistent
    }
    fn energy(&self, _x: &[Vector3<f64>]) -> Option<f64> {
        // R σ(ε) is the gradient of ½ε:Cε only when σ and the stretch S are coaxial (isotropy):
        // for an anisotropic C the corotational force R K (Rᵀx − X) is not conservative.
        None
    }
}
