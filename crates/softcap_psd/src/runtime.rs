//! Run-time data layout of the synthesis (thesis §5.5.2): everything one frame reads, stored
//! vertex-major in `f32` so each of the three per-frame passes streams memory once.
//!
//! * **Large scale** `x_v = x0_v + Σ_h B[v,h] u_h` (thesis §5.3). A row of the bi-Laplacian
//!   basis is dominated by the handles around `v`, so [`RuntimeLayout`] keeps per row the fewest
//!   largest-magnitude entries that hold all but `RuntimeSettings::basis_tolerance` (default
//!   1e-3) of the row's L1 mass, and rescales them so the kept row has the full row's sum. Rows
//!   of `B` sum to 1 (a rigid translation of all handles translates the shell), so translations
//!   stay exact; the error on the ICT face is measured in `tests/runtime.rs` and reported in
//!   `docs/psd.md`. `basis_tolerance = 0` keeps the dense basis (exact up to f32 summation order).
//! * **Normals** from a precomputed one-ring: per vertex the two other corners of each
//!   incident triangle in winding order, `n_v ∝ Σ (p_a − p_v) × (p_b − p_v)` — the area-weighted
//!   sum of face normals, without a face-normal pass or per-frame allocation.
//! * **Details** (eq. 5.3–5.5): per vertex the WPSD edge ids / weights `α_{v,i}` and the `3P`
//!   RBF weights; the per-frame table `g[i·P + j] = (f_i − f_{j,i})²` (F × P floats) stays in L1.
//!
//! Pass 1 writes the large-scale positions; pass 2 computes, per vertex, the large-scale normal
//! and local frame, the detail `d_v(f)` and the final position; pass 3 the final normals. Each
//! pass is a rayon loop over [`crate::frames::BLOCK`]-vertex blocks.

use crate::detail::{DetailModel, MAX_POSES, Metric};
use crate::error::{PsdError, Result};
use crate::frames::{BLOCK, Topology};
use crate::rig::FaceRig;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use softcap_mesh::ShellBasis;

/// Settings of the run-time layout.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct RuntimeSettings {
    /// Relative L1 mass of a basis row that may be dropped: per vertex the smallest set of
    /// largest-magnitude entries with `Σ_dropped |B[v,h]| ≤ basis_tolerance · Σ_h |B[v,h]|` is
    /// kept. `0` keeps `B` dense.
    pub basis_tolerance: f64,
}

impl Default for RuntimeSettings {
    fn default() -> Self {
        Self {
            basis_tolerance: 1e-3,
        }
    }
}

/// Sparse rows of the shell basis (CSR): the dominant (handle, weight) pairs of each vertex.
#[derive(Clone, Debug, PartialEq)]
pub struct TruncatedBasis {
    /// Number of vertices.
    pub n: usize,
    /// Number of handles H.
    pub h: usize,
    /// CSR offsets (n + 1).
    pub offsets: Vec<u32>,
    /// Handle ids (ascending within a row).
    pub handles: Vec<u16>,
    /// Weights (row sums equal the dense row sums).
    pub weights: Vec<f32>,
}

impl TruncatedBasis {
    /// Keep, per row of `basis`, the fewest largest-magnitude entries whose dropped L1 mass is at
    /// most `tolerance` of the row's (ties: lower handle id), scaled by `Σ_all / Σ_kept` so that
    /// each row keeps its sum (rows of `B` sum to 1: rigid translations stay exact).
    pub fn new(basis: &ShellBasis, tolerance: f64) -> Self {
        let rows: Vec<(Vec<u16>, Vec<f32>)> = (0..basis.n)
            .into_par_iter()
            .map(|v| {
                let row = basis.row(v);
                let mut order: Vec<usize> = (0..row.len()).collect();
                order.sort_by(|&a, &b| row[b].abs().total_cmp(&row[a].abs()).then(a.cmp(&b)));
                let total: f64 = row.iter().map(|&w| (w as f64).abs()).sum();
                let mut dropped = 0.0;
                let mut keep = order.len();
                while keep > 1 {
                    let w = (row[order[keep - 1]] as f64).abs();
                    if dropped + w > tolerance * total {
                        break;
                    }
                    dropped += w;
                    keep -= 1;
                }
                order.truncate(keep);
                order.sort_unstable(); // ascending handle ids: sequential reads of u_H
                let full: f64 = row.iter().map(|&w| w as f64).sum();
                let kept: f64 = order.iter().map(|&i| row[i] as f64).sum();
                let scale = if kept.abs() > 0.5 * full.abs() && kept.abs() > 0.0 {
                    full / kept
                } else {
                    1.0
                };
                (
                    order.iter().map(|&i| i as u16).collect(),
                    order
                        .iter()
                        .map(|&i| (row[i] as f64 * scale) as f32)
                        .collect(),
                )
            })
            .collect();
        let mut offsets = Vec::with_capacity(basis.n + 1);
        offsets.push(0u32);
        let (mut handles, mut weights) = (Vec::new(), Vec::new());
        for (hs, ws) in rows {
            handles.extend(hs);
            weights.extend(ws);
            offsets.push(handles.len() as u32);
        }
        Self {
            n: basis.n,
            h: basis.h,
            offsets,
            handles,
            weights,
        }
    }

