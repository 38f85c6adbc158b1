//! Run-time data layout of the synthesis (thesis §5.5.2): everything one frame reads, stored
//! vertex-major in `f32` so each of the three per-frame passes streams memory once.
//!
//! * **Large scale** `x = x0 + B u_H` (thesis §5.3) with a *block low-rank* `B`
//!   ([`LowRankBasis`]). Rows of `B` sum to 1 (constants are in the null space of `L` and
//!   `L M⁻¹ L`: moving all handles by `t` moves the shell by `t`), so with the handle mean `ū`
//!   and `ũ = u_H − ū`, `x = x0 + ū + B ũ` exactly. The shell solution is smooth at the scale of
//!   the handle spacing, so over a block of [`LOW_RANK_BLOCK`] consecutive vertices the
//!   translation-free part `B_b P` (`P = I − 11ᵀ/H`) has low numerical rank: it is stored as
//!   `U_b C_b` with `C_b = V_kᵀ` the leading `k_b` right singular vectors (eigenvectors of
//!   `(B_b P)ᵀ B_b P`) and `U_b = B_b P V_k`, `k_b` the smallest rank for which no row of the block
//!   is off by more than `RuntimeSettings::basis_tolerance` in L2 (a per-vertex bound
//!   `‖Δx_v‖ ≤ tolerance · ‖ũ‖₂`). Per frame and block `c_b = C_b ũ` (`k_b × 3`, L1-resident), per vertex
//!   `x_v = x0_v + ū + Σ_k U_b[v,k] c_b[k]`. Translations stay exact at any tolerance; the
//!   error is measured in `tests/runtime.rs` and reported in `docs/psd.md`.
//! * **Normals** from a precomputed one-ring stored as ordered fans ([`Fans`]): per vertex its
//!   neighbours in winding order, `n_v ∝ Σ_i (p_{i} − p_v) × (p_{i+1} − p_v)` — the area-weighted
//!   sum of the incident face normals, without a face pass, with one gather per neighbour.
//! * **Details** (eq. 5.3–5.5): per vertex the WPSD edge ids / weights `α_{v,i}` and the `3P`
//!   RBF weights; the per-frame table `g[i][j] = (f_i − f_{j,i})²` is padded to lanes of 8 poses
//!   (F × 8 floats for P ≤ 8, in L1) so `r_j² = Σ_i α_{v,i} g[i][j]` is a vector multiply-add
//!   per edge.
//!
//! Pass 1 writes the large-scale positions; pass 2 computes, per vertex, the large-scale normal
//! and local frame, the detail `d_v(f)` and the final position; pass 3 the final normals. Each
//! pass is a rayon loop over vertex blocks.

use crate::detail::{DetailModel, MAX_POSES, Metric};
use crate::error::{PsdError, Result};
use crate::frames::{BLOCK, Topology, cross, frame_from_edge, normalize, sub};
use crate::rig::FaceRig;
use nalgebra::DMatrix;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use softcap_mesh::ShellBasis;

/// Vertices per low-rank block of the shell basis (consecutive vertex ids).
pub const LOW_RANK_BLOCK: usize = 256;
/// Poses per SIMD lane group of the WPSD distance table.
pub const LANES: usize = 8;

/// Settings of the run-time layout.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct RuntimeSettings {
    /// Largest L2 error allowed in a row of the translation-free basis:
    /// `max_v ‖(B P)_v − (U_b C_b)_v‖₂ ≤ basis_tolerance`, so the large-scale position error of
    /// every vertex is at most `basis_tolerance · ‖u_H − ū‖₂` (Cauchy–Schwarz). `0` keeps full
    /// rank (exact up to f32 rounding).
    pub basis_tolerance: f64,
}

impl Default for RuntimeSettings {
    fn default() -> Self {
        Self {
            basis_tolerance: 1e-5,
        }
    }
}

