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
    /// Exact search: cluster members other than the representatives are culled only by
    /// their (cluster's) bound, never by the breadth limit K (see [`branch_and_bound`]).
    pub exact: bool,
    /// Slack subtracted from every box distance before culling [m] (0: the plain §8.4.2 bound).
    pub bound_margin_m: f64,
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
            exact: true,
            bound_margin_m: 0.0,
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

/// A bounded node of the decision tree: a prefix (materials of the first cells) with the
/// axis-aligned box of its uniform fills and its eq. 8.4 feature vector.
struct Node {
    prefix: Vec<usize>,
    lo: Vec<f64>,
    hi: Vec<f64>,
    features: Vec<f64>,
    bound: f64,
}

struct Search<'a, E: DesignEvaluator + ?Sized> {
    cells: usize,
    materials: usize,
    settings: &'a SearchSettings,
    tracker: Tracker<'a>,
    evaluator: &'a mut E,
    levels: Vec<LevelReport>,
}

impl<E: DesignEvaluator + ?Sized> Search<'_, E> {
    /// Bounds the given prefixes (§8.4.2 "Bound Estimation"): simulates their M uniform fills
    /// in one batch, and returns the nodes whose box is not already farther than d_min.
    fn bound(&mut self, prefixes: Vec<Vec<usize>>, level: usize) -> Vec<Node> {
        let m = self.materials;
        let cells = self.cells;
        let fills: Vec<Vec<usize>> = prefixes
            .iter()
            .flat_map(|c| {
                (0..m).map(move |j| {
                    let mut d = c.clone();
                    d.resize(cells, j);
                    d
                })
            })
            .collect();
        let responses = self.tracker.eval(self.evaluator, &fills);
        let d_min = self.tracker.d_min();
        let margin = self.settings.bound_margin_m;
        let mut out = Vec::new();
        let mut culled = 0;
        for (ci, prefix) in prefixes.into_iter().enumerate() {
            let rs = &responses[ci * m..(ci + 1) * m];
            let ok: Vec<&Arc<Vec<f64>>> = rs.iter().flatten().collect();
            let Some(first) = ok.first() else {
                culled += 1;
                continue;
            };
            let n = first.len();
            let mut lo = vec![f64::INFINITY; n];
            let mut hi = vec![f64::NEG_INFINITY; n];
            for r in &ok {
                for i in 0..n {
                    lo[i] = lo[i].min(r[i]);
                    hi[i] = hi[i].max(r[i]);
                }
            }
            let bound = (point_box_distance(self.tracker.target, &lo, &hi) - margin).max(0.0);
            if self.settings.cull && bound > d_min {
                culled += 1;
                continue;
            }
            // eq. 8.4 feature: concatenated uniform-fill responses (a failed fill borrows the
            // box centre so it adds no spurious distance).
            let mut features = Vec::with_capacity(n * m);
            for r in rs {
                match r {
                    Some(x) => features.extend_from_slice(x),
                    None => features.extend(lo.iter().zip(&hi).map(|(a, b)| 0.5 * (a + b))),
                }
            }
            out.push(Node {
                prefix,
                lo,
                hi,
                features,
                bound,
            });
        }
        let rep = &mut self.levels[level - 1];
        rep.nodes += out.len() + culled;
        rep.culled += culled;
        out
    }

    /// Children of `nodes` (one more cell decided), bounded.
    fn split(&mut self, nodes: &[&Node], level: usize) -> Vec<Node> {
        let m = self.materials;
        let children: Vec<Vec<usize>> = nodes
            .iter()
            .flat_map(|p| {
                (0..m).map(move |j| {
                    let mut c = p.prefix.clone();
                    c.push(j);
                    c
                })
            })
            .collect();
        if level > 0 {
            self.levels[level - 1].representatives += nodes.len();
        }
        self.bound(children, level + 1)
    }

    /// Processes the bounded nodes of `level` (see [`branch_and_bound`]).
    fn expand(&mut self, level: usize, mut nodes: Vec<Node>) -> Result<()> {
        let k = self.settings.clusters.max(1);
        loop {
            let d_min = self.tracker.d_min();
            if self.settings.cull {
                let before = nodes.len();
                nodes.retain(|n| n.bound <= d_min);
                self.levels[level.max(1) - 1].culled += before - nodes.len();
            }
            // A node at level N − 1 has the leaves as its uniform fills: all were simulated
            // when it was bounded, so its subtree is done.
            if nodes.is_empty() || level + 1 >= self.cells {
                break;
            }
            if nodes.len() <= k {
                let children = self.split(&nodes.iter().collect::<Vec<_>>(), level);
                self.expand(level + 1, children)?;
                break;
            }
            // k-means (K clusters) under eq. 8.4; the member nearest each centroid is split.
            let dim = nodes[0].features.len();
            let features: Vec<f64> = nodes
                .iter()
                .flat_map(|n| n.features.iter().copied())
                .collect();
            let km = kmeans(&features, dim, k, &self.settings.kmeans)?;
            let mut is_rep = vec![false; nodes.len()];
            for c in 0..k {
                let centroid = &km.centroids[c * dim..(c + 1) * dim];
                let best = (0..nodes.len())
                    .filter(|&i| km.assignments[i] == c)
                    .map(|i| (sq_dist(&nodes[i].features, centroid), i))
                    .min_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
                if let Some((_, i)) = best {
                    is_rep[i] = true;
                }
            }
            let reps: Vec<&Node> = nodes
                .iter()
                .zip(&is_rep)
                .filter(|(_, r)| **r)
                .map(|(n, _)| n)
                .collect();
            let children = self.split(&reps, level);
            self.expand(level + 1, children)?;
            if !self.settings.exact {
                // The thesis' heuristic: only representatives are split.
                break;
            }
            // Exact mode: the other members stay candidates until their cluster's box (the
            // union of the members' boxes) — and then each member's own box — is farther from
            // x̄ than the d_min that the representatives' subtrees have brought down.
            let d_min = self.tracker.d_min();
            let mut rest: Vec<(usize, Node)> = nodes
                .into_iter()
                .zip(is_rep)
                .zip(km.assignments.iter().copied())
                .filter(|((_, r), _)| !r)
                .map(|((n, _), c)| (c, n))
                .collect();
            let mut cluster_culled = vec![false; k];
            for c in 0..k {
                let members: Vec<&Node> = rest
                    .iter()
                    .filter(|(a, _)| *a == c)
                    .map(|(_, n)| n)
                    .collect();
                let Some(first) = members.first() else {
                    continue;
                };
                let mut lo = first.lo.clone();
                let mut hi = first.hi.clone();
                for n in &members[1..] {
                    for i in 0..lo.len() {
                        lo[i] = lo[i].min(n.lo[i]);
                        hi[i] = hi[i].max(n.hi[i]);
                    }
                }
                let b = (point_box_distance(self.tracker.target, &lo, &hi)
                    - self.settings.bound_margin_m)
                    .max(0.0);
                cluster_culled[c] = self.settings.cull && b > d_min;
            }
            let before = rest.len();
            rest.retain(|(c, _)| !cluster_culled[*c]);
            self.levels[level.max(1) - 1].culled += before - rest.len();
            nodes = rest.into_iter().map(|(_, n)| n).collect();
        }
        Ok(())
    }
}

