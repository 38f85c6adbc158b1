//! Handles and the feature graph (thesis §5.2, §5.4.1) and the WPSD edge weights (eq. 5.4).

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

/// `count` handle vertices by farthest-point sampling (Euclidean, rest pose), starting from
/// the vertex nearest to the centroid. Deterministic; ties broken by the lower index.
/// Thesis §5.3 uses mocap-marker positions; with no markers on the ICT face, farthest-point
/// sampling spreads the H handles evenly over the face region like a marker layout.
pub fn farthest_point_handles(rest: &[Vector3<f64>], count: usize) -> Vec<usize> {
    let n = rest.len();
    if n == 0 || count == 0 {
        return Vec::new();
    }
    let centroid = rest.iter().sum::<Vector3<f64>>() / n as f64;
    let first = argmax(rest.iter().map(|p| -(p - centroid).norm_squared()));
    let mut dist: Vec<f64> = rest
        .iter()
        .map(|p| (p - rest[first]).norm_squared())
        .collect();
    let mut out = vec![first];
    while out.len() < count.min(n) {
        let next = argmax(dist.iter().copied());
        out.push(next);
        for (d, p) in dist.iter_mut().zip(rest) {
            *d = d.min((p - rest[next]).norm_squared());
        }
    }
    out
}

fn argmax(it: impl Iterator<Item = f64>) -> usize {
    let mut best = (0, f64::NEG_INFINITY);
    for (i, x) in it.enumerate() {
        if x > best.1 {
            best = (i, x);
        }
    }
    best.0
}

/// The feature graph: F edges between handles with rest lengths `l_i` (thesis §5.2, Fig. 5.2).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FeatureGraph {
    /// Edges as pairs of handle indices (positions in the handle list, not vertex ids).
    pub edges: Vec<[usize; 2]>,
    /// Rest lengths `l_i`.
    pub rest_lengths: Vec<f64>,
}

impl FeatureGraph {
    /// Build a graph with `target_edges` edges over handle positions: every handle is joined to
    /// its two nearest handles, then the shortest remaining edges of the 8-nearest-neighbour
    /// graph are added until `target_edges` (thesis: edges follow the face, may cross, need not
    /// form a consistent mesh). Deterministic.
    pub fn nearest_neighbours(handle_rest: &[Vector3<f64>], target_edges: usize) -> Self {
        let h = handle_rest.len();
        let mut cand: Vec<(f64, [usize; 2])> = Vec::new();
        let mut must = Vec::new();
        for a in 0..h {
            let mut nb: Vec<(f64, usize)> = (0..h)
                .filter(|&b| b != a)
                .map(|b| ((handle_rest[a] - handle_rest[b]).norm(), b))
                .collect();
            nb.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)));
            for (k, &(d, b)) in nb.iter().take(8).enumerate() {
                let e = [a.min(b), a.max(b)];
                if k < 2 {
                    must.push((d, e));
                }
                cand.push((d, e));
            }
        }
        let key =
            |x: &(f64, [usize; 2]), y: &(f64, [usize; 2])| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1));
        must.sort_by(key);
        must.dedup_by(|x, y| x.1 == y.1);
        cand.sort_by(key);
        cand.dedup_by(|x, y| x.1 == y.1);
        let mut chosen: Vec<(f64, [usize; 2])> = must;
        for c in cand {
            if chosen.len() >= target_edges {
                break;
            }
            if !chosen.iter().any(|x| x.1 == c.1) {
                chosen.push(c);
            }
        }
        chosen.sort_by(key);
        Self {
            edges: chosen.iter().map(|c| c.1).collect(),
            rest_lengths: chosen.iter().map(|c| c.0).collect(),
        }
    }

    /// Same edges with rest lengths measured on another rest shape (detail transfer §5.4.4).
    pub fn with_rest(&self, handle_rest: &[Vector3<f64>]) -> Self {
        Self {
            edges: self.edges.clone(),
            rest_lengths: self
                .edges
                .iter()
                .map(|e| (handle_rest[e[0]] - handle_rest[e[1]]).norm())
                .collect(),
        }
    }

    /// Number of feature edges F.
    pub fn len(&self) -> usize {
        self.edges.len()
    }

    /// Whether the graph has no edges.
    pub fn is_empty(&self) -> bool {
        self.edges.is_empty()
    }

    /// Feature vector of relative stretch, `f_i = (‖p_i1 − p_i2‖ − l_i) / l_i` (thesis §5.4.1).
    pub fn features(&self, handle_positions: &[Vector3<f64>], out: &mut [f64]) {
        for ((f, e), l) in out.iter_mut().zip(&self.edges).zip(&self.rest_lengths) {
            *f = ((handle_positions[e[0]] - handle_positions[e[1]]).norm() - l) / l;
        }
    }
}

