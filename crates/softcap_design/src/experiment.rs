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
    AdditiveMargin, AdditiveResidual, BoundCheck, BoundMargin, BoxExcess, DesignEvaluator,
    Response, SearchSettings, TableEvaluator, additive_residual, bound_violations, box_excess,
    branch_and_bound, design_from_index, design_index, exhaustive_optimum, exhaustive_table,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
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
    /// Size of every batch handed to [`DesignEvaluator::evaluate`] (each batch is one parallel
    /// map; the search waits for it before it continues).
    pub batch_sizes: Vec<usize>,
}

impl ParallelEvaluator {
    /// Evaluator for the equal-thickness block of `settings`.
    pub fn new(materials: Arc<Vec<BaseMaterial>>, settings: &CompositeSettings) -> Result<Self> {
        Ok(Self {
            block: Arc::new(LayeredBlock::uniform(settings)?),
            materials,
            settings: settings.clone(),
            simulations: 0,
            batch_sizes: Vec::new(),
        })
    }

    /// Parallel efficiency of the batches on `workers` equal workers, assuming equal cost per
    /// design: Σ b / (workers · Σ ⌈b / workers⌉) (1 = every batch splits evenly; a batch of
    /// one design keeps one worker idle). CPU seconds / workers / this = the wall time on
    /// `workers` idle cores.
    pub fn parallel_efficiency(&self, workers: usize) -> f64 {
        let w = workers.max(1);
        let total: usize = self.batch_sizes.iter().sum();
        let rounds: usize = self.batch_sizes.iter().map(|b| b.div_ceil(w)).sum();
        if rounds == 0 {
            1.0
        } else {
            total as f64 / (w * rounds) as f64
        }
    }
}

impl DesignEvaluator for ParallelEvaluator {
    fn evaluate(&mut self, designs: &[Vec<usize>]) -> Vec<Response> {
        self.simulations += designs.len();
        if !designs.is_empty() {
            self.batch_sizes.push(designs.len());
        }
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
#[serde(default, deny_unknown_fields)]
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
    /// Cache of the exhaustive table ([`write_table`] format): read if it exists and matches
    /// (N, M, response length), otherwise computed and written there.
    pub table_path: Option<PathBuf>,
    /// Certify the bounds from the exhaustive table before searching: the searches use the
    /// relative [`BoundMargin`] of factor × the measured box excess ([`box_excess`]) and the
    /// additive bound with factor × the measured residual per reference
    /// ([`additive_residual`]), which makes every culling test a lower bound over the whole
    /// design space (any target), so the search is exact by the triangle inequality (factor
    /// ≥ 1). `None`: `search.margin` / `search.additive` as given.
    pub certify_margin: Option<f64>,
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
            table_path: None,
            certify_margin: Some(1.0),
        }
    }
}

/// Outcome for one target.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TargetOutcome {
    /// Material per layer of the target.
    pub target_design: Vec<usize>,
    /// Its layer thicknesses \[m\].
    pub target_thickness_m: Vec<f64>,
    /// Design found by branch-and-bound.
    pub found_design: Vec<usize>,
    /// RMS displacement error of the found design \[m\].
    pub found_rms_m: f64,
    /// Distinct designs the search simulated.
    pub evaluations: usize,
    /// Exhaustive optimum and its RMS error \[m\] (if run).
    pub exhaustive: Option<(Vec<usize>, f64)>,
    /// Found == exhaustive optimum.
    pub matches_exhaustive: Option<bool>,
    /// Design found by the thesis' heuristic (only the K representatives split), when the
    /// table is available.
    pub heuristic_design: Option<Vec<usize>>,
    /// Distinct designs the heuristic simulated.
    pub heuristic_evaluations: Option<usize>,
    /// Wall time of the search \[s\] (simulations included when not table-backed).
    pub search_seconds: f64,
}

/// Report of the experiment.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ExperimentReport {
    /// Per target.
    pub outcomes: Vec<TargetOutcome>,
    /// Mean RMS displacement error of the found designs \[m\] (bickel2010: 0.067 mm).
    pub mean_found_rms_m: f64,
    /// Targets whose found design equals the exhaustive optimum.
    pub matches: usize,
    /// Seconds spent on the exhaustive table.
    pub exhaustive_seconds: f64,
    /// Designs in the exhaustive table that failed to converge.
    pub exhaustive_failures: usize,
    /// Targets whose heuristic (K representatives only) design equals the exhaustive optimum.
    pub heuristic_matches: usize,
    /// The §8.4.2 bound assumption checked over the whole table (per level).
    pub bound_checks: Vec<BoundCheck>,
    /// Box excess per level over the table (in the search's cell order).
    pub box_excess: Vec<BoxExcess>,
    /// Additive-bound residual per level over the table.
    pub additive_residual: Vec<AdditiveResidual>,
    /// Box margin the searches used.
    pub margin: BoundMargin,
    /// Additive-bound margin the searches used.
    pub additive_margin: Option<AdditiveMargin>,
}

