//! Run-time data layout of the synthesis (thesis §5.5.2): everything one frame reads, stored
//! vertex-major (f32 positions, fixed-point per-vertex weights) so a frame streams memory once.
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
//! * **Details** (eq. 5.3–5.5), in batches of [`BATCH`] = 8 consecutive stored vertices, one
//!   vertex per SIMD lane ([`BatchDetails`]): per batch the union of its vertices' WPSD edges
//!   (ids `u8` when F ≤ 256) with one `α_{v,i}` lane per vertex (`u16` fixed point,
//!   [`ALPHA_STEP`]), and the `3P` RBF weights (f32) as lanes; the per-frame table
//!   `g[i][j] = (f_i − f_{j,i})²` is padded to lanes of 8 poses, so `r_j² = Σ_i α_{v,i} g[i][j]`
//!   is one 8-vertex multiply-add per union edge and pose, and the normalisations, local frames
//!   and the final `x = x_large + d_0 t + d_1 b + d_2 n` run 8 vertices wide (private `Lanes`).
//!   Everything that does not depend on the pose (edge selection, `α`, RBF weights, fans,
//!   reference neighbours) is precomputed.
//!
//! A frame ([`frame_pass`]) is the three passes over the whole mesh, each split into
//! independent chunks of stored vertices run in parallel (rayon): large scale
//! ([`large_scale_pass`]), normal + frame + WPSD detail ([`detail_pass`], one-rings from the
//! complete large-scale positions), final normals ([`normal_pass`]). Every vertex runs the same
//! arithmetic whatever the chunking or thread count (bit-identical results). (Sessions 7–9 fused
//! the passes into one sweep per chunk with the one-ring gathers hitting cache, but the vertices
//! whose one-ring left the sweep window — 9 % of the detail batches, 18 % of the normals on the
//! Morton-ordered 592k face — had to be finished after the sweep from memory, and that cost more
//! than the fusion saved: 28.5–30.2 vs 33.1–36.6 CPU-ms per frame,
//! docs/notes/2026-11-26-psd-frame-passes.md.)

use crate::detail::{DetailModel, MAX_POSES, Metric};
use crate::error::{PsdError, Result};
use crate::frames::{BLOCK, Topology, frame_from_edge, normalize};
#[cfg(test)]
use crate::frames::{cross, sub};
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
#[serde(default, deny_unknown_fields)]
pub struct RuntimeSettings {
    /// Largest L2 error allowed in a row of the translation-free basis:
    /// `max_v ‖(B P)_v − (U_b C_b)_v‖₂ ≤ basis_tolerance`, so the large-scale position error of
    /// every vertex is at most `basis_tolerance · ‖u_H − ū‖₂` (Cauchy–Schwarz). `0` keeps full
    /// rank (exact up to f32 rounding).
    pub basis_tolerance: f64,
    /// Store the run-time data in a locality order ([`morton_order`] of the rest positions)
    /// instead of the mesh's vertex order: one-ring gathers then hit nearby memory and every
    /// low-rank block is a compact surface patch (lower rank). Outputs stay in mesh order, so
    /// the last pass gathers through the permutation. Off by default: on the 592k-vertex face
    /// the passes got faster (large scale 18 → 12.5 ms, detail 110 → 98 ms, normals 29.5 → 19
    /// ms CPU) but the un-permuting normal pass ate the gain (frame 160.5 vs 170 ms; docs/psd.md).
    pub reorder: bool,
}

impl Default for RuntimeSettings {
    fn default() -> Self {
        Self {
            basis_tolerance: 1e-5,
            reorder: false,
        }
    }
}

