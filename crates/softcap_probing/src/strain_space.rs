//! The strain-space material of bickel2009 §3.3 and §4.2: one RBF p_e(ε) per tet (eq. 8, with
//! the degree-0 polynomial term of Carr et al. 2001), built by greedy basis selection.

use std::sync::Arc;

use nalgebra::Vector6;
use serde::{Deserialize, Serialize};
use softcap_fem::{CorotationalModel, FemError, LinearParams, StrainDependentParams};
use softcap_mesh::TetMesh;

use crate::probing_error;

/// One element's strain-space RBF (bickel2009 eq. 8 with the degree-0 polynomial term of
/// Carr et al. 2001): p(ε) = c + Σᵢ wᵢ ‖ε − εᵢ‖, wᵢ, c ∈ ℝ² (λ, α), with the side condition
/// Σᵢ wᵢ = 0 when c is fitted.
///
/// Why the constant term: eq. 8 alone (c = 0) cannot even reproduce a constant material, and
/// for ‖ε‖ → ∞ it grows like (Σᵢ wᵢ)‖ε‖ — a cone whose slope is set by how close the samples
/// are (two samples of the same λ at distance d extrapolate with slope 2λ/d). Samples of one
/// element cluster at small strains, so a novel deformation that leaves their span (a
/// different tip, a deeper press) meets parameters many times the measured ones (measured:
/// up to 13× on a three-layer block, docs/tissue.md). With c and Σwᵢ = 0 (Carr et al. 2001
/// §3, polynomial of degree 0 for the biharmonic kernel φ(r) = r), constants are reproduced
/// exactly and p is bounded: |p(ε) − c| ≤ Σᵢ |wᵢ| ‖εᵢ‖ for every ε. The linear polynomial
/// (1, ε₁ … ε₆) would need ≥ 7 unisolvent samples per element and extrapolates linearly
/// again, so it is not used.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ElementRbf {
    /// Sample indices of the centres (see [`StrainSpaceMaterial::fit`]).
    pub center_samples: Vec<usize>,
    /// Centres εᵢ (corotated Voigt strain).
    pub centers: Vec<[f64; 6]>,
    /// Weights wᵢ = (w_λ, w_α), Pa.
    pub weights: Vec<[f64; 2]>,
    /// Constant term c = (c_λ, c_α), Pa ([0, 0]: eq. 8 without polynomial term).
    #[serde(default)]
    pub constant: [f64; 2],
}

impl ElementRbf {
    /// p(ε) unclamped: (λ, α), Pa.
    pub fn evaluate(&self, strain: &[f64; 6]) -> [f64; 2] {
        let mut out = self.constant;
        for (c, w) in self.centers.iter().zip(&self.weights) {
            let r = strain_distance(c, strain);
            out[0] += w[0] * r;
            out[1] += w[1] * r;
        }
        out
    }
}

fn strain_distance(a: &[f64; 6], b: &[f64; 6]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y) * (x - y))
        .sum::<f64>()
        .sqrt()
}

/// Polynomial term of the strain-space RBF.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum StrainTail {
    /// bickel2009 eq. 8 as printed: no polynomial term.
    None,
    /// Constant c with Σwᵢ = 0 (Carr et al. 2001, degree 0): bounded extrapolation.
    #[default]
    Constant,
}

/// Settings of the strain-space basis (bickel2009 §4.2).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StrainBasisSettings {
    /// Greedy stops when the RMS parameter error over the samples is below this fraction of the
    /// element's mean λ.
    pub relative_tolerance: f64,
    /// At most this many centres per element.
    pub max_centers: usize,
    /// Evaluated parameters are clamped to λ ≥ this fraction of the element's smallest sample λ …
    pub lambda_floor_fraction: f64,
    /// … λ ≤ this fraction of its largest sample λ (≤ 0: no ceiling) …
    pub lambda_ceiling_fraction: f64,
    /// … and ν = α/λ to these bounds.
    pub nu_bounds: (f64, f64),
    /// Polynomial term (default: the constant of Carr et al. 2001, see [`ElementRbf`]).
    pub tail: StrainTail,
}

impl Default for StrainBasisSettings {
    fn default() -> Self {
        Self {
            relative_tolerance: 0.02,
            max_centers: 12,
            lambda_floor_fraction: 0.5,
            lambda_ceiling_fraction: 1.0,
            nu_bounds: (0.0, 0.49),
            tail: StrainTail::Constant,
        }
    }
}

/// One greedy step summed over the elements: error against basis size (bickel2009 Fig. 5).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct BasisErrorStep {
    /// Basis size M.
    pub num_centers: usize,
    /// RMS over elements (those still growing use their error at M, finished ones their final
    /// error) of the relative parameter error ‖p(εₖ) − pₖ‖/λ̄_e.
    pub relative_rms_error: f64,
}

