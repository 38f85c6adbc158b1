//! The face rig: handles, linear-shell basis, feature graph and edge weights on a rest mesh,
//! the conversion of example poses into training examples (thesis §5.4.2: details
//! `d = example − large-scale(example)` in local frames), and the run-time [`Animator`]
//! (thesis §5.5.2: large-scale kernel, normal update, fine-scale kernel, normal update).

use crate::detail::{DetailModel, Examples, Metric};
use crate::error::{PsdError, Result};
use crate::frames::{self, BLOCK, Topology};
use crate::graph::{EdgeWeightSettings, EdgeWeights, FeatureGraph, farthest_point_handles};
use crate::runtime::{self, RuntimeLayout, RuntimeSettings};
use nalgebra::Vector3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use softcap_mesh::{LinearShell, ShellBasis, ShellSettings, TriMesh};

/// Settings of the face rig.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RigSettings {
    /// Number of handle vertices H (thesis: 89).
    pub handles: usize,
    /// Number of feature edges F (thesis: 243).
    pub feature_edges: usize,
    /// Linear shell stiffnesses (thesis: k_s = 1, k_b = 100 for cm).
    pub shell: ShellSettings,
    /// WPSD edge weights (thesis: ≤ 16 edges, drop < 0.025).
    pub edge_weights: EdgeWeightSettings,
}

impl Default for RigSettings {
    fn default() -> Self {
        Self {
            handles: 89,
            feature_edges: 243,
            shell: ShellSettings::default(),
            edge_weights: EdgeWeightSettings::default(),
        }
    }
}

/// Everything that depends only on the rest mesh and the handle choice.
#[derive(Clone, Debug)]
pub struct FaceRig {
    /// Rest positions.
    pub rest: Vec<Vector3<f64>>,
    /// Rest positions in f32 for the run-time kernels.
    pub rest_f32: Vec<[f32; 3]>,
    /// Connectivity.
    pub topology: Topology,
    /// Handle vertex ids.
    pub handles: Vec<usize>,
    /// Shell basis `B` (thesis §5.3).
    pub basis: ShellBasis,
    /// Feature graph over the handles (§5.4.1).
    pub graph: FeatureGraph,
    /// WPSD edge weights (eq. 5.4).
    pub edge_weights: EdgeWeights,
}

/// The factorised shell of `mesh` over `handles` (thesis eq. 5.1;
/// [`LinearShell::from_mesh`]: cotangent Laplacian, Voronoi areas, nested-dissection order).
pub fn shell_for_mesh(
    mesh: &TriMesh,
    handles: &[usize],
    settings: &ShellSettings,
) -> Result<LinearShell> {
    Ok(LinearShell::from_mesh(mesh, handles, settings)?)
}

impl FaceRig {
    /// Build the rig on `mesh` with farthest-point handles (see [`farthest_point_handles`]).
    pub fn new(mesh: &TriMesh, settings: &RigSettings) -> Result<Self> {
        let handles = farthest_point_handles(&mesh.vertices, settings.handles);
        Self::with_handles(mesh, handles, None, settings)
    }

    /// Build the rig with given handles and, optionally, a given feature graph (its rest
    /// lengths are re-measured on this mesh — detail transfer, §5.4.4).
    pub fn with_handles(
        mesh: &TriMesh,
        handles: Vec<usize>,
        graph: Option<&FeatureGraph>,
        settings: &RigSettings,
    ) -> Result<Self> {
        let shell = shell_for_mesh(mesh, &handles, &settings.shell)?;
        let basis = shell.basis();
        let handle_rest: Vec<_> = handles.iter().map(|&v| mesh.vertices[v]).collect();
        let graph = match graph {
            Some(g) => g.with_rest(&handle_rest),
            None => FeatureGraph::nearest_neighbours(&handle_rest, settings.feature_edges),
        };
        let edge_weights =
            EdgeWeights::new(&mesh.vertices, &handle_rest, &graph, &settings.edge_weights);
        Ok(Self {
            rest: mesh.vertices.clone(),
            rest_f32: mesh
                .vertices
                .iter()
                .map(|p| [p.x as f32, p.y as f32, p.z as f32])
                .collect(),
            topology: Topology::new(mesh.vertices.len(), &mesh.triangles),
            handles,
            basis,
            graph,
            edge_weights,
        })
    }