/// Vertex order along a Morton (Z-order) curve of the positions (10 bits per axis over the
/// bounding box; ties by index): `order[k]` is the vertex stored `k`-th. Space-filling-curve
/// orders keep surface neighbours close in memory.
pub fn morton_order(positions: &[[f32; 3]]) -> Vec<u32> {
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for p in positions {
        for a in 0..3 {
            if p[a].is_finite() {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
    }
    let spread = |x: u32| -> u32 {
        // insert two zero bits between the 10 low bits of x
        let mut x = x & 0x3ff;
        x = (x | (x << 16)) & 0x0300_00ff;
        x = (x | (x << 8)) & 0x0300_f00f;
        x = (x | (x << 4)) & 0x030c_30c3;
        (x | (x << 2)) & 0x0924_9249
    };
    let codes: Vec<u32> = positions
        .iter()
        .map(|p| {
            let mut code = 0;
            for a in 0..3 {
                let extent = hi[a] - lo[a];
                let t = if extent > 0.0 && p[a].is_finite() {
                    ((p[a] - lo[a]) / extent * 1023.0).clamp(0.0, 1023.0) as u32
                } else {
                    0
                };
                code |= spread(t) << a;
            }
            code
        })
        .collect();
    let mut order: Vec<u32> = (0..positions.len() as u32).collect();
    order.sort_unstable_by_key(|&v| (codes[v as usize], v));
    order
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
    /// Start of each block's `C_b` (`k_b × H`, row-major, rows padded with zeros to
    /// [`LowRankBasis::padded_handles`]) in `coeffs`; length blocks + 1.
    pub coeff_offsets: Vec<usize>,
    /// Start of each block's `U_b` (stored rank-major, `k_b × m_b`: column `q` of `U_b` is
    /// contiguous) in `factors`; length blocks + 1.
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
        Self::with_order(basis, tolerance, None)
    }

    /// [`LowRankBasis::new`] over the rows of `basis` taken in `order` (`order[k]` = the
    /// vertex stored `k`-th; `None` = mesh order).
    pub fn with_order(basis: &ShellBasis, tolerance: f64, order: Option<&[u32]>) -> Self {
        let (n, h) = (basis.n, basis.h);
        let row_of = |k: usize| order.map_or(k, |o| o[k] as usize);
        let blocks = n.div_ceil(LOW_RANK_BLOCK);
        let parts: Vec<(u32, Vec<f32>, Vec<f32>)> = (0..blocks)
            .into_par_iter()
            .map(|b| {
                let rows = b * LOW_RANK_BLOCK..((b + 1) * LOW_RANK_BLOCK).min(n);
                let m = rows.len();
                // translation-free part B_b P: subtract each row's mean
                let block = DMatrix::<f64>::from_fn(m, h, |i, j| {
                    let row = basis.row(row_of(rows.start + i));
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
                // rows padded with zeros to whole SIMD lanes (`padded_handles`)
                let hp = h.div_ceil(BATCH) * BATCH;
                let coeffs: Vec<f32> = (0..k)
                    .flat_map(|j| (0..hp).map(move |i| (i, j)))
                    .map(|(i, j)| if i < h { vk[(i, j)] as f32 } else { 0.0 })
                    .collect();
                // rank-major (k × m): the run-time loop runs over vertices in SIMD lanes
                let factors: Vec<f32> = (0..k)
                    .flat_map(|j| (0..m).map(move |i| (i, j)))
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

    /// Length of a stored row of `C_b`: H rounded up to whole SIMD lanes ([`BATCH`]).
    pub fn padded_handles(&self) -> usize {
        self.h.div_ceil(BATCH) * BATCH
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

    /// The same fans stored in the locality order `order` (`order[k]` = old vertex stored
    /// `k`-th, `rank` its inverse): rows moved, neighbour ids renumbered.
    pub fn permuted(&self, order: &[u32], rank: &[u32]) -> Self {
        let mut offsets = Vec::with_capacity(order.len() + 1);
        offsets.push(0u32);
        let mut neighbours = Vec::with_capacity(self.neighbours.len());
        for &v in order {
            let v = v as usize;
            neighbours.extend(
                self.neighbours[self.offsets[v] as usize..self.offsets[v + 1] as usize]
                    .iter()
                    .map(|&w| rank[w as usize]),
            );
            offsets.push(neighbours.len() as u32);
        }
        Self {
            offsets,
            neighbours,
            kinds: order.iter().map(|&v| self.kinds[v as usize]).collect(),
            reference: order
                .iter()
                .map(|&v| rank[self.reference[v as usize] as usize])
                .collect(),
        }
    }

    /// Unit normal of vertex `v` of `positions`: normalised area-weighted sum of the incident
    /// face normals (`[0, 0, 1]` if degenerate).
    #[inline]
    pub fn normal(&self, positions: &[[f32; 3]], v: usize) -> [f32; 3] {
        normal_vertex(self, v, positions, 0)
    }

    /// Neighbours of vertex `v` (see [`FanKind`]).
    #[inline(always)]
    pub fn ring(&self, v: usize) -> &[u32] {
        &self.neighbours[self.offsets[v] as usize..self.offsets[v + 1] as usize]
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

/// Edge ids of the WPSD rows ([`BatchDetails::edges`]): one byte per id when F ≤ 256 (the
/// thesis' F = 243), two otherwise.
#[derive(Clone, Debug, PartialEq)]
pub enum EdgeIds {
    /// F ≤ 256.
    U8(Vec<u8>),
    /// F > 256.
    U16(Vec<u16>),
}

impl EdgeIds {
    /// Bytes stored.
    pub fn bytes(&self) -> usize {
        match self {
            Self::U8(v) => v.len(),
            Self::U16(v) => 2 * v.len(),
        }
    }
}

/// An id type of [`EdgeIds`].
trait EdgeId: Copy + Send + Sync {
    fn index(self) -> usize;
}
impl EdgeId for u8 {
    #[inline(always)]
    fn index(self) -> usize {
        self as usize
    }
}
impl EdgeId for u16 {
    #[inline(always)]
    fn index(self) -> usize {
        self as usize
    }
}

/// Vertices per batch of the across-vertex SIMD kernels (one vertex per lane).
pub const BATCH: usize = 8;

/// One value per vertex of a batch (structure of arrays).
pub type Lane = [f32; BATCH];

/// The WPSD inputs of the detail kernel (eq. 5.3–5.5) in batches of [`BATCH`] consecutive stored
/// vertices, one vertex per SIMD lane: per batch the *union* of its vertices' edges, with one
/// `α` lane per vertex (0 where the vertex does not use the edge), so
/// `r_j² = Σ_i α_{v,i} g[i][j]` is one 8-vertex multiply-add per union edge and pose; and the RBF
/// weights pose- and axis-major (`w[j][axis]` as a [`Lane`]), so `d = Σ_j w_j r_j` is one
/// 8-vertex multiply-add per pose and axis. In a locality order (Morton) the 8 vertices of a
/// batch are surface neighbours that mostly see the same edges, so the union is only a little
/// longer than one vertex's list (the mean is reported by [`BatchDetails::mean_union`]).
#[derive(Clone, Debug, PartialEq)]
pub struct BatchDetails {
    /// Start of each batch's edges in `edges` (batches + 1).
    pub offsets: Vec<u32>,
    /// Union of the WPSD edges of each batch's vertices, ascending ids.
    pub edges: EdgeIds,
    /// Per batch edge, `α_{v,i}` of the batch's vertices in steps of [`ALPHA_STEP`].
    pub alphas: Vec<[u16; BATCH]>,
    /// Per batch, `3P` lanes of RBF weights (`weights[b·3P + 3j + axis][lane]`; lanes past the
    /// last vertex are 0). Kept in f32: the linear-kernel interpolation weights cancel strongly
    /// (`Σ_j w_j r_j` ≪ `Σ_j |w_j| r_j`), and `i16` with one step per vertex measured 0.23 mm
    /// max / 0.0017 mm RMS on the ICT face.
    pub weights: Vec<Lane>,
}

impl BatchDetails {
    /// Batch the per-vertex rows: `edges`, `alphas` (`n × width`, `α` in steps of
    /// [`ALPHA_STEP`]) and `weights` (`n × 3P`, pose-major per vertex: `w[3j + axis]`).
    /// `width = 0` (PSD) stores no edges.
    pub fn new(
        poses: usize,
        width: usize,
        edges: &[u16],
        alphas: &[u16],
        weights: &[f32],
        num_features: usize,
    ) -> Self {
        let p3 = 3 * poses;
        let n = weights.len() / p3.max(1);
        assert!(edges.len() == n * width && alphas.len() == n * width);
        let batches = n.div_ceil(BATCH);
        let mut offsets = Vec::with_capacity(batches + 1);
        offsets.push(0u32);
        let mut ids: Vec<u16> = Vec::new();
        let mut lanes: Vec<[u16; BATCH]> = Vec::new();
        let mut out_weights = vec![[0.0f32; BATCH]; batches * p3];
        let mut union: Vec<u16> = Vec::new();
        for b in 0..batches {
            let vs = b * BATCH..((b + 1) * BATCH).min(n);
            union.clear();
            for v in vs.clone() {
                for k in v * width..(v + 1) * width {
                    if alphas[k] > 0 {
                        union.push(edges[k]);
                    }
                }
            }
            union.sort_unstable();
            union.dedup();
            let first = lanes.len();
            ids.extend_from_slice(&union);
            lanes.resize(first + union.len(), [0; BATCH]);
            for (l, v) in vs.clone().enumerate() {
                for k in v * width..(v + 1) * width {
                    if alphas[k] > 0 {
                        let at = union.binary_search(&edges[k]).unwrap_or(0);
                        let a = &mut lanes[first + at][l];
                        *a = a.saturating_add(alphas[k]);
                    }
                }
                for (c, &w) in weights[v * p3..(v + 1) * p3].iter().enumerate() {
                    out_weights[b * p3 + c][l] = w;
                }
            }
            offsets.push(ids.len() as u32);
        }
        let edges = if num_features <= 256 {
            EdgeIds::U8(ids.iter().map(|&i| i as u8).collect())
        } else {
            EdgeIds::U16(ids)
        };
        Self {
            offsets,
            edges,
            alphas: lanes,
            weights: out_weights,
        }
    }

    /// Mean number of union edges per batch.
    pub fn mean_union(&self) -> f64 {
        self.alphas.len() as f64 / (self.offsets.len() - 1).max(1) as f64
    }

    /// Bytes stored.
    pub fn bytes(&self) -> usize {
        4 * self.offsets.len()
            + self.edges.bytes()
            + 2 * BATCH * self.alphas.len()
            + 4 * BATCH * self.weights.len()
    }
}

/// Fixed-point step of the stored WPSD edge weights: `α_{v,i} = q_{v,i} · ALPHA_STEP`, `q` a
/// `u16` (absolute error ≤ 7.7e-6 on weights that sum to 1).
pub const ALPHA_STEP: f32 = 1.0 / 65535.0;

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
    /// WPSD edges per vertex of the model (0 for PSD).
    pub width: usize,
    /// Edge weights and RBF weights in batches of [`BATCH`] stored vertices.
    pub details: BatchDetails,
    /// Locality order (`order[k]` = mesh vertex stored `k`-th) when
    /// [`RuntimeSettings::reorder`] is on; every per-vertex array above is in this order.
    pub order: Option<Vec<u32>>,
    /// Inverse of `order` (`rank[v]` = storage index of mesh vertex `v`).
    pub rank: Option<Vec<u32>>,
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
        let p3 = 3 * model.num_poses();
        let fans = Fans::new(&rig.topology);
        let (order, rank) = if settings.reorder {
            let order = morton_order(&rig.rest_f32);
            let mut rank = vec![0u32; n];
            for (k, &v) in order.iter().enumerate() {
                rank[v as usize] = k as u32;
            }
            (Some(order), Some(rank))
        } else {
            (None, None)
        };
        fn rows<T: Copy>(src: &[T], width: usize, order: Option<&[u32]>) -> Vec<T> {
            match order {
                Some(order) => order
                    .iter()
                    .flat_map(|&v| &src[v as usize * width..(v as usize + 1) * width])
                    .copied()
                    .collect(),
                None => src.to_vec(),
            }
        }
        let o = order.as_deref();
        let fans = match (o, rank.as_deref()) {
            (Some(o), Some(r)) => fans.permuted(o, r),
            _ => fans,
        };
        let alphas: Vec<u16> = rows(&alphas, width, o)
            .iter()
            .map(|&a| (a.clamp(0.0, 1.0) / ALPHA_STEP).round() as u16)
            .collect();
        let details = BatchDetails::new(
            model.num_poses(),
            width,
            &rows(&edges, width, o),
            &alphas,
            &rows(&model.weights, p3, o),
            model.num_features,
        );
        Ok(Self {
            rest: rows(&rig.rest_f32, 1, o),
            basis: LowRankBasis::with_order(&rig.basis, settings.basis_tolerance, o),
            fans,
            poses: model.num_poses(),
            width,
            details,
            order,
            rank,
        })
    }

    /// Number of vertices.
    pub fn num_vertices(&self) -> usize {
        self.rest.len()
    }

    /// Bytes read from and written to memory per frame by the three passes ([`frame_pass`]):
    /// every per-vertex array of a pass once (one-ring gathers hit cache), the fans twice
    /// (detail and normal pass), the large-scale and final positions written and read back
    /// once, the normals written (the un-permute of [`RuntimeSettings::reorder`] adds
    /// 4 + 2·24 bytes per vertex).
    pub fn bytes_per_frame(&self) -> usize {
        let n = self.num_vertices();
        let fans = self.fans.neighbours.len() * 4 + n * (4 + 1); // ids, offsets, kind
        let detail = self.details.bytes() + n * 4; // + reference neighbours
        let unpermute = if self.rank.is_some() { n * 52 } else { 0 };
        self.basis.bytes() + n * 12 /* rest */ + 2 * fans + detail + n * 60 /* large, positions: write + read; normals */ + unpermute
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

/// Handle mean `ū` and centred displacements `ũ = u_H − ū` of pass 1, stored by axis
/// (`[ũ_x | ũ_y | ũ_z]`, each padded with zeros to [`LowRankBasis::padded_handles`] entries).
pub fn centre_handles(uh: &[[f32; 3]], centred: &mut Vec<f32>) -> [f32; 3] {
    let mut mean = [0.0f64; 3];
    for u in uh {
        for a in 0..3 {
            mean[a] += u[a] as f64;
        }
    }
    let mean = mean.map(|m| (m / uh.len().max(1) as f64) as f32);
    let hp = uh.len().div_ceil(BATCH) * BATCH;
    centred.clear();
    centred.resize(3 * hp, 0.0);
    for (h, u) in uh.iter().enumerate() {
        for a in 0..3 {
            centred[a * hp + h] = u[a] - mean[a];
        }
    }
    mean
}

/// Run `$body` with `$inputs: &DetailInputs<NC, E>` for the layout's lane count
/// `NC ≥ ⌈P / 8⌉` and edge id type (monomorphized per case).
macro_rules! with_inputs {
    ($layout:expr, $table:expr, $global_r:expr, |$inputs:ident| $body:expr) => {{
        let layout: &RuntimeLayout = $layout;
        let (table, global_r): (&[[f32; LANES]], Option<&[f32]>) = ($table, $global_r);
        match (&layout.details.edges, layout.poses.div_ceil(LANES)) {
            (EdgeIds::U8(e), 1) => {
                let $inputs = &DetailInputs::<1, u8>::new(layout, e, table, global_r);
                $body
            }
            (EdgeIds::U8(e), 2) => {
                let $inputs = &DetailInputs::<2, u8>::new(layout, e, table, global_r);
                $body
            }
            (EdgeIds::U8(e), 3 | 4) => {
                let $inputs = &DetailInputs::<4, u8>::new(layout, e, table, global_r);
                $body
            }
            (EdgeIds::U8(e), _) => {
                let $inputs =
                    &DetailInputs::<{ MAX_POSES / LANES }, u8>::new(layout, e, table, global_r);
                $body
            }
            (EdgeIds::U16(e), 1) => {
                let $inputs = &DetailInputs::<1, u16>::new(layout, e, table, global_r);
                $body
            }
            (EdgeIds::U16(e), 2) => {
                let $inputs = &DetailInputs::<2, u16>::new(layout, e, table, global_r);
                $body
            }
            (EdgeIds::U16(e), 3 | 4) => {
                let $inputs = &DetailInputs::<4, u16>::new(layout, e, table, global_r);
                $body
            }
            (EdgeIds::U16(e), _) => {
                let $inputs =
                    &DetailInputs::<{ MAX_POSES / LANES }, u16>::new(layout, e, table, global_r);
                $body
            }
        }
    }};
}

/// What the detail kernel reads besides positions (one frame).
struct DetailInputs<'a, const NC: usize, E> {
    layout: &'a RuntimeLayout,
    edges: &'a [E],
    table: &'a [[f32; LANES]],
    /// PSD: the global distances `r_j` (same for every vertex).
    global: Option<[[f32; LANES]; NC]>,
}

impl<'a, const NC: usize, E: EdgeId> DetailInputs<'a, NC, E> {
    fn new(
        layout: &'a RuntimeLayout,
        edges: &'a [E],
        table: &'a [[f32; LANES]],
        global_r: Option<&[f32]>,
    ) -> Self {
        let p = layout.poses;
        assert!(
            p <= NC * LANES && p <= MAX_POSES,
            "at most {MAX_POSES} basis poses"
        );
        assert!(
            global_r.is_some() || layout.width == 0 || table.len() >= p.div_ceil(LANES),
            "a feature table per frame"
        );
        let global = global_r.map(|g| {
            let mut r = [[0.0f32; LANES]; NC];
            for (j, &x) in g.iter().enumerate().take(p) {
                r[j / LANES][j % LANES] = x;
            }
            r
        });
        Self {
            layout,
            edges,
            table,
            global,
        }
    }

    /// Pass 2 of the batch `b` of stored vertices `BATCH·b ..` (thesis §5.5.2 fine-scale kernel,
    /// eq. 5.3–5.5), one vertex per SIMD lane ([`Lanes`]): large-scale normal and local frame
    /// `[t, b, n]` from the one-ring of `large` (storage index `u` at `large[u − base]`), WPSD
    /// distances `r_j = sqrt(Σ_i α_{v,i} g[i][j])` over the batch's union edges
    /// ([`BatchDetails`]; the global `r` for PSD), detail `d = Σ_j w_{v,j} r_j` and
    /// `x = x_large + d_0 t + d_1 b + d_2 n`. Returns the batch's vertex count and positions
    /// (lanes past the last vertex of the mesh repeat it and are not returned).
    #[inline(always)]
    fn batch<S: pulp::Simd>(
        &self,
        simd: S,
        b: usize,
        large: &[[f32; 3]],
        base: usize,
    ) -> (usize, [[f32; 3]; BATCH]) {
        let o = Lanes(simd);
        let layout = self.layout;
        let fans = &layout.fans;
        let details = &layout.details;
        let first = b * BATCH;
        let count = (layout.num_vertices() - first).min(BATCH);
        let mut vs = [0usize; BATCH];
        let mut at = [0usize; BATCH];
        for l in 0..BATCH {
            vs[l] = first + l.min(count - 1);
            at[l] = vs[l] - base;
        }
        let xl = gather(large, &at);
        let n = o.normalize(&fan_sums(fans, &vs, large, base, &xl), [0.0, 0.0, 1.0]);
        for l in 0..BATCH {
            at[l] = fans.reference[vs[l]] as usize - base;
        }
        let e = o.sub3(&gather(large, &at), &xl);
        let [t, bt] = o.tangents(&e, &n, count);
        // r[c][k]: distance to pose c·LANES + k of every vertex of the batch
        let p = layout.poses;
        let nc = p.div_ceil(LANES);
        let mut r = [[[0.0f32; BATCH]; LANES]; NC];
        match self.global {
            Some(g) => {
                for c in 0..NC {
                    for k in 0..LANES {
                        r[c][k] = [g[c][k]; BATCH];
                    }
                }
            }
            None => {
                let edges = details.offsets[b] as usize..details.offsets[b + 1] as usize;
                for (&i, al) in self.edges[edges.clone()].iter().zip(&details.alphas[edges]) {
                    let mut a = [0.0f32; BATCH];
                    for l in 0..BATCH {
                        a[l] = al[l] as f32;
                    }
                    for c in 0..nc.min(NC) {
                        let g = &self.table[i.index() * nc + c];
                        for k in 0..LANES {
                            if c * LANES + k < p {
                                r[c][k] = o.add(&r[c][k], &o.mul(&a, &[g[k]; BATCH]));
                            }
                        }
                    }
                }
                let step = [ALPHA_STEP; BATCH];
                for j in 0..p {
                    let rj = &mut r[j / LANES][j % LANES];
                    *rj = o.sqrt(&o.mul(rj, &step));
                }
            }
        }
        let w = &details.weights[b * 3 * p..(b + 1) * 3 * p];
        let mut d = [[0.0f32; BATCH]; 3];
        for j in 0..p {
            let rj = &r[j / LANES][j % LANES];
            for a in 0..3 {
                d[a] = o.add(&d[a], &o.mul(&w[3 * j + a], rj));
            }
        }
        // x = x_l + d_0 t + d_1 b + d_2 n, summed left to right
        let mut x = [[0.0f32; BATCH]; 3];
        for a in 0..3 {
            let s = o.add(&xl[a], &o.mul(&d[0], &t[a]));
            let s = o.add(&s, &o.mul(&d[1], &bt[a]));
            x[a] = o.add(&s, &o.mul(&d[2], &n[a]));
        }
        (count, transpose(&x))
    }
}

/// Element-wise arithmetic on [`BATCH`] lanes (one vertex per lane) in the dispatched SIMD type
/// `S` (one AVX2 instruction per operation; the scalar tail of `S::as_simd_f32s` covers SIMD
/// types of other widths). Plain IEEE operations, no `mul_add`: each lane gets exactly the bits
/// of the scalar expression written in the comment of each method.
#[derive(Clone, Copy)]
struct Lanes<S>(S);

/// `Lanes::$name(a, b)`: `a $op b` per lane.
macro_rules! lanes_binop {
    ($name:ident, $simd:ident, $op:tt) => {
        #[doc = concat!("`a ", stringify!($op), " b` per lane")]
        #[inline(always)]
        fn $name(self, a: &Lane, b: &Lane) -> Lane {
            let mut out = [0.0f32; BATCH];
            let (o_v, o_t) = S::as_mut_simd_f32s(&mut out);
            let (a_v, a_t) = S::as_simd_f32s(a);
            let (b_v, b_t) = S::as_simd_f32s(b);
            for ((o, &x), &y) in o_v.iter_mut().zip(a_v).zip(b_v) {
                *o = self.0.$simd(x, y);
            }
            for ((o, &x), &y) in o_t.iter_mut().zip(a_t).zip(b_t) {
                *o = x $op y;
            }
            out
        }
    };
}

// No closures in here: a closure is compiled as its own function, outside the
// target-feature context of `pulp::Arch::dispatch`, and its SIMD intrinsics become calls.
impl<S: pulp::Simd> Lanes<S> {
    lanes_binop!(add, add_f32s, +);
    lanes_binop!(sub, sub_f32s, -);
    lanes_binop!(mul, mul_f32s, *);
    lanes_binop!(div, div_f32s, /);

    /// `sqrt(a)` per lane (correctly rounded)
    #[inline(always)]
    fn sqrt(self, a: &Lane) -> Lane {
        let mut l = *a;
        let (l_v, l_t) = S::as_mut_simd_f32s(&mut l);
        for x in l_v {
            *x = self.0.sqrt_f32s(*x);
        }
        for x in l_t {
            *x = x.sqrt();
        }
        l
    }

    /// `(sqrt(a), 1 / sqrt(a))` as `l = a.sqrt(); 1.0 / l` (two correctly rounded operations)
    #[inline(always)]
    fn inv_sqrt(self, a: &Lane) -> (Lane, Lane) {
        let l = self.sqrt(a);
        let inv = self.div(&[1.0f32; BATCH], &l);
        (l, inv)
    }

    /// `if test > threshold { a } else { b }` per lane (false for NaN, as the scalar `>`)
    #[inline(always)]
    fn select_gt(self, test: &Lane, threshold: f32, a: &Lane, b: &Lane) -> Lane {
        let mut out = [0.0f32; BATCH];
        let th = self.0.splat_f32s(threshold);
        let (o_v, o_t) = S::as_mut_simd_f32s(&mut out);
        let (t_v, t_t) = S::as_simd_f32s(test);
        let (a_v, a_t) = S::as_simd_f32s(a);
        let (b_v, b_t) = S::as_simd_f32s(b);
        for (((o, &t), &x), &y) in o_v.iter_mut().zip(t_v).zip(a_v).zip(b_v) {
            // `select_u32s`, not the trait's `select_f32s` (only `#[inline]`: compiled outside
            // the dispatch, its blend became a call)
            let keep = self.0.greater_than_f32s(t, th);
            *o = pulp::cast(self.0.select_u32s(keep, pulp::cast(x), pulp::cast(y)));
        }
        for (((o, &t), &x), &y) in o_t.iter_mut().zip(t_t).zip(a_t).zip(b_t) {
            *o = if t > threshold { x } else { y };
        }
        out
    }

    /// `a − b` per coordinate
    #[inline(always)]
    fn sub3(self, a: &[Lane; 3], b: &[Lane; 3]) -> [Lane; 3] {
        [
            self.sub(&a[0], &b[0]),
            self.sub(&a[1], &b[1]),
            self.sub(&a[2], &b[2]),
        ]
    }

    /// `a · b` as [`dot`]: `(a_0 b_0 + a_1 b_1) + a_2 b_2`
    #[inline(always)]
    fn dot(self, a: &[Lane; 3], b: &[Lane; 3]) -> Lane {
        let s = self.add(&self.mul(&a[0], &b[0]), &self.mul(&a[1], &b[1]));
        self.add(&s, &self.mul(&a[2], &b[2]))
    }

    /// `a × b` as [`cross`](crate::frames::cross)
    #[inline(always)]
    fn cross(self, a: &[Lane; 3], b: &[Lane; 3]) -> [Lane; 3] {
        [
            self.sub(&self.mul(&a[1], &b[2]), &self.mul(&a[2], &b[1])),
            self.sub(&self.mul(&a[2], &b[0]), &self.mul(&a[0], &b[2])),
            self.sub(&self.mul(&a[0], &b[1]), &self.mul(&a[1], &b[0])),
        ]
    }

    /// [`normalize`] per lane: `a · (1 / ‖a‖)` if `‖a‖ > 1e-20`, else `fallback`.
    #[inline(always)]
    fn normalize(self, a: &[Lane; 3], fallback: [f32; 3]) -> [Lane; 3] {
        let (l, inv) = self.inv_sqrt(&self.dot(a, a));
        let mut out = [[0.0f32; BATCH]; 3];
        for k in 0..3 {
            out[k] = self.select_gt(&l, 1e-20, &self.mul(&a[k], &inv), &[fallback[k]; BATCH]);
        }
        out
    }

    /// Tangent and bitangent of [`frame_from_edge`] per lane: `t = normalize(e − (e·n) n)`,
    /// `b = n × t`; the (rare) lanes `< count` whose projected edge vanishes take the scalar
    /// axis fallback of [`frame_from_edge`].
    #[inline(always)]
    fn tangents(self, e: &[Lane; 3], n: &[Lane; 3], count: usize) -> [[Lane; 3]; 2] {
        let d = self.dot(e, n);
        let mut tp = [[0.0f32; BATCH]; 3];
        for k in 0..3 {
            tp[k] = self.sub(&e[k], &self.mul(&d, &n[k]));
        }
        // normalize(tp, [0, 0, 0]), keeping the length to find the degenerate lanes (t = 0
        // exactly when ‖tp‖ ≤ 1e-20 or NaN: otherwise some |tp_k / ‖tp‖| ≥ 1/√3)
        let (len, inv) = self.inv_sqrt(&self.dot(&tp, &tp));
        let mut t = [[0.0f32; BATCH]; 3];
        for k in 0..3 {
            t[k] = self.select_gt(&len, 1e-20, &self.mul(&tp[k], &inv), &[0.0; BATCH]);
        }
        let mut degenerate = false;
        for l in 0..BATCH {
            let regular = len[l] > 1e-20;
            degenerate |= !regular;
        }
        if degenerate {
            for l in 0..count {
                let regular = len[l] > 1e-20;
                if !regular {
                    let [tl, _, _] =
                        frame_from_edge([e[0][l], e[1][l], e[2][l]], [n[0][l], n[1][l], n[2][l]]);
                    for k in 0..3 {
                        t[k][l] = tl[k];
                    }
                }
            }
        }
        let b = self.cross(n, &t);
        [t, b]
    }
}

/// Positions `positions[at[l]]` of the lanes of a batch, structure of arrays.
#[inline(always)]
fn gather(positions: &[[f32; 3]], at: &[usize; BATCH]) -> [Lane; 3] {
    let mut q = [[0.0f32; 4]; BATCH];
    for l in 0..BATCH {
        q[l] = quad(positions[at[l]]);
    }
    lanes_of_quads(&q)
}

/// Structure of arrays back to one `[x, y, z]` per lane.
#[inline(always)]
fn transpose(x: &[Lane; 3]) -> [[f32; 3]; BATCH] {
    let mut out = [[0.0f32; 3]; BATCH];
    for l in 0..BATCH {
        out[l] = [x[0][l], x[1][l], x[2][l]];
    }
    out
}

/// [`fan_quad`] of each vertex of the batch `vs` (centres `p`), into one lane per
/// vertex. The fans are summed one vertex at a time: their points are stored vertex-major
/// (`[x, y, z]`), and moving every fan point into lanes costs as many instructions as the
/// cross products it would share (measured: the across-vertex fan walk was no faster); what
/// the lanes pay off for is the square-root / division chain that follows.
#[inline(always)]
fn fan_sums(
    fans: &Fans,
    vs: &[usize; BATCH],
    positions: &[[f32; 3]],
    base: usize,
    p: &[Lane; 3],
) -> [Lane; 3] {
    // whole [x, y, z, 0] sums per vertex, then lanes by constant indices: scattering scalars
    // into the lane arrays and reading them back as vectors stalls on store forwarding
    let mut q = [[0.0f32; 4]; BATCH];
    for l in 0..BATCH {
        let v = vs[l];
        q[l] = fan_quad(
            positions,
            base,
            fans.ring(v),
            fans.kinds[v],
            [p[0][l], p[1][l], p[2][l]],
        );
    }
    lanes_of_quads(&q)
}

/// `[x, y, z]` lanes of 8 quads `[x, y, z, _]` (constant indices).
#[inline(always)]
fn lanes_of_quads(q: &[[f32; 4]; BATCH]) -> [Lane; 3] {
    macro_rules! lane {
        ($a:expr) => {
            [
                q[0][$a], q[1][$a], q[2][$a], q[3][$a], q[4][$a], q[5][$a], q[6][$a], q[7][$a],
            ]
        };
    }
    [lane!(0), lane!(1), lane!(2)]
}

/// Unit normals of the stored vertices `vs` from the one-ring of `positions` (index `u − base`),
/// one vertex per lane ([`normal_vertex`] per lane, bit for bit).
#[inline(always)]
fn normal_batch<S: pulp::Simd>(
    simd: S,
    fans: &Fans,
    vs: &[usize; BATCH],
    positions: &[[f32; 3]],
    base: usize,
) -> [[f32; 3]; BATCH] {
    let o = Lanes(simd);
    let mut at = [0usize; BATCH];
    for l in 0..BATCH {
        at[l] = vs[l] - base;
    }
    let p = gather(positions, &at);
    let n = o.normalize(&fan_sums(fans, vs, positions, base, &p), [0.0, 0.0, 1.0]);
    transpose(&n)
}

/// `ids` in batches of [`BATCH`]: `(batch, count)`, the last batch padded by repeating its
/// last id (`count` = the valid lanes). An iterator, not a callback: the caller's loop body
/// stays inside the SIMD dispatch (see [`Lanes`]).
struct Batches<I>(I);

impl<I: Iterator<Item = usize>> Iterator for Batches<I> {
    type Item = ([usize; BATCH], usize);
    #[inline(always)]
    fn next(&mut self) -> Option<Self::Item> {
        let mut batch = [0usize; BATCH];
        let mut k = 0;
        while k < BATCH {
            match self.0.next() {
                Some(v) => {
                    batch[k] = v;
                    k += 1;
                }
                None => break,
            }
        }
        if k == 0 {
            return None;
        }
        let last = batch[k - 1];
        batch[k..].fill(last);
        Some((batch, k))
    }
}

/// Unnormalised normal of a one-ring fan around `p`: `Σ_i e_i × e_{i+1}` with
/// `e_i = p_i − p` — the area-weighted sum of the incident face normals (times 2). Along a
/// chain (closed or open fan) two consecutive terms share their middle point,
/// `e_{i−1} × e_i + e_i × e_{i+1} = e_i × (p_{i+1} − p_{i−1})` (`p` cancels in the difference),
/// so the sum takes one cross product per two faces (a chain of odd length ends with one plain
/// term). Storage index `u` at `positions[u − base]`. Returned as `[x, y, z, 0]` (the lanes
/// are built from whole quads).
#[inline(always)]
fn fan_quad(
    positions: &[[f32; 3]],
    base: usize,
    ids: &[u32],
    kind: FanKind,
    p: [f32; 3],
) -> [f32; 4] {
    // (a wrapped index fails the bounds check like an overflowing one)
    let point = |i: u32| quad(positions[(i as usize).wrapping_sub(base)]);
    let p = quad(p);
    let mut s = [0.0f32; 4];
    match kind {
        FanKind::Pairs => {
            for ab in ids.chunks_exact(2) {
                s = add4(s, cross4(sub4(point(ab[0]), p), sub4(point(ab[1]), p)));
            }
        }
        kind => {
            // chain q_0, q_1, … (a closed fan returns to q_0): pairs (q_k, q_{k+1}) for odd k
            let Some((&first, rest)) = ids.split_first() else {
                return s;
            };
            let q0 = point(first);
            let mut before = q0;
            let mut pairs = rest.chunks_exact(2);
            for pair in &mut pairs {
                let next = point(pair[1]);
                s = add4(s, cross4(sub4(point(pair[0]), p), sub4(next, before)));
                before = next;
            }
            let last = match (pairs.remainder(), kind == FanKind::Closed) {
                // closed, odd neighbour count left: q_{m−1} pairs with the closing q_0
                ([last], true) => cross4(sub4(point(*last), p), sub4(q0, before)),
                // open: one plain last term
                ([last], false) => cross4(sub4(before, p), sub4(point(*last), p)),
                // closed, even: the closing term alone
                ([], true) => cross4(sub4(before, p), sub4(q0, p)),
                _ => [0.0; 4],
            };
            s = add4(s, last);
        }
    }
    s
}

/// `[x, y, z, 0]`: a point in the 4 lanes of one SSE register, so the fan walk's
/// differences, cross products and sums are one 4-wide operation each ([`cross4`]) — per
/// coordinate the same IEEE operations as [`sub`](crate::frames::sub) / [`cross`](crate::frames::cross) on `[x, y, z]` (same bits).
#[inline(always)]
fn quad(a: [f32; 3]) -> [f32; 4] {
    [a[0], a[1], a[2], 0.0]
}

/// `a − b` per lane.
#[inline(always)]
fn sub4(a: [f32; 4], b: [f32; 4]) -> [f32; 4] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2], a[3] - b[3]]
}

/// `a + b` per lane.
#[inline(always)]
fn add4(a: [f32; 4], b: [f32; 4]) -> [f32; 4] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2], a[3] + b[3]]
}

/// [`cross`](crate::frames::cross) of the first three lanes as `a.yzx · b.zxy − a.zxy · b.yzx` (lane 3: `a_3 b_3 −
/// a_3 b_3`, 0 for the zero-padded [`quad`]s): two lane permutations per operand, two
/// multiplies, one subtraction.
#[inline(always)]
fn cross4(a: [f32; 4], b: [f32; 4]) -> [f32; 4] {
    let (a1, b2) = ([a[1], a[2], a[0], a[3]], [b[2], b[0], b[1], b[3]]);
    let (a2, b1) = ([a[2], a[0], a[1], a[3]], [b[1], b[2], b[0], b[3]]);
    [
        a1[0] * b2[0] - a2[0] * b1[0],
        a1[1] * b2[1] - a2[1] * b1[1],
        a1[2] * b2[2] - a2[2] * b1[2],
        a1[3] * b2[3] - a2[3] * b1[3],
    ]
}

/// Unit normal of stored vertex `v` from the one-ring of `positions` (index `u − base`).
#[inline(always)]
fn normal_vertex(fans: &Fans, v: usize, positions: &[[f32; 3]], base: usize) -> [f32; 3] {
    let s = fan_quad(
        positions,
        base,
        fans.ring(v),
        fans.kinds[v],
        positions[v - base],
    );
    normalize([s[0], s[1], s[2]], [0.0, 0.0, 1.0])
}

/// Pass 1 of one low-rank block (thesis §5.3 large-scale kernel):
/// `x_v = x0_v + ū + Σ_k U_b[v,k] (C_b ũ)_k`; `U_b` is rank-major, so the inner loop runs over
/// the block's vertices in SIMD lanes (three multiply-adds per 8 vertices and rank).
#[inline(always)]
fn large_block<S: pulp::Simd>(
    o: Lanes<S>,
    layout: &RuntimeLayout,
    blk: usize,
    centred: &[f32],
    mean: [f32; 3],
    out: &mut [[f32; 3]],
) {
    let b = &layout.basis;
    let m = out.len();
    assert!(m > 0 && m <= LOW_RANK_BLOCK);
    let first = blk * LOW_RANK_BLOCK;
    let rest = &layout.rest[first..first + m];
    let coeffs = &b.coeffs[b.coeff_offsets[blk]..b.coeff_offsets[blk + 1]];
    let factors = &b.factors[b.factor_offsets[blk]..b.factor_offsets[blk + 1]];
    let mut acc = [[0.0f32; LOW_RANK_BLOCK]; 3];
    let [ax, ay, az] = &mut acc;
    let (ax, ay, az) = (&mut ax[..m], &mut ay[..m], &mut az[..m]);
    let hp = b.padded_handles();
    let (ux, rest_u) = centred.split_at(hp);
    let (uy, uz) = rest_u.split_at(hp);
    for (row, col) in coeffs.chunks_exact(hp).zip(factors.chunks_exact(m)) {
        // c = C_b[q,:] · ũ: 8 partial sums per axis (handles h ≡ 0..7 mod 8) in SIMD lanes,
        // then added in a fixed order (the same bits for every SIMD width)
        let mut part = [[0.0f32; BATCH]; 3];
        for (k, w) in row.chunks_exact(BATCH).enumerate() {
            let w: &Lane = w.try_into().expect("rows padded to whole lanes");
            let at = k * BATCH..(k + 1) * BATCH;
            for (p, u) in part
                .iter_mut()
                .zip([&ux[at.clone()], &uy[at.clone()], &uz[at]])
            {
                let u: &Lane = u.try_into().expect("ũ padded to whole lanes");
                *p = o.add(p, &o.mul(w, u));
            }
        }
        let mut c = [0.0f32; 3];
        for a in 0..3 {
            let p = &part[a];
            c[a] = ((p[0] + p[1]) + (p[2] + p[3])) + ((p[4] + p[5]) + (p[6] + p[7]));
        }
        let [cx, cy, cz] = c;
        for i in 0..m {
            ax[i] += col[i] * cx;
            ay[i] += col[i] * cy;
            az[i] += col[i] * cz;
        }
    }
    for (i, (o, x0)) in out.iter_mut().zip(rest).enumerate() {
        *o = [
            x0[0] + mean[0] + ax[i],
            x0[1] + mean[1] + ay[i],
            x0[2] + mean[2] + az[i],
        ];
    }
}

/// Pass 1 over the low-rank blocks covering stored vertices `first..first + out.len()`
/// (`first` a multiple of [`LOW_RANK_BLOCK`]).
#[inline(always)]
fn large_range<S: pulp::Simd>(
    lanes: Lanes<S>,
    layout: &RuntimeLayout,
    first: usize,
    centred: &[f32],
    mean: [f32; 3],
    out: &mut [[f32; 3]],
) {
    for (k, o) in out.chunks_mut(LOW_RANK_BLOCK).enumerate() {
        large_block(lanes, layout, first / LOW_RANK_BLOCK + k, centred, mean, o);
    }
}

/// The run-time kernels as one [`pulp::WithSimd`] operation: `pulp::Arch::new().dispatch`
/// runs them with the widest SIMD instruction set this CPU offers (AVX2 + FMA on x86-64,
/// detected at run time; the portable baseline otherwise). `with_simd` and the kernel bodies
/// are `#[inline(always)]`, so the plain-Rust loops over fixed-size arrays and contiguous
/// slices are compiled — and vectorized — inside the target-feature function. No `mul_add`
/// is used, so every path gives the same bits.
enum Kernel<'a, const NC: usize, E> {
    /// Pass 1 over a range of whole low-rank blocks.
    Large {
        layout: &'a RuntimeLayout,
        centred: &'a [f32],
        mean: [f32; 3],
        first: usize,
        out: &'a mut [[f32; 3]],
    },
    /// Pass 2 of the stored vertices `first..first + out.len()` (`first` a multiple of
    /// [`BATCH`]) into `out`, one-rings from the complete `large`.
    Detail {
        inputs: &'a DetailInputs<'a, NC, E>,
        large: &'a [[f32; 3]],
        first: usize,
        out: &'a mut [[f32; 3]],
    },
    /// Final normals, as `Detail`, from the complete `positions`.
    Normals {
        fans: &'a Fans,
        positions: &'a [[f32; 3]],
        first: usize,
        out: &'a mut [[f32; 3]],
    },
}

impl<const NC: usize, E: EdgeId> pulp::WithSimd for Kernel<'_, NC, E> {
    type Output = ();
    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, simd: S) {
        match self {
            Kernel::Large {
                layout,
                centred,
                mean,
                first,
                out,
            } => large_range(Lanes(simd), layout, first, centred, mean, out),
            Kernel::Detail {
                inputs,
                large,
                first,
                out,
            } => {
                for b in first / BATCH..(first + out.len()).div_ceil(BATCH) {
                    let (count, x) = inputs.batch(simd, b, large, 0);
                    out[b * BATCH - first..][..count].copy_from_slice(&x[..count]);
                }
            }
            Kernel::Normals {
                fans,
                positions,
                first,
                out,
            } => {
                for (vs, count) in Batches(first..first + out.len()) {
                    let n = normal_batch(simd, fans, &vs, positions, 0);
                    out[vs[0] - first..][..count].copy_from_slice(&n[..count]);
                }
            }
        }
    }
}