/// The strain-space material of bickel2009 §3.3: one RBF p_e(ε) per tet.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StrainSpaceMaterial {
    /// Per-element RBFs.
    pub elements: Vec<ElementRbf>,
    /// Lower bound on λ per element, Pa (validity clamp).
    pub lambda_floor_pa: Vec<f64>,
    /// ν bounds of the validity clamp.
    pub nu_bounds: (f64, f64),
    /// Upper bound on λ per element, Pa (empty: none): the material does not leave the range of
    /// parameters measured for the element.
    #[serde(default)]
    pub lambda_ceiling_pa: Vec<f64>,
}

/// A strain-space sample: one fitted example at one element.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StrainSample {
    /// ε.
    pub strain: [f64; 6],
    /// p = (λ, α).
    pub params: LinearParams,
}

/// Least-squares fit of one element's RBF with the given centres (bickel2009 §4.2: "compute the
/// RBF weights that best fit the parameter vectors for all N example deformations in a
/// least-squares manner", eq. 8): minimizes Σₖ ‖p(εₖ) − pₖ‖² over (w, c) subject to Σwᵢ = 0
/// (constant tail; w = Z v with Z = [I; −1ᵀ] spanning the side condition) or over w alone (no
/// tail). Dense SVD (M ≤ a few tens): the minimum-norm solution when samples are duplicated.
/// Written here rather than with `softcap_core::Rbf` because that offers no degree-0 tail.
fn fit_element_rbf(
    samples: &[StrainSample],
    centers: &[usize],
    tail: StrainTail,
) -> Result<ElementRbf, FemError> {
    let n = samples.len();
    let m = centers.len();
    let (free, has_c) = match tail {
        StrainTail::Constant => (m.saturating_sub(1), true),
        StrainTail::None => (m, false),
    };
    let cols = free + usize::from(has_c);
    let mut a = nalgebra::DMatrix::<f64>::zeros(n, cols.max(1));
    let mut b = nalgebra::DMatrix::<f64>::zeros(n, 2);
    for (k, s) in samples.iter().enumerate() {
        let phi: Vec<f64> = centers
            .iter()
            .map(|&c| strain_distance(&samples[c].strain, &s.strain))
            .collect();
        match tail {
            StrainTail::Constant => {
                for j in 0..free {
                    a[(k, j)] = phi[j] - phi[m - 1];
                }
                a[(k, free)] = 1.0;
            }
            StrainTail::None => {
                for j in 0..m {
                    a[(k, j)] = phi[j];
                }
            }
        }
        b[(k, 0)] = s.params.lambda;
        b[(k, 1)] = s.params.alpha;
    }
    let svd = a.svd(true, true);
    let tol = 1e-12 * svd.singular_values.max().max(f64::MIN_POSITIVE);
    let x = svd
        .solve(&b, tol)
        .map_err(|e| probing_error(format!("strain-space least squares: {e}")))?;
    let mut weights = vec![[0.0; 2]; m];
    let mut constant = [0.0; 2];
    for o in 0..2 {
        match tail {
            StrainTail::Constant => {
                let mut last = 0.0;
                for j in 0..free {
                    weights[j][o] = x[(j, o)];
                    last -= x[(j, o)];
                }
                if m > 0 {
                    weights[m - 1][o] = last;
                }
                constant[o] = x[(free, o)];
            }
            StrainTail::None => {
                for j in 0..m {
                    weights[j][o] = x[(j, o)];
                }
            }
        }
    }
    if weights
        .iter()
        .chain(std::iter::once(&constant))
        .flatten()
        .any(|v| !v.is_finite())
    {
        return Err(probing_error(
            "strain-space least squares: non-finite weights",
        ));
    }
    Ok(ElementRbf {
        center_samples: centers.to_vec(),
        centers: centers.iter().map(|&c| samples[c].strain).collect(),
        weights,
        constant,
    })
}

