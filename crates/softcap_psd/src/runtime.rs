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
    /// Start of each block's `C_b` (`k_b × H`, row-major) in `coeffs`; length blocks + 1.
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
                let coeffs: Vec<f32> = (0..k)
                    .flat_map(|j| (0..h).map(move |i| (i, j)))
                    .map(|(i, j)| vk[(i, j)] as f32)
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
        let ids = &self.neighbours[self.offsets[v] as usize..self.offsets[v + 1] as usize];
        normalize(
            fan_normal_sum(positions, ids, self.kinds[v], positions[v]),
            [0.0, 0.0, 1.0],
        )
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
        if !settings.reorder {
            return Ok(Self {
                rest: rig.rest_f32.clone(),
                basis: LowRankBasis::new(&rig.basis, settings.basis_tolerance),
                fans,
                poses: model.num_poses(),
                width,
                edges,
                alphas,
                detail_weights: model.weights.clone(),
                order: None,
                rank: None,
            });
        }
        let order = morton_order(&rig.rest_f32);
        let mut rank = vec![0u32; n];
        for (k, &v) in order.iter().enumerate() {
            rank[v as usize] = k as u32;
        }
        fn rows<T: Copy>(src: &[T], width: usize, order: &[u32]) -> Vec<T> {
            order
                .iter()
                .flat_map(|&v| &src[v as usize * width..(v as usize + 1) * width])
                .copied()
                .collect()
        }
        Ok(Self {
            rest: rows(&rig.rest_f32, 1, &order),
            basis: LowRankBasis::with_order(&rig.basis, settings.basis_tolerance, Some(&order)),
            fans: fans.permuted(&order, &rank),
            poses: model.num_poses(),
            width,
            edges: rows(&edges, width, &order),
            alphas: rows(&alphas, width, &order),
            detail_weights: rows(&model.weights, p3, &order),
            order: Some(order),
            rank: Some(rank),
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
        let unpermute = if self.rank.is_some() { n * 4 } else { 0 };
        basis + fans + detail + unpermute + n * 12 /* large in */ + n * 24 /* positions, normals out */
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

/// The three run-time kernels as [`pulp::WithSimd`] operations: `pulp::Arch::new().dispatch`
/// runs them with the widest SIMD instruction set this CPU offers (AVX2 + FMA on x86-64,
/// detected at run time; the portable baseline otherwise). `with_simd` and the kernel bodies
/// are `#[inline(always)]`, so the plain-Rust loops over fixed-size arrays and contiguous
/// slices are compiled — and vectorized — inside the target-feature function. No `mul_add`
/// is used, so every path gives the same bits.
enum Kernel<'a, const NC: usize> {
    Large {
        layout: &'a RuntimeLayout,
        blk: usize,
        centred: &'a [[f32; 4]],
        mean: [f32; 3],
        chunk: &'a mut [[f32; 3]],
        scratch: &'a mut LargeScratch,
    },
    Detail {
        layout: &'a RuntimeLayout,
        large: &'a [[f32; 3]],
        table: &'a [[f32; LANES]],
        global_r: Option<&'a [f32]>,
        first: usize,
        chunk: &'a mut [[f32; 3]],
    },
    Normals {
        layout: &'a RuntimeLayout,
        positions: &'a [[f32; 3]],
        first: usize,
        chunk: &'a mut [[f32; 3]],
    },
    NormalsToMesh {
        layout: &'a RuntimeLayout,
        work: &'a [[f32; 3]],
        rank: &'a [u32],
        normals: &'a mut [[f32; 3]],
        positions: &'a mut [[f32; 3]],
    },
}

impl<const NC: usize> pulp::WithSimd for Kernel<'_, NC> {
    type Output = ();
    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        match self {
            Kernel::Large {
                layout,
                blk,
                centred,
                mean,
                chunk,
                scratch,
            } => large_block(layout, blk, centred, mean, chunk, scratch),
            Kernel::Detail {
                layout,
                large,
                table,
                global_r,
                first,
                chunk,
            } => detail_block::<NC>(layout, large, table, global_r, first, chunk),
            Kernel::Normals {
                layout,
                positions,
                first,
                chunk,
            } => normals_block(layout, positions, first, chunk),
            Kernel::NormalsToMesh {
                layout,
                work,
                rank,
                normals,
                positions,
            } => normals_to_mesh_block(layout, work, rank, normals, positions),
        }
    }
}

#[inline(always)]
fn dispatch<const NC: usize>(kernel: Kernel<'_, NC>) {
    pulp::Arch::new().dispatch(kernel)
}

/// Per-thread scratch of the large-scale pass: `c_b = C_b ũ` and the three coordinate
/// accumulators of one block.
#[derive(Default)]
struct LargeScratch {
    c: Vec<[f32; 4]>,
    acc: [Vec<f32>; 3],
}

