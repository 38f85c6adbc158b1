//! Fitting the invariant material (thesis eq. 8.1–8.2) to homogeneous rubber tests: Treloar's
//! uniaxial tension and Kawabata's general biaxial tension, both at once.
//!
//! Homogeneous deformation F = diag(λ₁, λ₂, λ₃) has R = I, so the corotated strain is
//! ε = diag(λᵢ − 1) and the corotational element stress σ = E(p(I(ε))) ε is the Biot stress T
//! (the FEM's element force is V R σ gₐ, i.e. R σ is the first Piola stress). Rubber is
//! incompressible and both data sets state their kinematics that way (λ₃ = 1/(λ₁λ₂); uniaxial
//! λ₂ = λ₃ = λ₁^{-1/2}), so, as is usual when fitting hyperelastic models to these data, the
//! hydrostatic pressure is the Lagrange multiplier that makes the thickness direction traction
//! free: Cauchy σᵢ = λᵢ Tᵢ − p with p = λ₃ T₃, hence the nominal stresses
//! P_i = T_i − (λ₃ / λ_i) T₃ (i = 1, 2). The uniaxial P₂ vanishes by symmetry.
//!
//! The fit is the LM of §8.3 over (p₀, w) with RBF centres placed by k-means on the strains
//! of the data (scaled invariants); residuals of each data set are divided by its RMS stress and
//! √n so that the two sets weigh equally.

use crate::error::{DesignError, Result};
use crate::material::{InvariantMaterial, IsotropicBounds, isotropic_matrix, strain_invariants};
use nalgebra::Vector6;
use serde::{Deserialize, Serialize};
use softcap_core::{
    KMeansSettings, LeastSquaresProblem, LevenbergMarquardtSettings, kmeans, levenberg_marquardt,
};
use std::path::Path;

/// One homogeneous test point: stretches (λ₁, λ₂) and measured nominal stresses \[Pa\]
/// (P₂ = None when not measured, as in uniaxial tension).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RubberPoint {
    /// λ₁, λ₂ (λ₃ = 1/(λ₁λ₂)).
    pub stretch: [f64; 2],
    /// Measured P₁ \[Pa\].
    pub stress1_pa: f64,
    /// Measured P₂ \[Pa\], if any.
    pub stress2_pa: Option<f64>,
}

fn read_csv(path: &Path, columns: usize) -> Result<Vec<Vec<f64>>> {
    let mut rdr = csv::Reader::from_path(path).map_err(|e| DesignError::File {
        path: path.into(),
        reason: e.to_string(),
    })?;
    let mut out = Vec::new();
    for (i, rec) in rdr.records().enumerate() {
        let line = i + 2;
        let rec = rec.map_err(|e| DesignError::File {
            path: path.into(),
            reason: format!("line {line}: {e}"),
        })?;
        if rec.len() != columns {
            return Err(DesignError::File {
                path: path.into(),
                reason: format!("line {line}: {} fields, expected {columns}", rec.len()),
            });
        }
        let row = rec
            .iter()
            .enumerate()
            .map(|(c, f)| {
                f.trim()
                    .parse::<f64>()
                    .ok()
                    .filter(|v| v.is_finite())
                    .ok_or_else(|| DesignError::File {
                        path: path.into(),
                        reason: format!(
                            "line {line}, column {}: not a finite number: {f:?}",
                            c + 1
                        ),
                    })
            })
            .collect::<Result<Vec<f64>>>()?;
        out.push(row);
    }
    Ok(out)
}

/// Reads Treloar's uniaxial table `stretch,nominal_stress_mpa`.
pub fn read_uniaxial(path: &Path) -> Result<Vec<RubberPoint>> {
    Ok(read_csv(path, 2)?
        .into_iter()
        .map(|r| RubberPoint {
            stretch: [r[0], r[0].powf(-0.5)],
            stress1_pa: r[1] * 1e6,
            stress2_pa: None,
        })
        .collect())
}

