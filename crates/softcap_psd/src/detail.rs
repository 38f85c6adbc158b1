//! Pose-space detail models: PSD (thesis eq. 5.2) and WPSD (eq. 5.3–5.5) with φ(r) = r,
//! exact interpolation of P poses or least squares over T poses, and greedy pose selection
//! (thesis §5.4.2, after Carr et al. 2001).

use crate::error::{PsdError, Result};
use crate::graph::EdgeWeights;
use nalgebra::DMatrix;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use softcap_core::{PolynomialTail, Rbf, RbfKernel, RbfSettings, ScatteredData};

/// Largest basis size P supported by the run-time kernel (stack buffer of distances).
pub const MAX_POSES: usize = 64;

fn check_basis(basis: &[usize], examples: &Examples) -> Result<()> {
    if basis.is_empty() || basis.len() > MAX_POSES {
        return Err(PsdError::InvalidSetting {
            field: "basis",
            reason: format!("{} poses; need 1..={MAX_POSES}", basis.len()),
        });
    }
    if let Some(&t) = basis.iter().find(|&&t| t >= examples.len()) {
        return Err(PsdError::InvalidSetting {
            field: "basis",
            reason: format!("example {t} ≥ {} examples", examples.len()),
        });
    }
    Ok(())
}

/// Training examples: feature vectors and per-vertex local details of T poses.
#[derive(Clone, Debug)]
pub struct Examples {
    /// Number of feature edges F.
    pub num_features: usize,
    /// Number of vertices n.
    pub num_vertices: usize,
    /// `T × F` feature vectors (row-major).
    pub features: Vec<f64>,
    /// `n × T × 3` details in local frames, vertex-major (cache-friendly per-vertex fits).
    pub details: Vec<f64>,
}

impl Examples {
    /// Number of examples T.
    pub fn len(&self) -> usize {
        self.features.len() / self.num_features.max(1)
    }
    /// Whether there are no examples.
    pub fn is_empty(&self) -> bool {
        self.features.is_empty()
    }
    /// Feature vector of example `t`.
    pub fn feature(&self, t: usize) -> &[f64] {
        &self.features[t * self.num_features..(t + 1) * self.num_features]
    }
    /// Detail of example `t` at vertex `v`.
    pub fn detail(&self, v: usize, t: usize) -> [f64; 3] {
        let i = (v * self.len() + t) * 3;
        [self.details[i], self.details[i + 1], self.details[i + 2]]
    }
}

/// How the RBF weights are computed (thesis §5.4.2).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum FitMode {
    /// `d(f_i) = d_i` for the P basis poses.
    Interpolate,
    /// Least squares over all T examples with P basis poses as centres.
    LeastSquares,
}

/// Feature-space metric.
#[derive(Clone, Debug, PartialEq)]
pub enum Metric {
    /// One Euclidean distance `‖f − f_j‖` for all vertices (PSD, eq. 5.2).
    Global,
    /// Per-vertex weighted distance `‖f − f_j‖_v` (WPSD, eq. 5.3).
    Weighted(EdgeWeights),
}

/// A fitted detail model: `d_v(f) = Σ_j w_{v,j} φ(‖f − f_j‖_(v))`, φ(r) = r.
#[derive(Clone, Debug, PartialEq)]
pub struct DetailModel {
    /// Number of feature edges F.
    pub num_features: usize,
    /// Basis pose feature vectors `f_j` (`P × F`).
    pub centers: Vec<f64>,
    /// `n × P × 3` weights `w_{v,j}` (f32: 3P floats per vertex, thesis §5.5.2).
    pub weights: Vec<f32>,
    /// The metric.
    pub metric: Metric,
}

impl DetailModel {
    /// Number of basis poses P.
    pub fn num_poses(&self) -> usize {
        self.centers.len() / self.num_features.max(1)
    }

    /// Number of vertices.
    pub fn num_vertices(&self) -> usize {
        self.weights.len() / (3 * self.num_poses()).max(1)
    }

    /// Per-frame table `g[i·P + j] = (f_i − f_{j,i})²` shared by all vertices (eq. 5.3).
    pub fn squared_feature_differences(&self, f: &[f64], g: &mut Vec<f32>) {
        let p = self.num_poses();
        g.clear();
        g.resize(self.num_features * p, 0.0);
        for j in 0..p {
            let c = &self.centers[j * self.num_features..(j + 1) * self.num_features];
            for i in 0..self.num_features {
                g[i * p + j] = ((f[i] - c[i]) * (f[i] - c[i])) as f32;
            }
        }
    }

