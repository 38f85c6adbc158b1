//! Seeded, deterministic k-means clustering (thesis §8.3 clusters the branch-and-bound tree
//! levels with it).
//!
//! * [`kmeans`]: Euclidean k-means. k-means++ seeding (Arthur & Vassilvitskii 2007: first
//!   centre uniform, then each next centre drawn with probability ∝ D(x)², the squared distance
//!   to the nearest chosen centre) from a ChaCha8 RNG seeded with `settings.seed`, followed by
//!   Lloyd iterations (assign to nearest centroid, move centroids to their cluster means) until
//!   no assignment changes. Minimizes the inertia Σₖ ‖xₖ − μ_{a(k)}‖².
//! * [`kmedoids`]: the same alternation for an arbitrary dissimilarity between items given by
//!   index, such as thesis eq. 8.4 (dist(a, b) = Σⱼ ‖x(…a…, m̄ⱼ) − x(…b…, m̄ⱼ)‖², a sum of
//!   squared displacement differences). A mean of such items need not exist, so each cluster
//!   is represented by its medoid (the member with the smallest summed dissimilarity to the
//!   other members). The dissimilarity is used where k-means uses the squared distance
//!   (k-means++ weights ∝ dist).
//!
//! Determinism: ties in assignment go to the lowest cluster index, reductions run in index
//! order, and the best of `restarts` runs (lowest cost, first on ties) is returned.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::error::{CoreError, Result, check_finite};

/// Settings of [`kmeans`] and [`kmedoids`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct KMeansSettings {
    /// RNG seed for k-means++ seeding.
    pub seed: u64,
    /// Lloyd iteration cap per run.
    pub max_iterations: usize,
    /// Independent k-means++ restarts; the lowest-cost run is returned.
    pub restarts: usize,
}

impl Default for KMeansSettings {
    fn default() -> Self {
        Self {
            seed: 0,
            max_iterations: 300,
            restarts: 4,
        }
    }
}

/// Result of [`kmeans`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct KMeansResult {
    /// Centroids, row-major k×d.
    pub centroids: Vec<f64>,
    /// Cluster index of every point.
    pub assignments: Vec<usize>,
    /// Σ ‖xₖ − μ_{a(k)}‖².
    pub inertia: f64,
    /// Lloyd iterations of the returned run.
    pub iterations: usize,
    /// True if assignments stopped changing before `max_iterations`.
    pub converged: bool,
}

/// Result of [`kmedoids`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct KMedoidsResult {
    /// Item index of each cluster's medoid.
    pub medoids: Vec<usize>,
    /// Cluster index of every item.
    pub assignments: Vec<usize>,
    /// Σ dist(item, medoid of its cluster).
    pub cost: f64,
    /// Iterations of the returned run.
    pub iterations: usize,
    /// True if assignments stopped changing before `max_iterations`.
    pub converged: bool,
}

fn check_k(k: usize, n: usize) -> Result<()> {
    if k == 0 {
        return Err(CoreError::InvalidSetting {
            field: "k",
            reason: "must be ≥ 1".into(),
        });
    }
    if n < k {
        return Err(CoreError::TooFewSamples {
            what: "k-means points (≥ k)",
            needed: k,
            got: n,
        });
    }
    Ok(())
}

/// k-means++ seeding over items 0..n with a "squared distance" `d2(i, j)`.
fn plus_plus_seeds(
    n: usize,
    k: usize,
    rng: &mut ChaCha8Rng,
    d2: &mut dyn FnMut(usize, usize) -> f64,
) -> Vec<usize> {
    let mut seeds = vec![rng.random_range(0..n)];
    let mut nearest: Vec<f64> = (0..n).map(|i| d2(i, seeds[0])).collect();
    while seeds.len() < k {
        let total: f64 = nearest.iter().sum();
        let next = if total > 0.0 && total.is_finite() {
            let target = rng.random::<f64>() * total;
            let mut acc = 0.0;
            let mut pick = n - 1;
            for (i, &w) in nearest.iter().enumerate() {
                acc += w;
                if acc > target && w > 0.0 {
                    pick = i;
                    break;
                }
            }
            // Never pick an existing seed (possible only through round-off at the end).
            if nearest[pick] > 0.0 {
                pick
            } else {
                (0..n).find(|i| !seeds.contains(i)).unwrap_or(pick)
            }
        } else {
            // All remaining points coincide with seeds: take the first unused index.
            (0..n).find(|i| !seeds.contains(i)).unwrap_or(0)
        };
        seeds.push(next);
        for i in 0..n {
            nearest[i] = nearest[i].min(d2(i, next));
        }
    }
    seeds
}

fn sq_dist(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum()
}

