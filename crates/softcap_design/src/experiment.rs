//! The validation of thesis §8.6 ("Validation of the Goal-based Design"): random layered designs
//! are simulated and used as targets; the branch-and-bound search must find a design whose
//! displacements match, and is compared with the exhaustive optimum over all M^N designs.
//!
//! Targets are simulated with *their own* random layer thicknesses (thesis: "we picked a given
//! combination of layers and their thicknesses"), so a target is in general not exactly
//! representable by the equal-thickness designs the search chooses from: the RMS error of the
//! found design is then a real residual and the exhaustive optimum is not trivially the target.

use crate::composite::{CompositeSettings, CompositeSimulator, LayeredBlock};
use crate::error::{DesignError, Result};
use crate::material::{BaseMaterial, InvariantMaterial, TransverseMaterial, TransverseParams};
use crate::search::{
    DesignEvaluator, Response, SearchSettings, TableEvaluator, branch_and_bound, design_from_index,
    design_index, exhaustive_optimum, exhaustive_table,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::sync::Arc;
use std::time::Instant;

/// Evaluates designs in parallel (rayon, one simulator per worker); results are in input order,
/// so the outcome does not depend on the thread count.
#[derive(Clone, Debug)]
pub struct ParallelEvaluator {
    /// The block all designs share.
    pub block: Arc<LayeredBlock>,
    /// Base materials.
    pub materials: Arc<Vec<BaseMaterial>>,
    /// Simulation settings.
    pub settings: CompositeSettings,
    /// Designs simulated so far.
    pub simulations: usize,
}

impl ParallelEvaluator {
    /// Evaluator for the equal-thickness block of `settings`.
    pub fn new(materials: Arc<Vec<BaseMaterial>>, settings: &CompositeSettings) -> Result<Self> {
        Ok(Self {
            block: Arc::new(LayeredBlock::uniform(settings)?),
            materials,
            settings: settings.clone(),
            simulations: 0,
        })
    }
}

impl DesignEvaluator for ParallelEvaluator {
    fn evaluate(&mut self, designs: &[Vec<usize>]) -> Vec<Response> {
        self.simulations += designs.len();
        designs
            .par_iter()
            .map_init(
                || {
                    CompositeSimulator::new(
                        self.block.clone(),
                        self.materials.clone(),
                        &self.settings,
                    )
                    .ok()
                },
                |sim, d| {
                    sim.as_mut()
                        .and_then(|s| s.simulate(d).ok())
                        .map(|r| Arc::new(r.displacements_m))
                },
            )
            .collect()
    }
}

/// A library of nine known non-linear base materials spanning soft to hard (used where no
/// recordings exist; see docs/design.md): seven isotropic ones, (λ, μ) = p₀ (1 + β‖q(I)‖)
/// (strain-stiffening, thesis eq. 8.2 with one centre at zero strain), and two transversely
/// isotropic ones (tubes along z: stiffer vertically than in-plane).
pub fn reference_library() -> Vec<BaseMaterial> {
    let mut out = Vec::new();
    for i in 0..7 {
        let young = 1.5e5 * 1.7f64.powi(i);
        let nu = 0.28 + 0.025 * i as f64;
        let beta = [1.5, 0.4, 2.5, 0.8, 1.2, 0.2, 2.0][i as usize];
        let mut m = InvariantMaterial::from_young_poisson(young, nu);
        let p0 = m.rbf.constant.clone();
        m.rbf.scale = vec![0.1, 0.01, 0.001];
        m.rbf.centres = vec![vec![0.0, 0.0, 0.0]];
        m.rbf.weights = vec![vec![beta * p0[0], beta * p0[1]]];
        out.push(BaseMaterial::Isotropic(m));
    }
    for (e_in, e_z, beta) in [(2.0e5, 6.0e5, 1.0), (6.0e5, 1.5e6, 0.5)] {
        let nu = 0.3;
        let lame = e_in * nu / ((1.0 + nu) * (1.0 - 2.0 * nu));
        let mu = e_in / (2.0 * (1.0 + nu));
        let mut p = TransverseParams::isotropic(lame, mu);
        p.e33 = e_z * (1.0 - nu) / ((1.0 + nu) * (1.0 - 2.0 * nu));
        p.e44 = 0.8 * mu;
        let mut m = TransverseMaterial::linear(p);
        let p0 = m.rbf.constant.clone();
        m.rbf.scale = vec![0.1; 6];
        m.rbf.centres = vec![vec![0.0; 6]];
        m.rbf.weights = vec![p0.iter().map(|v| beta * v).collect()];
        out.push(BaseMaterial::Transverse(m));
    }
    out
}

/// Settings of the validation experiment.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct ExperimentSettings {
    /// Composite simulation (layers N, forces of the examples …).
    pub composite: CompositeSettings,
    /// Search settings (K = 20).
    pub search: SearchSettings,
    /// Number of random target designs.
    pub targets: usize,
    /// Seed of the target designs and thicknesses.
    pub seed: u64,
    /// Relative jitter of the targets' layer thicknesses (0: exactly representable targets).
    pub thickness_jitter: f64,
    /// Also evaluate all M^N designs as the reference.
    pub exhaustive: bool,
}

impl Default for ExperimentSettings {
    fn default() -> Self {
        Self {
            composite: CompositeSettings::default(),
            search: SearchSettings::default(),
            targets: 20,
            seed: 2010,
            thickness_jitter: 0.15,
            exhaustive: true,
        }
    }
}

