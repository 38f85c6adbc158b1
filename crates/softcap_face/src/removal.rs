//! Wrinkle removal preprocess (thesis §3.3.2): wrinkles already present in the relaxed-pose
//! scan are removed by a three-step multi-scale smoothing of a wrinkle region so that the
//! synthesis of §3.3.1 does not amplify them:
//!
//! 1. fine-scale details are split off by a small amount of (umbrella) Laplacian smoothing
//!    (Desbrun et al. 1999) and stored as local-frame displacements (Kobbelt et al. 1999);
//! 2. the medium-scale wrinkles are removed by the steady state of bi-Laplacian smoothing, i.e.
//!    one bi-Laplacian linear system Δ²x = 0 on the region with every other vertex fixed
//!    (softcap_mesh [`LinearShell`] with k_s = 0, cotangent weights of the step-1 surface) —
//!    the patch blends tangent-continuously into the fixed surroundings;
//! 3. the details are added back in the local frames of the smooth patch.

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use softcap_mesh::TriMesh;
use softcap_mesh::laplacian::{cotan_laplacian, voronoi_areas};
use softcap_mesh::shell::{LinearShell, ShellSettings};

use crate::error::{FaceError, Result};
use crate::raster::vertex_normals;

/// Settings of [`remove_wrinkles`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RemovalSettings {
    /// Umbrella-smoothing passes that split off the fine-scale details (step 1).
    pub detail_smoothing_passes: usize,
    /// Step size λ of each pass, x ← x + λ (mean of neighbours − x).
    pub detail_smoothing_step: f64,
}

impl Default for RemovalSettings {
    fn default() -> Self {
        Self {
            detail_smoothing_passes: 2,
            detail_smoothing_step: 0.5,
        }
    }
}

fn one_rings(n: usize, triangles: &[[usize; 3]]) -> Vec<Vec<usize>> {
    let mut r = vec![Vec::new(); n];
    for t in triangles {
        for k in 0..3 {
            r[t[k]].push(t[(k + 1) % 3]);
            r[t[k]].push(t[(k + 2) % 3]);
        }
    }
    for v in &mut r {
        v.sort_unstable();
        v.dedup();
    }
    r
}

/// Orthonormal local frame (t1, t2, n) at `v` of surface `x`: n the vertex normal, t1 towards
/// the first one-ring neighbour projected into the tangent plane.
fn frame(
    x: &[Vector3<f64>],
    normals: &[Vector3<f64>],
    rings: &[Vec<usize>],
    v: usize,
) -> [Vector3<f64>; 3] {
    let n = normals[v];
    let e = x[rings[v][0]] - x[v];
    let t1 = (e - n * n.dot(&e)).normalize();
    [t1, n.cross(&t1), n]
}

/// Remove medium-scale wrinkles from the vertices in `region` of `mesh` (thesis §3.3.2),
/// keeping the rest of the mesh fixed. Returns the new vertex positions.
pub fn remove_wrinkles(
    mesh: &TriMesh,
    region: &[usize],
    settings: &RemovalSettings,
) -> Result<Vec<Vector3<f64>>> {
    let n = mesh.vertices.len();
    let mut in_region = vec![false; n];
    for &v in region {
        if v >= n {
            return Err(FaceError::InvalidInput {
                what: "wrinkle region",
                reason: format!("vertex {v} out of range ({n} vertices)"),
            });
        }
        in_region[v] = true;
    }
    if !(settings.detail_smoothing_step > 0.0 && settings.detail_smoothing_step <= 1.0) {
        return Err(FaceError::InvalidSetting {
            field: "detail_smoothing_step",
            reason: format!("{} is not in (0, 1]", settings.detail_smoothing_step),
        });
    }
    if let Some(t) = mesh
        .triangles
        .iter()
        .position(|t| t.iter().any(|&v| v >= n))
    {
        return Err(FaceError::InvalidInput {
            what: "mesh",
            reason: format!("triangle {t} references a vertex ≥ {n}"),
        });
    }
    let rings = one_rings(n, &mesh.triangles);
    if let Some(&v) = region.iter().find(|&&v| rings[v].is_empty()) {
        return Err(FaceError::InvalidInput {
            what: "wrinkle region",
            reason: format!("vertex {v} belongs to no triangle"),
        });
    }
    // 1. fine-scale details by a little umbrella smoothing, as local-frame displacements
    let mut s = mesh.vertices.clone();
    for _ in 0..settings.detail_smoothing_passes {
        let prev = s.clone();
        for &v in region {
            let mean =
                rings[v].iter().fold(Vector3::zeros(), |a, &j| a + prev[j]) / rings[v].len() as f64;
            s[v] = prev[v] + (mean - prev[v]) * settings.detail_smoothing_step;
        }
    }
    let s_normals = vertex_normals(&s, &mesh.triangles);
    let details: Vec<(usize, Vector3<f64>)> = region
        .iter()
        .map(|&v| {
            let f = frame(&s, &s_normals, &rings, v);
            let d = mesh.vertices[v] - s[v];
            (v, Vector3::new(f[0].dot(&d), f[1].dot(&d), f[2].dot(&d)))
        })
        .collect();
    // 2. bi-Laplacian patch with the outside fixed: positions solve Δ²x = 0 on the region
    let smooth_mesh = TriMesh {
        vertices: s,
        triangles: mesh.triangles.clone(),
    };
    let handles: Vec<usize> = (0..n).filter(|&v| !in_region[v]).collect();
    let shell = LinearShell::new(
        cotan_laplacian(&smooth_mesh).as_ref(),
        &voronoi_areas(&smooth_mesh),
        &handles,
        &ShellSettings { k_s: 0.0, k_b: 1.0 },
    )
    .map_err(|e| FaceError::Factorization {
        what: "wrinkle-removal bi-Laplacian",
        reason: e.to_string(),
    })?;
    let fixed: Vec<Vector3<f64>> = handles.iter().map(|&v| mesh.vertices[v]).collect();
    let mut out = shell.solve(&fixed).map_err(|e| FaceError::Factorization {
        what: "wrinkle-removal bi-Laplacian",
        reason: e.to_string(),
    })?;
    // 3. details back in the frames of the smooth patch
    let b_normals = vertex_normals(&out, &mesh.triangles);
    let base = out.clone();
    for (v, d) in details {
        let f = frame(&base, &b_normals, &rings, v);
        out[v] = base[v] + f[0] * d.x + f[1] * d.y + f[2] * d.z;
    }
    Ok(out)
}
