//! Material parameters: the (λ, α) parameterization of bickel2009 eq. 2–6, its conversions to and
//! from (E, ν) and Lamé (λ_L, μ), and the stable neo-Hookean parameters of Smith et al. 2018.

use crate::FemError;
use nalgebra::Matrix6;
use serde::{Deserialize, Serialize};

/// Per-element linear isotropic material in the parameterization of bickel2009 eq. 5–6
/// (Becker & Teschner 2007):
///
/// E = λ G + α H,  λ = E / ((1 + ν)(1 − 2ν)),  α = λ ν.
///
/// α is Lamé's first parameter; the shear modulus is μ = λ/2 − α. The stiffness matrix and the
/// elastic forces are linear in (λ, α) (bickel2009 eq. 7), which the fitter exploits.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LinearParams {
    /// bickel2009 λ \[Pa\] (not Lamé's λ).
    pub lambda: f64,
    /// bickel2009 α = λν \[Pa\] = Lamé's first parameter.
    pub alpha: f64,
}

impl LinearParams {
    /// From Young's modulus `young_pa` > 0 and Poisson ratio ν ∈ (−1, 0.5) (bickel2009 eq. 6).
    pub fn from_young_poisson(young_pa: f64, nu: f64) -> Result<Self, FemError> {
        check_young_poisson(young_pa, nu)?;
        let lambda = young_pa / ((1.0 + nu) * (1.0 - 2.0 * nu));
        Ok(Self {
            lambda,
            alpha: lambda * nu,
        })
    }

    /// Back to (E \[Pa\], ν): ν = α/λ, E = λ(1 + ν)(1 − 2ν). Errors unless λ > 0 and ν ∈ (−1, 0.5).
    pub fn to_young_poisson(&self) -> Result<(f64, f64), FemError> {
        self.validate(usize::MAX)?;
        let nu = self.alpha / self.lambda;
        Ok((self.lambda * (1.0 + nu) * (1.0 - 2.0 * nu), nu))
    }

    /// From Lamé's (λ_L, μ): α = λ_L, λ = 2(μ + λ_L). Requires μ > 0 and bulk modulus λ_L + 2μ/3 > 0.
    pub fn from_lame(lame_lambda: f64, mu: f64) -> Result<Self, FemError> {
        if !(mu > 0.0
            && lame_lambda + 2.0 * mu / 3.0 > 0.0
            && lame_lambda.is_finite()
            && mu.is_finite())
        {
            return Err(FemError::InvalidLame {
                lambda: lame_lambda,
                mu,
            });
        }
        Ok(Self {
            lambda: 2.0 * (mu + lame_lambda),
            alpha: lame_lambda,
        })
    }

    /// Lamé parameters (λ_L, μ) = (α, λ/2 − α). No validity check (a fitter may pass through
    /// invalid values; use [`Self::validate`]).
    pub fn lame(&self) -> (f64, f64) {
        (self.alpha, 0.5 * self.lambda - self.alpha)
    }

    /// Checks λ > 0 and −1 < α/λ < 0.5 (equivalently E > 0 and ν physically valid).
    pub fn validate(&self, element: usize) -> Result<(), FemError> {
        let ok = self.lambda.is_finite()
            && self.alpha.is_finite()
            && self.lambda > 0.0
            && self.alpha / self.lambda > -1.0
            && self.alpha / self.lambda < 0.5;
        if ok {
            Ok(())
        } else {
            Err(FemError::InvalidParameters {
                element,
                lambda: self.lambda,
                alpha: self.alpha,
            })
        }
    }

    /// The 6×6 stress–strain matrix E = λG + αH (bickel2009 eq. 5) acting on the Voigt strain
    /// (ε_xx, ε_yy, ε_zz, γ_xy, γ_xz, γ_yz) with engineering shears γ = 2ε.
    pub fn stress_strain_matrix(&self) -> Matrix6<f64> {
        self.lambda * matrix_g() + self.alpha * matrix_h()
    }
}

fn check_young_poisson(young_pa: f64, nu: f64) -> Result<(), FemError> {
    if !(young_pa.is_finite() && young_pa > 0.0) {
        return Err(FemError::InvalidYoungModulus { young_pa });
    }
    if !(nu.is_finite() && nu > -1.0 && nu < 0.5) {
        return Err(FemError::InvalidPoissonRatio { nu });
    }
    Ok(())
}

/// G = diag(1, 1, 1, 0.5, 0.5, 0.5) (bickel2009 eq. 3).
pub fn matrix_g() -> Matrix6<f64> {
    Matrix6::from_diagonal(&nalgebra::Vector6::new(1.0, 1.0, 1.0, 0.5, 0.5, 0.5))
}