/// Settings of the WPSD edge weights (thesis eq. 5.4).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EdgeWeightSettings {
    /// Maximum number of feature edges seen by a vertex (thesis: 16).
    pub max_edges: usize,
    /// Unnormalised weights below this are dropped (thesis: 0.025).
    pub min_weight: f64,
}

impl Default for EdgeWeightSettings {
    fn default() -> Self {
        Self {
            max_edges: 16,
            min_weight: 0.025,
        }
    }
}

/// Sparse per-vertex feature-edge weights `α_{v,i}` (thesis eq. 5.4), at most `max_edges`
/// per vertex, stored in fixed-width rows (unused slots: edge 0 with weight 0).
#[derive(Clone, Debug, PartialEq)]
pub struct EdgeWeights {
    /// Row width (= `max_edges`).
    pub width: usize,
    /// `n × width` edge indices.
    pub edges: Vec<u16>,
    /// `n × width` normalised weights `α_{v,i}` (each row sums to 1).
    pub alphas: Vec<f32>,
}

impl EdgeWeights {
    /// `ᾱ_{v,i} = exp(−β_v (L_{v,i} − l_i))`, `α = ᾱ / Σ ᾱ` (thesis eq. 5.4), with `L_{v,i}` the
    /// sum of rest distances from `v` to the endpoints of edge `i`. `β_v` is chosen per vertex so
    /// that the (max_edges+1)-th closest edge gets exactly `min_weight` — the vertex sees at most
    /// `max_edges` edges, adapted to the local handle density as the thesis suggests; weights
    /// below `min_weight` are dropped.
    pub fn new(
        rest: &[Vector3<f64>],
        handle_rest: &[Vector3<f64>],
        graph: &FeatureGraph,
        settings: &EdgeWeightSettings,
    ) -> Self {
        use rayon::prelude::*;
        let width = settings.max_edges.max(1);
        let ln_min = -(settings.min_weight.clamp(1e-12, 0.999)).ln();
        let rows: Vec<(Vec<u16>, Vec<f32>)> = rest
            .par_iter()
            .map(|x| {
                let mut excess: Vec<(f64, usize)> = graph
                    .edges
                    .iter()
                    .zip(&graph.rest_lengths)
                    .enumerate()
                    .map(|(i, (e, l))| {
                        (
                            (x - handle_rest[e[0]]).norm() + (x - handle_rest[e[1]]).norm() - l,
                            i,
                        )
                    })
                    .collect();
                excess.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
                let e0 = excess.first().map_or(0.0, |e| e.0);
                // Shift by the closest edge's excess so the nearest edge always has weight 1 (the
                // normalisation of eq. 5.4 cancels the common factor exp(β e0)).
                let cut = excess.get(width).map_or(f64::INFINITY, |e| e.0 - e0);
                let beta = if cut > 0.0 && cut.is_finite() {
                    ln_min / cut
                } else {
                    0.0
                };
                let mut ids = vec![0u16; width];
                let mut al = vec![0f32; width];
                let mut sum = 0.0;
                let mut kept = Vec::new();
                for &(e, i) in excess.iter().take(width) {
                    let a = (-beta * (e - e0)).exp();
                    if a >= settings.min_weight || kept.is_empty() {
                        kept.push((i, a));
                        sum += a;
                    }
                }
                for (k, (i, a)) in kept.into_iter().enumerate() {
                    ids[k] = i as u16;
                    al[k] = (a / sum) as f32;
                }
                (ids, al)
            })
            .collect();
        let mut edges = Vec::with_capacity(rest.len() * width);
        let mut alphas = Vec::with_capacity(rest.len() * width);
        for (i, a) in rows {
            edges.extend(i);
            alphas.extend(a);
        }
        Self {
            width,
            edges,
            alphas,
        }
    }