/// Block low-rank shell basis: per block of [`LOW_RANK_BLOCK`] vertices `B_b P ≈ U_b C_b`.
#[derive(Clone, Debug, PartialEq)]
pub struct LowRankBasis {
    /// Number of vertices.
    pub n: usize,
    /// Number of handles H.
    pub h: usize,
    /// Rank `k_b` of each block.
    pub ranks: Vec<u32>,
    /// Start of each block's `C_b` (`k_b × H`, row-major) in `coeffs`; length blocks + 1.
    pub coeff_offsets: Vec<usize>,
    /// Start of each block's `U_b` (`m_b × k_b`, vertex-major) in `factors`; length blocks + 1.
    pub factor_offsets: Vec<usize>,
    /// All `C_b`.
    pub coeffs: Vec<f32>,
    /// All `U_b`.
    pub factors: Vec<f32>,
}

impl LowRankBasis {
    /// Compress `basis` block by block (see the module docs; `tolerance` as in
    /// [`RuntimeSettings::basis_tolerance`]).
    pub fn new(basis: &ShellBasis, tolerance: f64) -> Self {
        let (n, h) = (basis.n, basis.h);
        let blocks = n.div_ceil(LOW_RANK_BLOCK);
        let parts: Vec<(u32, Vec<f32>, Vec<f32>)> = (0..blocks)
            .into_par_iter()
            .map(|b| {
                let rows = b * LOW_RANK_BLOCK..((b + 1) * LOW_RANK_BLOCK).min(n);
                let m = rows.len();
                // translation-free part B_b P: subtract each row's mean
                let block = DMatrix::<f64>::from_fn(m, h, |i, j| {
                    let row = basis.row(rows.start + i);
                    let mean = row.iter().map(|&w| w as f64).sum::<f64>() / h as f64;
                    row[j] as f64 - mean
                });
                let gram = block.tr_mul(&block);
                let eig = gram.symmetric_eigen();
                let mut order: Vec<usize> = (0..h).collect();
                order.sort_by(|&a, &c| {
                    eig.eigenvalues[c]
                        .total_cmp(&eig.eigenvalues[a])
                        .then(a.cmp(&c))
                });
                let v_sorted =
                    DMatrix::<f64>::from_fn(h, h, |i, j| eig.eigenvectors[(i, order[j])]);
                let u_full = &block * &v_sorted; // m × H, columns by decreasing singular value
                // smallest k whose largest row residual ‖(B_b P)_v − (U_b C_b)_v‖₂ ≤ tolerance
                let k = if tolerance <= 0.0 {
                    h.min(m)
                } else {
                    let mut tails = vec![0.0f64; m];
                    let mut k = h;
                    while k > 0 {
                        let col = u_full.column(k - 1);
                        let worst = tails
                            .iter()
                            .zip(col.iter())
                            .map(|(t, c)| t + c * c)
                            .fold(0.0f64, f64::max);
                        if worst > tolerance * tolerance {
                            break;
                        }
                        for (t, c) in tails.iter_mut().zip(col.iter()) {
                            *t += c * c;
                        }
                        k -= 1;
                    }
                    k
                };
                let vk = v_sorted.columns(0, k).into_owned();
                let u = u_full.columns(0, k).into_owned(); // m × k
                let coeffs: Vec<f32> = (0..k)
                    .flat_map(|j| (0..h).map(move |i| (i, j)))
                    .map(|(i, j)| vk[(i, j)] as f32)
                    .collect();
                let factors: Vec<f32> = (0..m)
                    .flat_map(|i| (0..k).map(move |j| (i, j)))
                    .map(|(i, j)| u[(i, j)] as f32)
                    .collect();
                (k as u32, coeffs, factors)
            })
            .collect();
        let mut out = Self {
            n,
            h,
            ranks: Vec::with_capacity(blocks),
            coeff_offsets: vec![0],
            factor_offsets: vec![0],
            coeffs: Vec::new(),
            factors: Vec::new(),
        };
        for (k, c, f) in parts {
            out.ranks.push(k);
            out.coeffs.extend(c);
            out.factors.extend(f);
            out.coeff_offsets.push(out.coeffs.len());
            out.factor_offsets.push(out.factors.len());
        }
        out
    }

