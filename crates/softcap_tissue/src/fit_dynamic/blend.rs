//! Material control points and their blending weights (wang2015 §6.2): E_e = Σ_c w_ec E_c, the
//! weights of each tet summing to one. Two weightings, as in the paper:
//!
//! * **linear** (its taro plant): control points along the body's principal axis, hat functions
//!   of the normalised axial coordinate between neighbouring control points;
//! * **harmonic** (its dinosaur): w_c solves the graph Laplace equation L w_c = 0 on the mesh's
//!   node graph (the umbrella Laplacian) with w_c = 1 at control point c's node and 0 at the
//!   others; a tet's weight is the mean of its nodes'.

use faer::linalg::solvers::Solve;
use faer::sparse::{SparseColMat, Triplet};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use softcap_mesh::TetMesh;

use crate::error::{Result, TissueError};

/// How the control-point values are blended over the tets.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Blending {
    /// Hat functions of the axial coordinate (control points along the principal axis).
    Linear,
    /// Harmonic coordinates on the node graph.
    Harmonic,
}

/// Control points and per-tet weights.
#[derive(Clone, Debug, PartialEq)]
pub struct ControlPoints {
    /// Positions, m.
    pub positions_m: Vec<Vector3<f64>>,
    /// Per tet, one weight per control point (each row sums to 1).
    pub weights: Vec<Vec<f64>>,
}

impl ControlPoints {
    /// Number of control points.
    pub fn len(&self) -> usize {
        self.positions_m.len()
    }

    /// True when there are none.
    pub fn is_empty(&self) -> bool {
        self.positions_m.is_empty()
    }

    /// E per tet from E per control point.
    pub fn blend(&self, values: &[f64]) -> Vec<f64> {
        self.weights
            .iter()
            .map(|w| w.iter().zip(values).map(|(a, b)| a * b).sum())
            .collect()
    }
}

/// Principal axis (largest-variance direction) and centroid of the free nodes, and the axial
/// range, oriented from the support towards the far end when there is a support.
fn principal_axis(mesh: &TetMesh, support: &[usize]) -> (Vector3<f64>, Vector3<f64>) {
    let n = mesh.vertices.len() as f64;
    let c = mesh.vertices.iter().sum::<Vector3<f64>>() / n;
    let mut cov = nalgebra::Matrix3::zeros();
    for v in &mesh.vertices {
        let d = v - c;
        cov += d * d.transpose();
    }
    let eig = cov.symmetric_eigen();
    let imax = eig.eigenvalues.imax();
    let mut axis: Vector3<f64> = eig.eigenvectors.column(imax).into_owned();
    if !support.is_empty() {
        let s = support
            .iter()
            .map(|&i| mesh.vertices[i])
            .sum::<Vector3<f64>>()
            / support.len() as f64;
        if (s - c).dot(&axis) > 0.0 {
            axis = -axis;
        }
    } else if axis
        .iter()
        .cloned()
        .fold(0.0, |a: f64, b| if b.abs() > a.abs() { b } else { a })
        < 0.0
    {
        axis = -axis;
    }
    (c, axis)
}

/// `count` control points blended by `blending` (module docs). Control points sit on the
/// principal axis at evenly spaced axial coordinates from one end of the body to the other (one
/// control point: homogeneous, weight 1 everywhere).
pub fn control_points(
    mesh: &TetMesh,
    support: &[usize],
    count: usize,
    blending: Blending,
) -> Result<ControlPoints> {
    if count == 0 {
        return Err(TissueError::BadSettings {
            field: "control_points".into(),
            problem: "need at least one control point".into(),
        });
    }
    let (c, axis) = principal_axis(mesh, support);
    let s: Vec<f64> = mesh.vertices.iter().map(|v| (v - c).dot(&axis)).collect();
    let (s0, s1) = s
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
            (a.min(v), b.max(v))
        });
    let at: Vec<f64> = (0..count)
        .map(|i| {
            if count == 1 {
                0.5 * (s0 + s1)
            } else {
                s0 + (s1 - s0) * i as f64 / (count - 1) as f64
            }
        })
        .collect();
    // A control point's position: the mean of the nodes in its axial slab (on the body).
    let slab = (s1 - s0) / (2.0 * count as f64);
    let positions_m: Vec<Vector3<f64>> = at
        .iter()
        .map(|&a| {
            let near: Vec<&Vector3<f64>> = mesh
                .vertices
                .iter()
                .zip(&s)
                .filter(|(_, si)| (**si - a).abs() <= slab)
                .map(|(v, _)| v)
                .collect();
            if near.is_empty() {
                c + axis * a
            } else {
                near.iter().copied().sum::<Vector3<f64>>() / near.len() as f64
            }
        })
        .collect();
    let node_weights = match (count, blending) {
        (1, _) => vec![vec![1.0]; mesh.vertices.len()],
        (_, Blending::Linear) => s.iter().map(|&si| hat_weights(&at, si)).collect(),
        (_, Blending::Harmonic) => harmonic_weights(mesh, &positions_m)?,
    };
    let weights = mesh
        .tets
        .iter()
        .map(|t| {
            (0..count)
                .map(|k| t.iter().map(|&i| node_weights[i][k]).sum::<f64>() / 4.0)
                .collect()
        })
        .collect();
    Ok(ControlPoints {
        positions_m,
        weights,
    })
}