    /// Number of vertices.
    pub fn len(&self) -> usize {
        self.alphas.len() / self.width
    }

    /// Whether there are no vertices.
    pub fn is_empty(&self) -> bool {
        self.alphas.is_empty()
    }

    /// Row of vertex `v`: (edge ids, weights).
    pub fn row(&self, v: usize) -> (&[u16], &[f32]) {
        let r = v * self.width..(v + 1) * self.width;
        (&self.edges[r.clone()], &self.alphas[r])
    }

    /// Weighted squared feature distance `Σ_i α_{v,i} (f_i − g_i)²` (thesis eq. 5.3, squared).
    pub fn distance2(&self, v: usize, f: &[f64], g: &[f64]) -> f64 {
        let (ids, al) = self.row(v);
        ids.iter()
            .zip(al)
            .map(|(&i, &a)| a as f64 * (f[i as usize] - g[i as usize]).powi(2))
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(nx: usize, ny: usize) -> Vec<Vector3<f64>> {
        (0..nx * ny)
            .map(|k| Vector3::new((k % nx) as f64, (k / nx) as f64, 0.0))
            .collect()
    }

    #[test]
    fn farthest_points_spread_and_graph_has_target_size() {
        let g = grid(30, 30);
        let h = farthest_point_handles(&g, 20);
        assert_eq!(h.len(), 20);
        // first pick nearest the centroid, the next a corner
        assert!((g[h[0]] - Vector3::new(14.5, 14.5, 0.0)).norm() < 1.0);
        assert!([0, 29, 870, 899].contains(&h[1]));
        let hp: Vec<_> = h.iter().map(|&v| g[v]).collect();
        let fg = FeatureGraph::nearest_neighbours(&hp, 45);
        assert_eq!(fg.len(), 45);
        let mut f = vec![0.0; fg.len()];
        fg.features(&hp, &mut f);
        assert!(f.iter().all(|x| x.abs() < 1e-12));
        // uniform scaling by 1.1 gives relative stretch 0.1 on every edge, any rotation 0
        let scaled: Vec<_> = hp.iter().map(|p| p * 1.1).collect();
        fg.features(&scaled, &mut f);
        assert!(f.iter().all(|x| (x - 0.1).abs() < 1e-12));
        let rot = nalgebra::Rotation3::from_euler_angles(0.3, -0.2, 1.0);
        let rotated: Vec<_> = hp
            .iter()
            .map(|p| rot * p + Vector3::new(1.0, 2.0, 3.0))
            .collect();
        fg.features(&rotated, &mut f);
        assert!(f.iter().all(|x| x.abs() < 1e-12));
    }

    #[test]
    fn edge_weights_follow_eq_5_4() {
        let g = grid(20, 20);
        let h = farthest_point_handles(&g, 30);
        let hp: Vec<_> = h.iter().map(|&v| g[v]).collect();
        let fg = FeatureGraph::nearest_neighbours(&hp, 70);
        let s = EdgeWeightSettings::default();
        let w = EdgeWeights::new(&g, &hp, &fg, &s);
        assert_eq!(w.len(), g.len());
        for v in 0..g.len() {
            let (ids, al) = w.row(v);
            let sum: f32 = al.iter().sum();
            assert!((sum - 1.0).abs() < 1e-5);
            let nonzero = al.iter().filter(|&&a| a > 0.0).count();
            assert!((1..=16).contains(&nonzero));
            // the heaviest edge is the one with least excess L_{v,i} − l_i
            let excess = |i: usize| {
                let e = fg.edges[i];
                (g[v] - hp[e[0]]).norm() + (g[v] - hp[e[1]]).norm() - fg.rest_lengths[i]
            };
            let best = (0..fg.len()).map(excess).fold(f64::INFINITY, f64::min);
            assert!((excess(ids[0] as usize) - best).abs() < 1e-12);
            // ratios follow exp(−β ΔL): weights decrease with the excess
            for k in 1..nonzero {
                assert!(al[k] <= al[k - 1] + 1e-7);
            }
        }
        // a vertex on a feature edge (a handle) sees that edge with the largest weight
        let (ids, _) = w.row(h[fg.edges[0][0]]);
        let e = fg.edges[ids[0] as usize];
        assert!(e.contains(&fg.edges[0][0]));
    }
}