    /// Mean rank per vertex (multiply-adds per vertex and coordinate of the per-vertex step).
    pub fn mean_rank(&self) -> f64 {
        self.factors.len() as f64 / self.n.max(1) as f64
    }

    /// Bytes of the compressed basis.
    pub fn bytes(&self) -> usize {
        4 * (self.coeffs.len() + self.factors.len())
    }
}

/// How a vertex's neighbour list in [`Fans`] closes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum FanKind {
    /// Interior vertex: neighbours form a cycle (`k` neighbours, `k` triangles).
    Closed = 0,
    /// Boundary vertex: one open chain (`k + 1` neighbours, `k` triangles).
    Open = 1,
    /// Anything else (non-manifold, isolated): `[a, b]` pairs per incident triangle.
    Pairs = 2,
}

/// One-ring of every vertex as ordered fans of neighbours (CSR).
#[derive(Clone, Debug, PartialEq)]
pub struct Fans {
    /// CSR offsets into `neighbours` (n + 1).
    pub offsets: Vec<u32>,
    /// Neighbours in winding order.
    pub neighbours: Vec<u32>,
    /// Kind of each vertex's list.
    pub kinds: Vec<FanKind>,
    /// Neighbour defining the tangent of the local frame ([`Topology::reference_neighbour`]).
    pub reference: Vec<u32>,
}

impl Fans {
    /// Ordered fans of `topo`: the incident triangles `v → a → b` of each vertex are chained
    /// (`b` of one = `a` of the next).
    pub fn new(topo: &Topology) -> Self {
        let n = topo.num_vertices();
        let mut offsets = Vec::with_capacity(n + 1);
        offsets.push(0u32);
        let mut neighbours = Vec::with_capacity(topo.vertex_faces.len() + n / 8);
        let mut kinds = Vec::with_capacity(n);
        let mut pairs: Vec<[u32; 2]> = Vec::new();
        let mut used: Vec<bool> = Vec::new();
        for v in 0..n {
            pairs.clear();
            for &f in
                &topo.vertex_faces[topo.face_offsets[v] as usize..topo.face_offsets[v + 1] as usize]
            {
                let t = topo.triangles[f as usize];
                let k = t.iter().position(|&x| x as usize == v).unwrap_or(0);
                pairs.push([t[(k + 1) % 3], t[(k + 2) % 3]]);
            }
            let (kind, seq) = chain(&pairs, &mut used);
            kinds.push(kind);
            neighbours.extend(seq);
            offsets.push(neighbours.len() as u32);
        }
        Self {
            offsets,
            neighbours,
            kinds,
            reference: topo.reference_neighbour.clone(),
        }
    }

    /// Unit normal of vertex `v` of `positions`: normalised area-weighted sum of the incident
    /// face normals (`[0, 0, 1]` if degenerate).
    #[inline]
    pub fn normal(&self, positions: &[[f32; 3]], v: usize) -> [f32; 3] {
        let p = positions[v];
        let ids = &self.neighbours[self.offsets[v] as usize..self.offsets[v + 1] as usize];
        let mut s = [0.0f32; 3];
        let mut add = |a: [f32; 3], b: [f32; 3]| {
            let c = cross(a, b);
            s = [s[0] + c[0], s[1] + c[1], s[2] + c[2]];
        };
        match self.kinds[v] {
            FanKind::Pairs => {
                for ab in ids.chunks_exact(2) {
                    add(
                        sub(positions[ab[0] as usize], p),
                        sub(positions[ab[1] as usize], p),
                    );
                }
            }
            kind => {
                if let Some((&first, rest)) = ids.split_first() {
                    let e0 = sub(positions[first as usize], p);
                    let mut prev = e0;
                    for &i in rest {
                        let e = sub(positions[i as usize], p);
                        add(prev, e);
                        prev = e;
                    }
                    if kind == FanKind::Closed {
                        add(prev, e0);
                    }
                }
            }
        }
        normalize(s, [0.0, 0.0, 1.0])
    }
}