/// Euclidean k-means of `points` (row-major n×`dim`) into `k` clusters (see module docs).
pub fn kmeans(
    points: &[f64],
    dim: usize,
    k: usize,
    settings: &KMeansSettings,
) -> Result<KMeansResult> {
    if dim == 0 || !points.len().is_multiple_of(dim) {
        return Err(CoreError::DimensionMismatch {
            what: "k-means points (multiple of dim)",
            expected: points.len().checked_div(dim).unwrap_or(0) * dim,
            got: points.len(),
        });
    }
    check_finite("k-means points", points)?;
    let n = points.len() / dim;
    check_k(k, n)?;
    let pt = |i: usize| &points[i * dim..(i + 1) * dim];
    let mut rng = ChaCha8Rng::seed_from_u64(settings.seed);
    let mut best: Option<KMeansResult> = None;
    for _ in 0..settings.restarts.max(1) {
        let seeds = plus_plus_seeds(n, k, &mut rng, &mut |i, j| sq_dist(pt(i), pt(j)));
        let mut centroids: Vec<f64> = seeds.iter().flat_map(|&s| pt(s).iter().copied()).collect();
        let mut assignments = vec![usize::MAX; n];
        let mut iterations = 0;
        let mut converged = false;
        while iterations < settings.max_iterations {
            iterations += 1;
            let mut changed = false;
            for i in 0..n {
                let c = nearest_centroid(pt(i), &centroids, dim).0;
                if assignments[i] != c {
                    assignments[i] = c;
                    changed = true;
                }
            }
            if !changed {
                converged = true;
                break;
            }
            let mut sums = vec![0.0; k * dim];
            let mut counts = vec![0usize; k];
            for i in 0..n {
                let c = assignments[i];
                counts[c] += 1;
                for j in 0..dim {
                    sums[c * dim + j] += pt(i)[j];
                }
            }
            for c in 0..k {
                if counts[c] > 0 {
                    for j in 0..dim {
                        centroids[c * dim + j] = sums[c * dim + j] / counts[c] as f64;
                    }
                } else {
                    // Empty cluster: re-seed it at the point farthest from its centroid.
                    let far = (0..n)
                        .map(|i| {
                            (
                                i,
                                sq_dist(
                                    pt(i),
                                    &centroids[assignments[i] * dim..(assignments[i] + 1) * dim],
                                ),
                            )
                        })
                        .fold(
                            (0, -1.0),
                            |acc, (i, d)| if d > acc.1 { (i, d) } else { acc },
                        )
                        .0;
                    centroids[c * dim..(c + 1) * dim].copy_from_slice(pt(far));
                    assignments[far] = c;
                }
            }
        }
        let inertia: f64 = (0..n)
            .map(|i| {
                sq_dist(
                    pt(i),
                    &centroids[assignments[i] * dim..(assignments[i] + 1) * dim],
                )
            })
            .sum();
        if best.as_ref().is_none_or(|b| inertia < b.inertia) {
            best = Some(KMeansResult {
                centroids,
                assignments,
                inertia,
                iterations,
                converged,
            });
        }
    }
    Ok(best.expect("restarts ≥ 1"))
}

fn nearest_centroid(x: &[f64], centroids: &[f64], dim: usize) -> (usize, f64) {
    let k = centroids.len() / dim;
    let mut best = (0, f64::INFINITY);
    for c in 0..k {
        let d = sq_dist(x, &centroids[c * dim..(c + 1) * dim]);
        if d < best.1 {
            best = (c, d);
        }
    }
    best
}

/// k-medoids of `n` items under a symmetric dissimilarity `dist(i, j) ≥ 0` with
/// `dist(i, i) = 0` — e.g. thesis eq. 8.4 (see module docs).
pub fn kmedoids<D: FnMut(usize, usize) -> f64>(
    n: usize,
    k: usize,
    mut dist: D,
    settings: &KMeansSettings,
) -> Result<KMedoidsResult> {
    check_k(k, n)?;
    let mut rng = ChaCha8Rng::seed_from_u64(settings.seed);
    let mut best: Option<KMedoidsResult> = None;
    for _ in 0..settings.restarts.max(1) {
        let mut medoids = plus_plus_seeds(n, k, &mut rng, &mut |i, j| dist(i, j).max(0.0));
        let mut assignments = vec![usize::MAX; n];
        let mut iterations = 0;
        let mut converged = false;
        while iterations < settings.max_iterations {
            iterations += 1;
            let mut changed = false;
            for i in 0..n {
                let c = match medoids.iter().position(|&m| m == i) {
                    Some(own) => own,
                    None => {
                        let mut b = (0, f64::INFINITY);
                        for (c, &m) in medoids.iter().enumerate() {
                            let d = dist(i, m);
                            if d < b.1 {
                                b = (c, d);
                            }
                        }
                        b.0
                    }
                };
                if assignments[i] != c {
                    assignments[i] = c;
                    changed = true;
                }
            }
            if !changed {
                converged = true;
                break;
            }
            for (c, medoid) in medoids.iter_mut().enumerate() {
                let members: Vec<usize> = (0..n).filter(|&i| assignments[i] == c).collect();
                let mut b = (*medoid, f64::INFINITY);
                for &cand in &members {
                    let s: f64 = members.iter().map(|&o| dist(cand, o)).sum();
                    if s < b.1 {
                        b = (cand, s);
                    }
                }
                *medoid = b.0;
            }
        }
        let cost: f64 = (0..n).map(|i| dist(i, medoids[assignments[i]])).sum();
        if best.as_ref().is_none_or(|b| cost < b.cost) {
            best = Some(KMedoidsResult {
                medoids,
                assignments,
                cost,
                iterations,
                converged,
            });
        }
    }
    Ok(best.expect("restarts ≥ 1"))
}
