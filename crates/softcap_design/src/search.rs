//! Goal-based design search (thesis §8.4): branch-and-bound with clustering over the decision tree
//! of cells, and the exhaustive reference.
//!
//! The tree has one level per cell; a node at level l fixes the materials of cells 1…l. Every
//! node a is bounded (§8.4.2 "Bound Estimation") by filling its undecided cells uniformly with
//! each base material m̄_j, simulating those M designs x_j and taking the axis-aligned box
//! [x_j] = [min_j x_j, max_j x_j] in displacement space; the subtree is culled if
//! dist(x̄, [x_j]) > d_min, where d_min is the smallest displacement error ‖x − x̄‖ of any design
//! simulated so far (every uniform fill is a design, so d_min improves as the tree is visited).
//! The tree is traversed breadth-first; before splitting, the surviving nodes of a level are
//! clustered by k-means into K clusters (thesis: K = 20) with the distance of eq. 8.4,
//! dist(a, b) = Σ_j ‖x(a, m̄_j …) − x(b, m̄_j …)‖², which is the squared Euclidean distance between
//! the concatenated uniform-fill responses (x(a, m̄_1 …), …, x(a, m̄_M …)) — so plain k-means on
//! those vectors *is* k-means under eq. 8.4. The representative of a cluster is its member closest
//! to the centroid; only representatives are split. Evaluations are cached, so a design simulated
//! twice (e.g. a uniform fill shared by parent and child) counts once.

use crate::error::{DesignError, Result};
use serde::{Deserialize, Serialize};
use softcap_core::{KMeansSettings, kmeans};
use std::collections::BTreeMap;
use std::sync::Arc;

/// Settings of the branch-and-bound search.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct SearchSettings {
    /// Number of clusters K per level (thesis: 20).
    pub clusters: usize,
    /// Bound-based culling on/off.
    pub cull: bool,
    /// k-means settings (seeded: deterministic).
    pub kmeans: KMeansSettings,
}

impl Default for SearchSettings {
    fn default() -> Self {
        Self {
            clusters: 20,
            cull: true,
            kmeans: KMeansSettings {
                seed: 11,
                max_iterations: 100,
                restarts: 2,
            },
        }
    }
}

/// A response x of a design (the grouped surface displacements), or `None` if its simulation
/// failed (such a design is never chosen).
pub type Response = Option<Arc<Vec<f64>>>;

/// Anything that simulates batches of designs (same order out as in).
pub trait DesignEvaluator {
    /// Responses of `designs`.
    fn evaluate(&mut self, designs: &[Vec<usize>]) -> Vec<Response>;
}

/// Per-level statistics.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LevelReport {
    /// Level l (cells decided).
    pub level: usize,
    /// Nodes created by splitting.
    pub nodes: usize,
    /// Nodes culled by the bound.
    pub culled: usize,
    /// Nodes kept after clustering (split at the next level).
    pub representatives: usize,
    /// d_min after this level.
    pub d_min: f64,
}

/// Result of a search.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SearchReport {
    /// Material index per cell.
    pub design: Vec<usize>,
    /// Displacement error ‖x − x̄‖ [m].
    pub error_m: f64,
    /// Distinct designs simulated by the search.
    pub evaluations: usize,
    /// Per-level statistics.
    pub levels: Vec<LevelReport>,
}

fn sq_dist(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum()
}

/// Euclidean distance from `p` to the axis-aligned box [lo, hi].
pub fn point_box_distance(p: &[f64], lo: &[f64], hi: &[f64]) -> f64 {
    p.iter()
        .zip(lo.iter().zip(hi))
        .map(|(&v, (&l, &h))| {
            let d = if v < l {
                l - v
            } else if v > h {
                v - h
            } else {
                0.0
            };
            d * d
        })
        .sum::<f64>()
        .sqrt()
}

struct Tracker<'a> {
    target: &'a [f64],
    best: Option<(Vec<usize>, f64)>,
    seen: BTreeMap<Vec<usize>, Response>,
}

impl Tracker<'_> {
    fn eval<E: DesignEvaluator + ?Sized>(
        &mut self,
        ev: &mut E,
        designs: &[Vec<usize>],
    ) -> Vec<Response> {
        let todo: Vec<Vec<usize>> = {
            let mut t: Vec<Vec<usize>> = designs
                .iter()
                .filter(|d| !self.seen.contains_key(*d))
                .cloned()
                .collect();
            t.sort();
            t.dedup();
            t
        };
        if !todo.is_empty() {
            let res = ev.evaluate(&todo);
            for (d, r) in todo.into_iter().zip(res) {
                if let Some(x) = &r {
                    let e = sq_dist(x, self.target).sqrt();
                    // Ties: keep the lexicographically smallest design (deterministic).
                    let better = match &self.best {
                        None => true,
                        Some((bd, be)) => e < *be || (e == *be && d < *bd),
                    };
                    if better {
                        self.best = Some((d.clone(), e));
                    }
                }
                self.seen.insert(d, r);
            }
        }
        designs.iter().map(|d| self.seen[d].clone()).collect()
    }

    fn d_min(&self) -> f64 {
        self.best.as_ref().map_or(f64::INFINITY, |b| b.1)
    }
}

