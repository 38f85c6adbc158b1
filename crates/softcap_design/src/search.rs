//! Goal-based design search (thesis §8.4): branch-and-bound with clustering over the decision tree
//! of cells, and the exhaustive reference.
//!
//! The tree has one level per cell; a node at level l fixes the materials of cells 1…l. Every
//! node a is bounded (§8.4.2 "Bound Estimation") by filling its undecided cells uniformly with
//! each base material m̄_j, simulating those M designs x_j and taking the axis-aligned box
//! \[x_j\] = [min_j x_j, max_j x_j] in displacement space; the subtree is culled if
//! dist(x̄, \[x_j\]) > d_min, where d_min is the smallest displacement error ‖x − x̄‖ of any design
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
#[serde(default, deny_unknown_fields)]
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
    /// Sweeps of coordinate descent from the best homogeneous design before the tree is
    /// visited (0: none): a low incumbent d_min early (see `Search::descend`).
    pub incumbent_sweeps: usize,
    /// Additive bound (see [`additive_residual`]) with this slack per level; `None`: only the
    /// §8.4.2 box.
    pub additive: Option<AdditiveMargin>,
    /// Order in which the tree levels decide the cells (see [`CellOrder`]).
    pub cell_order: CellOrder,
    /// Slack subtracted from every box distance before culling (zero: the plain §8.4.2
    /// bound; see [`BoundMargin`]).
    pub margin: BoundMargin,
}

/// Which cell each level of the decision tree decides. §8.4.2 does not fix the order; it
/// decides how much of the response is still open below a node.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum CellOrder {
    /// Level 1 decides cell 0 (the bottom layer, on the table), level N the top layer.
    BottomFirst,
    /// Level 1 decides cell N − 1 (the top layer, under the probe), level N the bottom layer:
    /// the undecided cells of a node are the deep ones, whose effect on the top surface is
    /// small and smooth, so the uniform-fill boxes are tight (default).
    #[default]
    TopFirst,
}

impl CellOrder {
    /// Cell decided at each level (index = level − 1) for `cells` cells.
    pub fn cells(self, cells: usize) -> Vec<usize> {
        match self {
            CellOrder::BottomFirst => (0..cells).collect(),
            CellOrder::TopFirst => (0..cells).rev().collect(),
        }
    }
}

/// Slack that makes the §8.4.2 box a lower bound. A node a at level l with box B_a (its M
/// uniform fills) is culled when dist(x̄, B_a) − μ_a > d_min, with
/// μ_a = `absolute_m`[l − 1] + `relative`[l − 1] · diag(B_a) (missing entries: 0).
///
/// Validity (triangle inequality): for a completion m of a, let q be the point of B_a nearest
/// x(m); then ‖x(m) − x̄‖ ≥ ‖q − x̄‖ − ‖x(m) − q‖ ≥ dist(x̄, B_a) − dist(x(m), B_a). So if
/// μ_a ≥ dist(x(m), B_a) for every completion m (the *box excess*, measured by [`box_excess`]),
/// the culling test never removes a design closer to x̄ than d_min, for every target x̄,
/// and branch-and-bound returns the exhaustive optimum. Level N − 1 boxes are exact (their
/// fills are all the completions) and need no slack.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BoundMargin {
    /// Absolute slack per level \[m\].
    pub absolute_m: Vec<f64>,
    /// Slack per level relative to the box diagonal ‖hi − lo‖.
    pub relative: Vec<f64>,
}

impl BoundMargin {
    /// The slack μ of a node at `level` whose box has diagonal `diagonal_m`.
    pub fn slack(&self, level: usize, diagonal_m: f64) -> f64 {
        let i = level.saturating_sub(1);
        self.absolute_m.get(i).copied().unwrap_or(0.0)
            + self.relative.get(i).copied().unwrap_or(0.0) * diagonal_m
    }