impl StrainSpaceMaterial {
    /// Builds the per-element RBFs from `samples[e]` (sample k of element e) by greedy selection
    /// (bickel2009 §4.2 after Carr et al. 2001): start with sample 0 (by convention the
    /// zero-strain sample with the average parameters; with the constant tail the one-centre fit
    /// is the least-squares constant, i.e. the average material), fit eq. 8 to all samples in
    /// the least-squares sense (`fit_element_rbf`), add the sample with the largest error,
    /// until the RMS error is below `relative_tolerance` × mean λ (`max_centers` at most).
    /// Evaluation clamps λ to [floor, ceiling] from the element's smallest / largest sample λ
    /// and ν = α/λ to `nu_bounds`, so the material stays physically valid at any strain.
    /// Returns the material and the error-vs-basis-size curve (bickel2009 Fig. 5).
    pub fn fit(
        samples: &[Vec<StrainSample>],
        settings: &StrainBasisSettings,
    ) -> Result<(Self, Vec<BasisErrorStep>), FemError> {
        let mut elements = Vec::with_capacity(samples.len());
        let mut floors = Vec::with_capacity(samples.len());
        let mut ceilings = Vec::with_capacity(samples.len());
        let mut histories: Vec<Vec<f64>> = Vec::with_capacity(samples.len());
        let max_centers = settings.max_centers.max(1);
        for (e, s) in samples.iter().enumerate() {
            if s.is_empty() {
                return Err(probing_error(format!("element {e}: no strain samples")));
            }
            if let Some(k) = s.iter().position(|p| {
                !(p.strain.iter().all(|v| v.is_finite())
                    && p.params.lambda.is_finite()
                    && p.params.alpha.is_finite())
            }) {
                return Err(probing_error(format!("element {e}: sample {k} not finite")));
            }
            let mean_lambda = s.iter().map(|p| p.params.lambda).sum::<f64>() / s.len() as f64;
            let tolerance = settings.relative_tolerance * mean_lambda.abs();
            let mut centers = vec![0usize];
            let mut history = Vec::new();
            let rbf = loop {
                let rbf = fit_element_rbf(s, &centers, settings.tail)
                    .map_err(|err| probing_error(format!("element {e}: {err}")))?;
                let errors: Vec<f64> = s
                    .iter()
                    .map(|p| {
                        let v = rbf.evaluate(&p.strain);
                        (v[0] - p.params.lambda).hypot(v[1] - p.params.alpha)
                    })
                    .collect();
                let rms = (errors.iter().map(|v| v * v).sum::<f64>() / s.len() as f64).sqrt();
                history.push(rms / mean_lambda.abs().max(f64::MIN_POSITIVE));
                // Worst sample among non-centres whose strain is not already a centre's.
                let worst = (0..s.len())
                    .filter(|k| {
                        centers
                            .iter()
                            .all(|&c| strain_distance(&s[c].strain, &s[*k].strain) > 0.0)
                    })
                    .max_by(|&a, &b| errors[a].total_cmp(&errors[b]).then(b.cmp(&a)));
                match worst {
                    Some(k) if rms > tolerance && centers.len() < max_centers => centers.push(k),
                    _ => break rbf,
                }
            };
            elements.push(rbf);
            let min_lambda = s
                .iter()
                .map(|p| p.params.lambda)
                .fold(f64::INFINITY, f64::min);
            let max_lambda = s.iter().map(|p| p.params.lambda).fold(0.0, f64::max);
            let floor = settings.lambda_floor_fraction * min_lambda;
            floors.push(floor);
            if settings.lambda_ceiling_fraction > 0.0 {
                ceilings.push((settings.lambda_ceiling_fraction * max_lambda).max(floor));
            }
            histories.push(history);
        }
        let longest = histories.iter().map(Vec::len).max().unwrap_or(0);
        let curve = (0..longest)
            .map(|k| {
                let sum2: f64 = histories
                    .iter()
                    .map(|h| {
                        let v = h[k.min(h.len() - 1)];
                        v * v
                    })
                    .sum();
                BasisErrorStep {
                    num_centers: k + 1,
                    relative_rms_error: (sum2 / histories.len().max(1) as f64).sqrt(),
                }
            })
            .collect();
        Ok((
            Self {
                elements,
                lambda_floor_pa: floors,
                nu_bounds: settings.nu_bounds,
                lambda_ceiling_pa: ceilings,
            },
            curve,
        ))
    }