#[inline(always)]
fn dispatch<const NC: usize, E: EdgeId>(kernel: Kernel<'_, NC, E>) {
    pulp::Arch::new().dispatch(kernel)
}

/// One frame of the run-time synthesis (thesis §5.5.2): large scale (`centred`, `mean` from
/// [`centre_handles`]; [`large_scale_pass`]), then normal + frame + WPSD detail (`table` from
/// [`feature_table`]; `global_r` the PSD distances; [`detail_pass`]), then final normals
/// ([`normal_pass`]) — three parallel passes over independent chunks of stored vertices, two
/// synchronisation points, no allocation. Outputs are in storage order (see
/// [`to_mesh_order_into`]).
#[allow(clippy::too_many_arguments)]
pub fn frame_pass(
    layout: &RuntimeLayout,
    centred: &[f32],
    mean: [f32; 3],
    table: &[[f32; LANES]],
    global_r: Option<&[f32]>,
    large: &mut [[f32; 3]],
    positions: &mut [[f32; 3]],
    normals: &mut [[f32; 3]],
) {
    let n = layout.num_vertices();
    assert!(
        large.len() == n && positions.len() == n && normals.len() == n,
        "one output per vertex"
    );
    large_pass(layout, centred, mean, large);
    detail_pass(layout, large, table, global_r, positions);
    normal_pass(layout, positions, normals);
}