    /// Absolute slack `factor` × the measured largest box excess per level ([`box_excess`]).
    pub fn absolute(excess: &[BoxExcess], factor: f64) -> Self {
        Self {
            absolute_m: excess.iter().map(|e| factor * e.max_excess_m).collect(),
            relative: Vec::new(),
        }
    }

    /// Slack relative to the box diagonal: `factor` × the measured largest
    /// dist(x(m), B)/diag(B) per level ([`box_excess`]).
    pub fn relative(excess: &[BoxExcess], factor: f64) -> Self {
        Self {
            absolute_m: Vec::new(),
            relative: excess.iter().map(|e| factor * e.max_relative).collect(),
        }
    }
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
            incumbent_sweeps: 3,
            additive: None,
            cell_order: CellOrder::default(),
            margin: BoundMargin::default(),
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
    /// Displacement error ‖x − x̄‖ \[m\].
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

/// The design with the cells of `prefix` (tree order `order`) decided and every other cell
/// filled with material `fill`.
fn fill_design(prefix: &[usize], fill: usize, order: &[usize]) -> Vec<usize> {
    let mut d = vec![fill; order.len()];
    for (level, &m) in prefix.iter().enumerate() {
        d[order[level]] = m;
    }
    d
}

/// min over all choices (one entry per group of `deltas`) of ‖start + Σ_c deltas[c][j_c]‖²
/// (depth-first enumeration, M^u · dim operations).
fn additive_min(start: &[f64], deltas: &[Vec<Vec<f64>>]) -> f64 {
    let Some((first, rest)) = deltas.split_first() else {
        return start.iter().map(|v| v * v).sum();
    };
    let mut best = f64::INFINITY;
    let mut buf = vec![0.0; start.len()];
    for d in first {
        for ((o, s), v) in buf.iter_mut().zip(start).zip(d) {
            *o = s + v;
        }
        best = best.min(additive_min(&buf, rest));
    }
    best
}

/// A bounded node of the decision tree: a prefix (materials of the first cells) with the
/// axis-aligned box of its uniform fills and its eq. 8.4 feature vector.
struct Node {
    /// Materials of the decided cells, in tree (level) order.
    prefix: Vec<usize>,
    lo: Vec<f64>,
    hi: Vec<f64>,
    features: Vec<f64>,
    /// Slack μ of the node's box ([`BoundMargin`]).
    slack: f64,
    bound: f64,
    /// Fill nearest x̄ (reference of the additive bound).
    best_fill: Option<usize>,
}

struct Search<'a, E: DesignEvaluator + ?Sized> {
    cells: usize,
    /// Cell decided at each level.
    order: Vec<usize>,
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
        let order = &self.order;
        let fills: Vec<Vec<usize>> = prefixes
            .iter()
            .flat_map(|c| (0..m).map(move |j| fill_design(c, j, order)))
            .collect();
        let responses = self.tracker.eval(self.evaluator, &fills);
        let d_min = self.tracker.d_min();
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
            let slack = self
                .settings
                .margin
                .slack(prefix.len(), sq_dist(&lo, &hi).sqrt());
            let bound = (point_box_distance(self.tracker.target, &lo, &hi) - slack).max(0.0);
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
            let best_fill = rs
                .iter()
                .enumerate()
                .filter_map(|(j, r)| r.as_ref().map(|x| (sq_dist(x, self.tracker.target), j)))
                .min_by(|a, b| a.0.total_cmp(&b.0))
                .map(|p| p.1);
            out.push(Node {
                prefix,
                lo,
                hi,
                features,
                slack,
                bound,
                best_fill,
            });
        }
        if let Some(additive) = self.settings.additive.clone() {
            let before = out.len();
            out = self.additive_bound(out, &additive);
            culled += before - out.len();
        }
        let rep = &mut self.levels[level - 1];
        rep.nodes += out.len() + culled;
        rep.culled += culled;
        out
    }

    /// The additive bound of `nodes` (see [`additive_residual`]): with the reference fill b
    /// nearest x̄ and the single-cell variations x(a, b … j … b), every completion is
    /// predicted as x_b + Σ_c δ_c(m_c), δ_c(j) = x(a, b … j at c … b) − x_b; the node's bound
    /// becomes max(box bound, min over the M^u predictions of ‖x̂ − x̄‖ − μ). Evaluates the
    /// variations of all nodes in one batch; culls those whose bound exceeds d_min.
    fn additive_bound(&mut self, nodes: Vec<Node>, margin: &AdditiveMargin) -> Vec<Node> {
        let (m, cells) = (self.materials, self.cells);
        let mut designs = Vec::new();
        for node in &nodes {
            let (Some(b), true) = (node.best_fill, cells - node.prefix.len() >= 2) else {
                continue;
            };
            let base = fill_design(&node.prefix, b, &self.order);
            for &cell in &self.order[node.prefix.len()..] {
                for j in (0..m).filter(|&j| j != b) {
                    let mut d = base.clone();
                    d[cell] = j;
                    designs.push(d);
                }
            }
        }
        self.tracker.eval(self.evaluator, &designs);
        let d_min = self.tracker.d_min();
        let target = self.tracker.target;
        let mut out = Vec::with_capacity(nodes.len());
        for mut node in nodes {
            let level = node.prefix.len();
            if let (Some(b), true) = (node.best_fill, cells - level >= 2) {
                let base = fill_design(&node.prefix, b, &self.order);
                let xb = self.tracker.seen[&base].clone();
                let mut deltas: Vec<Vec<Vec<f64>>> = Vec::new();
                let mut complete = xb.is_some();
                if let Some(xb) = &xb {
                    for &cell in &self.order[level..] {
                        let mut per = Vec::with_capacity(m);
                        for j in 0..m {
                            let mut d = base.clone();
                            d[cell] = j;
                            match &self.tracker.seen[&d] {
                                Some(x) => {
                                    per.push(x.iter().zip(xb.iter()).map(|(a, c)| a - c).collect())
                                }
                                None => complete = false,
                            }
                        }
                        deltas.push(per);
                    }
                }
                if let (true, Some(xb)) = (complete, xb) {
                    let scale: f64 = deltas
                        .iter()
                        .map(|per| {
                            per.iter()
                                .map(|d| sq_dist(d, &vec![0.0; d.len()]).sqrt())
                                .fold(0.0, f64::max)
                        })
                        .sum();
                    let start: Vec<f64> = xb.iter().zip(target).map(|(a, t)| a - t).collect();
                    let best = additive_min(&start, &deltas);
                    let bound = best.sqrt() - margin.slack(level, b, scale);
                    node.bound = node.bound.max(bound);
                }
            }
            if self.settings.cull && node.bound > d_min {
                continue;
            }
            out.push(node);
        }
        out
    }

    /// Coordinate descent from the best design so far (the best homogeneous one): per sweep,
    /// each cell in tree order takes the material that minimizes ‖x − x̄‖ with the others
    /// fixed; stops after `sweeps` sweeps or when a sweep changes nothing. It only lowers the
    /// incumbent d_min before the tree is visited (more culling from the start); it removes no
    /// design from the tree, so exactness is unchanged.
    fn descend(&mut self, sweeps: usize) {
        for _ in 0..sweeps {
            let Some((start, _)) = self.tracker.best.clone() else {
                return;
            };
            let mut current = start.clone();
            for level in 0..self.cells {
                let cell = self.order[level];
                let designs: Vec<Vec<usize>> = (0..self.materials)
                    .map(|j| {
                        let mut d = current.clone();
                        d[cell] = j;
                        d
                    })
                    .collect();
                self.tracker.eval(self.evaluator, &designs);
                if let Some((best, _)) = &self.tracker.best {
                    current.clone_from(best);
                }
            }
            if current == start {
                return;
            }
        }
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
                let mut slack = first.slack;
                for n in &members[1..] {
                    for i in 0..lo.len() {
                        lo[i] = lo[i].min(n.lo[i]);
                        hi[i] = hi[i].max(n.hi[i]);
                    }
                    slack = slack.max(n.slack);
                }
                // dist(x̄, union) ≤ dist(x̄, B_a) for every member a, so subtracting the
                // largest member slack keeps the cluster test a lower bound.
                let b = (point_box_distance(self.tracker.target, &lo, &hi) - slack).max(0.0);
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
        order: settings.cell_order.cells(cells),
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
    search.descend(settings.incumbent_sweeps);
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

/// Boxes of every level-`level` prefix (tree order `order`) over a complete table, indexed by
/// the prefix key Σ m_{order[i]} M^{level−1−i}; `None` if every fill failed.
fn prefix_boxes(
    table: &[Response],
    materials: usize,
    order: &[usize],
    level: usize,
) -> Vec<Option<(Vec<f64>, Vec<f64>)>> {
    let keys = materials.pow(level as u32);
    (0..keys)
        .map(|key| {
            let mut prefix = vec![0; level];
            let mut k = key;
            for p in prefix.iter_mut().rev() {
                *p = k % materials;
                k /= materials;
            }
            let mut bx: Option<(Vec<f64>, Vec<f64>)> = None;
            for j in 0..materials {
                let d = fill_design(&prefix, j, order);
                if let Some(r) = &table[design_index(&d, materials)] {
                    let (lo, hi) = bx.get_or_insert_with(|| ((**r).clone(), (**r).clone()));
                    for i in 0..r.len() {
                        lo[i] = lo[i].min(r[i]);
                        hi[i] = hi[i].max(r[i]);
                    }
                }
            }
            bx
        })
        .collect()
}

/// Prefix key (see [`prefix_boxes`]) of `design` at `level`.
fn prefix_key(design: &[usize], materials: usize, order: &[usize], level: usize) -> usize {
    order[..level]
        .iter()
        .fold(0, |acc, &c| acc * materials + design[c])
}

/// Checks the §8.4.2 bound over a complete table (tree order `order`): for every prefix of
/// every length 1 … N − 1, do all completions lie in the box of its M uniform fills, and does
/// the culling test (box distance minus the `margin` slack) ever exceed the best distance in
/// the subtree for the given targets? Returns per level (prefixes checked, prefixes with a
/// completion outside the box, largest excess \[m\] of a component outside its box, number and
/// largest excess \[m\] of (prefix, target) pairs whose bound exceeds the subtree's best).
pub fn bound_violations(
    table: &[Response],
    cells: usize,
    materials: usize,
    targets: &[Vec<f64>],
    order: CellOrder,
    margin: &BoundMargin,
) -> Vec<BoundCheck> {
    let order = order.cells(cells);
    let mut out = Vec::new();
    for level in 1..cells {
        let boxes = prefix_boxes(table, materials, &order, level);
        let mut check = BoundCheck {
            level,
            prefixes: boxes.len(),
            violating_prefixes: 0,
            max_component_excess_m: 0.0,
            max_bound_excess_m: 0.0,
            bound_failures: 0,
        };
        let mut violated = vec![false; boxes.len()];
        let mut best = vec![f64::INFINITY; boxes.len() * targets.len()];
        for (index, r) in table.iter().enumerate() {
            let Some(r) = r else { continue };
            let d = design_from_index(index, cells, materials);
            let key = prefix_key(&d, materials, &order, level);
            if let Some((lo, hi)) = &boxes[key] {
                for i in 0..r.len() {
                    let ex = (lo[i] - r[i]).max(r[i] - hi[i]);
                    if ex > 0.0 {
                        violated[key] = true;
                        check.max_component_excess_m = check.max_component_excess_m.max(ex);
                    }
                }
            }
            for (t, target) in targets.iter().enumerate() {
                let b = &mut best[key * targets.len() + t];
                *b = b.min(sq_dist(r, target).sqrt());
            }
        }
        check.violating_prefixes = violated.iter().filter(|v| **v).count();
        for (key, bx) in boxes.iter().enumerate() {
            let Some((lo, hi)) = bx else { continue };
            let slack = margin.slack(level, sq_dist(lo, hi).sqrt());
            for (t, target) in targets.iter().enumerate() {
                let bound = point_box_distance(target, lo, hi) - slack;
                let b = best[key * targets.len() + t];
                if bound > b {
                    check.bound_failures += 1;
                    check.max_bound_excess_m = check.max_bound_excess_m.max(bound - b);
                }
            }
        }
        out.push(check);
    }
    out
}

/// How far the completions of a prefix leave its uniform-fill box, per level, over a complete
/// table (tree order `order`): the quantity a [`BoundMargin`] must cover.
pub fn box_excess(
    table: &[Response],
    cells: usize,
    materials: usize,
    order: CellOrder,
) -> Vec<BoxExcess> {
    let all: Vec<usize> = (0..table.len()).collect();
    box_excess_of(table, cells, materials, order, &all)
}

/// [`box_excess`] over the designs `sample` only (indices into the table): the estimate a
/// calibration from a sample of designs (plus their prefixes' fills) would give.
pub fn box_excess_of(
    table: &[Response],
    cells: usize,
    materials: usize,
    order: CellOrder,
    sample: &[usize],
) -> Vec<BoxExcess> {
    let order = order.cells(cells);
    let mut out = Vec::new();
    for level in 1..cells {
        let boxes = prefix_boxes(table, materials, &order, level);
        let mut e = BoxExcess {
            level,
            prefixes: boxes.len(),
            designs_outside: 0,
            max_excess_m: 0.0,
            max_relative: 0.0,
            mean_diagonal_m: 0.0,
        };
        let mut n_diag = 0usize;
        for (lo, hi) in boxes.iter().flatten() {
            e.mean_diagonal_m += sq_dist(lo, hi).sqrt();
            n_diag += 1;
        }
        e.mean_diagonal_m /= n_diag.max(1) as f64;
        for &index in sample {
            let Some(r) = &table[index] else { continue };
            let d = design_from_index(index, cells, materials);
            let key = prefix_key(&d, materials, &order, level);
            let Some((lo, hi)) = &boxes[key] else {
                continue;
            };
            let ex = point_box_distance(r, lo, hi);
            if ex > 0.0 {
                e.designs_outside += 1;
                e.max_excess_m = e.max_excess_m.max(ex);
                let diag = sq_dist(lo, hi).sqrt();
                e.max_relative =
                    e.max_relative
                        .max(if diag > 0.0 { ex / diag } else { f64::INFINITY });
            }
        }
        out.push(e);
    }
    out
}

/// How far the completions of a prefix leave the additive prediction of the additive bound
/// (`SearchSettings::additive`), per level, over a complete table, for *every* reference
/// fill b (the search picks b by the target, so the certificate must hold for all b):
/// r(m, b) = ‖x(m) − x_b − Σ_c (x(a, b … m_c at c … b) − x_b)‖, reported as the largest
/// r (`max_excess_m`) and the largest r / s, s = Σ_c max_j ‖δ_c(j)‖ (`max_relative`).
///
/// Validity: ‖x(m) − x̄‖ ≥ ‖x̂(m) − x̄‖ − r(m, b) ≥ min over predictions − r, so a slack
/// μ ≥ r over the table makes the additive test a lower bound for every target.
/// Levels with a single undecided cell are exact (r = 0) and not listed.
pub fn additive_residual(
    table: &[Response],
    cells: usize,
    materials: usize,
    order: CellOrder,
) -> Vec<AdditiveResidual> {
    let all: Vec<usize> = (0..table.len()).collect();
    additive_residual_of(table, cells, materials, order, &all)
}

/// [`additive_residual`] over the designs `sample` only (indices into the table).
pub fn additive_residual_of(
    table: &[Response],
    cells: usize,
    materials: usize,
    order: CellOrder,
    sample: &[usize],
) -> Vec<AdditiveResidual> {
    use rayon::prelude::*;
    let order = order.cells(cells);
    let m = materials;
    let mut out = Vec::new();
    for level in 1..cells.saturating_sub(1) {
        let keys = m.pow(level as u32);
        let prefix_of = |key: usize| {
            let mut prefix = vec![0; level];
            let mut k = key;
            for p in prefix.iter_mut().rev() {
                *p = k % m;
                k /= m;
            }
            prefix
        };
        // scale s(key, b)
        let scales: Vec<f64> = (0..keys * m)
            .into_par_iter()
            .map(|kb| {
                let (key, b) = (kb / m, kb % m);
                let base = fill_design(&prefix_of(key), b, &order);
                let Some(xb) = &table[design_index(&base, m)] else {
                    return f64::NAN;
                };
                order[level..]
                    .iter()
                    .map(|&c| {
                        (0..m)
                            .filter_map(|j| {
                                let mut d = base.clone();
                                d[c] = j;
                                table[design_index(&d, m)]
                                    .as_ref()
                                    .map(|x| sq_dist(x, xb).sqrt())
                            })
                            .fold(0.0, f64::max)
                    })
                    .sum()
            })
            .collect();
        let (n_out, max_r, max_rel) = sample
            .par_iter()
            .map(|&index| {
                let Some(x) = &table[index] else {
                    return (0usize, vec![0.0f64; m], vec![0.0f64; m]);
                };
                let d = design_from_index(index, cells, m);
                let key = prefix_key(&d, m, &order, level);
                let prefix = prefix_of(key);
                let mut acc = (0usize, vec![0.0f64; m], vec![0.0f64; m]);
                for b in 0..m {
                    let base = fill_design(&prefix, b, &order);
                    let Some(xb) = &table[design_index(&base, m)] else {
                        continue;
                    };
                    let mut pred: Vec<f64> = xb.to_vec();
                    let mut ok = true;
                    for &c in &order[level..] {
                        let mut v = base.clone();
                        v[c] = d[c];
                        match &table[design_index(&v, m)] {
                            Some(xv) => {
                                for i in 0..pred.len() {
                                    pred[i] += xv[i] - xb[i];
                                }
                            }
                            None => ok = false,
                        }
                    }
                    if !ok {
                        continue;
                    }
                    let r = sq_dist(x, &pred).sqrt();
                    if r > 0.0 {
                        acc.0 += 1;
                        acc.1[b] = acc.1[b].max(r);
                        let sc = scales[key * m + b];
                        acc.2[b] = acc.2[b].max(if sc > 0.0 { r / sc } else { f64::INFINITY });
                    }
                }
                acc
            })
            .reduce(
                || (0, vec![0.0; m], vec![0.0; m]),
                |a, b| {
                    let mx = |u: Vec<f64>, v: Vec<f64>| {
                        u.iter().zip(&v).map(|(p, q)| p.max(*q)).collect()
                    };
                    (a.0 + b.0, mx(a.1, b.1), mx(a.2, b.2))
                },
            );
        let valid: Vec<f64> = scales.iter().copied().filter(|v| v.is_finite()).collect();
        out.push(AdditiveResidual {
            level,
            prefixes: keys,
            residuals: n_out,
            max_residual_m: max_r.iter().copied().fold(0.0, f64::max),
            max_relative: max_rel.iter().copied().fold(0.0, f64::max),
            mean_scale_m: valid.iter().sum::<f64>() / valid.len().max(1) as f64,
            per_reference_max_m: max_r,
            per_reference_relative: max_rel,
        });
    }
    out
}

/// One level of [`additive_residual`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AdditiveResidual {
    /// Cells decided.
    pub level: usize,
    /// Prefixes at this level (M^level).
    pub prefixes: usize,
    /// (design, reference) pairs with a non-zero residual.
    pub residuals: usize,
    /// Largest residual r over all references \[m\].
    pub max_residual_m: f64,
    /// Largest r / s over all references.
    pub max_relative: f64,
    /// Mean scale s over (prefix, reference) \[m\].
    pub mean_scale_m: f64,
    /// Largest r per reference material b \[m\].
    pub per_reference_max_m: Vec<f64>,
    /// Largest r / s per reference material b.
    pub per_reference_relative: Vec<f64>,
}