/// Branch-and-bound with clustering (thesis §8.4.2) over `cells` cells and `materials` base
/// materials for the goal displacements `target` (x̄).
pub fn branch_and_bound<E: DesignEvaluator + ?Sized>(
    cells: usize,
    materials: usize,
    target: &[f64],
    evaluator: &mut E,
    settings: &SearchSettings,
) -> Result<SearchReport> {
    if cells == 0 || materials == 0 {
        return Err(DesignError::Invalid {
            field: "cells / materials",
            reason: format!("need ≥ 1 of each, got {cells} cells, {materials} materials"),
        });
    }
    let k = settings.clusters.max(1);
    let mut tr = Tracker {
        target,
        best: None,
        seen: BTreeMap::new(),
    };
    let mut levels = Vec::new();
    let mut prefixes: Vec<Vec<usize>> = vec![Vec::new()];
    for level in 1..=cells {
        // Split the representatives of the previous level.
        let children: Vec<Vec<usize>> = prefixes
            .iter()
            .flat_map(|p| {
                (0..materials).map(move |j| {
                    let mut c = p.clone();
                    c.push(j);
                    c
                })
            })
            .collect();
        if level == cells {
            tr.eval(evaluator, &children);
            levels.push(LevelReport {
                level,
                nodes: children.len(),
                culled: 0,
                representatives: 0,
                d_min: tr.d_min(),
            });
            break;
        }
        // Bounds from the uniform fills.
        let fills: Vec<Vec<usize>> = children
            .iter()
            .flat_map(|c| {
                (0..materials).map(move |j| {
                    let mut d = c.clone();
                    d.resize(cells, j);
                    d
                })
            })
            .collect();
        let responses = tr.eval(evaluator, &fills);
        let d_min = tr.d_min();
        let mut survivors = Vec::new();
        let mut features: Vec<f64> = Vec::new();
        let mut dim = 0;
        for (ci, c) in children.iter().enumerate() {
            let rs = &responses[ci * materials..(ci + 1) * materials];
            let ok: Vec<&Arc<Vec<f64>>> = rs.iter().flatten().collect();
            let Some(first) = ok.first() else { continue };
            let n = first.len();
            let mut lo = vec![f64::INFINITY; n];
            let mut hi = vec![f64::NEG_INFINITY; n];
            for r in &ok {
                for i in 0..n {
                    lo[i] = lo[i].min(r[i]);
                    hi[i] = hi[i].max(r[i]);
                }
            }
            if settings.cull && point_box_distance(target, &lo, &hi) > d_min {
                continue;
            }
            // eq. 8.4 feature: concatenated uniform-fill responses (a failed fill borrows the
            // box centre so it adds no spurious distance).
            dim = n * materials;
            for r in rs {
                match r {
                    Some(x) => features.extend_from_slice(x),
                    None => features.extend(lo.iter().zip(&hi).map(|(a, b)| 0.5 * (a + b))),
                }
            }
            survivors.push(c.clone());
        }
        let culled = children.len() - survivors.len();
        if survivors.is_empty() {
            // Everything culled: the best design simulated so far stands.
            levels.push(LevelReport {
                level,
                nodes: children.len(),
                culled,
                representatives: 0,
                d_min,
            });
            break;
        }
        prefixes = if survivors.len() <= k {
            survivors
        } else {
            let km = kmeans(&features, dim, k, &settings.kmeans)?;
            let mut reps = Vec::new();
            for c in 0..k {
                let centroid = &km.centroids[c * dim..(c + 1) * dim];
                let best = (0..survivors.len())
                    .filter(|&i| km.assignments[i] == c)
                    .map(|i| (sq_dist(&features[i * dim..(i + 1) * dim], centroid), i))
                    .min_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
                if let Some((_, i)) = best {
                    reps.push(survivors[i].clone());
                }
            }
            reps.sort();
            reps
        };
        levels.push(LevelReport {
            level,
            nodes: children.len(),
            culled,
            representatives: prefixes.len(),
            d_min,
        });
    }
    let Some((design, error_m)) = tr.best else {
        return Err(DesignError::NotConverged {
            what: "every design of the search".into(),
            status: "no simulation succeeded".into(),
        });
    };
    Ok(SearchReport {
        design,
        error_m,
        evaluations: tr.seen.len(),
        levels,
    })
}

/// Design ↔ index in base M (cell 0 most significant).
pub fn design_from_index(mut index: usize, cells: usize, materials: usize) -> Vec<usize> {
    let mut d = vec![0; cells];
    for c in (0..cells).rev() {
        d[c] = index % materials;
        index /= materials;
    }
    d
}