    /// Details of vertices `first..first + out.len()` in local frames for a frame whose
    /// [`DetailModel::squared_feature_differences`] are `g` (eq. 5.2 / 5.5).
    pub fn evaluate_rows(&self, g: &[f32], first: usize, out: &mut [[f32; 3]]) {
        let p = self.num_poses();
        assert!(
            p <= MAX_POSES,
            "at most {MAX_POSES} basis poses (checked by the fits)"
        );
        let mut r = [0.0f32; MAX_POSES];
        if let Metric::Global = self.metric {
            for j in 0..p {
                r[j] = (0..self.num_features)
                    .map(|i| g[i * p + j])
                    .sum::<f32>()
                    .sqrt();
            }
        }
        for (k, o) in out.iter_mut().enumerate() {
            let v = first + k;
            if let Metric::Weighted(ew) = &self.metric {
                let (ids, al) = ew.row(v);
                r[..p].fill(0.0);
                for (&i, &a) in ids.iter().zip(al) {
                    let gi = &g[i as usize * p..(i as usize + 1) * p];
                    for j in 0..p {
                        r[j] += a * gi[j];
                    }
                }
                for x in &mut r[..p] {
                    *x = x.sqrt();
                }
            }
            let w = &self.weights[v * 3 * p..(v + 1) * 3 * p];
            let mut d = [0.0f32; 3];
            for j in 0..p {
                d[0] += w[3 * j] * r[j];
                d[1] += w[3 * j + 1] * r[j];
                d[2] += w[3 * j + 2] * r[j];
            }
            *o = d;
        }
    }

    /// Details of all vertices for feature vector `f` (parallel).
    pub fn evaluate(&self, f: &[f64]) -> Vec<[f32; 3]> {
        let mut g = Vec::new();
        self.squared_feature_differences(f, &mut g);
        let mut out = vec![[0.0f32; 3]; self.num_vertices()];
        out.par_chunks_mut(crate::frames::BLOCK)
            .enumerate()
            .for_each(|(b, c)| self.evaluate_rows(&g, b * crate::frames::BLOCK, c));
        out
    }
}

/// PSD (thesis eq. 5.2): one global metric; the RBF fit is `softcap_core::Rbf` with φ(r) = r
/// and no polynomial tail (exact interpolation, or least squares with the basis as centres).
pub fn fit_psd(examples: &Examples, basis: &[usize], mode: FitMode) -> Result<DetailModel> {
    check_basis(basis, examples)?;
    let (f, n, t_all) = (examples.num_features, examples.num_vertices, examples.len());
    let p = basis.len();
    let centers: Vec<f64> = basis
        .iter()
        .flat_map(|&j| examples.feature(j).to_vec())
        .collect();
    let settings = RbfSettings {
        kernel: RbfKernel::Linear,
        tail: PolynomialTail::None,
        ..Default::default()
    };
    let mut weights = vec![0.0f32; n * 3 * p];
    let samples: Vec<usize> = match mode {
        FitMode::Interpolate => basis.to_vec(),
        FitMode::LeastSquares => (0..t_all).collect(),
    };
    // A single pose has distance matrix [0]: its only consistent interpolant is d ≡ d_0 = 0
    // for the rest pose, which zero weights give.
    if !(mode == FitMode::Interpolate && p == 1) {
        let mut values = vec![0.0; samples.len() * 3 * n];
        for (s, &t) in samples.iter().enumerate() {
            for v in 0..n {
                let d = examples.detail(v, t);
                values[s * 3 * n + 3 * v..s * 3 * n + 3 * v + 3].copy_from_slice(&d);
            }
        }
        let points: Vec<f64> = samples
            .iter()
            .flat_map(|&t| examples.feature(t).to_vec())
            .collect();
        let data = ScatteredData::new(&points, f, &values, 3 * n)?;
        let rbf = match mode {
            FitMode::Interpolate => Rbf::interpolate(&data, &settings)?,
            FitMode::LeastSquares => Rbf::fit_least_squares(&data, &centers, &settings)?,
        };
        let w = rbf.weights(); // P × 3n
        for j in 0..p {
            for v in 0..n {
                for k in 0..3 {
                    weights[(v * p + j) * 3 + k] = w[j * 3 * n + 3 * v + k] as f32;
                }
            }
        }
    }
    Ok(DetailModel {
        num_features: f,
        centers,
        weights,
        metric: Metric::Global,
    })
}