    /// Number of vertices.
    pub fn num_vertices(&self) -> usize {
        self.rest.len()
    }

    /// Handle positions of a full pose.
    pub fn handle_positions(&self, pose: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        self.handles.iter().map(|&v| pose[v]).collect()
    }

    /// Feature vector (§5.4.1) of given handle positions.
    pub fn features(&self, handle_positions: &[Vector3<f64>]) -> Vec<f64> {
        let mut f = vec![0.0; self.graph.len()];
        self.graph.features(handle_positions, &mut f);
        f
    }

    /// Large-scale positions `x0 + B·u_H` (thesis §5.3) and their unit vertex normals.
    pub fn large_scale(&self, handle_positions: &[Vector3<f64>]) -> (Vec<[f32; 3]>, Vec<[f32; 3]>) {
        let uh = self.handle_displacements(handle_positions);
        let mut x = vec![[0.0f32; 3]; self.num_vertices()];
        large_scale_kernel(&self.basis, &self.rest_f32, &uh, &mut x);
        let mut fnrm = vec![[0.0f32; 3]; self.topology.triangles.len()];
        frames::face_normals(&self.topology, &x, &mut fnrm);
        let mut nrm = vec![[0.0f32; 3]; x.len()];
        frames::vertex_normals(&self.topology, &fnrm, &mut nrm);
        (x, nrm)
    }

    fn handle_displacements(&self, handle_positions: &[Vector3<f64>]) -> Vec<[f32; 3]> {
        self.handles
            .iter()
            .zip(handle_positions)
            .map(|(&v, p)| {
                let u = p - self.rest[v];
                [u.x as f32, u.y as f32, u.z as f32]
            })
            .collect()
    }

    /// Training examples from full poses: features of the handles and details
    /// `d = R_vᵀ (x_pose − x_large)` in the local frames of the large-scale deformation.
    pub fn examples(&self, poses: &[Vec<Vector3<f64>>]) -> Result<Examples> {
        let n = self.num_vertices();
        let t = poses.len();
        let fdim = self.graph.len();
        let mut features = vec![0.0; t * fdim];
        let mut details = vec![0.0; n * t * 3];
        for (s, pose) in poses.iter().enumerate() {
            if pose.len() != n {
                return Err(PsdError::SizeMismatch {
                    what: "pose vertices",
                    expected: n,
                    got: pose.len(),
                });
            }
            let hp = self.handle_positions(pose);
            self.graph
                .features(&hp, &mut features[s * fdim..(s + 1) * fdim]);
            let (x, nrm) = self.large_scale(&hp);
            for v in 0..n {
                let fr = frames::local_frame(&self.topology, &x, nrm[v], v);
                let e = [
                    (pose[v].x - x[v][0] as f64) as f32,
                    (pose[v].y - x[v][1] as f64) as f32,
                    (pose[v].z - x[v][2] as f64) as f32,
                ];
                let d = frames::to_local(&fr, e);
                for k in 0..3 {
                    details[(v * t + s) * 3 + k] = d[k] as f64;
                }
            }
        }
        Ok(Examples {
            num_features: fdim,
            num_vertices: n,
            features,
            details,
        })
    }
}

/// `x[v] = x0[v] + Σ_h B[v,h] u_H[h]` in parallel vertex blocks (thesis §5.3 "large-scale kernel").
pub fn large_scale_kernel(
    basis: &ShellBasis,
    rest: &[[f32; 3]],
    uh: &[[f32; 3]],
    x: &mut [[f32; 3]],
) {
    x.par_chunks_mut(BLOCK).enumerate().for_each(|(b, chunk)| {
        basis.apply_rows(uh, b * BLOCK, chunk);
        for (k, o) in chunk.iter_mut().enumerate() {
            let r = rest[b * BLOCK + k];
            *o = [o[0] + r[0], o[1] + r[1], o[2] + r[2]];
        }
    });
}