/// Chain the `[a, b]` corner pairs of one vertex into one fan; see [`FanKind`].
fn chain(pairs: &[[u32; 2]], used: &mut Vec<bool>) -> (FanKind, Vec<u32>) {
    let fallback = || (FanKind::Pairs, pairs.iter().flatten().copied().collect());
    if pairs.is_empty() {
        return fallback();
    }
    // an open fan starts at the pair whose `a` is no pair's `b`
    let starts: Vec<usize> = (0..pairs.len())
        .filter(|&i| !pairs.iter().any(|q| q[1] == pairs[i][0]))
        .collect();
    let (start, open) = match starts.len() {
        0 => (0, false),
        1 => (starts[0], true),
        _ => return fallback(),
    };
    used.clear();
    used.resize(pairs.len(), false);
    used[start] = true;
    let mut seq = vec![pairs[start][0], pairs[start][1]];
    for _ in 1..pairs.len() {
        let last = seq[seq.len() - 1];
        let Some(next) = (0..pairs.len()).find(|&i| !used[i] && pairs[i][0] == last) else {
            return fallback();
        };
        used[next] = true;
        seq.push(pairs[next][1]);
    }
    if open {
        (FanKind::Open, seq)
    } else if seq.last() == seq.first() && seq.len() > 2 {
        seq.pop();
        (FanKind::Closed, seq)
    } else {
        fallback()
    }
}

/// Per-frame buffers and the vertex-major run-time data of a rig + detail model.
#[derive(Clone, Debug)]
pub struct RuntimeLayout {
    /// Rest positions `x0` (f32).
    pub rest: Vec<[f32; 3]>,
    /// Block low-rank shell basis.
    pub basis: LowRankBasis,
    /// Ordered one-ring fans.
    pub fans: Fans,
    /// Basis size P.
    pub poses: usize,
    /// WPSD edges per vertex (0 for PSD).
    pub width: usize,
    /// `n × width` edge ids.
    pub edges: Vec<u16>,
    /// `n × width` edge weights `α_{v,i}`.
    pub alphas: Vec<f32>,
    /// `n × 3P` RBF weights (pose-major per vertex: `w[3j + axis]`).
    pub detail_weights: Vec<f32>,
}

impl RuntimeLayout {
    /// Build the layout of `rig` + `model`.
    pub fn new(rig: &FaceRig, model: &DetailModel, settings: &RuntimeSettings) -> Result<Self> {
        let n = rig.num_vertices();
        if model.num_vertices() != n {
            return Err(PsdError::SizeMismatch {
                what: "detail-model vertices",
                expected: n,
                got: model.num_vertices(),
            });
        }
        if model.num_features != rig.graph.len() {
            return Err(PsdError::SizeMismatch {
                what: "feature edges",
                expected: rig.graph.len(),
                got: model.num_features,
            });
        }
        if !(settings.basis_tolerance.is_finite() && settings.basis_tolerance >= 0.0) {
            return Err(PsdError::InvalidSetting {
                field: "basis_tolerance",
                reason: format!("{} is not a tolerance ≥ 0", settings.basis_tolerance),
            });
        }
        let (width, edges, alphas) = match &model.metric {
            Metric::Weighted(ew) => (ew.width, ew.edges.clone(), ew.alphas.clone()),
            Metric::Global => (0, Vec::new(), Vec::new()),
        };
        Ok(Self {
            rest: rig.rest_f32.clone(),
            basis: LowRankBasis::new(&rig.basis, settings.basis_tolerance),
            fans: Fans::new(&rig.topology),
            poses: model.num_poses(),
            width,
            edges,
            alphas,
            detail_weights: model.weights.clone(),
        })
    }

