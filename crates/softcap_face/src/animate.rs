//! Large-scale animation (thesis §3.2.1): the marker displacements u_{i,t} of the
//! correspondence (§4.2.1) drive the bi-Laplacian linear shell −k_s Δu + k_b Δ²u = 0
//! (thesis eq. 3.3; k_s = 1, k_b = 100, cotangent Laplacian with Voronoi areas, eq. 3.4–3.5),
//! solved by softcap_mesh's [`LinearShell`]: one sparse Cholesky factorization, one
//! substitution per frame.

use nalgebra::Vector3;
use softcap_mesh::TriMesh;
use softcap_mesh::laplacian::{cotan_laplacian, voronoi_areas};
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