/// WPSD (thesis eq. 5.3–5.5): per vertex v, solve the P×P system `Φ_v w_v = d_v` with
/// `Φ_v[i][j] = ‖f_i − f_j‖_v` (interpolation), or the least-squares system with the `T × P`
/// matrix `Φ_v[t][j] = ‖f_t − f_j‖_v` via ridge-stabilised normal equations (ridge 1e-10 of the
/// mean diagonal). A per-vertex metric can make two basis poses indistinguishable at a vertex;
/// then the interpolation system is singular and the minimum-norm (SVD) solution is used.
pub fn fit_wpsd(
    examples: &Examples,
    basis: &[usize],
    mode: FitMode,
    edge_weights: &EdgeWeights,
) -> Result<DetailModel> {
    check_basis(basis, examples)?;
    let (f, n, t_all) = (examples.num_features, examples.num_vertices, examples.len());
    if edge_weights.len() != n {
        return Err(PsdError::SizeMismatch {
            what: "edge-weight rows",
            expected: n,
            got: edge_weights.len(),
        });
    }
    let p = basis.len();
    let centers: Vec<f64> = basis
        .iter()
        .flat_map(|&j| examples.feature(j).to_vec())
        .collect();
    let samples: Vec<usize> = match mode {
        FitMode::Interpolate => basis.to_vec(),
        FitMode::LeastSquares => (0..t_all).collect(),
    };
    let mut weights = vec![0.0f32; n * 3 * p];
    weights
        .par_chunks_mut(3 * p)
        .enumerate()
        .for_each(|(v, wv)| {
            let phi = DMatrix::from_fn(samples.len(), p, |s, j| {
                edge_weights
                    .distance2(
                        v,
                        examples.feature(samples[s]),
                        &centers[j * f..(j + 1) * f],
                    )
                    .sqrt()
            });
            let rhs = DMatrix::from_fn(samples.len(), 3, |s, k| examples.detail(v, samples[s])[k]);
            let sol = match mode {
                FitMode::Interpolate => solve_square(phi, rhs),
                FitMode::LeastSquares => {
                    let mut ata = phi.transpose() * &phi;
                    let atb = phi.transpose() * rhs;
                    let ridge = 1e-10 * ata.trace() / p as f64 + 1e-300;
                    for j in 0..p {
                        ata[(j, j)] += ridge;
                    }
                    match ata.clone().cholesky() {
                        Some(c) => c.solve(&atb),
                        None => solve_square(ata, atb),
                    }
                }
            };
            for j in 0..p {
                for k in 0..3 {
                    wv[3 * j + k] = sol[(j, k)] as f32;
                }
            }
        });
    Ok(DetailModel {
        num_features: f,
        centers,
        weights,
        metric: Metric::Weighted(edge_weights.clone()),
    })
}

fn solve_square(a: DMatrix<f64>, b: DMatrix<f64>) -> DMatrix<f64> {
    let scale = a.amax().max(1e-300);
    if let Some(x) = a.clone().lu().solve(&b) {
        // accept the LU solution only if it is well conditioned in practice
        let resid = (&a * &x - &b).amax();
        if resid <= 1e-9 * (b.amax() + scale * x.amax())
            && x.amax() * scale <= 1e8 * b.amax().max(1e-300)
        {
            return x;
        }
    }
    let svd = a.svd(true, true);
    svd.solve(&b, 1e-10 * scale)
        .unwrap_or_else(|_| DMatrix::zeros(b.nrows(), b.ncols()))
}

/// Which model a greedy run fits.
#[derive(Clone, Debug)]
pub enum Method {
    /// PSD, eq. 5.2.
    Psd(FitMode),
    /// WPSD, eq. 5.3–5.5.
    Wpsd(FitMode, EdgeWeights),
}

impl Method {
    /// Fit this method with the given basis.
    pub fn fit(&self, examples: &Examples, basis: &[usize]) -> Result<DetailModel> {
        match self {
            Method::Psd(m) => fit_psd(examples, basis, *m),
            Method::Wpsd(m, w) => fit_wpsd(examples, basis, *m, w),
        }
    }
}

/// Squared detail error `Σ_v ‖d_v(f_t) − d_{v,t}‖²` of every example.
pub fn example_errors(model: &DetailModel, examples: &Examples) -> Vec<f64> {
    (0..examples.len())
        .into_par_iter()
        .map(|t| {
            let d = model.evaluate(examples.feature(t));
            d.iter()
                .enumerate()
                .map(|(v, x)| {
                    let e = examples.detail(v, t);
                    (0..3).map(|k| (x[k] as f64 - e[k]).powi(2)).sum::<f64>()
                })
                .sum()
        })
        .collect()
}

/// One step of greedy basis selection.
#[derive(Clone, Debug, Serialize)]
pub struct GreedyStep {
    /// Basis after this step (example indices).
    pub basis: Vec<usize>,
    /// RMS per-vertex detail error over all training examples (length unit of the mesh).
    pub training_rms: f64,
}