/// Pass 1 over the whole mesh from the centred handle displacements ([`centre_handles`]).
fn large_pass(layout: &RuntimeLayout, centred: &[f32], mean: [f32; 3], large: &mut [[f32; 3]]) {
    assert_eq!(
        centred.len(),
        3 * layout.basis.padded_handles(),
        "one displacement per handle and axis (centre_handles)"
    );
    assert_eq!(large.len(), layout.num_vertices(), "one output per vertex");
    let span = 8 * LOW_RANK_BLOCK;
    large.par_chunks_mut(span).enumerate().for_each(|(k, out)| {
        dispatch::<1, u8>(Kernel::Large {
            layout,
            centred,
            mean,
            first: k * span,
            out,
        })
    });
}

/// Pass 1 alone (thesis §5.3 large-scale kernel) over the whole mesh: `x_v = x0_v + ū +
/// Σ_k U_b[v,k] (C_b ũ)_k` per low-rank block, `u_H` the handle displacements (allocates the
/// centred displacements; a frame runs [`frame_pass`]).
pub fn large_scale_pass(layout: &RuntimeLayout, uh: &[[f32; 3]], large: &mut [[f32; 3]]) {
    assert_eq!(uh.len(), layout.basis.h, "one displacement per handle");
    let mut centred = Vec::new();
    let mean = centre_handles(uh, &mut centred);
    large_pass(layout, &centred, mean, large);
}