/// Branch-and-bound with clustering (thesis §8.4.2) over `cells` cells and `materials` base
/// materials for the goal displacements `target` (x̄).
///
/// Every node is bounded by the box of its M uniform fills and culled when
/// dist(x̄, box) > d_min. The surviving nodes of a level are clustered by k-means (K
/// clusters, eq. 8.4) and the representatives are split first, depth-first through the
/// levels, so that d_min drops early. With `settings.exact` (default) the other members are
/// *not* discarded: once the representatives' subtrees are done, a cluster is culled only if
/// its box (union of its members' boxes) is farther than d_min, then each member by its own
/// box, and the remaining members are clustered and split in turn. The result is then the
/// exact optimum whenever the uniform-fill boxes contain every completion of their prefix (the
/// monotonicity assumption of §8.4.2; checked over the full design space in
/// [`bound_violations`]); K only orders the work. With `exact = false` only the
/// representatives are split (the thesis' speed heuristic, which can lose the optimum).
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
    let mut search = Search {
        cells,
        materials,
        settings,
        tracker: Tracker {
            target,
            best: None,
            seen: BTreeMap::new(),
        },
        evaluator,
        levels: (1..=cells)
            .map(|level| LevelReport {
                level,
                nodes: 0,
                culled: 0,
                representatives: 0,
                d_min: f64::INFINITY,
            })
            .collect(),
    };
    // The root's uniform fills are the M homogeneous designs.
    let root = search.bound(vec![Vec::new()], 1);
    search.levels[0].nodes = 0;
    search.levels[0].culled = 0;
    if cells == 1 {
        // The root's fills are all designs.
    } else {
        let children = search.split(&root.iter().collect::<Vec<_>>(), 0);
        search.expand(1, children)?;
    }
    let d_min = search.tracker.d_min();
    for l in &mut search.levels {
        l.d_min = d_min;
    }
    let Some((design, error_m)) = search.tracker.best else {
        return Err(DesignError::NotConverged {
            what: "every design of the search".into(),
            status: "no simulation succeeded".into(),
        });
    };
    Ok(SearchReport {
        design,
        error_m,
        evaluations: search.tracker.seen.len(),
        levels: search.levels,
    })
}