/// Reads Kawabata's biaxial table `stretch1,stretch2,nominal_stress1_mpa,nominal_stress2_mpa`.
pub fn read_biaxial(path: &Path) -> Result<Vec<RubberPoint>> {
    Ok(read_csv(path, 4)?
        .into_iter()
        .map(|r| RubberPoint {
            stretch: [r[0], r[1]],
            stress1_pa: r[2] * 1e6,
            stress2_pa: Some(r[3] * 1e6),
        })
        .collect())
}

fn strain_of(stretch: [f64; 2]) -> (Vector6<f64>, [f64; 3]) {
    let l = [stretch[0], stretch[1], 1.0 / (stretch[0] * stretch[1])];
    (
        Vector6::new(l[0] - 1.0, l[1] - 1.0, l[2] - 1.0, 0.0, 0.0, 0.0),
        l,
    )
}

/// Nominal stresses (P₁, P₂) \[Pa\] of the invariant material under incompressible homogeneous
/// stretch (λ₁, λ₂) (see module docs).
pub fn nominal_stress(material: &InvariantMaterial, stretch: [f64; 2]) -> [f64; 2] {
    let (eps, l) = strain_of(stretch);
    let (lam, mu) = material.lame_at(&eps);
    let t = isotropic_matrix(lam, mu) * eps;
    [t[0] - l[2] / l[0] * t[2], t[1] - l[2] / l[1] * t[2]]
}

/// Settings of the rubber fit.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RubberFitSettings {
    /// RBF centres P.
    pub centres: usize,
    /// LM settings.
    pub lm: LevenbergMarquardtSettings,
    /// Valid range of (E, ν).
    pub bounds: IsotropicBounds,
}

impl Default for RubberFitSettings {
    fn default() -> Self {
        Self {
            centres: 8,
            lm: LevenbergMarquardtSettings {
                max_iterations: 300,
                ..LevenbergMarquardtSettings::default()
            },
            bounds: IsotropicBounds {
                young_min_pa: 1e3,
                nu_min: 0.0,
                nu_max: 0.49,
            },
        }
    }
}

/// Error of the fit on one data set.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DataSetError {
    /// Data set name.
    pub name: String,
    /// Stress values compared.
    pub count: usize,
    /// RMS nominal-stress error \[MPa\].
    pub rms_mpa: f64,
    /// RMS error / largest measured stress.
    pub relative: f64,
}

/// Result of [`fit_rubber`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RubberFitReport {
    /// Fitted material.
    pub material: InvariantMaterial,
    /// Per data set errors.
    pub errors: Vec<DataSetError>,
    /// LM status.
    pub status: String,
    /// LM iterations.
    pub iterations: usize,
}

struct RubberProblem<'a> {
    sets: &'a [(&'a str, &'a [RubberPoint])],
    material: InvariantMaterial,
    weights: Vec<f64>,
    count: usize,
}

impl LeastSquaresProblem for RubberProblem<'_> {
    fn num_params(&self) -> usize {
        self.material.rbf.num_parameters()
    }
    fn num_residuals(&self) -> usize {
        self.count
    }
    fn residuals(&mut self, params: &[f64], residuals: &mut [f64]) {
        self.material.rbf.set_parameters(params);
        let mut k = 0;
        for (s, (_, pts)) in self.sets.iter().enumerate() {
            for p in pts.iter() {
                let st = nominal_stress(&self.material, p.stretch);
                residuals[k] = (st[0] - p.stress1_pa) * self.weights[s];
                k += 1;
                if let Some(s2) = p.stress2_pa {
                    residuals[k] = (st[1] - s2) * self.weights[s];
                    k += 1;
                }
            }
        }
    }
}

