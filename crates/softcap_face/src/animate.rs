//! Large-scale animation (thesis §3.2.1): the marker displacements u_{i,t} of the
//! correspondence (§4.2.1) drive the bi-Laplacian linear shell −k_s Δu + k_b Δ²u = 0
//! (thesis eq. 3.3; k_s = 1, k_b = 100, cotangent Laplacian with Voronoi areas, eq. 3.4–3.5),
//! solved by softcap_mesh's [`LinearShell`]: one sparse Cholesky factorization, one
//! substitution per frame.
//!
//! The cotangent matrix and mixed Voronoi areas (Meyer et al. 2003) are assembled here
//! because softcap_mesh's Laplacian module had not landed when this stage was built; the lead
//! will deduplicate them.

use faer::sparse::{SparseColMat, Triplet};
use nalgebra::Vector3;
use softcap_mesh::TriMesh;
use softcap_mesh::shell::{LinearShell, ShellSettings};

use crate::correspondence::Correspondence;
use crate::error::{FaceError, Result};

/// A face scan rigged to mocap markers.
pub struct FaceAnimator {
    /// The neutral face F.
    pub mesh: TriMesh,
    /// Handle vertices, one per marker (marker order).
    pub handles: Vec<usize>,
    /// The space warp c.
    pub correspondence: Correspondence,
    shell: LinearShell,
}

impl FaceAnimator {
    /// Fit the correspondence from the neutral mocap frame to the handle vertices and factor
    /// the shell.
    pub fn new(
        mesh: TriMesh,
        handles: Vec<usize>,
        mocap_neutral: &[Vector3<f64>],
        settings: &ShellSettings,
    ) -> Result<Self> {
        if let Some(&h) = handles.iter().find(|&&h| h >= mesh.vertices.len()) {
            return Err(FaceError::InvalidInput {
                what: "handles",
                reason: format!("vertex {h} out of range"),
            });
        }
        let face_points: Vec<Vector3<f64>> = handles.iter().map(|&h| mesh.vertices[h]).collect();
        let correspondence = Correspondence::fit(mocap_neutral, &face_points)?;
        let shell = factor_shell(&mesh, &handles, settings)?;
        Ok(Self {
            mesh,
            handles,
            correspondence,
            shell,
        })
    }

    /// Deformed vertex positions for one mocap frame (thesis eq. 3.1: the shell interpolates
    /// u_{i,t} at the handles).
    pub fn frame(&self, mocap_frame: &[Vector3<f64>]) -> Result<Vec<Vector3<f64>>> {
        let u_h = self.correspondence.displacements(mocap_frame)?;
        let u = self
            .shell
            .solve(&u_h)
            .map_err(|e| FaceError::Factorization {
                what: "linear shell",
                reason: e.to_string(),
            })?;
        Ok(self
            .mesh
            .vertices
            .iter()
            .zip(&u)
            .map(|(x, d)| x + d)
            .collect())
    }
}

/// Assemble and factor the linear shell of `mesh` with the given handles (thesis eq. 3.3).
pub fn factor_shell(
    mesh: &TriMesh,
    handles: &[usize],
    settings: &ShellSettings,
) -> Result<LinearShell> {
    let l = cotan_laplacian(mesh);
    let areas = voronoi_areas(mesh);
    LinearShell::new(l.as_ref(), &areas, handles, settings).map_err(|e| FaceError::Factorization {
        what: "linear shell",
        reason: e.to_string(),
    })
}

/// Symmetric cotangent matrix L_ij = ½(cot α_ij + cot β_ij), L_ii = −Σ_j L_ij (thesis eq. 3.5).
pub fn cotan_laplacian(mesh: &TriMesh) -> SparseColMat<usize, f64> {
    let n = mesh.vertices.len();
    let mut trip = Vec::with_capacity(mesh.triangles.len() * 12);
    for t in &mesh.triangles {
        for k in 0..3 {
            let (i, j, o) = (t[(k + 1) % 3], t[(k + 2) % 3], t[k]);
            let (a, b) = (
                mesh.vertices[i] - mesh.vertices[o],
                mesh.vertices[j] - mesh.vertices[o],
            );
            let cot = a.dot(&b) / a.cross(&b).norm().max(1e-300);
            let w = 0.5 * cot;
            trip.push(Triplet::new(i, j, w));
            trip.push(Triplet::new(j, i, w));
            trip.push(Triplet::new(i, i, -w));
            trip.push(Triplet::new(j, j, -w));
        }
    }
    SparseColMat::try_new_from_triplets(n, n, &trip).expect("triplet indices are in range")
}

/// Mixed Voronoi vertex areas A_i of Meyer et al. 2003 (obtuse triangles split ½/¼/¼).
pub fn voronoi_areas(mesh: &TriMesh) -> Vec<f64> {
    let mut area = vec![0.0; mesh.vertices.len()];
    for t in &mesh.triangles {
        let p = t.map(|i| mesh.vertices[i]);
        let tri = 0.5 * (p[1] - p[0]).cross(&(p[2] - p[0])).norm();
        if tri <= 0.0 {
            continue;
        }
        let obtuse = (0..3).find(|&k| (p[(k + 1) % 3] - p[k]).dot(&(p[(k + 2) % 3] - p[k])) < 0.0);
        match obtuse {
            Some(k) => {
                for m in 0..3 {
                    area[t[m]] += if m == k { 0.5 * tri } else { 0.25 * tri };
                }
            }
            None => {
                for k in 0..3 {
                    let (i, j, o) = (t[(k + 1) % 3], t[(k + 2) % 3], k);
                    let (a, b) = (p[(k + 1) % 3] - p[o], p[(k + 2) % 3] - p[o]);
                    let cot = a.dot(&b) / a.cross(&b).norm();
                    let e2 = (mesh.vertices[i] - mesh.vertices[j]).norm_squared();
                    area[i] += cot * e2 / 8.0;
                    area[j] += cot * e2 / 8.0;
                }
            }
        }
    }
    area
}