/// Run-time synthesis (thesis §5.5.2): handle positions → detailed positions and normals.
/// The vertex-major layout ([`RuntimeLayout`], block low-rank basis) and all buffers are built
/// once; a frame is three parallel passes ([`runtime::frame_pass`]: large scale; normal +
/// frame + WPSD detail; normals) and allocates nothing.
#[derive(Debug)]
pub struct Animator<'a> {
    rig: &'a FaceRig,
    model: &'a DetailModel,
    /// The run-time data.
    pub layout: RuntimeLayout,
    /// Final positions of the last frame.
    pub positions: Vec<[f32; 3]>,
    /// Final unit normals of the last frame.
    pub normals: Vec<[f32; 3]>,
    large: Vec<[f32; 3]>,
    work: Vec<[f32; 3]>,
    work_normals: Vec<[f32; 3]>,
    centred: Vec<f32>,
    features: Vec<f64>,
    table: Vec<[f32; runtime::LANES]>,
    global_r: Vec<f32>,
    uh: Vec<[f32; 3]>,
}

impl<'a> Animator<'a> {
    /// Prepare buffers for `rig` with detail `model` and default [`RuntimeSettings`].
    pub fn new(rig: &'a FaceRig, model: &'a DetailModel) -> Result<Self> {
        Self::with_settings(rig, model, &RuntimeSettings::default())
    }

    /// Prepare buffers with explicit run-time settings (basis compression).
    pub fn with_settings(
        rig: &'a FaceRig,
        model: &'a DetailModel,
        settings: &RuntimeSettings,
    ) -> Result<Self> {
        let layout = RuntimeLayout::new(rig, model, settings)?;
        let n = rig.num_vertices();
        let p = model.num_poses();
        Ok(Self {
            rig,
            model,
            layout,
            positions: vec![[0.0; 3]; n],
            normals: vec![[0.0; 3]; n],
            large: vec![[0.0; 3]; n],
            work: vec![[0.0; 3]; n],
            work_normals: vec![[0.0; 3]; n],
            centred: Vec::with_capacity(
                3 * rig.handles.len().div_ceil(runtime::BATCH) * runtime::BATCH,
            ),
            features: vec![0.0; rig.graph.len()],
            table: Vec::with_capacity(rig.graph.len() * p.div_ceil(runtime::LANES)),
            global_r: vec![0.0; p],
            uh: vec![[0.0; 3]; rig.handles.len()],
        })
    }

    /// The rig this animator runs.
    pub fn rig(&self) -> &'a FaceRig {
        self.rig
    }

    /// The detail model this animator evaluates.
    pub fn model(&self) -> &'a DetailModel {
        self.model
    }

    /// Large-scale positions of the last frame (before details), in mesh order.
    pub fn large_scale_positions(&self) -> Vec<[f32; 3]> {
        runtime::to_mesh_order(&self.layout, &self.large)
    }

    /// Synthesize one frame from handle positions (`H` entries).
    pub fn frame(&mut self, handle_positions: &[Vector3<f64>]) -> Result<()> {
        let rig = self.rig;
        let h = rig.handles.len();
        if handle_positions.len() != h {
            return Err(PsdError::SizeMismatch {
                what: "handle positions",
                expected: h,
                got: handle_positions.len(),
            });
        }
        for ((&v, p), u) in rig.handles.iter().zip(handle_positions).zip(&mut self.uh) {
            let d = p - rig.rest[v];
            *u = [d.x as f32, d.y as f32, d.z as f32];
        }
        rig.graph.features(handle_positions, &mut self.features);
        runtime::feature_table(self.model, &self.features, &mut self.table);
        let global = matches!(self.model.metric, Metric::Global);
        if global {
            let nc = self.model.num_poses().div_ceil(runtime::LANES);
            for (j, r) in self.global_r.iter_mut().enumerate() {
                *r = (0..self.model.num_features)
                    .map(|i| self.table[i * nc + j / runtime::LANES][j % runtime::LANES])
                    .sum::<f32>()
                    .sqrt();
            }
        }
        let mean = runtime::centre_handles(&self.uh, &mut self.centred);
        let global_r = global.then_some(&self.global_r[..]);
        // Full-rank layouts are stored in mesh order and write straight into the outputs; the
        // low-rank (permuted) layout runs into its work buffers and is un-permuted after.
        let permuted = self.layout.rank.is_some();
        let (positions, normals) = if permuted {
            (&mut self.work, &mut self.work_normals)
        } else {
            (&mut self.positions, &mut self.normals)
        };
        runtime::frame_pass(
            &self.layout,
            &self.centred,
            mean,
            &self.table,
            global_r,
            &mut self.large,
            positions,
            normals,
        );
        if permuted {
            runtime::to_mesh_order_into(
                &self.layout,
                &self.work,
                &self.work_normals,
                &mut self.positions,
                &mut self.normals,
            );
        }
        Ok(())
    }
}