/// Piecewise-linear interpolation weights of `s` between the sorted knots `at` (clamped).
fn hat_weights(at: &[f64], s: f64) -> Vec<f64> {
    let mut w = vec![0.0; at.len()];
    if s <= at[0] {
        w[0] = 1.0;
        return w;
    }
    let last = at.len() - 1;
    if s >= at[last] {
        w[last] = 1.0;
        return w;
    }
    let k = at.windows(2).position(|p| s <= p[1]).unwrap_or(last - 1);
    let t = (s - at[k]) / (at[k + 1] - at[k]);
    w[k] = 1.0 - t;
    w[k + 1] = t;
    w
}

/// Harmonic coordinates on the node graph: for every control point c, L w = 0 on the nodes that
/// are not control nodes, w = δ_c on the control nodes (one sparse LU of the reduced Laplacian,
/// all right-hand sides at once).
fn harmonic_weights(mesh: &TetMesh, positions: &[Vector3<f64>]) -> Result<Vec<Vec<f64>>> {
    let n = mesh.vertices.len();
    let anchors: Vec<usize> = positions
        .iter()
        .map(|p| {
            (0..n)
                .min_by(|&a, &b| {
                    (mesh.vertices[a] - p)
                        .norm_squared()
                        .total_cmp(&(mesh.vertices[b] - p).norm_squared())
                })
                .unwrap_or(0)
        })
        .collect();
    let mut sorted = anchors.clone();
    sorted.sort_unstable();
    sorted.dedup();
    if sorted.len() != anchors.len() {
        return Err(TissueError::BadSettings {
            field: "control_points".into(),
            problem: format!(
                "{} control points on a mesh this coarse share nodes",
                anchors.len()
            ),
        });
    }
    let adjacency = softcap_mesh::adjacency::vertex_vertices(n, &mesh.tets);
    let mut free_index = vec![usize::MAX; n];
    let mut free = Vec::new();
    for i in 0..n {
        if !anchors.contains(&i) {
            free_index[i] = free.len();
            free.push(i);
        }
    }
    let nf = free.len();
    let k = anchors.len();
    let mut triplets = Vec::new();
    let mut rhs = faer::Mat::<f64>::zeros(nf, k);
    for (fi, &i) in free.iter().enumerate() {
        triplets.push(Triplet::new(fi, fi, adjacency[i].len() as f64));
        for &j in &adjacency[i] {
            if free_index[j] != usize::MAX {
                triplets.push(Triplet::new(fi, free_index[j], -1.0));
            } else if let Some(c) = anchors.iter().position(|&a| a == j) {
                rhs[(fi, c)] += 1.0;
            }
        }
    }
    let lu = SparseColMat::<usize, f64>::try_new_from_triplets(nf, nf, &triplets)
        .map_err(|e| format!("{e:?}"))
        .and_then(|a| a.sp_lu().map_err(|e| format!("{e:?}")))
        .map_err(|reason| TissueError::NotConverged {
            what: "harmonic control-point weights".into(),
            status: reason,
        })?;
    lu.solve_in_place(rhs.as_mut());
    let mut w = vec![vec![0.0; k]; n];
    for (c, &a) in anchors.iter().enumerate() {
        w[a][c] = 1.0;
    }
    for (fi, &i) in free.iter().enumerate() {
        let row: Vec<f64> = (0..k).map(|c| rhs[(fi, c)].max(0.0)).collect();
        let sum: f64 = row.iter().sum();
        w[i] = row.iter().map(|v| v / sum.max(f64::MIN_POSITIVE)).collect();
    }
    Ok(w)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weights_are_a_partition_of_unity_and_one_at_their_control_point() {
        let mesh =
            softcap_mesh::box_tet_mesh([0.0, -0.015, -0.015], [0.2, 0.015, 0.015], [12, 2, 2]);
        let support: Vec<usize> = (0..mesh.vertices.len())
            .filter(|&i| mesh.vertices[i].x < 1e-9)
            .collect();
        for blending in [Blending::Linear, Blending::Harmonic] {
            let cp = control_points(&mesh, &support, 4, blending).unwrap();
            assert_eq!(cp.len(), 4);
            // The first control point is at the support end.
            assert!(cp.positions_m[0].x < cp.positions_m[3].x);
            for w in &cp.weights {
                assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-12);
                assert!(w.iter().all(|v| *v >= 0.0));
            }
            let e = cp.blend(&[1.0, 2.0, 3.0, 4.0]);
            // Blended E grows from the clamp to the tip.
            let first = e[0];
            let tip = e
                .iter()
                .zip(&mesh.tets)
                .filter(|(_, t)| t.iter().all(|&i| mesh.vertices[i].x > 0.18))
                .map(|(v, _)| *v)
                .next()
                .unwrap();
            assert!(first < 1.6 && tip > 3.4, "{blending:?}: {first} {tip}");
        }
    }
}