/// Slack of the additive bound per level and reference material b:
/// μ = `absolute_m`[l−1]\[b\] plus `relative`[l−1]\[b\] · s (missing entries: 0). Valid when it
/// covers [`additive_residual`] (see there).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AdditiveMargin {
    /// Absolute slack \[m\] per level, per reference.
    pub absolute_m: Vec<Vec<f64>>,
    /// Slack relative to s per level, per reference.
    pub relative: Vec<Vec<f64>>,
}

impl AdditiveMargin {
    /// The slack of a node at `level` with reference `b` and scale `scale_m`.
    pub fn slack(&self, level: usize, b: usize, scale_m: f64) -> f64 {
        let get = |v: &Vec<Vec<f64>>| {
            v.get(level.saturating_sub(1))
                .and_then(|r| r.get(b))
                .copied()
                .unwrap_or(0.0)
        };
        get(&self.absolute_m) + get(&self.relative) * scale_m
    }

    /// `factor` × the measured largest residual per level and reference.
    pub fn absolute(residual: &[AdditiveResidual], factor: f64) -> Self {
        Self {
            absolute_m: residual
                .iter()
                .map(|r| r.per_reference_max_m.iter().map(|v| factor * v).collect())
                .collect(),
            relative: Vec::new(),
        }
    }