/// Random layer thicknesses with relative jitter, summing to the block height.
fn jittered_thickness(rng: &mut ChaCha8Rng, layers: usize, height_m: f64, jitter: f64) -> Vec<f64> {
    let raw: Vec<f64> = (0..layers)
        .map(|_| 1.0 + jitter * (2.0 * rng.random::<f64>() - 1.0))
        .collect();
    let s: f64 = raw.iter().sum();
    raw.iter().map(|r| r / s * height_m).collect()
}

/// A validation target: a random design with its own layer thicknesses and its response.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Target {
    /// Material per layer (bottom first).
    pub design: Vec<usize>,
    /// Layer thicknesses \[m\] (jittered, summing to the block height).
    pub thickness_m: Vec<f64>,
    /// Response x̄ on its own mesh (same lateral grid, so the same top nodes as the search's).
    pub response: Vec<f64>,
}

/// The `settings.targets` random targets of the validation (seeded: the same list every run).
pub fn random_targets(
    materials: &Arc<Vec<BaseMaterial>>,
    settings: &ExperimentSettings,
) -> Result<Vec<Target>> {
    let cs = &settings.composite;
    let (n, m) = (cs.layers, materials.len());
    let mut rng = ChaCha8Rng::seed_from_u64(settings.seed);
    let mut targets = Vec::new();
    for _ in 0..settings.targets {
        let design: Vec<usize> = (0..n).map(|_| rng.random_range(0..m)).collect();
        let thick = jittered_thickness(&mut rng, n, cs.block_size_m[2], settings.thickness_jitter);
        targets.push((design, thick));
    }
    targets
        .into_par_iter()
        .map(|(design, thickness_m)| -> Result<Target> {
            let block = Arc::new(LayeredBlock::new(cs, &thickness_m)?);
            let mut sim = CompositeSimulator::new(block, materials.clone(), cs)?;
            let response = sim.simulate(&design)?.displacements_m;
            Ok(Target {
                design,
                thickness_m,
                response,
            })
        })
        .collect()
}