    /// Rebuilds a material from the flat layout of `/tissue/basis` (docs/formats.md): T tets ×
    /// M padded centres, `centers_strain` T·M·6, `weights` T·M·2, `constants` T·2 (empty: no
    /// polynomial term), `centers_per_tet` T (empty: all M used), `center_samples` T·M (empty:
    /// 0..C), `lambda_floor_pa` T (empty: 1 Pa), `lambda_ceiling_pa` T or empty, ν bounds.
    #[allow(clippy::too_many_arguments)]
    pub fn from_flat(
        tets: usize,
        centers: usize,
        centers_strain: &[f64],
        weights: &[f64],
        constants: &[f64],
        centers_per_tet: &[u32],
        center_samples: &[u32],
        lambda_floor_pa: &[f64],
        lambda_ceiling_pa: &[f64],
        nu_bounds: (f64, f64),
    ) -> Result<Self, FemError> {
        let (t, m) = (tets, centers);
        let bad = |what: &str| Err(probing_error(format!("strain-space basis: {what}")));
        if centers_strain.len() != t * m * 6 || weights.len() != t * m * 2 {
            return bad("centres / weights length is not tets × M × 6 / 2");
        }
        if !(constants.is_empty() || constants.len() == 2 * t)
            || !(centers_per_tet.is_empty() || centers_per_tet.len() == t)
            || !(center_samples.is_empty() || center_samples.len() == t * m)
            || !(lambda_floor_pa.is_empty() || lambda_floor_pa.len() == t)
            || !(lambda_ceiling_pa.is_empty() || lambda_ceiling_pa.len() == t)
        {
            return bad("an array has neither 0 nor the per-tet length");
        }
        if centers_strain
            .iter()
            .chain(weights)
            .chain(constants)
            .chain(lambda_floor_pa)
            .chain(lambda_ceiling_pa)
            .any(|v| !v.is_finite())
        {
            return bad("non-finite value");
        }
        if !(nu_bounds.0 > -1.0 && nu_bounds.0 <= nu_bounds.1 && nu_bounds.1 < 0.5) {
            return bad("ν bounds outside (−1, 0.5)");
        }
        let mut elements = Vec::with_capacity(t);
        for e in 0..t {
            let c = centers_per_tet.get(e).map_or(m, |&c| c as usize);
            if c > m {
                return bad("centers_per_tet larger than M");
            }
            elements.push(ElementRbf {
                center_samples: if center_samples.is_empty() {
                    (0..c).collect()
                } else {
                    center_samples[e * m..e * m + c]
                        .iter()
                        .map(|&s| s as usize)
                        .collect()
                },
                centers: (0..c)
                    .map(|i| {
                        let s = &centers_strain[(e * m + i) * 6..(e * m + i + 1) * 6];
                        [s[0], s[1], s[2], s[3], s[4], s[5]]
                    })
                    .collect(),
                weights: (0..c)
                    .map(|i| [weights[(e * m + i) * 2], weights[(e * m + i) * 2 + 1]])
                    .collect(),
                constant: if constants.is_empty() {
                    [0.0; 2]
                } else {
                    [constants[2 * e], constants[2 * e + 1]]
                },
            });
        }
        let floors: Vec<f64> = (0..t)
            .map(|e| {
                lambda_floor_pa
                    .get(e)
                    .copied()
                    .filter(|v| *v > 0.0)
                    .unwrap_or(1.0)
            })
            .collect();
        Ok(Self {
            elements,
            lambda_floor_pa: floors,
            nu_bounds,
            lambda_ceiling_pa: lambda_ceiling_pa.to_vec(),
        })
    }

    /// p_e(ε) clamped to the valid region (floor ≤ λ ≤ ceiling, ν within bounds).
    pub fn evaluate(&self, element: usize, strain: &Vector6<f64>) -> LinearParams {
        let s = [
            strain[0], strain[1], strain[2], strain[3], strain[4], strain[5],
        ];
        let [l, a] = self.elements[element].evaluate(&s);
        let floor = self.lambda_floor_pa[element];
        let ceiling = self
            .lambda_ceiling_pa
            .get(element)
            .copied()
            .unwrap_or(f64::INFINITY)
            .max(floor);
        let lambda = if l.is_finite() {
            l.clamp(floor, ceiling)
        } else {
            floor
        };
        let nu = if a.is_finite() { a / lambda } else { 0.0 };
        let nu = nu.clamp(self.nu_bounds.0, self.nu_bounds.1);
        LinearParams {
            lambda,
            alpha: nu * lambda,
        }
    }

    /// Mean number of centres per element.
    pub fn mean_centers(&self) -> f64 {
        self.elements.iter().map(|e| e.centers.len()).sum::<usize>() as f64
            / self.elements.len().max(1) as f64
    }

    /// A corotational model over `mesh` whose parameters follow this material at every
    /// equilibrium iteration (bickel2009 §3.4).
    pub fn model(self: &Arc<Self>, mesh: &TetMesh) -> Result<CorotationalModel, FemError> {
        let zero = Vector6::zeros();
        let params = (0..mesh.tets.len())
            .map(|e| self.evaluate(e, &zero))
            .collect();
        Ok(CorotationalModel::new(mesh, params)?
            .with_strain_dependence(self.clone() as Arc<dyn StrainDependentParams>))
    }
}

impl StrainDependentParams for StrainSpaceMaterial {
    fn params(&self, element: usize, strain: &Vector6<f64>) -> LinearParams {
        self.evaluate(element, strain)
    }
}