/// Pass 1 (thesis §5.3 large-scale kernel): `x_v = x0_v + ū + Σ_k U_b[v,k] (C_b ũ)_k` per
/// low-rank block, `u_H` the handle displacements. `U_b` is rank-major, so the inner loop runs
/// over the block's vertices in SIMD lanes (three multiply-adds per 8 vertices and rank).
pub fn large_scale_pass(layout: &RuntimeLayout, uh: &[[f32; 3]], large: &mut [[f32; 3]]) {
    let b = &layout.basis;
    assert_eq!(uh.len(), b.h, "one displacement per handle");
    assert_eq!(large.len(), b.n, "one output per vertex");
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
        .for_each_init(LargeScratch::default, |s, (blk, chunk)| {
            dispatch::<1>(Kernel::Large {
                layout,
                blk,
                centred: &centred,
                mean,
                chunk,
                scratch: s,
            })
        });
}

#[inline(always)]
fn large_block(
    layout: &RuntimeLayout,
    blk: usize,
    centred: &[[f32; 4]],
    mean: [f32; 3],
    chunk: &mut [[f32; 3]],
    s: &mut LargeScratch,
) {
    let b = &layout.basis;
    let m = chunk.len();
    let first = blk * LOW_RANK_BLOCK;
    let rest = &layout.rest[first..first + m];
    let coeffs = &b.coeffs[b.coeff_offsets[blk]..b.coeff_offsets[blk + 1]];
    s.c.clear();
    s.c.extend(coeffs.chunks_exact(b.h).map(|row| {
        let mut acc = [0.0f32; 4];
        for (&w, u) in row.iter().zip(centred) {
            for a in 0..4 {
                acc[a] += w * u[a];
            }
        }
        acc
    }));
    let [ax, ay, az] = &mut s.acc;
    for acc in [&mut *ax, &mut *ay, &mut *az] {
        acc.clear();
        acc.resize(m, 0.0);
    }
    let (ax, ay, az) = (&mut ax[..m], &mut ay[..m], &mut az[..m]);
    let factors = &b.factors[b.factor_offsets[blk]..b.factor_offsets[blk + 1]];
    for (col, c) in factors.chunks_exact(m).zip(&s.c) {
        let col = &col[..m];
        let [cx, cy, cz, _] = *c;
        for i in 0..m {
            ax[i] += col[i] * cx;
            ay[i] += col[i] * cy;
            az[i] += col[i] * cz;
        }
    }
    for (i, (o, x0)) in chunk.iter_mut().zip(rest).enumerate() {
        *o = [
            x0[0] + mean[0] + ax[i],
            x0[1] + mean[1] + ay[i],
            x0[2] + mean[2] + az[i],
        ];
    }
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

/// Unnormalised normal of a one-ring fan around `p`: `Σ_i (p_i − p) × (p_{i+1} − p)`.
#[inline(always)]
fn fan_normal_sum(positions: &[[f32; 3]], ids: &[u32], kind: FanKind, p: [f32; 3]) -> [f32; 3] {
    let mut s = [0.0f32; 3];
    let mut add = |a: [f32; 3], b: [f32; 3]| {
        let c = cross(a, b);
        s = [s[0] + c[0], s[1] + c[1], s[2] + c[2]];
    };
    match kind {
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
    s
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
    assert_eq!(
        large.len(),
        layout.num_vertices(),
        "one large-scale position per vertex"
    );
    assert_eq!(
        positions.len(),
        layout.num_vertices(),
        "one output per vertex"
    );
    positions
        .par_chunks_mut(BLOCK)
        .enumerate()
        .for_each(|(blk, chunk)| {
            dispatch::<NC>(Kernel::Detail {
                layout,
                large,
                table,
                global_r,
                first: blk * BLOCK,
                chunk,
            })
        });
}

#[inline(always)]
fn detail_block<const NC: usize>(
    layout: &RuntimeLayout,
    large: &[[f32; 3]],
    table: &[[f32; LANES]],
    global_r: Option<&[f32]>,
    first: usize,
    chunk: &mut [[f32; 3]],
) {
    let p = layout.poses;
    let nc = p.div_ceil(LANES);
    let width = layout.width;
    let fans = &layout.fans;
    let m = chunk.len();
    let mut r = [[0.0f32; LANES]; NC];
    if let Some(gr) = global_r {
        for (j, &x) in gr.iter().enumerate().take(p) {
            r[j / LANES][j % LANES] = x;
        }
    }
    let offsets = &fans.offsets[first..first + m + 1];
    let kinds = &fans.kinds[first..first + m];
    let reference = &fans.reference[first..first + m];
    let xl_block = &large[first..first + m];
    let weights = &layout.detail_weights[first * 3 * p..(first + m) * 3 * p];
    let (edges, alphas) = if global_r.is_none() {
        (
            &layout.edges[first * width..(first + m) * width],
            &layout.alphas[first * width..(first + m) * width],
        )
    } else {
        (&layout.edges[..0], &layout.alphas[..0])
    };
    for (k, o) in chunk.iter_mut().enumerate() {
        let xl = xl_block[k];
        let ids = &fans.neighbours[offsets[k] as usize..offsets[k + 1] as usize];
        let n = normalize(fan_normal_sum(large, ids, kinds[k], xl), [0.0, 0.0, 1.0]);
        let [t, bt, n] = frame_from_edge(sub(large[reference[k] as usize], xl), n);
        if global_r.is_none() && NC == 1 {
            // P ≤ 8: one 8-lane accumulator in registers, one table row per edge
            let ids = &edges[k * width..(k + 1) * width];
            let al = &alphas[k * width..(k + 1) * width];
            let mut acc = [0.0f32; LANES];
            for (&i, &a) in ids.iter().zip(al) {
                let g = table[i as usize];
                for l in 0..LANES {
                    acc[l] += a * g[l];
                }
            }
            for l in 0..LANES {
                r[0][l] = acc[l].sqrt();
            }
        } else if global_r.is_none() {
            r = [[0.0; LANES]; NC];
            let ids = &edges[k * width..(k + 1) * width];
            let al = &alphas[k * width..(k + 1) * width];
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
        let w = &weights[k * 3 * p..(k + 1) * 3 * p];
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
}

/// Pass 3: unit vertex normals of `positions` from the one-ring fans.
pub fn normal_pass(layout: &RuntimeLayout, positions: &[[f32; 3]], normals: &mut [[f32; 3]]) {
    assert_eq!(
        positions.len(),
        layout.num_vertices(),
        "one position per vertex"
    );
    assert_eq!(
        normals.len(),
        layout.num_vertices(),
        "one output per vertex"
    );
    normals
        .par_chunks_mut(BLOCK)
        .enumerate()
        .for_each(|(blk, chunk)| {
            dispatch::<1>(Kernel::Normals {
                layout,
                positions,
                first: blk * BLOCK,
                chunk,
            })
        });
}

#[inline(always)]
fn normals_block(
    layout: &RuntimeLayout,
    positions: &[[f32; 3]],
    first: usize,
    chunk: &mut [[f32; 3]],
) {
    let fans = &layout.fans;
    let m = chunk.len();
    let offsets = &fans.offsets[first..first + m + 1];
    let kinds = &fans.kinds[first..first + m];
    let own = &positions[first..first + m];
    for (k, o) in chunk.iter_mut().enumerate() {
        let ids = &fans.neighbours[offsets[k] as usize..offsets[k + 1] as usize];
        *o = normalize(
            fan_normal_sum(positions, ids, kinds[k], own[k]),
            [0.0, 0.0, 1.0],
        );
    }
}

/// Pass 3 with the layout's locality order undone: for every mesh vertex `v` (storage index
/// `k = rank[v]`) `normals[v]` = the unit normal of `work` at `k` and `positions[v] = work[k]`.
/// Without a reorder this is [`normal_pass`] plus a copy.
pub fn normal_pass_to_mesh_order(
    layout: &RuntimeLayout,
    work: &[[f32; 3]],
    positions: &mut [[f32; 3]],
    normals: &mut [[f32; 3]],
) {
    let n = layout.num_vertices();
    assert!(work.len() == n && positions.len() == n && normals.len() == n);
    let Some(rank) = layout.rank.as_deref() else {
        positions.copy_from_slice(work);
        normal_pass(layout, work, normals);
        return;
    };
    normals
        .par_chunks_mut(BLOCK)
        .zip(positions.par_chunks_mut(BLOCK))
        .enumerate()
        .for_each(|(blk, (nrm, pos))| {
            let first = blk * BLOCK;
            dispatch::<1>(Kernel::NormalsToMesh {
                layout,
                work,
                rank: &rank[first..first + nrm.len()],
                normals: nrm,
                positions: pos,
            })
        });
}

#[inline(always)]
fn normals_to_mesh_block(
    layout: &RuntimeLayout,
    work: &[[f32; 3]],
    rank: &[u32],
    normals: &mut [[f32; 3]],
    positions: &mut [[f32; 3]],
) {
    let fans = &layout.fans;
    for ((o, x), &k) in normals.iter_mut().zip(positions.iter_mut()).zip(rank) {
        let k = k as usize;
        let ids = &fans.neighbours[fans.offsets[k] as usize..fans.offsets[k + 1] as usize];
        *o = normalize(
            fan_normal_sum(work, ids, fans.kinds[k], work[k]),
            [0.0, 0.0, 1.0],
        );
        *x = work[k];
    }
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
                            .map(|q| u[q * m + i] as f64 * c[q * h + j] as f64)
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

    #[test]
    fn morton_order_is_a_permutation_and_fans_follow_it() {
        // 12×12 bumpy grid
        let n = 12;
        let pos: Vec<[f32; 3]> = (0..n * n)
            .map(|k| [(k % n) as f32, (k / n) as f32, 0.1 * ((k * 7 % 5) as f32)])
            .collect();
        let mut tris = Vec::new();
        for j in 0..n - 1 {
            for i in 0..n - 1 {
                let a = j * n + i;
                tris.push([a, a + 1, a + n + 1]);
                tris.push([a, a + n + 1, a + n]);
            }
        }
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
}