/// Index of a design in base M (inverse of [`design_from_index`]).
pub fn design_index(design: &[usize], materials: usize) -> usize {
    design.iter().fold(0, |acc, &m| acc * materials + m)
}

/// All M^N responses (the exhaustive reference of the validation, thesis §8.6), index-ordered.
pub fn exhaustive_table<E: DesignEvaluator + ?Sized>(
    cells: usize,
    materials: usize,
    evaluator: &mut E,
    batch: usize,
) -> Vec<Response> {
    let total = materials.pow(cells as u32);
    let mut out = Vec::with_capacity(total);
    let mut start = 0;
    while start < total {
        let end = (start + batch.max(1)).min(total);
        let designs: Vec<Vec<usize>> = (start..end)
            .map(|i| design_from_index(i, cells, materials))
            .collect();
        out.extend(evaluator.evaluate(&designs));
        start = end;
    }
    out
}

/// Exhaustive optimum over a table of [`exhaustive_table`]: (design index, ‖x − x̄‖).
pub fn exhaustive_optimum(table: &[Response], target: &[f64]) -> Option<(usize, f64)> {
    table
        .iter()
        .enumerate()
        .filter_map(|(i, r)| r.as_ref().map(|x| (i, sq_dist(x, target).sqrt())))
        .min_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)))
}

/// Evaluator over a precomputed exhaustive table (lookups; the search still counts distinct
/// designs it asked for).
#[derive(Debug)]
pub struct TableEvaluator<'a> {
    /// The table.
    pub table: &'a [Response],
    /// Materials M.
    pub materials: usize,
}

impl DesignEvaluator for TableEvaluator<'_> {
    fn evaluate(&mut self, designs: &[Vec<usize>]) -> Vec<Response> {
        designs
            .iter()
            .map(|d| self.table[design_index(d, self.materials)].clone())
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A synthetic additive "material" (smooth, monotone in every cell).
    struct Additive {
        v: Vec<f64>,
        calls: usize,
    }
    impl DesignEvaluator for Additive {
        fn evaluate(&mut self, designs: &[Vec<usize>]) -> Vec<Response> {
            self.calls += designs.len();
            designs
                .iter()
                .map(|d| {
                    // x_k = Σ_c v[m_c] / (1 + |c − k|): a "surface" response, one entry per cell.
                    let x = (0..d.len())
                        .map(|k| {
                            d.iter()
                                .enumerate()
                                .map(|(c, &m)| self.v[m] / (1.0 + c.abs_diff(k) as f64))
                                .sum()
                        })
                        .collect();
                    Some(Arc::new(x))
                })
                .collect()
        }
    }

    #[test]
    fn index_round_trip_and_box_distance() {
        for i in [0, 1, 80, 59_048] {
            assert_eq!(design_index(&design_from_index(i, 5, 9), 9), i);
        }
        assert_eq!(design_from_index(10, 3, 3), vec![1, 0, 1]);
        assert!((point_box_distance(&[3.0, 0.5], &[0.0, 0.0], &[1.0, 1.0]) - 2.0).abs() < 1e-15);
        assert_eq!(
            point_box_distance(&[0.5, 0.5], &[0.0, 0.0], &[1.0, 1.0]),
            0.0
        );
    }

    #[test]
    fn culling_is_exact_on_a_monotone_model_and_clustering_bounds_the_work() {
        let v = vec![1.0, 1.7, 2.9, 4.4, 6.5, 9.0];
        let (cells, m) = (4, v.len());
        let mut ev = Additive { v, calls: 0 };
        let table = exhaustive_table(cells, m, &mut ev, 100);
        assert_eq!(ev.calls, 1296);
        for target_index in [7, 500, 1234] {
            let target = table[target_index].clone().unwrap();
            let (opt, e) = exhaustive_optimum(&table, &target).unwrap();
            assert_eq!((opt, e), (target_index, 0.0));
            let mut tev = TableEvaluator {
                table: &table,
                materials: m,
            };
            // Without clustering, the uniform-fill boxes are conservative for a model that is
            // monotone in every cell: branch-and-bound is exact and still culls.
            let exact = SearchSettings {
                clusters: usize::MAX,
                ..SearchSettings::default()
            };
            let rep = branch_and_bound(cells, m, &target, &mut tev, &exact).unwrap();
            assert_eq!(design_index(&rep.design, m), opt);
            assert!(rep.evaluations < table.len(), "{}", rep.evaluations);
            // With K clusters, each level splits at most K nodes: ≤ M + M² + (N−2)·K·M² designs.
            let k = 3;
            let clustered = SearchSettings {
                clusters: k,
                ..SearchSettings::default()
            };
            let rep = branch_and_bound(cells, m, &target, &mut tev, &clustered).unwrap();
            assert!(rep.evaluations <= m + m * m + (cells - 2) * k * m * m);
            assert!(rep.levels.iter().all(|l| l.representatives <= k));
            assert!(rep.error_m.is_finite());
        }
    }
}
