//! Large-scale animation (thesis §3.2.1): the marker displacements u_{i,t} of the
//! correspondence (§4.2.1) drive the bi-Laplacian linear shell −k_s Δu + k_b Δ²u = 0
//! (thesis eq. 3.3; k_s = 1, k_b = 100, cotangent Laplacian with Voronoi areas, eq. 3.4–3.5),
//! solved by softcap_mesh's [`LinearShell`]: one sparse Cholesky factorization, one
//! substitution per frame.

use nalgebra::Vector3;
use rayon::prelude::*;
use softcap_mesh::TriMesh;
use softcap_mesh::shell::{LinearShell, ShellBasis, ShellSettings};

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
    /// B = −A_FF⁻¹ A_FH (f32, thesis §5.3) once [`FaceAnimator::precompute_basis`] ran.
    basis: Option<ShellBasis>,
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
        let mut sorted = handles.clone();
        sorted.sort_unstable();
        if let Some(w) = sorted.windows(2).find(|w| w[0] == w[1]) {
            return Err(FaceError::InvalidInput {
                what: "handles",
                reason: format!("vertex {} is the handle of two markers", w[0]),
            });
        }
        let face_points: Vec<Vector3<f64>> = handles.iter().map(|&h| mesh.vertices[h]).collect();
        // the neutral mocap frame comes from the user's take: a degenerate marker layout is bad
        // input, not a failure of the stage
        let correspondence =
            Correspondence::fit(mocap_neutral, &face_points).map_err(|e| match e {
                FaceError::Core(reason) => FaceError::InvalidInput {
                    what: "neutral mocap frame (correspondence r³ warp)",
                    reason,
                },
                other => other,
            })?;
        let shell = factor_shell(&mesh, &handles, settings)?;
        Ok(Self {
            mesh,
            handles,
            correspondence,
            shell,
            basis: None,
        })
    }

    /// Precompute the shell basis B = −A_FF⁻¹ A_FH (thesis §5.3: u = B u_H) so that every later
    /// [`FaceAnimator::frame`] is one dense n × H product instead of two triangular solves with
    /// the factor. The shell acts on x, y and z alike, so B has one column per handle
    /// ([`LinearShell::basis`]: all H = 41 columns of the marker handles in one block solve, one
    /// pass over the factor). B is stored in f32 (n × H × 4 bytes): its entries are O(1) and
    /// rows sum to 1, so a frame is accurate to ~1e-7 of the handle displacement; handles
    /// themselves are set exactly.
    pub fn precompute_basis(&mut self) -> Result<()> {
        self.basis = Some(self.shell.basis());
        Ok(())
    }

    /// Whether frames use the precomputed basis.
    pub fn has_basis(&self) -> bool {
        self.basis.is_some()
    }

    /// Deformed vertex positions for one mocap frame (thesis eq. 3.1: the shell interpolates
    /// u_{i,t} at the handles).
    pub fn frame(&self, mocap_frame: &[Vector3<f64>]) -> Result<Vec<Vector3<f64>>> {
        let u_h = self.correspondence.displacements(mocap_frame)?;
        if let Some(basis) = &self.basis {
            const BLOCK: usize = 4096;
            let u32: Vec<[f32; 3]> = u_h
                .iter()
                .map(|u| [u.x as f32, u.y as f32, u.z as f32])
                .collect();
            let mut u = vec![[0.0f32; 3]; basis.n];
            u.par_chunks_mut(BLOCK)
                .enumerate()
                .for_each(|(k, out)| basis.apply_rows(&u32, k * BLOCK, out));
            let mut x: Vec<Vector3<f64>> = self
                .mesh
                .vertices
                .iter()
                .zip(&u)
                .map(|(x, d)| x + Vector3::new(d[0] as f64, d[1] as f64, d[2] as f64))
                .collect();
            for (&v, d) in self.handles.iter().zip(&u_h) {
                x[v] = self.mesh.vertices[v] + d;
            }
            return Ok(x);
        }
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

/// Assemble and factor the linear shell of `mesh` with the given handles (thesis eq. 3.3;
/// [`LinearShell::from_mesh`]: cotangent Laplacian, Voronoi areas, nested-dissection order).
pub fn factor_shell(
    mesh: &TriMesh,
    handles: &[usize],
    settings: &ShellSettings,
) -> Result<LinearShell> {
    LinearShell::from_mesh(mesh, handles, settings).map_err(|e| FaceError::Factorization {
        what: "linear shell",
        reason: e.to_string(),
    })
}

/// One midpoint subdivision of a triangle mesh carrying several vertex fields with the same
/// topology (e.g. the rest face and a deformed frame): every triangle becomes four, every edge
/// gets its midpoint, and original vertices keep their indices (so marker handles stay valid).
/// Returns the new triangles and the subdivided fields. Used to build the ≈600k-vertex face of
/// the benches (the thesis's scans have ≈700k vertices, §4.4.1).
///
/// Triangles referencing a vertex outside a field are an error.
pub fn subdivide_midpoint(
    triangles: &[[usize; 3]],
    fields: &[&[Vector3<f64>]],
) -> Result<(Vec<[usize; 3]>, Vec<Vec<Vector3<f64>>>)> {
    let n = fields.iter().map(|f| f.len()).min().unwrap_or(0);
    if let Some(f) = fields.iter().find(|f| f.len() != n) {
        return Err(FaceError::InvalidInput {
            what: "subdivision fields",
            reason: format!("fields of {} and {n} vertices", f.len()),
        });
    }
    if let Some(t) = triangles.iter().position(|t| t.iter().any(|&v| v >= n)) {
        return Err(FaceError::InvalidInput {
            what: "subdivision triangles",
            reason: format!("triangle {t} references a vertex ≥ {n}"),
        });
    }
    let mut out: Vec<Vec<Vector3<f64>>> = fields.iter().map(|f| f.to_vec()).collect();
    let mut mid = std::collections::HashMap::new();
    let mut tris = Vec::with_capacity(4 * triangles.len());
    for t in triangles {
        let mut m = [0usize; 3];
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            let next = n + mid.len();
            m[k] = *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                for (o, f) in out.iter_mut().zip(fields) {
                    o.push((f[a] + f[b]) * 0.5);
                }
                next
            });
        }
        tris.push([t[0], m[0], m[2]]);
        tris.push([t[1], m[1], m[0]]);
        tris.push([t[2], m[2], m[1]]);
        tris.push(m);
    }
    Ok((tris, out))
}