    /// `factor` × the measured largest r / s per level and reference.
    pub fn relative(residual: &[AdditiveResidual], factor: f64) -> Self {
        Self {
            absolute_m: Vec::new(),
            relative: residual
                .iter()
                .map(|r| {
                    r.per_reference_relative
                        .iter()
                        .map(|v| factor * v)
                        .collect()
                })
                .collect(),
        }
    }
}

/// One level of [`box_excess`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BoxExcess {
    /// Cells decided.
    pub level: usize,
    /// Prefixes at this level (M^level).
    pub prefixes: usize,
    /// Designs lying outside their level-`level` prefix's box.
    pub designs_outside: usize,
    /// Largest Euclidean distance dist(x(m), B) of a design from its prefix's box \[m\].
    pub max_excess_m: f64,
    /// Largest dist(x(m), B) / diag(B).
    pub max_relative: f64,
    /// Mean box diagonal ‖hi − lo‖ at this level \[m\].
    pub mean_diagonal_m: f64,
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
    /// Largest distance of a response component outside its box \[m\].
    pub max_component_excess_m: f64,
    /// (prefix, target) pairs whose culling bound exceeds the subtree's true best distance.
    pub bound_failures: usize,
    /// Largest such excess \[m\].
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
                incumbent_sweeps: 0,
                cell_order: CellOrder::BottomFirst,
                ..SearchSettings::default()
            };
            let rep = branch_and_bound(cells, m, &target, &mut tev, &clustered).unwrap();
            assert!(rep.evaluations <= m + m * m + (cells - 2) * k * m * m);
            assert!(rep.levels.iter().all(|l| l.representatives <= k));
            // The monotone additive model satisfies the bound assumption everywhere.
            let checks = bound_violations(
                &table,
                cells,
                m,
                std::slice::from_ref(&target),
                CellOrder::BottomFirst,
                &BoundMargin::default(),
            );
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