    /// Number of vertices.
    pub fn num_vertices(&self) -> usize {
        self.rest.len()
    }

    /// Bytes streamed per frame by the three passes (vertex-major arrays, excluding gathers of
    /// neighbour positions) — the memory-bandwidth floor of a frame.
    pub fn bytes_per_frame(&self) -> usize {
        let n = self.num_vertices();
        let basis = self.basis.bytes() + n * 24; // rest in, large out
        let fans = 2 * (self.fans.neighbours.len() * 4 + n * 5) + n * 4; // + reference
        let detail = self.edges.len() * 2 + self.alphas.len() * 4 + self.detail_weights.len() * 4;
        basis + fans + detail + n * 12 /* large in */ + n * 24 /* positions, normals out */
    }
}

/// Per-frame WPSD table padded to [`LANES`]: `table[i·nc + c][l] = (f_i − f_{j,i})²` with
/// `j = c·LANES + l` (zero for `j ≥ P`), `nc = ⌈P / LANES⌉` (eq. 5.3).
pub fn feature_table(model: &DetailModel, features: &[f64], table: &mut Vec<[f32; LANES]>) {
    let (p, nf) = (model.num_poses(), model.num_features);
    let nc = p.div_ceil(LANES);
    table.clear();
    table.resize(nf * nc, [0.0; LANES]);
    for j in 0..p {
        let c = &model.centers[j * nf..(j + 1) * nf];
        for i in 0..nf {
            let d = features[i] - c[i];
            table[i * nc + j / LANES][j % LANES] = (d * d) as f32;
        }
    }
}

/// Pass 1 (thesis §5.3 large-scale kernel): `x_v = x0_v + ū + Σ_k U_b[v,k] (C_b ũ)_k` per
/// low-rank block, `u_H` the handle displacements.
pub fn large_scale_pass(layout: &RuntimeLayout, uh: &[[f32; 3]], large: &mut [[f32; 3]]) {
    let b = &layout.basis;
    assert_eq!(uh.len(), b.h, "one displacement per handle");
    let mut mean = [0.0f64; 3];
    for u in uh {
        for a in 0..3 {
            mean[a] += u[a] as f64;
        }
    }
    let mean = mean.map(|m| (m / b.h.max(1) as f64) as f32);
    let centred: Vec<[f32; 4]> = uh
        .iter()
        .map(|u| [u[0] - mean[0], u[1] - mean[1], u[2] - mean[2], 0.0])
        .collect();
    large
        .par_chunks_mut(LOW_RANK_BLOCK)
        .enumerate()
        .for_each_init(Vec::new, |c, (blk, chunk)| {
            let k = b.ranks[blk] as usize;
            let coeffs = &b.coeffs[b.coeff_offsets[blk]..b.coeff_offsets[blk + 1]];
            c.clear();
            c.extend(coeffs.chunks_exact(b.h).map(|row| {
                let mut s = [0.0f32; 4];
                for (&w, u) in row.iter().zip(&centred) {
                    for a in 0..4 {
                        s[a] += w * u[a];
                    }
                }
                s
            }));
            let factors = &b.factors[b.factor_offsets[blk]..b.factor_offsets[blk + 1]];
            let first = blk * LOW_RANK_BLOCK;
            let rest = &layout.rest[first..first + chunk.len()];
            if k == 0 {
                for (o, x0) in chunk.iter_mut().zip(rest) {
                    *o = [x0[0] + mean[0], x0[1] + mean[1], x0[2] + mean[2]];
                }
                return;
            }
            for ((o, x0), urow) in chunk.iter_mut().zip(rest).zip(factors.chunks_exact(k)) {
                let mut s = [0.0f32; 4];
                for (&w, ck) in urow.iter().zip(c.iter()) {
                    for a in 0..4 {
                        s[a] += w * ck[a];
                    }
                }
                *o = [
                    x0[0] + mean[0] + s[0],
                    x0[1] + mean[1] + s[1],
                    x0[2] + mean[2] + s[2],
                ];
            }
        });
}