/// Pass 2 alone (thesis §5.5.2 fine-scale kernel, eq. 5.3–5.5) over the whole mesh: per vertex
/// the large-scale normal and local frame `[t, b, n]`, the distances `r_j = sqrt(Σ_i α_{v,i}
/// g[i][j])` (or the global `r` for PSD), the detail `d = Σ_j w_{v,j} r_j` and `x = x_large +
/// d_0 t + d_1 b + d_2 n`. `table` is [`feature_table`]'s.
pub fn detail_pass(
    layout: &RuntimeLayout,
    large: &[[f32; 3]],
    table: &[[f32; LANES]],
    global_r: Option<&[f32]>,
    positions: &mut [[f32; 3]],
) {
    let n = layout.num_vertices();
    assert!(
        large.len() == n && positions.len() == n,
        "one value per vertex"
    );
    with_inputs!(layout, table, global_r, |inputs| positions
        .par_chunks_mut(BLOCK)
        .enumerate()
        .for_each(|(k, out)| dispatch(Kernel::Detail {
            inputs,
            large,
            first: k * BLOCK,
            out,
        })));
}

/// Pass 3 alone: unit vertex normals of `positions` from the one-ring fans.
pub fn normal_pass(layout: &RuntimeLayout, positions: &[[f32; 3]], normals: &mut [[f32; 3]]) {
    let n = layout.num_vertices();
    assert!(
        positions.len() == n && normals.len() == n,
        "one value per vertex"
    );
    normals
        .par_chunks_mut(BLOCK)
        .enumerate()
        .for_each(|(k, out)| {
            dispatch::<1, u8>(Kernel::Normals {
                fans: &layout.fans,
                positions,
                first: k * BLOCK,
                out,
            })
        });
}