/// The exhaustive table of all M^N designs with `evaluator` (the search's own evaluation):
/// read from `settings.table_path` if it exists and matches (N, M, response length),
/// otherwise computed and, with a path, written there.
pub fn load_or_compute_table(
    evaluator: &mut ParallelEvaluator,
    settings: &ExperimentSettings,
) -> Result<Vec<Response>> {
    let n = evaluator.block.layers;
    let m = evaluator.materials.len();
    let dim = evaluator.block.top_nodes.len() * 3 * evaluator.settings.forces_n.len();
    if let Some(p) = &settings.table_path
        && p.exists()
        && let Ok(t) = read_table(p)
        && t.cells == n
        && t.materials == m
        && t.dim == dim
    {
        return Ok(t.responses);
    }
    let t = exhaustive_table(n, m, evaluator, 4096);
    if let Some(p) = &settings.table_path {
        write_table(p, n, m, dim, &t)?;
    }
    Ok(t)
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
    let targets = random_targets(&materials, settings)?;
    let target_x: Vec<Vec<f64>> = targets.iter().map(|t| t.response.clone()).collect();
    let mut evaluator = ParallelEvaluator::new(materials.clone(), cs)?;
    let t0 = Instant::now();
    let table = if settings.exhaustive {
        Some(load_or_compute_table(&mut evaluator, settings)?)
    } else {
        None
    };
    let exhaustive_seconds = t0.elapsed().as_secs_f64();
    let excess = table.as_ref().map_or_else(Vec::new, |t| {
        box_excess(t, n, m, settings.search.cell_order)
    });
    let residual = table.as_ref().map_or_else(Vec::new, |t| {
        additive_residual(t, n, m, settings.search.cell_order)
    });
    let mut search_settings = settings.search.clone();
    if let (Some(factor), Some(_)) = (settings.certify_margin, &table) {
        search_settings.margin = BoundMargin::relative(&excess, factor);
        search_settings.additive = Some(AdditiveMargin::relative(&residual, factor));
    }
    let settings = &ExperimentSettings {
        search: search_settings,
        ..settings.clone()
    };
    let mut outcomes = Vec::new();
    for (target, tx) in targets.iter().zip(&target_x) {
        let (design, thick) = (&target.design, &target.thickness_m);
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
        let heuristic = match &table {
            Some(tab) => {
                let mut tev = TableEvaluator {
                    table: tab,
                    materials: m,
                };
                let hs = SearchSettings {
                    exact: false,
                    ..settings.search.clone()
                };
                Some(branch_and_bound(n, m, tx, &mut tev, &hs)?)
            }
            None => None,
        };
        outcomes.push(TargetOutcome {
            target_design: design.clone(),
            target_thickness_m: thick.clone(),
            found_design: rep.design,
            found_rms_m,
            evaluations: rep.evaluations,
            exhaustive,
            matches_exhaustive,
            heuristic_design: heuristic.as_ref().map(|h| h.design.clone()),
            heuristic_evaluations: heuristic.as_ref().map(|h| h.evaluations),
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
    let heuristic_matches = outcomes
        .iter()
        .filter(
            |o| matches!((&o.heuristic_design, &o.exhaustive), (Some(h), Some((d, _))) if h == d),
        )
        .count();
    let bound_checks = table.as_ref().map_or_else(Vec::new, |t| {
        bound_violations(
            t,
            n,
            m,
            &target_x,
            settings.search.cell_order,
            &settings.search.margin,
        )
    });
    Ok(ExperimentReport {
        outcomes,
        mean_found_rms_m,
        matches,
        exhaustive_seconds,
        exhaustive_failures,
        heuristic_matches,
        bound_checks,
        box_excess: excess,
        additive_residual: residual,
        margin: settings.search.margin.clone(),
        additive_margin: settings.search.additive.clone(),
    })
}

/// A table of all M^N design responses (index order of [`design_from_index`]).
#[derive(Clone, Debug)]
pub struct ResponseTable {
    /// Cells N.
    pub cells: usize,
    /// Materials M.
    pub materials: usize,
    /// Length of one response.
    pub dim: usize,
    /// Responses (`None`: simulation failed).
    pub responses: Vec<Response>,
}

const TABLE_MAGIC: &[u8; 8] = b"SCDTAB01";

/// Writes a response table: magic `SCDTAB01`, u64 LE N, M, dim, then per design one byte
/// (1 = simulated) and dim f64 LE (zeros for a failed design). Atomic (tmp + rename).
pub fn write_table(
    path: &Path,
    cells: usize,
    materials: usize,
    dim: usize,
    table: &[Response],
) -> Result<()> {
    let mut bytes = Vec::with_capacity(32 + table.len() * (1 + 8 * dim));
    bytes.extend_from_slice(TABLE_MAGIC);
    for v in [cells, materials, dim] {
        bytes.extend_from_slice(&(v as u64).to_le_bytes());
    }
    for r in table {
        match r {
            Some(x) if x.len() == dim => {
                bytes.push(1);
                for v in x.iter() {
                    bytes.extend_from_slice(&v.to_le_bytes());
                }
            }
            _ => {
                bytes.push(0);
                bytes.extend(std::iter::repeat_n(0u8, 8 * dim));
            }
        }
    }
    softcap_app::write_atomic(path, &bytes).map_err(|source| DesignError::Io {
        path: path.into(),
        source,
    })
}

/// Reads a table written by [`write_table`]; a wrong magic, header or length is an error
/// naming the file.
pub fn read_table(path: &Path) -> Result<ResponseTable> {
    let bytes = std::fs::read(path).map_err(|source| DesignError::Io {
        path: path.into(),
        source,
    })?;
    let bad = |reason: String| DesignError::File {
        path: path.into(),
        reason,
    };
    if bytes.len() < 32 || &bytes[..8] != TABLE_MAGIC {
        return Err(bad("not a softcap design table (magic SCDTAB01)".into()));
    }
    let word = |i: usize| {
        let mut b = [0u8; 8];
        b.copy_from_slice(&bytes[8 + 8 * i..16 + 8 * i]);
        u64::from_le_bytes(b) as usize
    };
    let (cells, materials, dim) = (word(0), word(1), word(2));
    let count = u32::try_from(cells)
        .ok()
        .and_then(|c| materials.checked_pow(c))
        .ok_or_else(|| bad(format!("{materials}^{cells} designs overflow")))?;
    let rec = 1 + 8 * dim;
    if bytes.len() != 32 + count * rec {
        return Err(bad(format!(
            "{} bytes, expected {} for {count} designs × {dim} values",
            bytes.len(),
            32 + count * rec
        )));
    }
    let responses = (0..count)
        .map(|k| {
            let o = 32 + k * rec;
            (bytes[o] == 1).then(|| {
                Arc::new(
                    (0..dim)
                        .map(|i| {
                            let mut b = [0u8; 8];
                            b.copy_from_slice(&bytes[o + 1 + 8 * i..o + 9 + 8 * i]);
                            f64::from_le_bytes(b)
                        })
                        .collect(),
                )
            })
        })
        .collect();
    Ok(ResponseTable {
        cells,
        materials,
        dim,
        responses,
    })
}