/// Pass 2 (thesis §5.5.2 fine-scale kernel, eq. 5.3–5.5): per vertex the large-scale normal and
/// local frame `[t, b, n]`, the distances `r_j = sqrt(Σ_i α_{v,i} g[i][j])` (or the global
/// `r` for PSD), the detail `d = Σ_j w_{v,j} r_j` and `x = x_large + d_0 t + d_1 b + d_2 n`.
/// `table` is [`feature_table`]'s.
pub fn detail_pass(
    layout: &RuntimeLayout,
    large: &[[f32; 3]],
    table: &[[f32; LANES]],
    global_r: Option<&[f32]>,
    positions: &mut [[f32; 3]],
) {
    let nc = layout.poses.div_ceil(LANES);
    match nc {
        1 => detail_pass_lanes::<1>(layout, large, table, global_r, positions),
        2 => detail_pass_lanes::<2>(layout, large, table, global_r, positions),
        3 | 4 => detail_pass_lanes::<4>(layout, large, table, global_r, positions),
        _ => detail_pass_lanes::<{ MAX_POSES / LANES }>(layout, large, table, global_r, positions),
    }
}

fn detail_pass_lanes<const NC: usize>(
    layout: &RuntimeLayout,
    large: &[[f32; 3]],
    table: &[[f32; LANES]],
    global_r: Option<&[f32]>,
    positions: &mut [[f32; 3]],
) {
    let p = layout.poses;
    let nc = p.div_ceil(LANES);
    assert!(
        nc <= NC && p <= MAX_POSES,
        "at most {MAX_POSES} basis poses"
    );
    assert!(global_r.is_some() || table.len() >= layout.width.min(1) * nc);
    let width = layout.width;
    let fans = &layout.fans;
    positions
        .par_chunks_mut(BLOCK)
        .enumerate()
        .for_each(|(blk, chunk)| {
            let first = blk * BLOCK;
            let mut r = [[0.0f32; LANES]; NC];
            if let Some(gr) = global_r {
                for (j, &x) in gr.iter().enumerate().take(p) {
                    r[j / LANES][j % LANES] = x;
                }
            }
            for (k, o) in chunk.iter_mut().enumerate() {
                let v = first + k;
                let xl = large[v];
                let n = fans.normal(large, v);
                let [t, bt, n] = frame_from_edge(sub(large[fans.reference[v] as usize], xl), n);
                if global_r.is_none() {
                    r = [[0.0; LANES]; NC];
                    let ids = &layout.edges[v * width..(v + 1) * width];
                    let al = &layout.alphas[v * width..(v + 1) * width];
                    for (&i, &a) in ids.iter().zip(al) {
                        let row = &table[i as usize * nc..i as usize * nc + nc];
                        for (rc, gc) in r.iter_mut().zip(row) {
                            for l in 0..LANES {
                                rc[l] += a * gc[l];
                            }
                        }
                    }
                    for rc in r.iter_mut().take(nc) {
                        for x in rc.iter_mut() {
                            *x = x.sqrt();
                        }
                    }
                }
                let w = &layout.detail_weights[v * 3 * p..(v + 1) * 3 * p];
                let mut d = [0.0f32; 3];
                for (j, wj) in w.chunks_exact(3).enumerate() {
                    let rj = r[j / LANES][j % LANES];
                    d[0] += wj[0] * rj;
                    d[1] += wj[1] * rj;
                    d[2] += wj[2] * rj;
                }
                *o = [
                    xl[0] + d[0] * t[0] + d[1] * bt[0] + d[2] * n[0],
                    xl[1] + d[0] * t[1] + d[1] * bt[1] + d[2] * n[1],
                    xl[2] + d[0] * t[2] + d[1] * bt[2] + d[2] * n[2],
                ];
            }
        });
}