/// Per-set errors of `material` on `sets`.
pub fn rubber_errors(
    material: &InvariantMaterial,
    sets: &[(&str, &[RubberPoint])],
) -> Vec<DataSetError> {
    sets.iter()
        .map(|(name, pts)| {
            let mut se = 0.0;
            let mut n = 0;
            let mut max_s: f64 = 0.0;
            for p in pts.iter() {
                let st = nominal_stress(material, p.stretch);
                se += (st[0] - p.stress1_pa).powi(2);
                n += 1;
                max_s = max_s.max(p.stress1_pa.abs());
                if let Some(s2) = p.stress2_pa {
                    se += (st[1] - s2).powi(2);
                    n += 1;
                    max_s = max_s.max(s2.abs());
                }
            }
            let rms = (se / n.max(1) as f64).sqrt();
            DataSetError {
                name: name.to_string(),
                count: n,
                rms_mpa: rms * 1e-6,
                relative: rms / max_s.max(f64::MIN_POSITIVE),
            }
        })
        .collect()
}

/// Fits one invariant material to all `sets` at once (see module docs).
pub fn fit_rubber(
    sets: &[(&str, &[RubberPoint])],
    settings: &RubberFitSettings,
) -> Result<RubberFitReport> {
    let all: Vec<&RubberPoint> = sets.iter().flat_map(|s| s.1.iter()).collect();
    if all.len() < 2 {
        return Err(DesignError::Invalid {
            field: "rubber data",
            reason: "need at least two points".into(),
        });
    }
    // Invariant coordinates of every data strain, their scales, and k-means centres.
    let inv: Vec<[f64; 3]> = all
        .iter()
        .map(|p| strain_invariants(&strain_of(p.stretch).0))
        .collect();
    let mut scale = [0.0f64; 3];
    for v in &inv {
        for k in 0..3 {
            scale[k] = scale[k].max(v[k].abs());
        }
    }
    let scale = scale.map(|s| if s > 0.0 { s } else { 1.0 });
    let pts: Vec<f64> = inv
        .iter()
        .flat_map(|v| (0..3).map(move |k| v[k] / scale[k]))
        .collect();
    let p = settings.centres.min(all.len()).max(1);
    let km = kmeans(
        &pts,
        3,
        p,
        &KMeansSettings {
            seed: 8,
            ..KMeansSettings::default()
        },
    )?;
    // Start: a linear material with the small-strain shear modulus of the first uniaxial slope.
    let mu0 = all
        .iter()
        .filter(|p| p.stretch[0] > 1.0)
        .map(|p| p.stress1_pa / (3.0 * (p.stretch[0] - 1.0)))
        .next()
        .unwrap_or(1e5)
        .max(1e3);
    let mut material = InvariantMaterial::linear(mu0, mu0);
    material.bounds = settings.bounds;
    material.rbf.scale = scale.to_vec();
    material.rbf.centres = km.centroids.chunks(3).map(|c| c.to_vec()).collect();
    material.rbf.weights = vec![vec![0.0, 0.0]; p];
    let mut weights = Vec::new();
    let mut count = 0;
    for (_, pts) in sets {
        let mut ss = 0.0;
        let mut n = 0;
        for p in pts.iter() {
            ss += p.stress1_pa.powi(2);
            n += 1;
            if let Some(s2) = p.stress2_pa {
                ss += s2 * s2;
                n += 1;
            }
        }
        count += n;
        let rms = (ss / n.max(1) as f64).sqrt().max(f64::MIN_POSITIVE);
        weights.push(1.0 / (rms * (n.max(1) as f64).sqrt()));
    }
    let init = material.rbf.parameters();
    let mut problem = RubberProblem {
        sets,
        material,
        weights,
        count,
    };
    let rep = levenberg_marquardt(&mut problem, &init, None, &settings.lm)?;
    problem.material.rbf.set_parameters(&rep.params);
    let errors = rubber_errors(&problem.material, sets);
    Ok(RubberFitReport {
        material: problem.material,
        errors,
        status: format!("{:?}", rep.status),
        iterations: rep.iterations,
    })
}