/// Greedy pose selection (thesis §5.4.2): start with `first` (the rest pose), repeatedly add
/// the example with the largest error and refit, up to `max_poses`. Examples whose feature
/// vector coincides with a basis pose (distance < 1e-9) are never added (duplicate centres).
/// `on_step` sees each fitted model (e.g. to measure held-out error).
pub fn greedy_selection(
    examples: &Examples,
    method: &Method,
    first: usize,
    max_poses: usize,
    mut on_step: impl FnMut(&GreedyStep, &DetailModel) -> Result<()>,
) -> Result<Vec<GreedyStep>> {
    let mut basis = vec![first];
    let mut steps = Vec::new();
    let total = (examples.len() * examples.num_vertices) as f64;
    loop {
        let model = method.fit(examples, &basis)?;
        let err = example_errors(&model, examples);
        let step = GreedyStep {
            basis: basis.clone(),
            training_rms: (err.iter().sum::<f64>() / total).sqrt(),
        };
        on_step(&step, &model)?;
        steps.push(step);
        if basis.len() >= max_poses {
            break;
        }
        let f = examples.num_features;
        let candidate = (0..examples.len())
            .filter(|&t| {
                basis.iter().all(|&b| {
                    let d: f64 = examples
                        .feature(t)
                        .iter()
                        .zip(examples.feature(b))
                        .map(|(x, y)| (x - y).powi(2))
                        .sum();
                    d.sqrt() > 1e-9 * (f as f64).sqrt()
                })
            })
            .max_by(|&a, &b| err[a].total_cmp(&err[b]).then(b.cmp(&a)));
        match candidate {
            Some(t) if err[t] > 0.0 => basis.push(t),
            _ => break,
        }
    }
    Ok(steps)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::graph::{EdgeWeightSettings, FeatureGraph};
    use nalgebra::Vector3;

    /// Synthetic examples: details are a smooth function of the features.
    fn synthetic(t: usize, n: usize) -> (Examples, EdgeWeights) {
        let hp: Vec<Vector3<f64>> = (0..6)
            .map(|k| Vector3::new(k as f64, (k % 2) as f64, 0.0))
            .collect();
        let graph = FeatureGraph::nearest_neighbours(&hp, 9);
        let rest: Vec<Vector3<f64>> = (0..n)
            .map(|v| Vector3::new(5.0 * v as f64 / n as f64, 0.5, 0.0))
            .collect();
        let ew = EdgeWeights::new(
            &rest,
            &hp,
            &graph,
            &EdgeWeightSettings {
                max_edges: 4,
                min_weight: 0.025,
            },
        );
        let fdim = graph.len();
        let mut features = vec![0.0; t * fdim];
        for s in 1..t {
            for i in 0..fdim {
                features[s * fdim + i] = 0.1 * ((s * 7 + i * 3) as f64).sin();
            }
        }
        let mut details = vec![0.0; n * t * 3];
        for v in 0..n {
            for s in 0..t {
                let f = &features[s * fdim..(s + 1) * fdim];
                let x = f
                    .iter()
                    .enumerate()
                    .map(|(i, y)| y * (1.0 + (i + v) as f64 * 0.1))
                    .sum::<f64>();
                details[(v * t + s) * 3..(v * t + s) * 3 + 3].copy_from_slice(&[x, x * x, -x]);
            }
        }
        (
            Examples {
                num_features: fdim,
                num_vertices: n,
                features,
                details,
            },
            ew,
        )
    }

    #[test]
    fn interpolation_reproduces_basis_poses() {
        let (ex, ew) = synthetic(12, 30);
        let basis = [0, 3, 5, 7, 11];
        for model in [
            fit_psd(&ex, &basis, FitMode::Interpolate).unwrap(),
            fit_wpsd(&ex, &basis, FitMode::Interpolate, &ew).unwrap(),
        ] {
            for &t in &basis {
                let d = model.evaluate(ex.feature(t));
                for v in 0..30 {
                    let e = ex.detail(v, t);
                    for k in 0..3 {
                        assert!(
                            (d[v][k] as f64 - e[k]).abs() < 1e-4,
                            "t {t} v {v}: {:?} vs {e:?}",
                            d[v]
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn greedy_least_squares_error_decreases() {
        let (ex, ew) = synthetic(20, 25);
        for method in [
            Method::Psd(FitMode::LeastSquares),
            Method::Wpsd(FitMode::LeastSquares, ew.clone()),
        ] {
            let steps = greedy_selection(&ex, &method, 0, 8, |_, _| Ok(())).unwrap();
            assert_eq!(steps.len(), 8);
            for w in steps.windows(2) {
                assert!(
                    w[1].training_rms <= w[0].training_rms * (1.0 + 1e-6),
                    "{steps:?}"
                );
            }
            assert!(
                steps[7].training_rms < 0.5 * steps[0].training_rms,
                "{steps:?}"
            );
        }
    }
}