/// Dense reference synthesis of one frame (thesis §5.5.2, no truncation): `x0 + B·u_H` with the
/// full basis, face → vertex normals, local frames, details (eq. 5.3–5.5), final normals.
/// Returns `(positions, normals)`; used to measure the run-time layout's error.
pub fn reference_frame(
    rig: &FaceRig,
    model: &DetailModel,
    handle_positions: &[Vector3<f64>],
) -> Result<(Vec<[f32; 3]>, Vec<[f32; 3]>)> {
    if handle_positions.len() != rig.handles.len() {
        return Err(PsdError::SizeMismatch {
            what: "handle positions",
            expected: rig.handles.len(),
            got: handle_positions.len(),
        });
    }
    let (large, large_n) = rig.large_scale(handle_positions);
    let d = model.evaluate(&rig.features(handle_positions));
    let x: Vec<[f32; 3]> = (0..large.len())
        .map(|v| {
            let fr = frames::local_frame(&rig.topology, &large, large_n[v], v);
            let w = frames::to_world(&fr, d[v]);
            [large[v][0] + w[0], large[v][1] + w[1], large[v][2] + w[2]]
        })
        .collect();
    let mut fnrm = vec![[0.0f32; 3]; rig.topology.triangles.len()];
    frames::face_normals(&rig.topology, &x, &mut fnrm);
    let mut nrm = vec![[0.0f32; 3]; x.len()];
    frames::vertex_normals(&rig.topology, &fnrm, &mut nrm);
    Ok((x, nrm))
}

/// One level of midpoint (1→4) subdivision; returns the new mesh and, per new vertex, its two
/// parent vertices (equal for old vertices). Used to build the ≈530k-vertex benchmark face.
pub fn subdivide_midpoint(mesh: &TriMesh) -> (TriMesh, Vec<[u32; 2]>) {
    use std::collections::HashMap;
    let mut vertices = mesh.vertices.clone();
    let mut parents: Vec<[u32; 2]> = (0..vertices.len() as u32).map(|v| [v, v]).collect();
    let mut mid: HashMap<(usize, usize), usize> = HashMap::new();
    let mut triangles = Vec::with_capacity(mesh.triangles.len() * 4);
    for t in &mesh.triangles {
        let mut m = [0usize; 3];
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            let key = (a.min(b), a.max(b));
            m[k] = *mid.entry(key).or_insert_with(|| {
                vertices.push(0.5 * (mesh.vertices[a] + mesh.vertices[b]));
                parents.push([key.0 as u32, key.1 as u32]);
                vertices.len() - 1
            });
        }
        triangles.push([t[0], m[0], m[2]]);
        triangles.push([t[1], m[1], m[0]]);
        triangles.push([t[2], m[2], m[1]]);
        triangles.push([m[0], m[1], m[2]]);
    }
    (
        TriMesh {
            vertices,
            triangles,
        },
        parents,
    )
}

