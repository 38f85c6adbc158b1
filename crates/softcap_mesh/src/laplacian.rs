//! Discrete Laplacians: the cotangent Laplace–Beltrami operator with mixed Voronoi areas
//! (Meyer et al. 2003; thesis eq. 3.4–3.5), its bi-Laplacian, and the umbrella graph Laplacian
//! used to smooth per-element material parameters (bickel2009 eq. 9).
//!
//! Sign conventions. The cotangent *stiffness* matrix `L` has
//!
//! ```text
//! L_ij = ½ (cot α_ij + cot β_ij)   (i ≠ j, edge ij)        thesis eq. 3.5
//! L_ii = −Σ_j L_ij
//! ```
//!
//! so `L` is symmetric negative semidefinite and annihilates constants; `uᵀ(−L)u = ∫|∇u|²`
//! for the piecewise-linear interpolant. The mass matrix `M = diag(A_i)` holds the mixed
//! Voronoi areas, and the normalised operator `Δ = M⁻¹ L` is thesis eq. 3.4 with `w_i = 1/A_i`:
//! `(Δu)_i = (1/A_i) Σ_j w_ij (u_j − u_i)`, which approximates the Laplace–Beltrami operator
//! (`Δ_S Y_l = −l(l+1) Y_l` on the unit sphere).

use crate::error::{MeshError, Result};
use crate::types::TriMesh;
use faer::Par;
use faer::sparse::linalg::matmul::sparse_sparse_matmul;
use faer::sparse::{SparseColMat, SparseColMatRef, Triplet};

/// Builds an `n × m` sparse matrix from triplets, summing duplicates.
pub fn sparse_from_triplets(
    nrows: usize,
    ncols: usize,
    mut entries: Vec<(usize, usize, f64)>,
) -> SparseColMat<usize, f64> {
    entries.sort_unstable_by_key(|&(r, c, _)| (c, r));
    let mut merged: Vec<Triplet<usize, usize, f64>> = Vec::with_capacity(entries.len());
    for (r, c, v) in entries {
        match merged.last_mut() {
            Some(t) if t.row == r && t.col == c => t.val += v,
            _ => merged.push(Triplet::new(r, c, v)),
        }
    }
    SparseColMat::try_new_from_triplets(nrows, ncols, &merged)
        .expect("merged triplets are in range and unique")
}

/// `y = A x` for a sparse column-major matrix.
pub fn sparse_mul_vec(a: SparseColMatRef<'_, usize, f64>, x: &[f64]) -> Vec<f64> {
    assert_eq!(a.ncols(), x.len(), "dimension mismatch");
    let mut y = vec![0.0; a.nrows()];
    let sym = a.symbolic();
    let (rows, vals) = (sym.row_idx(), a.val());
    for j in 0..a.ncols() {
        for k in sym.col_range(j) {
            y[rows[k]] += vals[k] * x[j];
        }
    }
    y
}

/// Cotangent of the angle at `o` in the triangle `(o, p, q)`.
fn cot_at(
    o: &nalgebra::Vector3<f64>,
    p: &nalgebra::Vector3<f64>,
    q: &nalgebra::Vector3<f64>,
) -> f64 {
    let (u, v) = (p - o, q - o);
    u.dot(&v) / u.cross(&v).norm()
}

/// The cotangent stiffness matrix `L` (thesis eq. 3.5): `L_ij = ½(cot α_ij + cot β_ij)`,
/// `L_ii = −Σ_j L_ij`. Symmetric, negative semidefinite, `L·1 = 0`. Boundary edges get the
/// single opposite angle. Degenerate triangles (zero area) contribute nothing.
pub fn cotan_laplacian(mesh: &TriMesh) -> SparseColMat<usize, f64> {
    let n = mesh.vertices.len();
    let mut entries = Vec::with_capacity(mesh.triangles.len() * 12);
    for t in &mesh.triangles {
        let p = t.map(|i| mesh.vertices[i]);
        for k in 0..3 {
            // Angle at corner k is opposite edge (k+1, k+2).
            let (i, j) = (t[(k + 1) % 3], t[(k + 2) % 3]);
            let c = cot_at(&p[k], &p[(k + 1) % 3], &p[(k + 2) % 3]);
            if !c.is_finite() {
                continue;
            }
            let w = 0.5 * c;
            entries.push((i, j, w));
            entries.push((j, i, w));
            entries.push((i, i, -w));
            entries.push((j, j, -w));
        }
    }
    sparse_from_triplets(n, n, entries)
}

/// Mixed Voronoi areas `A_i` (Meyer et al. 2003, §3.3 "A_mixed"; thesis Fig. 3.3).
///
/// For each triangle: if it is non-obtuse, vertex `P` receives its Voronoi region
/// `⅛ Σ |PR|² cot Q` over its two edges `PR` (cot of the angle opposite that edge);
/// if it is obtuse, the obtuse-angle vertex receives half the triangle area and the other two
/// a quarter each. The areas sum to the total surface area.
pub fn voronoi_areas(mesh: &TriMesh) -> Vec<f64> {
    let mut area = vec![0.0; mesh.vertices.len()];
    for t in &mesh.triangles {
        let p = t.map(|i| mesh.vertices[i]);
        let tri_area = 0.5 * (p[1] - p[0]).cross(&(p[2] - p[0])).norm();
        if tri_area == 0.0 || !tri_area.is_finite() {
            continue;
        }
        let dots = [0, 1, 2].map(|k| (p[(k + 1) % 3] - p[k]).dot(&(p[(k + 2) % 3] - p[k])));
        if let Some(obtuse) = (0..3).find(|&k| dots[k] < 0.0) {
            for k in 0..3 {
                area[t[k]] += if k == obtuse { 0.5 } else { 0.25 } * tri_area;
            }
        } else {
            for k in 0..3 {
                // Edge (k, k+1) is opposite corner k+2; edge (k, k+2) is opposite corner k+1.
                let (a, b) = ((k + 1) % 3, (k + 2) % 3);
                let cot_a = dots[a] / (2.0 * tri_area);
                let cot_b = dots[b] / (2.0 * tri_area);
                area[t[k]] += 0.125
                    * ((p[a] - p[k]).norm_squared() * cot_b + (p[b] - p[k]).norm_squared() * cot_a);
            }
        }
    }
    area
}