    /// Mean kept entries per row.
    pub fn mean_terms(&self) -> f64 {
        self.handles.len() as f64 / self.n.max(1) as f64
    }
}

/// Per-frame buffers and the vertex-major run-time data of a rig + detail model.
#[derive(Clone, Debug)]
pub struct RuntimeLayout {
    /// Rest positions `x0` (f32).
    pub rest: Vec<[f32; 3]>,
    /// Truncated shell basis.
    pub basis: TruncatedBasis,
    /// CSR offsets into `ring` (n + 1).
    pub ring_offsets: Vec<u32>,
    /// Other two corners `[a, b]` of each incident triangle, in winding order `v → a → b`.
    /// The first entry's `a` is the reference neighbour of the local frame (as in [`Topology`]).
    pub ring: Vec<[u32; 2]>,
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
        if rig.basis.h > u16::MAX as usize + 1 {
            return Err(PsdError::InvalidSetting {
                field: "handles",
                reason: format!(
                    "{} handles; the run-time layout indexes ≤ 65536",
                    rig.basis.h
                ),
            });
        }
        let (ring_offsets, ring) = one_ring(&rig.topology);
        let (width, edges, alphas) = match &model.metric {
            Metric::Weighted(ew) => (ew.width, ew.edges.clone(), ew.alphas.clone()),
            Metric::Global => (0, Vec::new(), Vec::new()),
        };
        Ok(Self {
            rest: rig.rest_f32.clone(),
            basis: TruncatedBasis::new(&rig.basis, settings.basis_tolerance),
            ring_offsets,
            ring,
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
        let basis = self.basis.handles.len() * 6 + n * 28; // ids + weights + offsets, rest, out
        let ring = 2 * (self.ring.len() * 8 + self.ring_offsets.len() * 4);
        let detail = self.edges.len() * 2 + self.alphas.len() * 4 + self.detail_weights.len() * 4;
        basis + ring + detail + n * 24 + n * 12
    }
}

/// Per-vertex incident-triangle corners in winding order (CSR), vertex order of [`Topology`].
fn one_ring(topo: &Topology) -> (Vec<u32>, Vec<[u32; 2]>) {
    let n = topo.num_vertices();
    let mut ring = Vec::with_capacity(topo.vertex_faces.len());
    for v in 0..n {
        for &f in
            &topo.vertex_faces[topo.face_offsets[v] as usize..topo.face_offsets[v + 1] as usize]
        {
            let t = topo.triangles[f as usize];
            let k = t.iter().position(|&x| x as usize == v).unwrap_or(0);
            ring.push([t[(k + 1) % 3], t[(k + 2) % 3]]);
        }
    }
    (topo.face_offsets.clone(), ring)
}

#[inline]
fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
#[inline]
fn cross(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
#[inline]
fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Unit normal of vertex `v` from its one-ring (`[0, 0, 1]` if degenerate).
#[inline]
fn ring_normal(layout: &RuntimeLayout, positions: &[[f32; 3]], v: usize) -> [f32; 3] {
    let p = positions[v];
    let mut s = [0.0f32; 3];
    let r = layout.ring_offsets[v] as usize..layout.ring_offsets[v + 1] as usize;
    for &[a, b] in &layout.ring[r] {
        let c = cross(sub(positions[a as usize], p), sub(positions[b as usize], p));
        s = [s[0] + c[0], s[1] + c[1], s[2] + c[2]];
    }
    let l = dot(s, s).sqrt();
    if l > 1e-20 {
        [s[0] / l, s[1] / l, s[2] / l]
    } else {
        [0.0, 0.0, 1.0]
    }
}

/// Pass 1 (thesis §5.3 large-scale kernel): `x_v = x0_v + Σ_s w_{v,s} u_{h(v,s)}` over the kept
/// basis entries. `uh` is `[u_x (H) | u_y (H) | u_z (H)]`.
pub fn large_scale_pass(layout: &RuntimeLayout, uh: &[f32], large: &mut [[f32; 3]]) {
    let b = &layout.basis;
    let (ux, rest) = uh.split_at(b.h);
    let (uy, uz) = rest.split_at(b.h);
    large
        .par_chunks_mut(BLOCK)
        .enumerate()
        .for_each(|(blk, chunk)| {
            let first = blk * BLOCK;
            for (k, o) in chunk.iter_mut().enumerate() {
                let v = first + k;
                let r = b.offsets[v] as usize..b.offsets[v + 1] as usize;
                let x0 = layout.rest[v];
                let (mut x, mut y, mut z) = (x0[0], x0[1], x0[2]);
                for (&i, &w) in b.handles[r.clone()].iter().zip(&b.weights[r]) {
                    let i = i as usize;
                    x += w * ux[i];
                    y += w * uy[i];
                    z += w * uz[i];
                }
                *o = [x, y, z];
            }
        });
}

/// Pass 2 (thesis §5.5.2 fine-scale kernel, eq. 5.3–5.5): per vertex the large-scale normal and
/// local frame `[t, b, n]`, the distances `r_j = sqrt(Σ_i α_{v,i} g[i·P + j])` (or the global
/// `r` for PSD), the detail `d = Σ_j w_{v,j} r_j` and `x = x_large + d_0 t + d_1 b + d_2 n`.
pub fn detail_pass(
    layout: &RuntimeLayout,
    large: &[[f32; 3]],
    g: &[f32],
    global_r: Option<&[f32]>,
    positions: &mut [[f32; 3]],
) {
    let p = layout.poses;
    assert!(p <= MAX_POSES, "at most {MAX_POSES} basis poses");
    let width = layout.width;
    positions
        .par_chunks_mut(BLOCK)
        .enumerate()
        .for_each(|(blk, chunk)| {
            let first = blk * BLOCK;
            let mut r = [0.0f32; MAX_POSES];
            if let Some(gr) = global_r {
                r[..p].copy_from_slice(gr);
            }
            for (k, o) in chunk.iter_mut().enumerate() {
                let v = first + k;
                let xl = large[v];
                let n = ring_normal(layout, large, v);
                // local frame (same construction as frames::local_frame)
                let (r0, r1) = (layout.ring_offsets[v], layout.ring_offsets[v + 1]);
                let refn = if r0 < r1 {
                    layout.ring[r0 as usize][0] as usize
                } else {
                    v
                };
                let e = sub(large[refn], xl);
                let dn = dot(e, n);
                let tp = [e[0] - dn * n[0], e[1] - dn * n[1], e[2] - dn * n[2]];
                let lt = dot(tp, tp).sqrt();
                let t = if lt > 1e-20 {
                    [tp[0] / lt, tp[1] / lt, tp[2] / lt]
                } else {
                    let a = if n[0].abs() < 0.9 {
                        [1.0, 0.0, 0.0]
                    } else {
                        [0.0, 1.0, 0.0]
                    };
                    let d = dot(a, n);
                    let q = [a[0] - d * n[0], a[1] - d * n[1], a[2] - d * n[2]];
                    let l = dot(q, q).sqrt().max(1e-30);
                    [q[0] / l, q[1] / l, q[2] / l]
                };
                let bt = cross(n, t);
                if global_r.is_none() {
                    r[..p].fill(0.0);
                    let ids = &layout.edges[v * width..(v + 1) * width];
                    let al = &layout.alphas[v * width..(v + 1) * width];
                    for (&i, &a) in ids.iter().zip(al) {
                        let gi = &g[i as usize * p..(i as usize + 1) * p];
                        for (rj, &gj) in r[..p].iter_mut().zip(gi) {
                            *rj += a * gj;
                        }
                    }
                    for x in &mut r[..p] {
                        *x = x.sqrt();
                    }
                }
                let w = &layout.detail_weights[v * 3 * p..(v + 1) * 3 * p];
                let mut d = [0.0f32; 3];
                for (wj, &rj) in w.chunks_exact(3).zip(&r[..p]) {
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

/// Pass 3: unit vertex normals of `positions` from the one-ring.
pub fn normal_pass(layout: &RuntimeLayout, positions: &[[f32; 3]], normals: &mut [[f32; 3]]) {
    normals
        .par_chunks_mut(BLOCK)
        .enumerate()
        .for_each(|(blk, chunk)| {
            for (k, o) in chunk.iter_mut().enumerate() {
                *o = ring_normal(layout, positions, blk * BLOCK + k);
            }
        });
}