/// Refine a rig and its detail model by `levels` midpoint subdivisions (benchmark faces of
/// thesis §5.5.2 size). New rows of `B` and of the RBF weights are the averages of the two
/// parent rows — the barycentric weight interpolation of the transfer (§5.4.4) — instead of a
/// shell solve on the fine mesh; per-frame work is identical. Edge weights (eq. 5.4) are
/// recomputed on the fine rest shape.
pub fn subdivide_rig(
    rig: &FaceRig,
    model: &DetailModel,
    levels: usize,
    edge_settings: &EdgeWeightSettings,
) -> (FaceRig, DetailModel) {
    let mut mesh = TriMesh {
        vertices: rig.rest.clone(),
        triangles: rig
            .topology
            .triangles
            .iter()
            .map(|t| t.map(|v| v as usize))
            .collect(),
    };
    let mut b = rig.basis.weights.clone();
    let mut w = model.weights.clone();
    let h = rig.basis.h;
    let p3 = 3 * model.num_poses();
    for _ in 0..levels {
        let (fine, parents) = subdivide_midpoint(&mesh);
        let avg = |src: &[f32], width: usize| -> Vec<f32> {
            let mut out = vec![0.0f32; parents.len() * width];
            out.par_chunks_mut(width).zip(&parents).for_each(|(o, pa)| {
                let (a, c) = (pa[0] as usize, pa[1] as usize);
                for k in 0..width {
                    o[k] = 0.5 * (src[a * width + k] + src[c * width + k]);
                }
            });
            out
        };
        b = avg(&b, h);
        w = avg(&w, p3);
        mesh = fine;
    }
    let handle_rest: Vec<_> = rig.handles.iter().map(|&v| mesh.vertices[v]).collect();
    let edge_weights = EdgeWeights::new(&mesh.vertices, &handle_rest, &rig.graph, edge_settings);
    let n = mesh.vertices.len();
    let fine_rig = FaceRig {
        rest_f32: mesh
            .vertices
            .iter()
            .map(|p| [p.x as f32, p.y as f32, p.z as f32])
            .collect(),
        topology: Topology::new(n, &mesh.triangles),
        rest: mesh.vertices,
        handles: rig.handles.clone(),
        basis: ShellBasis { n, h, weights: b },
        graph: rig.graph.clone(),
        edge_weights: edge_weights.clone(),
    };
    let metric = match model.metric {
        crate::detail::Metric::Global => crate::detail::Metric::Global,
        crate::detail::Metric::Weighted(_) => crate::detail::Metric::Weighted(edge_weights),
    };
    let fine_model = DetailModel {
        num_features: model.num_features,
        centers: model.centers.clone(),
        weights: w,
        metric,
    };
    (fine_rig, fine_model)
}

/// The same rig and detail model with the vertices stored in `order` (`order[k]` = vertex
/// stored `k`-th, e.g. [`runtime::morton_order`] of the rest positions): positions, triangles,
/// handle ids, shell-basis rows, edge-weight rows and RBF-weight rows renumbered. A locality
/// order applied once when the asset is built (as a renderer orders its vertex buffer): the
/// run-time passes ([`runtime::frame_pass`]) then gather nearby memory, its low-rank blocks are
/// compact surface patches, and no per-frame un-permute is needed (unlike
/// [`RuntimeSettings::reorder`], which keeps the caller's order). Frames are the same up to the
/// renumbering (triangles keep their order, so fans and local frames are identical; the
/// low-rank blocks differ).
pub fn permute_rig(rig: &FaceRig, model: &DetailModel, order: &[u32]) -> (FaceRig, DetailModel) {
    let n = rig.num_vertices();
    assert_eq!(order.len(), n, "one entry per vertex");
    let mut rank = vec![u32::MAX; n];
    for (k, &v) in order.iter().enumerate() {
        rank[v as usize] = k as u32;
    }
    assert!(
        rank.iter().all(|&k| k != u32::MAX),
        "order is a permutation"
    );
    fn rows<T: Copy>(src: &[T], width: usize, order: &[u32]) -> Vec<T> {
        order
            .iter()
            .flat_map(|&v| &src[v as usize * width..(v as usize + 1) * width])
            .copied()
            .collect()
    }
    let triangles: Vec<[usize; 3]> = rig
        .topology
        .triangles
        .iter()
        .map(|t| t.map(|v| rank[v as usize] as usize))
        .collect();
    let ew = &rig.edge_weights;
    let edge_weights = EdgeWeights {
        width: ew.width,
        edges: rows(&ew.edges, ew.width, order),
        alphas: rows(&ew.alphas, ew.width, order),
    };
    let h = rig.basis.h;
    let fine = FaceRig {
        rest: rows(&rig.rest, 1, order),
        rest_f32: rows(&rig.rest_f32, 1, order),
        topology: Topology::new(n, &triangles),
        handles: rig.handles.iter().map(|&v| rank[v] as usize).collect(),
        basis: ShellBasis {
            n,
            h,
            weights: rows(&rig.basis.weights, h, order),
        },
        graph: rig.graph.clone(),
        edge_weights: edge_weights.clone(),
    };
    let p3 = 3 * model.num_poses();
    let metric = match &model.metric {
        Metric::Global => Metric::Global,
        Metric::Weighted(w) => Metric::Weighted(EdgeWeights {
            width: w.width,
            edges: rows(&w.edges, w.width, order),
            alphas: rows(&w.alphas, w.width, order),
        }),
    };
    let permuted = DetailModel {
        num_features: model.num_features,
        centers: model.centers.clone(),
        weights: rows(&model.weights, p3, order),
        metric,
    };
    (fine, permuted)
}