/// The layout's locality order undone: `positions[v] = work[rank[v]]`, `normals[v] =
/// work_normals[rank[v]]` (a copy without [`RuntimeSettings::reorder`]).
pub fn to_mesh_order_into(
    layout: &RuntimeLayout,
    work: &[[f32; 3]],
    work_normals: &[[f32; 3]],
    positions: &mut [[f32; 3]],
    normals: &mut [[f32; 3]],
) {
    let n = layout.num_vertices();
    assert!(
        work.len() == n && work_normals.len() == n && positions.len() == n && normals.len() == n
    );
    let Some(rank) = layout.rank.as_deref() else {
        positions.copy_from_slice(work);
        normals.copy_from_slice(work_normals);
        return;
    };
    positions
        .par_chunks_mut(BLOCK)
        .zip(normals.par_chunks_mut(BLOCK))
        .zip(rank.par_chunks(BLOCK))
        .for_each(|((pos, nrm), rank)| {
            for ((x, o), &k) in pos.iter_mut().zip(nrm.iter_mut()).zip(rank) {
                *x = work[k as usize];
                *o = work_normals[k as usize];
            }
        });
}

/// `out[v] = stored[rank[v]]`: a per-vertex array of the layout back in mesh order.
pub fn to_mesh_order(layout: &RuntimeLayout, stored: &[[f32; 3]]) -> Vec<[f32; 3]> {
    match layout.rank.as_deref() {
        Some(rank) => rank.iter().map(|&k| stored[k as usize]).collect(),
        None => stored.to_vec(),
    }
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
                        let m = u.len() / k.max(1);
                        let got: f64 = (0..k)
                            .map(|q| u[q * m + i] as f64 * c[q * lr.padded_handles() + j] as f64)
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
    fn batch_details_keep_every_vertex_edge_weight_and_rbf_weight() {
        // 19 vertices (2 full batches + 3), 4 edge slots, P = 2; vertex v uses edges v % 7 ..
        let (n, width, p) = (19, 4, 2);
        let edges: Vec<u16> = (0..n * width)
            .map(|k| ((k / width) % 7 + 3 * (k % width)) as u16)
            .collect();
        let alphas: Vec<u16> = (0..n * width)
            .map(|k| if k % 5 == 0 { 0 } else { 100 + k as u16 })
            .collect();
        let weights: Vec<f32> = (0..n * 3 * p).map(|k| k as f32 - 20.5).collect();
        let d = BatchDetails::new(p, width, &edges, &alphas, &weights, 300);
        let EdgeIds::U16(ids) = &d.edges else {
            panic!("F = 300 > 256 needs u16 ids")
        };
        assert_eq!(d.offsets.len(), n.div_ceil(BATCH) + 1);
        for v in 0..n {
            let (b, l) = (v / BATCH, v % BATCH);
            let range = d.offsets[b] as usize..d.offsets[b + 1] as usize;
            assert!(
                ids[range.clone()].windows(2).all(|w| w[0] < w[1]),
                "ascending union"
            );
            // every (edge, α > 0) of the vertex is in its lane, and nothing else
            let mut want: Vec<(u16, u16)> = (v * width..(v + 1) * width)
                .filter(|&k| alphas[k] > 0)
                .map(|k| (edges[k], alphas[k]))
                .collect();
            want.sort_unstable();
            let got: Vec<(u16, u16)> = range
                .filter(|&k| d.alphas[k][l] > 0)
                .map(|k| (ids[k], d.alphas[k][l]))
                .collect();
            assert_eq!(got, want, "vertex {v}");
            for c in 0..3 * p {
                assert_eq!(d.weights[b * 3 * p + c][l], weights[v * 3 * p + c]);
            }
        }
        // lanes past the last vertex are zero
        let last = n / BATCH;
        for l in n % BATCH..BATCH {
            for c in 0..3 * p {
                assert_eq!(d.weights[last * 3 * p + c][l], 0.0);
            }
        }
        let small = BatchDetails::new(p, width, &edges, &alphas, &weights, 256);
        assert!(matches!(small.edges, EdgeIds::U8(_)), "F ≤ 256: u8 ids");
    }

    #[test]
    fn fan_sum_pairs_terms_and_matches_face_normals() {
        // the paired sum equals the plain Σ e_i × e_{i+1} up to rounding, for closed and open
        // fans of odd and even length, and the batched unit normals equal the scalar ones
        let n = 7;
        let (pos, tris) = crate::frames::bumpy_grid(n);
        let topo = Topology::new(n * n, &tris);
        let fans = Fans::new(&topo);
        let mut lens = std::collections::BTreeSet::new();
        for v in 0..n * n {
            let ring = fans.ring(v);
            lens.insert((fans.kinds[v] as u8, ring.len() % 2));
            let p = pos[v];
            let e = |i: u32| sub(pos[i as usize], p);
            let closed = fans.kinds[v] == FanKind::Closed;
            let mut want = [0.0f64; 3];
            let terms = if closed { ring.len() } else { ring.len() - 1 };
            for k in 0..terms {
                let c = cross(e(ring[k]), e(ring[(k + 1) % ring.len()]));
                for a in 0..3 {
                    want[a] += c[a] as f64;
                }
            }
            let got = fan_quad(&pos, 0, ring, fans.kinds[v], p);
            for a in 0..3 {
                assert!((got[a] as f64 - want[a]).abs() < 1e-5, "vertex {v}");
            }
        }
        assert!(lens.len() >= 3, "fan kinds and parities covered: {lens:?}");
        struct Normals<'a>(&'a Fans, &'a [[f32; 3]]);
        impl pulp::WithSimd for Normals<'_> {
            type Output = Vec<[f32; 3]>;
            #[inline(always)]
            fn with_simd<S: pulp::Simd>(self, simd: S) -> Vec<[f32; 3]> {
                let mut out = Vec::new();
                for (vs, count) in Batches(0..self.1.len()) {
                    out.extend_from_slice(&normal_batch(simd, self.0, &vs, self.1, 0)[..count]);
                }
                out
            }
        }
        let batched = pulp::Arch::new().dispatch(Normals(&fans, &pos));
        for v in 0..n * n {
            assert_eq!(batched[v], fans.normal(&pos, v), "vertex {v}");
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

    #[test]
    fn morton_order_is_a_permutation_and_fans_follow_it() {
        let n = 12;
        let (pos, tris) = crate::frames::bumpy_grid(n);
        let order = morton_order(&pos);
        let mut seen = vec![false; n * n];
        for &v in &order {
            assert!(!seen[v as usize]);
            seen[v as usize] = true;
        }
        assert!(seen.iter().all(|&x| x));
        // on the flat grid the first 4 stored vertices are the 2×2 corner cell of the Z curve
        let flat: Vec<[f32; 3]> = pos.iter().map(|p| [p[0], p[1], 0.0]).collect();
        let mut first: Vec<u32> = morton_order(&flat)[..4].to_vec();
        first.sort_unstable();
        assert_eq!(first, vec![0, 1, n as u32, n as u32 + 1]);
        let mut rank = vec![0u32; n * n];
        for (k, &v) in order.iter().enumerate() {
            rank[v as usize] = k as u32;
        }
        let fans = Fans::new(&Topology::new(n * n, &tris));
        let moved = fans.permuted(&order, &rank);
        let stored: Vec<[f32; 3]> = order.iter().map(|&v| pos[v as usize]).collect();
        for v in 0..n * n {
            let k = rank[v] as usize;
            assert_eq!(fans.normal(&pos, v), moved.normal(&stored, k));
            assert_eq!(order[moved.reference[k] as usize], fans.reference[v]);
        }
    }

    /// A `k × k` bumpy grid layout with a smooth synthetic basis, random edge weights and RBF
    /// weights, stored in `order` (Morton or not).
    fn grid_layout(k: usize, p: usize, morton: bool) -> RuntimeLayout {
        let n = k * k;
        let mut pos: Vec<[f32; 3]> = (0..n)
            .map(|v| {
                let (x, y) = ((v % k) as f32, (v / k) as f32);
                [x, y, 0.3 * (0.7 * x).sin() * (0.4 * y).cos()]
            })
            .collect();
        let (_, mut tris) = crate::frames::bumpy_grid(k);
        if morton {
            let order = morton_order(&pos);
            let mut rank = vec![0usize; n];
            for (s, &v) in order.iter().enumerate() {
                rank[v as usize] = s;
            }
            pos = order.iter().map(|&v| pos[v as usize]).collect();
            for t in &mut tris {
                *t = t.map(|v| rank[v]);
            }
        }
        let h = 9;
        let mut weights = vec![0.0f32; n * h];
        for (v, x) in pos.iter().enumerate() {
            let row: Vec<f64> = (0..h)
                .map(|j| {
                    let (cx, cy) = (
                        (j % 3) as f64 * k as f64 / 2.0,
                        (j / 3) as f64 * k as f64 / 2.0,
                    );
                    (-((x[0] as f64 - cx).powi(2) + (x[1] as f64 - cy).powi(2)) / (k * k) as f64
                        * 8.0)
                        .exp()
                })
                .collect();
            let s: f64 = row.iter().sum();
            for j in 0..h {
                weights[v * h + j] = (row[j] / s) as f32;
            }
        }
        let basis = LowRankBasis::new(&ShellBasis { n, h, weights }, 1e-5);
        let fans = Fans::new(&Topology::new(n, &tris));
        let width = 4;
        let mut seed = 12345u64;
        let mut rnd = move || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 33) as f32 / (1u64 << 31) as f32
        };
        let edges: Vec<u16> = (0..n * width).map(|_| (rnd() * 20.0) as u16).collect();
        let alphas: Vec<u16> = (0..n * width).map(|_| (rnd() * 16000.0) as u16).collect();
        let detail_weights: Vec<f32> = (0..n * 3 * p).map(|_| rnd() - 0.5).collect();
        RuntimeLayout {
            rest: pos,
            basis,
            fans,
            poses: p,
            width,
            details: BatchDetails::new(p, width, &edges, &alphas, &detail_weights, 20),
            order: None,
            rank: None,
        }
    }

    #[test]
    fn frame_is_bit_identical_for_every_thread_count() {
        // 99 × 99 = 9801 vertices: 5 parallel chunks of BLOCK, a partial last batch
        for (morton, p) in [(true, 6), (false, 6), (true, 11)] {
            let layout = grid_layout(99, p, morton);
            let n = layout.num_vertices();
            let h = layout.basis.h;
            let uh: Vec<[f32; 3]> = (0..h)
                .map(|j| {
                    [
                        0.1 * j as f32,
                        -0.05 * (j * j) as f32,
                        0.3 - 0.02 * j as f32,
                    ]
                })
                .collect();
            let nc = p.div_ceil(LANES);
            let table: Vec<[f32; LANES]> = (0..20 * nc)
                .map(|i| std::array::from_fn(|l| 0.01 * ((i * 7 + l * 3) % 11) as f32))
                .collect();
            let mut centred = Vec::new();
            let mean = centre_handles(&uh, &mut centred);
            let run = |threads: usize| {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                let mut large = vec![[9.0f32; 3]; n];
                let mut pos = vec![[9.0f32; 3]; n];
                let mut nrm = vec![[9.0f32; 3]; n];
                pool.install(|| {
                    frame_pass(
                        &layout, &centred, mean, &table, None, &mut large, &mut pos, &mut nrm,
                    )
                });
                (large, pos, nrm)
            };
            let (large, pos, nrm) = run(1);
            for threads in [2, 3] {
                assert!(run(threads) == (large.clone(), pos.clone(), nrm.clone()));
            }
            // the passes alone give the same bits; the batched normals are the scalar ones
            let mut l2 = vec![[0.0f32; 3]; n];
            large_scale_pass(&layout, &uh, &mut l2);
            assert_eq!(l2, large);
            for v in 0..n {
                assert_eq!(nrm[v], layout.fans.normal(&pos, v), "vertex {v}");
                assert!(pos[v] != large[v], "vertex {v} has a detail");
            }
        }
    }
}