/// Outcome for one target.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TargetOutcome {
    /// Material per layer of the target.
    pub target_design: Vec<usize>,
    /// Its layer thicknesses [m].
    pub target_thickness_m: Vec<f64>,
    /// Design found by branch-and-bound.
    pub found_design: Vec<usize>,
    /// RMS displacement error of the found design [m].
    pub found_rms_m: f64,
    /// Distinct designs the search simulated.
    pub evaluations: usize,
    /// Exhaustive optimum and its RMS error [m] (if run).
    pub exhaustive: Option<(Vec<usize>, f64)>,
    /// Found == exhaustive optimum.
    pub matches_exhaustive: Option<bool>,
    /// Wall time of the search [s] (simulations included when not table-backed).
    pub search_seconds: f64,
}

/// Report of the experiment.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ExperimentReport {
    /// Per target.
    pub outcomes: Vec<TargetOutcome>,
    /// Mean RMS displacement error of the found designs [m] (bickel2010: 0.067 mm).
    pub mean_found_rms_m: f64,
    /// Targets whose found design equals the exhaustive optimum.
    pub matches: usize,
    /// Seconds spent on the exhaustive table.
    pub exhaustive_seconds: f64,
    /// Designs in the exhaustive table that failed to converge.
    pub exhaustive_failures: usize,
}

/// Random layer thicknesses with relative jitter, summing to the block height.
fn jittered_thickness(rng: &mut ChaCha8Rng, layers: usize, height_m: f64, jitter: f64) -> Vec<f64> {
    let raw: Vec<f64> = (0..layers)
        .map(|_| 1.0 + jitter * (2.0 * rng.random::<f64>() - 1.0))
        .collect();
    let s: f64 = raw.iter().sum();
    raw.iter().map(|r| r / s * height_m).collect()
}

/// Runs the validation of thesis §8.6 (see module docs).
pub fn run_experiment(
    materials: Arc<Vec<BaseMaterial>>,
    settings: &ExperimentSettings,
) -> Result<ExperimentReport> {
    let cs = &settings.composite;
    let (n, m) = (cs.layers, materials.len());
    if n == 0 || m == 0 {
        return Err(DesignError::Invalid {
            field: "layers / materials",
            reason: "need ≥ 1 of each".into(),
        });
    }
    let mut rng = ChaCha8Rng::seed_from_u64(settings.seed);
    let mut targets = Vec::new();
    for _ in 0..settings.targets {
        let design: Vec<usize> = (0..n).map(|_| rng.random_range(0..m)).collect();
        let thick = jittered_thickness(&mut rng, n, cs.block_size_m[2], settings.thickness_jitter);
        targets.push((design, thick));
    }
    // Target responses on their own meshes (same lateral grid: same top nodes).
    let target_x: Vec<Vec<f64>> = targets
        .par_iter()
        .map(|(d, t)| -> Result<Vec<f64>> {
            let block = Arc::new(LayeredBlock::new(cs, t)?);
            let mut sim = CompositeSimulator::new(block, materials.clone(), cs)?;
            Ok(sim.simulate(d)?.displacements_m)
        })
        .collect::<Result<_>>()?;
    let mut evaluator = ParallelEvaluator::new(materials.clone(), cs)?;
    let t0 = Instant::now();
    let table = if settings.exhaustive {
        Some(exhaustive_table(n, m, &mut evaluator, 2048))
    } else {
        None
    };
    let exhaustive_seconds = t0.elapsed().as_secs_f64();
    let mut outcomes = Vec::new();
    for ((design, thick), tx) in targets.iter().zip(&target_x) {
        let t = Instant::now();
        let rep = match &table {
            Some(tab) => {
                let mut tev = TableEvaluator {
                    table: tab,
                    materials: m,
                };
                branch_and_bound(n, m, tx, &mut tev, &settings.search)?
            }
            None => branch_and_bound(n, m, tx, &mut evaluator, &settings.search)?,
        };
        let search_seconds = t.elapsed().as_secs_f64();
        let found_rms_m = rep.error_m / ((tx.len() / 3) as f64).sqrt();
        let exhaustive = table.as_ref().and_then(|tab| {
            exhaustive_optimum(tab, tx).map(|(i, e)| {
                (
                    design_from_index(i, n, m),
                    e / ((tx.len() / 3) as f64).sqrt(),
                )
            })
        });
        let matches_exhaustive = exhaustive
            .as_ref()
            .map(|(d, _)| design_index(d, m) == design_index(&rep.design, m));
        outcomes.push(TargetOutcome {
            target_design: design.clone(),
            target_thickness_m: thick.clone(),
            found_design: rep.design,
            found_rms_m,
            evaluations: rep.evaluations,
            exhaustive,
            matches_exhaustive,
            search_seconds,
        });
    }
    let mean_found_rms_m =
        outcomes.iter().map(|o| o.found_rms_m).sum::<f64>() / outcomes.len().max(1) as f64;
    let matches = outcomes
        .iter()
        .filter(|o| o.matches_exhaustive == Some(true))
        .count();
    let exhaustive_failures = table
        .as_ref()
        .map_or(0, |t| t.iter().filter(|r| r.is_none()).count());
    Ok(ExperimentReport {
        outcomes,
        mean_found_rms_m,
        matches,
        exhaustive_seconds,
        exhaustive_failures,
    })
}