/// H of bickel2009 eq. 4.
#[rustfmt::skip]
pub fn matrix_h() -> Matrix6<f64> {
    Matrix6::new(
        -1.0,  1.0,  1.0,  0.0,  0.0,  0.0,
         1.0, -1.0,  1.0,  0.0,  0.0,  0.0,
         1.0,  1.0, -1.0,  0.0,  0.0,  0.0,
         0.0,  0.0,  0.0, -1.0,  0.0,  0.0,
         0.0,  0.0,  0.0,  0.0, -1.0,  0.0,
         0.0,  0.0,  0.0,  0.0,  0.0, -1.0,
    )
}

/// Parameters of the stable neo-Hookean energy (Smith, de Goes & Kim 2018, eq. 14 without the
/// log term): Ψ = μ/2 (I_C − 3) − μ(J − 1) + λ/2 (J − 1)².
///
/// `lambda` and `mu` are the *reparameterized* values: linearizing Ψ at F = I gives Lamé
/// parameters (λ − μ, μ), so λ = λ_Lamé + μ (Smith 2018 §3.4).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct NeoHookeanParams {
    /// reparameterized λ = λ_Lamé + μ \[Pa\]
    pub lambda: f64,
    /// shear modulus μ \[Pa\]
    pub mu: f64,
}

impl NeoHookeanParams {
    /// From Lamé (λ_L, μ): λ = λ_L + μ so the small-strain response equals linear elasticity.
    pub fn from_lame(lame_lambda: f64, mu: f64) -> Result<Self, FemError> {
        if !(mu > 0.0
            && lame_lambda + 2.0 * mu / 3.0 > 0.0
            && lame_lambda.is_finite()
            && mu.is_finite())
        {
            return Err(FemError::InvalidLame {
                lambda: lame_lambda,
                mu,
            });
        }
        Ok(Self {
            lambda: lame_lambda + mu,
            mu,
        })
    }

    /// From Young's modulus and Poisson ratio (via Lamé).
    pub fn from_young_poisson(young_pa: f64, nu: f64) -> Result<Self, FemError> {
        check_young_poisson(young_pa, nu)?;
        let mu = young_pa / (2.0 * (1.0 + nu));
        let lame = young_pa * nu / ((1.0 + nu) * (1.0 - 2.0 * nu));
        Self::from_lame(lame, mu)
    }

    /// From the corotational (λ, α): same small-strain response.
    pub fn from_linear(p: &LinearParams) -> Result<Self, FemError> {
        let (l, m) = p.lame();
        Self::from_lame(l, m)
    }

    /// Lamé parameters of the linearization at rest: (λ − μ, μ).
    pub fn lame(&self) -> (f64, f64) {
        (self.lambda - self.mu, self.mu)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn young_poisson_round_trip_and_bounds() {
        let p = LinearParams::from_young_poisson(1.0e5, 0.3).unwrap();
        let (e, nu) = p.to_young_poisson().unwrap();
        assert!((e - 1.0e5).abs() < 1e-8 && (nu - 0.3).abs() < 1e-14);
        let (l, m) = p.lame();
        let q = LinearParams::from_lame(l, m).unwrap();
        assert!((q.lambda - p.lambda).abs() < 1e-8 && (q.alpha - p.alpha).abs() < 1e-8);
        assert!((m - 1.0e5 / 2.6).abs() < 1e-8);
        assert!(LinearParams::from_young_poisson(1.0, 0.5).is_err());
        assert!(LinearParams::from_young_poisson(1.0, -1.0).is_err());
        assert!(LinearParams::from_young_poisson(-1.0, 0.2).is_err());
        assert!(
            LinearParams {
                lambda: 1.0,
                alpha: 0.6
            }
            .to_young_poisson()
            .is_err()
        );
        assert!(
            LinearParams {
                lambda: -1.0,
                alpha: 0.1
            }
            .validate(3)
            .is_err()
        );
    }

    #[test]
    fn stress_strain_matrix_is_isotropic_hooke() {
        // E = λG + αH equals eq. 2: E/((1+ν)(1−2ν)) (G + νH).
        let (e, nu) = (2.0e4, 0.25);
        let p = LinearParams::from_young_poisson(e, nu).unwrap();
        let eq2 = e / ((1.0 + nu) * (1.0 - 2.0 * nu)) * (matrix_g() + nu * matrix_h());
        assert!((p.stress_strain_matrix() - eq2).norm() < 1e-9);
        // Shear entry = μ (engineering shear strain), normal diagonal = λ_L + 2μ.
        let (l, m) = p.lame();
        let c = p.stress_strain_matrix();
        assert!((c[(3, 3)] - m).abs() < 1e-9 && (c[(0, 0)] - (l + 2.0 * m)).abs() < 1e-9);
    }
}