/// Checks the §8.4.2 bound assumption over a complete table of responses: for every prefix of
/// every length 1 … N − 1, do all completions lie in the box of its M uniform fills? Returns
/// per level (prefixes checked, prefixes with a completion outside the box, largest excess
/// [m] of a component outside its box, largest excess of the distance bound over the
/// distance of the subtree's best design for the given targets [m]).
pub fn bound_violations(
    table: &[Response],
    cells: usize,
    materials: usize,
    targets: &[Vec<f64>],
) -> Vec<BoundCheck> {
    let mut out = Vec::new();
    for level in 1..cells {
        let subtree = materials.pow((cells - level) as u32);
        let prefixes = materials.pow(level as u32);
        let mut check = BoundCheck {
            level,
            prefixes,
            violating_prefixes: 0,
            max_component_excess_m: 0.0,
            max_bound_excess_m: 0.0,
            bound_failures: 0,
        };
        for p in 0..prefixes {
            let first = p * subtree;
            let fills: Vec<&Arc<Vec<f64>>> = (0..materials)
                .filter_map(|j| {
                    // uniform fill j: every remaining digit = j
                    let mut idx = first;
                    let mut w = 1;
                    for _ in 0..cells - level {
                        idx += j * w;
                        w *= materials;
                    }
                    table[idx].as_ref()
                })
                .collect();
            let Some(f0) = fills.first() else { continue };
            let n = f0.len();
            let mut lo = vec![f64::INFINITY; n];
            let mut hi = vec![f64::NEG_INFINITY; n];
            for r in &fills {
                for i in 0..n {
                    lo[i] = lo[i].min(r[i]);
                    hi[i] = hi[i].max(r[i]);
                }
            }
            let mut violated = false;
            for r in table[first..first + subtree].iter().flatten() {
                for i in 0..n {
                    let ex = (lo[i] - r[i]).max(r[i] - hi[i]);
                    if ex > 0.0 {
                        violated = true;
                        check.max_component_excess_m = check.max_component_excess_m.max(ex);
                    }
                }
            }
            check.violating_prefixes += usize::from(violated);
            for t in targets {
                let bound = point_box_distance(t, &lo, &hi);
                let best = table[first..first + subtree]
                    .iter()
                    .flatten()
                    .map(|r| sq_dist(r, t).sqrt())
                    .fold(f64::INFINITY, f64::min);
                if bound > best {
                    check.bound_failures += 1;
                    check.max_bound_excess_m = check.max_bound_excess_m.max(bound - best);
                }
            }
        }
        out.push(check);
    }
    out
}

/// One level of [`bound_violations`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BoundCheck {
    /// Cells decided.
    pub level: usize,
    /// Prefixes at this level (M^level).
    pub prefixes: usize,
    /// Prefixes with at least one completion outside their uniform-fill box.
    pub violating_prefixes: usize,
    /// Largest distance of a response component outside its box [m].
    pub max_component_excess_m: f64,
    /// (prefix, target) pairs whose box distance exceeds the subtree's true best distance.
    pub bound_failures: usize,
    /// Largest such excess [m].
    pub max_bound_excess_m: f64,
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
            // Exact mode with K = 3 clusters: the same optimum.
            let clustered_exact = SearchSettings {
                clusters: 3,
                ..SearchSettings::default()
            };
            let rep = branch_and_bound(cells, m, &target, &mut tev, &clustered_exact).unwrap();
            assert_eq!(design_index(&rep.design, m), opt);
            // The thesis' heuristic (only representatives split): each level splits at most K
            // nodes: ≤ M + M² + (N−2)·K·M² designs.
            let k = 3;
            let clustered = SearchSettings {
                clusters: k,
                exact: false,
                ..SearchSettings::default()
            };
            let rep = branch_and_bound(cells, m, &target, &mut tev, &clustered).unwrap();
            assert!(rep.evaluations <= m + m * m + (cells - 2) * k * m * m);
            assert!(rep.levels.iter().all(|l| l.representatives <= k));
            // The monotone additive model satisfies the bound assumption everywhere.
            let checks = bound_violations(&table, cells, m, std::slice::from_ref(&target));
            assert_eq!(checks.len(), cells - 1);
            assert!(
                checks
                    .iter()
                    .all(|c| c.violating_prefixes == 0 && c.bound_failures == 0)
            );
            assert!(rep.error_m.is_finite());
        }
    }
}