/// Pass 3: unit vertex normals of `positions` from the one-ring fans.
pub fn normal_pass(layout: &RuntimeLayout, positions: &[[f32; 3]], normals: &mut [[f32; 3]]) {
    normals
        .par_chunks_mut(BLOCK)
        .enumerate()
        .for_each(|(blk, chunk)| {
            for (k, o) in chunk.iter_mut().enumerate() {
                *o = layout.fans.normal(positions, blk * BLOCK + k);
            }
        });
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `U_b C_b` against `B_b P` per block: the largest row L2 error.
    fn block_errors(basis: &ShellBasis, lr: &LowRankBasis) -> Vec<f64> {
        let h = basis.h;
        (0..lr.ranks.len())
            .map(|b| {
                let k = lr.ranks[b] as usize;
                let c = &lr.coeffs[lr.coeff_offsets[b]..lr.coeff_offsets[b + 1]];
                let u = &lr.factors[lr.factor_offsets[b]..lr.factor_offsets[b + 1]];
                let mut worst = 0.0f64;
                for (i, v) in
                    (b * LOW_RANK_BLOCK..((b + 1) * LOW_RANK_BLOCK).min(basis.n)).enumerate()
                {
                    let row = basis.row(v);
                    let mean = row.iter().map(|&w| w as f64).sum::<f64>() / h as f64;
                    let mut err = 0.0f64;
                    for j in 0..h {
                        let want = row[j] as f64 - mean;
                        let got: f64 = (0..k)
                            .map(|q| u[i * k + q] as f64 * c[q * h + j] as f64)
                            .sum();
                        err += (got - want).powi(2);
                    }
                    worst = worst.max(err.sqrt());
                }
                worst
            })
            .collect()
    }

    #[test]
    fn low_rank_blocks_reproduce_the_basis_within_tolerance() {
        // 600 vertices (2 full blocks + 1 partial), H = 12, smooth rows that sum to 1
        let (n, h) = (600, 12);
        let mut weights = vec![0.0f32; n * h];
        for v in 0..n {
            let x = v as f64 / n as f64;
            let row: Vec<f64> = (0..h)
                .map(|j| (-((x - j as f64 / h as f64) * 6.0).powi(2)).exp() + 1e-3)
                .collect();
            let s: f64 = row.iter().sum();
            for j in 0..h {
                weights[v * h + j] = (row[j] / s) as f32;
            }
        }
        let basis = ShellBasis { n, h, weights };
        let full = LowRankBasis::new(&basis, 0.0);
        assert_eq!(full.ranks, vec![12, 12, 12]);
        for e in block_errors(&basis, &full) {
            assert!(e < 1e-5, "full rank error {e}");
        }
        for tol in [1e-2, 1e-3] {
            let lr = LowRankBasis::new(&basis, tol);
            assert!(lr.ranks.iter().all(|&k| k < 12), "{:?}", lr.ranks);
            for e in block_errors(&basis, &lr) {
                assert!(e <= tol * 1.01 + 1e-6, "tolerance {tol}: error {e}");
            }
        }
    }

    #[test]
    fn fans_chain_closed_open_and_fall_back_to_pairs() {
        let mut used = Vec::new();
        // interior vertex with 4 triangles given out of order
        let (k, s) = chain(&[[3, 4], [1, 2], [4, 1], [2, 3]], &mut used);
        assert_eq!((k, s), (FanKind::Closed, vec![3, 4, 1, 2]));
        // boundary vertex: 1 → 2 → 3
        let (k, s) = chain(&[[2, 3], [1, 2]], &mut used);
        assert_eq!((k, s), (FanKind::Open, vec![1, 2, 3]));
        // two separate fans (non-manifold)
        let (k, s) = chain(&[[1, 2], [5, 6]], &mut used);
        assert_eq!((k, s), (FanKind::Pairs, vec![1, 2, 5, 6]));
    }
}