/// The diagonal mass matrix `M = diag(A_i)` of mixed Voronoi areas.
pub fn mass_matrix(mesh: &TriMesh) -> SparseColMat<usize, f64> {
    let a = voronoi_areas(mesh);
    sparse_from_triplets(
        a.len(),
        a.len(),
        a.iter().enumerate().map(|(i, &v)| (i, i, v)).collect(),
    )
}

/// The cotangent Laplacian split into stiffness `L` and Voronoi areas `A` (diagonal of `M`).
#[derive(Clone, Debug)]
pub struct CotanLaplacian {
    /// Symmetric negative semidefinite stiffness matrix (thesis eq. 3.5).
    pub stiffness: SparseColMat<usize, f64>,
    /// Mixed Voronoi area of each vertex.
    pub areas: Vec<f64>,
}

impl CotanLaplacian {
    /// Assembles `L` and `A` for `mesh`. Fails with [`MeshError::UnusedVertex`] when a vertex has
    /// zero area (unreferenced, or only in degenerate triangles), since `M⁻¹` would not exist.
    pub fn new(mesh: &TriMesh) -> Result<Self> {
        let areas = voronoi_areas(mesh);
        if let Some(v) = areas.iter().position(|a| !(*a > 0.0 && a.is_finite())) {
            return Err(MeshError::UnusedVertex { vertex: v });
        }
        Ok(CotanLaplacian {
            stiffness: cotan_laplacian(mesh),
            areas,
        })
    }

    /// The diagonal mass matrix `M`.
    pub fn mass(&self) -> SparseColMat<usize, f64> {
        let n = self.areas.len();
        sparse_from_triplets(
            n,
            n,
            self.areas
                .iter()
                .enumerate()
                .map(|(i, &a)| (i, i, a))
                .collect(),
        )
    }

    /// The normalised Laplace–Beltrami operator `Δ = M⁻¹ L` (thesis eq. 3.4, `w_i = 1/A_i`).
    /// Not symmetric.
    pub fn normalized(&self) -> SparseColMat<usize, f64> {
        let l = self.stiffness.as_ref();
        let sym = l.symbolic();
        let mut entries = Vec::with_capacity(l.val().len());
        for j in 0..l.ncols() {
            for k in sym.col_range(j) {
                let i = sym.row_idx()[k];
                entries.push((i, j, l.val()[k] / self.areas[i]));
            }
        }
        sparse_from_triplets(l.nrows(), l.ncols(), entries)
    }

    /// Applies `Δ = M⁻¹ L` to a per-vertex scalar field.
    pub fn apply(&self, u: &[f64]) -> Vec<f64> {
        let mut y = sparse_mul_vec(self.stiffness.as_ref(), u);
        for (y, a) in y.iter_mut().zip(&self.areas) {
            *y /= a;
        }
        y
    }

    /// The bi-Laplacian `L M⁻¹ L` (symmetric positive semidefinite): the discrete bending
    /// energy matrix, `uᵀ L M⁻¹ L u ≈ ∫ (Δu)²` (thesis eq. 3.2–3.3, 5.1).
    pub fn bilaplacian(&self) -> SparseColMat<usize, f64> {
        let l = self.stiffness.as_ref();
        let sym = l.symbolic();
        // B = L M⁻¹ (scale column j by 1/A_j).
        let mut entries = Vec::with_capacity(l.val().len());
        for j in 0..l.ncols() {
            for k in sym.col_range(j) {
                entries.push((sym.row_idx()[k], j, l.val()[k] / self.areas[j]));
            }
        }
        let b = sparse_from_triplets(l.nrows(), l.ncols(), entries);
        sparse_sparse_matmul(b.as_ref(), l, 1.0, Par::Seq).expect("sparse product fits in memory")
    }
}

/// The umbrella graph Laplacian of bickel2009 §4.1 (eq. 9 regulariser `γ‖Lp‖²`):
/// `(Lp)_i = Σ_j w_ij (p_i − p_j)` with `w_ij = 1` for each neighbour `j` listed in
/// `adjacency[i]` — i.e. `L = D − W`, symmetric positive semidefinite for a symmetric
/// adjacency, `L·1 = 0`. For bickel2009, pass
/// [`tet_vertex_adjacency`](crate::adjacency::tet_vertex_adjacency) (tets sharing a vertex);
/// [`tet_face_adjacency`](crate::adjacency::tet_face_adjacency) gives the sparser face graph.
pub fn umbrella_laplacian(adjacency: &[Vec<usize>]) -> SparseColMat<usize, f64> {
    let n = adjacency.len();
    let mut entries = Vec::with_capacity(adjacency.iter().map(|a| a.len() + 1).sum());
    for (i, nb) in adjacency.iter().enumerate() {
        entries.push((i, i, nb.len() as f64));
        for &j in nb {
            entries.push((i, j, -1.0));
        }
    }
    sparse_from_triplets(n, n, entries)
}
